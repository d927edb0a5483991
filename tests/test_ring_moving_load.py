"""Tests of the ring under random moving loads (thesis ch. 6): load transfer, validation, dtypes, Monte Carlo
against the recursion, gradients against finite differences, CLI. A 12-element ring keeps them small."""

import argparse
import json
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _outputs import assert_readme_lists_every_file

import pgtjax as pg
from pgtjax._summary import missing_units
from pgtjax.cli import ring as cli_ring
from pgtjax.models import ring_moving_load as rml
from pgtjax.models.ring import RingParams
from pgtjax.studies import ring_moving_load as rml_study


def _small(**kw):
    return rml.default_params(n_elements=12).replace(**kw)


def _rigid(ring: RingParams, d):
    """Nodal DOFs of a rigid translation d = (dx, dy) [m] and of a unit rigid rotation (u_r inward)."""
    th = 2 * np.pi * np.arange(ring.n_elements) / ring.n_elements
    trans = np.stack(
        [-(d[0] * np.cos(th) + d[1] * np.sin(th)), -d[0] * np.sin(th) + d[1] * np.cos(th), np.zeros_like(th)],
        axis=1,
    ).ravel()
    rot = np.stack(
        [np.zeros_like(th), float(ring.radius) * np.ones_like(th), np.ones_like(th)], axis=1
    ).ravel()
    return trans, rot


def test_load_transfer_is_work_equivalent():
    p = _small(carrier_speed=7.3, initial_angle=0.4)
    loads = rml.MovingLoads(p)
    alpha = float(p.pressure_angle)
    for t in (0.0, 0.0371, 0.2):
        f = np.asarray(loads.nodal_forces(t))
        th = np.asarray(loads.angles(t))
        fn = np.asarray(loads.deterministic_forces(t))
        f_r, f_tau = -fn * np.sin(alpha), -fn * np.cos(alpha)  # Eqs. 6.13-6.14, radial positive inward
        # global force of each load: f_r along -e_r (inward), f_tau along e_theta
        fx = np.sum(-f_r * np.cos(th) - f_tau * np.sin(th))
        fy = np.sum(-f_r * np.sin(th) + f_tau * np.cos(th))
        for d, expected in (((1.0, 0.0), fx), ((0.0, 1.0), fy)):
            trans, rot = _rigid(p.ring, d)
            np.testing.assert_allclose(f @ trans, expected, rtol=1e-10, atol=1e-9 * np.abs(fn).sum())
        _, rot = _rigid(p.ring, (0.0, 0.0))
        np.testing.assert_allclose(f @ rot, float(p.ring.radius) * np.sum(f_tau), rtol=1e-10)
        # noise input: column n is b_n times the unit load vector of load n
        b = np.asarray(loads.noise_matrix(t))
        trans, _ = _rigid(p.ring, (1.0, 0.0))
        unit_fx = -(-np.sin(alpha)) * np.cos(th) - (-np.cos(alpha)) * np.sin(th)
        np.testing.assert_allclose(
            b.T @ trans, np.asarray(p.noise_intensity) * unit_fx, rtol=1e-10, atol=1e-6
        )


def test_validation_errors():
    ring = rml.default_params(n_elements=12).ring
    cases = [
        (dict(carrier_speed=-1.0), "carrier_speed"),
        (dict(pressure_angle=2.0), "pressure_angle"),
        (dict(force_amplitude=-5.0), "force_amplitude"),
        (dict(noise_intensity=[1.0, 2.0]), "noise_intensity"),
        (dict(n_loads=0), "n_loads"),
        (dict(rayleigh_stiffness=-1e-6), "rayleigh_stiffness"),
        (dict(modal_damping_ratio=-0.1), "modal_damping_ratio"),
        (dict(mean_force=float("nan")), "mean_force"),
    ]
    for kw, name in cases:
        with pytest.raises(ValueError, match=name):
            rml.RingMovingLoadParams(ring, **kw)
    with pytest.raises(ValueError, match="n_modes"):
        rml.ring_moving_load_system(_small(), n_modes=0)
    with pytest.raises(ValueError, match="does not exist"):
        rml.load_params("/nonexistent/ring.toml")
    with pytest.raises(ValueError, match="multiple of `n_bolts`"):
        rml.load_params(None, n_elements=10)
    with pytest.raises(ValueError, match="case"):
        rml.support_case(_small(), 4)


@pytest.mark.slow
@pytest.mark.parametrize("propagation", ["eigen", "physical"])
def test_peaks_of_a_moving_contact_point_follow_every_step_at_its_time(propagation):
    """The contact-point output C(t) u moves with the load. Without noise every sample follows the response
    that :func:`pgtjax.simulate` computes with its own loop; the output's value at each step, interpolated
    independently (:func:`pgtjax.models.ring.ring_displacement_at` at the load's angle then), gives the peak
    over every step, and every sample lies in its bin at each reported time. A row taken at another time
    than the step's end, or only at the saves, would give other bins."""
    from pgtjax.models.ring import ring_displacement_at

    p = _small(carrier_speed=30.0)
    quiet = rml.build(p)
    quiet = eqx.tree_at(lambda x: x.spectral_density, quiet, jnp.zeros_like(quiet.spectral_density))
    outputs = rml.observables(p)
    u0, v0 = rml.static_initial_state(quiet)
    dt, n_steps = 2e-4, 60
    run = pg.simulate(quiet, dt=dt, n_steps=n_steps, initial_displacement=u0, initial_velocity=v0)
    u = np.asarray(run.u)
    point = np.array(
        [
            float(ring_displacement_at(p.ring, rml.contact_angle(p, k * dt), u[k])[0])
            for k in range(n_steps + 1)
        ]
    )
    name = f"obs:{rml.OBSERVER_NAME}"
    magnitude = np.abs(point)
    edges = np.linspace(0.98 * magnitude.min(), 1.02 * magnitude.max(), 301)
    times = [dt * k for k in (20, 40, 60)]
    mc = pg.monte_carlo(quiet, n_samples=5, key=jax.random.key(5), progress=False, dt=dt, n_steps=n_steps,
                        save_every=20, observables=outputs, initial_displacement=u0, initial_velocity=v0,
                        peaks={name: edges}, histogram_times=times, propagation=propagation)  # fmt: skip
    step_peak = np.maximum.accumulate(magnitude)[20::20]
    saves_only = np.maximum.accumulate(magnitude[::20])[1:]
    assert np.any(np.searchsorted(edges, step_peak) != np.searchsorted(edges, saves_only))  # meaningful
    assert np.min(np.abs(step_peak[:, None] - edges[None, :])) > 1e-9 * edges[-1]  # decisive bins
    expected = np.zeros((3, 300))
    expected[np.arange(3), np.searchsorted(edges, step_peak, side="right") - 1] = 5.0
    np.testing.assert_array_equal(np.asarray(mc.peak_histograms[name]), expected)


@pytest.mark.slow
def test_monte_carlo_matches_recursion_dtypes_and_observables():
    p = _small(carrier_speed=30.0)
    s = rml.build(p)
    for x in (s.mass, s.damping, s.stiffness, s.load(0.01), s.noise_input(0.01)):
        assert x.dtype == jnp.float64
    assert s.dof_names == tuple(rml.ring_dof_names(p.ring))  # no observer DOFs: outputs are Observables
    outputs = rml.observables(p)
    assert outputs.names == (rml.OBSERVER_NAME, rml.MID_NAME)
    u0, v0 = rml.static_initial_state(s)
    kw = dict(
        dt=2e-4, n_steps=60, save_every=20, initial_displacement=u0, initial_velocity=v0, observables=outputs
    )
    sl = pg.solve_moments(s, covariance_dofs="all", **kw)
    assert sl.mean_obs.dtype == jnp.float64 and sl.std_obs.dtype == jnp.float64
    # the contact-point output is the ring interpolated under load 1 (an independent evaluation of the same
    # shape functions), its mean and its std from the full covariance; the mid-node output is that DOF
    from pgtjax.models.ring import ring_displacement_at, ring_interpolation

    mid = sl.dof(f"ring_node{rml.mid_node(p.ring)}_radial")
    c, m = sl.observable(rml.OBSERVER_NAME), sl.observable(rml.MID_NAME)
    for k, t in enumerate(np.asarray(sl.times)):
        u = sl.mean_u[k]
        ur = float(ring_displacement_at(p.ring, rml.contact_angle(p, t), u)[0])
        np.testing.assert_allclose(
            float(sl.mean_obs[k, c]), ur, rtol=1e-12, atol=1e-14 * float(jnp.abs(u).max())
        )
        row = ring_interpolation(p.ring, rml.contact_angle(p, t))[0]
        var = float(row @ sl.cov_uu[k] @ row)
        np.testing.assert_allclose(float(sl.std_obs[k, c]) ** 2, var, rtol=1e-10, atol=1e-30)
    np.testing.assert_allclose(sl.std_obs[:, m], sl.std_u[:, mid], rtol=1e-12)
    np.testing.assert_allclose(sl.mean_obs[:, m], sl.mean_u[:, mid], rtol=1e-12)
    # Monte Carlo of the same discretisation: within 3 standard errors at every saved time
    mc = pg.monte_carlo(s, n_samples=400, key=jax.random.key(3), progress=False, **kw)
    assert mc.mean_u.dtype == jnp.float64 and mc.mean_obs.dtype == jnp.float64
    se_m, se_s = mc.standard_error("obs")
    for j, name in enumerate(outputs.names):
        for k in (1, 2, 3):
            assert abs(float(mc.mean_obs[k, j] - sl.mean_obs[k, j])) < 3 * float(se_m[k, j]), (name, k)
            assert abs(float(mc.std_obs[k, j] - sl.std_obs[k, j])) < 3 * float(se_s[k, j]), (name, k)
    se_m, se_s = mc.standard_error("u")
    for name in ("ring_node4_tangential", "ring_node7_rotation"):
        j = sl.dof(name)
        for k in (1, 2, 3):
            assert abs(float(mc.mean_u[k, j] - sl.mean_u[k, j])) < 3 * float(se_m[k, j]), (name, k)
            assert abs(float(mc.std_u[k, j] - sl.std_u[k, j])) < 3 * float(se_s[k, j]), (name, k)


def test_modal_model_outputs_include_the_static_correction():
    """With n_modes, the outputs' mean adds c R F_d (the dropped modes' quasi-static part): at the quasi-static
    start it equals the full model's static deflection under the loads."""
    p = _small(carrier_speed=30.0)
    full, modal = rml.build(p), rml.build(p, n_modes=12)
    u_full, _ = rml.static_initial_state(full)
    q, _ = rml.static_initial_state(modal)
    y_full = rml.observables(p)(0.0) @ u_full
    out = rml.observables(p, n_modes=12)
    y_modal = out(0.0) @ q + out.shift(0.0)
    np.testing.assert_allclose(np.asarray(y_modal), np.asarray(y_full), rtol=1e-9)
    with pytest.raises(ValueError, match="contact.*mid"):
        rml.observables(p, contact=False, mid=False)


@pytest.mark.slow
def test_gradient_matches_finite_differences():
    p0 = _small(carrier_speed=30.0)
    mid = f"ring_node{rml.mid_node(p0.ring)}_radial"

    def objective(thickness, k_support):
        ring = eqx.tree_at(lambda r: (r.thickness, r.k_support_radial), p0.ring, (thickness, k_support))
        p = eqx.tree_at(lambda q: q.ring, p0, ring)
        s = rml.build(p)
        r = pg.solve_moments(s, dt=2e-4, n_steps=30, save_every=5)
        return jnp.max(r.std_u[:, r.dof(mid)])  # max over the saved times (its location is stable, see below)

    h0, k0 = float(p0.ring.thickness), float(p0.ring.k_support_radial)
    grad = jax.jit(jax.grad(objective, argnums=(0, 1)))(h0, k0)
    objective = jax.jit(objective)
    for i, (x0, step) in enumerate(((h0, 1e-6 * h0), (k0, 1e-4 * k0))):
        args = [h0, k0]
        args[i] = x0 + step
        fp = float(objective(*args))
        args[i] = x0 - step
        fm = float(objective(*args))
        fd = (fp - fm) / (2 * step)
        assert math.isfinite(float(grad[i]))
        np.testing.assert_allclose(float(grad[i]), fd, rtol=1e-5)


def _parser():
    parser = argparse.ArgumentParser(prog="pgtjax")
    sub = parser.add_subparsers(dest="command")
    cli_ring.register(sub)
    return parser


@pytest.mark.slow
def test_cli_smoke(tmp_path, capsys):
    parser = _parser()
    args = parser.parse_args(["ring-modal", "--n-elements", "12", "--modes", "4", "--json"])
    assert args.func(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["modes"]) == 4 and out["modes"][0]["frequency_hz"] > 0
    args = parser.parse_args(
        [
            "ring-moving-load",
            "--n-elements",
            "12",
            "--modes",
            "12",
            "--revolutions",
            "0.02",
            "--dt",
            "2e-4",
            "--samples",
            "20",
            "--speeds",
            "30",
            "--sweep-speeds",
            "0",
            "--supports",
            "3",
            "--out",
            str(tmp_path),
            "--quiet",
        ]
    )
    assert args.func(args) == 0
    assert (tmp_path / "summary.json").is_file() and (tmp_path / "fig6_7_sweep.png").exists() is False
    assert (tmp_path / "fig6_4_mid_base.png").is_file() and (tmp_path / "modes_ch6_ring.png").is_file()
    assert_readme_lists_every_file(tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert missing_units(summary) == []
    assert summary["magnitude_check"]["finding"] == rml_study.MAGNITUDE_NOTE
    assert rml_study.MAGNITUDE_NOTE in capsys.readouterr().out  # the CLI prints the note with the magnitudes
    assert set(summary["speeds"]) == {"30_rad_per_s"} and summary["supports_mid_max_std"]["case3_soft_pins"]
    assert summary["mc_vs_recursion"][0]["max_std_error_in_se"] >= 0.0
    res, attrs = pg.load_results(tmp_path / "base_sl.npz")
    assert rml.MID_NAME in res.observable_names and attrs["carrier_speed_rad_s"] == 2.8
    capsys.readouterr()
    # a bad input is a clear error with exit code 2
    bad = tmp_path / "bad.toml"
    bad.write_text("[ring]\nouter_radius = 0.5\n")
    args = parser.parse_args(["ring-modal", "--params", str(bad)])
    assert args.func(args) == 2
    assert "pgtjax: error:" in capsys.readouterr().err


def test_free_vibration_cli_writes_readme_and_says_why_table_5_3_disagrees(tmp_path, capsys):
    from pgtjax.studies import ring_free_vibration as fv

    args = _parser().parse_args(["ring-free-vibration", "--n-elements", "16", "--out", str(tmp_path)])
    assert args.func(args) == 0
    assert fv.DISAGREEMENT_NOTE in capsys.readouterr().out
    assert_readme_lists_every_file(tmp_path)


def test_sweep_figure_marks_every_critical_speed_the_console_lists():
    """Each mesh-family critical speed above the figure's cut is visible: a shaded band, or a line where the
    group's natural frequencies coincide (the second group's bands, 1e-5 rad/s wide, were drawn invisibly)."""
    import matplotlib.colors as mcolors

    from pgtjax import plots
    from pgtjax.studies import ring_moving_load as study

    critical = study.critical_speed_table(study.load_params())
    speeds = np.linspace(2.8, 50.0, 20)
    sweep = dict(speeds=speeds, xi_m=np.ones_like(speeds), xi_sd=np.ones_like(speeds), peaks=[])
    fig = study.sweep_figure(sweep, critical, min_band_speed=15.0)
    try:
        ax = fig.axes[0]
        marks = []  # (x from, x to, drawn width in points) of each band or line
        for patch in ax.patches:
            x0, x1 = patch.get_x(), patch.get_x() + patch.get_width()
            marks.append((x0, x1, np.diff(ax.transData.transform([(x0, 0), (x1, 0)])[:, 0])[0]))
        for line in ax.lines:
            x = np.asarray(line.get_xdata(), dtype=float)
            if x.size == 2 and x[0] == x[1] and mcolors.to_hex(line.get_color()) != mcolors.to_hex("tab:red"):
                marks.append((x[0], x[0], line.get_linewidth()))
        wanted = [r for r in critical["mesh_family"] if r["speed_high"] >= 15.0]
        assert {r["group"] for r in wanted} == {1, 2}
        for r in wanted:
            hits = [
                m for m in marks if m[0] - 1e-9 <= 0.5 * (r["speed_low"] + r["speed_high"]) <= m[1] + 1e-9
            ]
            assert hits and max(h[2] for h in hits) >= 1.0, (r, hits)  # at least a point wide: visible
    finally:
        plots.plt.close(fig)


def test_bolted_ring_modes_carry_only_the_harmonics_the_modal_table_names():
    """A ring with N equally spaced supports is N-periodic, so each mode's shape holds only the harmonics
    |n +/- N k| of its labelled n (Bloch's theorem), as the ring-modal table's last line says."""
    from pgtjax.models.ring import natural_frequencies, nodal_diameter, ring_matrices

    p = rml.default_params()
    count = len(p.ring.support_nodes)
    _, modes = natural_frequencies(*ring_matrices(p.ring))
    modes = np.asarray(modes)
    for k in range(12):
        v = modes[:, k].reshape(-1, 3)
        energy = np.abs(np.fft.rfft(v[:, 0])) ** 2 + np.abs(np.fft.rfft(v[:, 1])) ** 2
        n = nodal_diameter(modes[:, k])
        harmonics = np.arange(energy.size)
        allowed = ((harmonics - n) % count == 0) | ((harmonics + n) % count == 0)
        assert np.sum(energy[~allowed]) <= 1e-12 * np.sum(energy), (k, n)
    text = rml_study.format_modal_table(p, rml_study.modal_table(p, 4))
    assert text.splitlines()[-1].startswith("n: the circumferential harmonic")
    assert f"|n +/- {count} k|" in text

    # 100 tooth masses do not repeat from bolt to bolt: the harmonics mix, and the table does not claim it
    import dataclasses

    toothed = dataclasses.replace(p, ring=dataclasses.replace(p.ring, tooth_mass=0.5, n_teeth=100))
    _, modes = natural_frequencies(*ring_matrices(toothed.ring))
    v = np.asarray(modes)[:, 0].reshape(-1, 3)
    energy = np.abs(np.fft.rfft(v[:, 0])) ** 2 + np.abs(np.fft.rfft(v[:, 1])) ** 2
    n = nodal_diameter(np.asarray(modes)[:, 0])
    harmonics = np.arange(energy.size)
    allowed = ((harmonics - n) % count == 0) | ((harmonics + n) % count == 0)
    assert np.sum(energy[~allowed]) > 1e-6 * np.sum(energy)
    text = rml_study.format_modal_table(toothed, rml_study.modal_table(toothed, 4))
    assert "+/-" not in text and text.splitlines()[-1].startswith("n: the circumferential harmonic")
