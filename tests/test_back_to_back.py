"""Acceptance tests of the back-to-back bench (bench paper, Hammami et al.) against independent computations."""

import argparse
import dataclasses
import json
import math
import tomllib
from pathlib import Path
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _outputs import assert_readme_lists_every_file

import pgtjax as pg
from pgtjax.cli import back_to_back as cli_back_to_back
from pgtjax.models import back_to_back as bb
from pgtjax.models import mesh_stiffness as ms
from pgtjax.studies import back_to_back as study

DT = 1e-4
N_STEPS = 3000  # both regimes use the same length: one compilation of the integrator
STEPS_PER_MESH_PERIOD = 48  # divisible by 3: the planets' 1/3-period phase shifts fall on the time grid


@pytest.fixture(scope="module")
def params():
    return bb.default_params()


@pytest.fixture(scope="module")
def stationary(params):
    """Constant speed (974 rpm) chosen so that the mesh period is exactly 48 steps."""
    f_m = 1.0 / (STEPS_PER_MESH_PERIOD * DT)
    rpm = f_m / bb.mesh_cycles_per_radian(params) / bb.RPM
    return study.run_regime(bb.stationary(params, speed_rpm=rpm), "stationary", t_end=N_STEPS * DT, dt=DT)


@pytest.fixture(scope="module")
def run_up(params):
    p = params.replace(
        speed_start=1000 * bb.RPM, speed_end=1500 * bb.RPM, ramp_start=0.05, ramp_duration=0.25
    )
    return study.run_regime(p, "run_up", t_end=N_STEPS * DT, dt=DT)


# ------------------------------------------------------------------------------------- regimes


@pytest.mark.slow
def test_stationary_response_repeats_at_the_mesh_period(stationary):
    n = STEPS_PER_MESH_PERIOD
    d = np.asarray(stationary.trajectory.delta)
    acc = stationary.acceleration[:, bb.DOF_NAMES.index("ring_T")]
    for x in (d, acc[:, None]):
        late = x[-4 * n :]
        amplitude = late.max(axis=0) - late.min(axis=0)
        shift_period = np.max(np.abs(late[n:] - late[:-n]) / amplitude)
        shift_half = np.max(np.abs(late[n // 2 :] - late[: -(n // 2)]) / amplitude)
        assert shift_period < 1e-3, shift_period
        assert shift_half > 0.1  # not periodic at half the mesh period: the check can fail
    # steady speed: the loop carries the circulating torque; the motor only feeds the damping (mean ~ 0)
    mean_motor = abs(stationary.motor_torque[-4 * n :].mean())
    assert mean_motor < 1e-2 * float(stationary.model.params.sun_torque), mean_motor
    assert int(stationary.trajectory.unconverged) == 0


@pytest.mark.slow
def test_ring_acceleration_keeps_only_multiples_of_three_mesh_harmonics(stationary):
    """Three equally spaced planets with Z_r/3, Z_s/3 not integer: harmonics 1, 2 cancel in the ring
    torque."""
    acc = stationary.acceleration[:, bb.DOF_NAMES.index("ring_T")]
    a = study.harmonic_amplitudes(stationary, acc, orders=(1, 2, 3), last_s=0.144)
    assert a[1] < 1e-2 * a[3] and a[2] < 1e-2 * a[3]
    te = stationary.mesh.transmission_error[:, bb.CONTACT_NAMES.index("ring-planet1_T")]
    b = study.harmonic_amplitudes(stationary, te, orders=(1, 3), last_s=0.144)
    assert b[1] > b[3]  # every single mesh carries the fundamental


def test_run_up_stft_ridge_follows_ring_teeth_times_carrier_frequency(run_up, params):
    # the carrier frequency comes from the simulated velocities (the bench's tachometer), not from the profile
    # (it oscillates by ~1 % about the prescribed value: the ramp excites the 86 Hz mode of the motor shaft)
    t = run_up.times
    prescribed = bb.carrier_ratio(params) * run_up.motor_speed / (2 * np.pi)
    centres = np.arange(0.05, 0.26, 0.05)
    simulated = study.frame_average(t, run_up.carrier_frequency, centres, 0.05)
    assert np.allclose(simulated, study.frame_average(t, prescribed, centres, 0.05), rtol=5e-3)
    assert run_up.mesh_frequency[-1] > 1.4 * run_up.mesh_frequency[0]  # the mesh period shortens
    checks = study.ridge_check(run_up, window_s=0.05)
    for label, c in checks.items():
        assert len(c["ridge_hz"]) >= 10
        assert c["max_relative_error"] < 0.02, (label, c["max_relative_error"])
    # the ridge moves with the speed (a ridge stuck at the start frequency would fail the 2 % check)
    r = checks["transmission_error_ring-planet1_T"]["ridge_hz"]
    assert r[-1] > 1.3 * r[0]


def test_mesh_phase_is_the_integral_of_the_mesh_frequency(params):
    p = params.replace(ramp_start=0.1, ramp_duration=0.3)
    phase = bb.mesh_phase_function(p)
    t = np.linspace(0.0, 0.6, 60_001)
    f_m = bb.mesh_frequency(p, np.asarray(phase.profile.speed(jnp.asarray(t))))
    cycles_numeric = np.asarray(
        ms.mesh_cycles(t, f_m)
    )  # cumulative trapezoid, independent of the closed form
    cycles = np.asarray(jax.vmap(phase.cycles)(jnp.asarray(t)))
    assert np.max(np.abs(cycles - cycles_numeric)) < 1e-6
    # mesh-frequency check of the corrected Eq. 2 (docs/corrections.md C12): f_m = Z_r Z_s / (Z_r + Z_s) f_sun
    assert math.isclose(bb.mesh_frequency(p, 2 * np.pi), 65 * 16 / 81, rel_tol=1e-14)


# ------------------------------------------------------------------------------------- energy


@pytest.mark.parametrize("spin_rpm, tolerance", [(0.0, 1e-9), (1500.0, 1e-6)])
def test_integrator_conserves_energy_without_damping_and_excitation(params, spin_rpm, tolerance):
    model = bb.build_model(params, contacts="linear", motor=False, damping=False, loads=False)
    s = model.system
    M = np.asarray(s.mass)
    K = (
        np.asarray(s.stiffness)
        + (np.asarray(model.directions) * np.asarray(model.mean_stiffness)) @ np.asarray(model.directions).T
    )
    phi = np.asarray(model.rigid)
    rng = np.random.default_rng(1)
    u0 = rng.normal(size=12) * 1e-5
    v0 = rng.normal(size=12) * 1e-2
    v0 = v0 - phi * (phi @ M @ v0) / (phi @ M @ phi) + phi * spin_rpm * bb.RPM
    f_m = bb.mesh_frequency(params, 1500.0 * bb.RPM)
    n = 100 * int(math.ceil(1000.0 / f_m / DT / 100))  # >= 1000 mesh periods at 1500 rpm
    traj = pg.simulate(s, dt=DT, n_steps=n, initial_displacement=u0, initial_velocity=v0, save_every=100)
    u, v = np.asarray(traj.u), np.asarray(traj.v)
    # energy from M, K and the states; the rigid rotation (K phi = 0) is removed before the quadratic form
    u_el = u - np.outer(u @ M @ phi / (phi @ M @ phi), phi)
    energy = 0.5 * np.einsum("ti,ij,tj->t", v, M, v) + 0.5 * np.einsum("ti,ij,tj->t", u_el, K, u_el)
    assert np.max(np.abs(energy - energy[0])) / energy[0] <= tolerance
    assert np.allclose(K @ phi, 0.0, atol=1e-12 * np.abs(K).max())


# ------------------------------------------------------------------------------------- model


def test_rigid_rotation_leaves_meshes_and_shafts_undeformed(params):
    phi = bb.rigid_rotation(params)
    assert np.allclose(bb.contact_directions(params).T @ phi, 0.0, atol=1e-15)
    assert np.allclose(bb.shaft_stiffness_matrix(params, motor=False) @ phi, 0.0, atol=1e-6)
    th = np.asarray(phi / bb.dof_radii(params))
    c, r, s = (bb.DOF_NAMES.index(n) for n in ("carrier_T", "ring_T", "sun_T"))
    assert math.isclose(th[c] / th[s], 16 / 81, rel_tol=1e-12) and th[r] == 0.0


def test_static_state_shares_the_circulating_torque(params):
    model = bb.build_model(params.replace(sun_torque=150.0))
    u = bb.static_equilibrium(model)
    g = model.directions
    f = np.asarray(model.law.force(g.T @ u, model.phase(0.0), model.system.contact_clearance()))
    r_bs = float(bb.radii(params).sun)
    for s in ("R", "T"):
        sun = [bb.CONTACT_NAMES.index(f"sun-planet{n}_{s}") for n in (1, 2, 3)]
        ring = [bb.CONTACT_NAMES.index(f"ring-planet{n}_{s}") for n in (1, 2, 3)]
        assert math.isclose(f[sun].sum() * r_bs, 150.0, rel_tol=1e-9)  # sun torque balance
        assert np.allclose(f[sun], f[ring], rtol=1e-9)  # each planet's moment balance
        assert np.ptp(f[sun]) > 1e-3 * f[sun].mean()  # planets at different mesh phases share unequally


def test_mesh_matrix_is_the_papers_eq19_for_standard_teeth(params):
    """G diag(k) G^T of one set equals Eq. 19 (symmetrised: the printed (1,3) entry -sum K_r should read
    -sum K_s) when Z_r = Z_s + 2 Z_p; with Table 1's Z_r = 65 the carrier entries differ (kappa = 41/40)."""
    ring64 = dataclasses.replace(params.ring_planet, z_gear=64)
    for p, exact in ((params.replace(ring_planet=ring64), True), (params, False)):
        g = np.asarray(bb.contact_directions(p))
        rng = np.random.default_rng(0)
        ks, kr = rng.uniform(2e8, 4e8, 3), rng.uniform(3e8, 5e8, 3)
        k = np.concatenate([ks, kr, ks, kr])
        km = (g * k) @ g.T
        paper = np.zeros((6, 6))  # order c, r, s, p1, p2, p3 (Eq. 15)
        paper[0, 0] = ks.sum() + kr.sum()
        paper[0, 1] = paper[1, 0] = -kr.sum()
        paper[0, 2] = paper[2, 0] = -ks.sum()
        paper[1, 1], paper[2, 2] = kr.sum(), ks.sum()
        for n in range(3):
            paper[0, 3 + n] = paper[3 + n, 0] = kr[n] - ks[n]
            paper[1, 3 + n] = paper[3 + n, 1] = -kr[n]
            paper[2, 3 + n] = paper[3 + n, 2] = ks[n]
            paper[3 + n, 3 + n] = ks[n] + kr[n]
        for o in (0, 6):
            match = np.allclose(km[o : o + 6, o : o + 6], paper, rtol=1e-12, atol=1e-3)
            assert match == exact
        assert np.allclose(km[:6, 6:], 0.0)


@pytest.mark.slow
def test_contact_law_matches_the_mesh_stiffness_module(params):
    law = bb.hertzian_mesh_law(params)
    b = jnp.zeros(12)
    for j, mesh, pinion_drives in (
        (bb.CONTACT_NAMES.index("sun-planet1_T"), params.sun_planet, False),
        (bb.CONTACT_NAMES.index("ring-planet1_T"), params.ring_planet, True),
    ):
        for lam in (0.05, 0.4, 0.83):
            for delta in (1.5e-5, 4e-5):
                d = jnp.zeros(12).at[j].set(delta)
                ph = jnp.full(12, lam)
                ours = float(law.force(d, ph, b)[j])
                ref = float(ms.mesh_force(mesh, lam, delta, pinion_drives))
                assert math.isclose(ours, ref, rel_tol=2e-4), (j, lam, delta, ours, ref)
                # tangent stiffness = derivative of the force; force = derivative of the potential
                h = 1e-10
                fd = (law.force(d.at[j].add(h), ph, b)[j] - law.force(d.at[j].add(-h), ph, b)[j]) / (2 * h)
                assert math.isclose(float(law.stiffness(d, ph, b)[j]), float(fd), rel_tol=1e-6)
                grad = jax.grad(lambda x: law.potential(d.at[j].set(x), ph, b)[j])(delta)
                assert math.isclose(float(grad), ours, rel_tol=1e-9)
    # dead zone and back flank
    b5 = jnp.full(12, 5e-5)
    f = law.force(jnp.array([3e-5, -3e-5, 7e-5, -7e-5] * 3), jnp.full(12, 0.3), b5)
    assert np.all(np.asarray(f[:2]) == 0.0) and float(f[2]) > 0.0 and float(f[3]) < 0.0


def test_gauss_hermite_linearization_limits(params):
    law = bb.hertzian_mesh_law(params)
    mu, ph, b = jnp.full(12, 3e-5), jnp.full(12, 0.2), jnp.zeros(12)
    lin0 = law.linearize(mu, jnp.zeros(12), ph, b)
    assert np.allclose(lin0.f_0, law.force(mu, ph, b), rtol=1e-12)
    assert np.allclose(lin0.k_e, law.stiffness(mu, ph, b), rtol=1e-12)
    for crit in (pg.ForceCriterion(), pg.EnergyCriterion()):
        lin = law.linearize(mu, jnp.full(12, 1e-7), ph, b, criterion=crit)
        assert np.allclose(lin.k_e, lin0.k_e, rtol=1e-3)
    m, sd = law.force_moments(mu, jnp.full(12, 1e-7), ph, b)
    assert np.allclose(sd, lin0.k_e * 1e-7, rtol=1e-3)


# ------------------------------------------------------------------------------------- modal


def test_modal_analysis_sanity(params):
    s = bb.linear_system(params)
    M, K = (
        np.asarray(s.mass),
        np.asarray(s.stiffness)
        + (np.asarray(s.contacts.direction) * np.asarray(s.contacts.stiffness))
        @ np.asarray(s.contacts.direction).T,
    )
    assert np.array_equal(M, M.T) and np.allclose(K, K.T, rtol=0, atol=1e-9 * np.abs(K).max())

    def zero_modes(system):
        f = np.asarray(pg.modal_analysis(system).frequencies_hz)
        return int(np.sum(f < 1e-3 * f[-1] * 1e-3)), f

    n0, f = zero_modes(s)
    assert n0 == 1  # the free rigid rotation of the train
    assert zero_modes(bb.linear_system(params.replace(ring_support_stiffness=0.0)))[0] == 2
    assert zero_modes(bb.linear_system(params, motor=True))[0] == 0
    # planet modes (Lin & Parker): centre members at rest, omega^2 = (k_s + k_r) / M_p, N - 1 = 2 per set
    k_s, k_r = (float(x) for x in bb.mean_mesh_stiffness(params))
    m_p = float(params.planet_inertia) / float(bb.radii(params).planet) ** 2
    f_p = math.sqrt((k_s + k_r) / m_p) / (2 * math.pi)
    assert int(np.sum(np.isclose(f, f_p, rtol=1e-9))) == 4
    # the mean mesh stiffness agrees with mesh_stiffness.mesh_cycle (no tables there)
    load = bb.nominal_mesh_load(params)
    _, st = ms.mesh_cycle(params.sun_planet, load, 64, pinion_drives=False)
    assert math.isclose(k_s, float(jnp.mean(st.stiffness)), rel_tol=1e-4)


# ------------------------------------------------------------------------------------- inputs, dtypes, CLI


@pytest.mark.parametrize(
    "change, name",
    [
        (dict(sun_shaft_stiffness=-1.0), "sun_shaft_stiffness"),
        (dict(carrier_inertia=0.0), "carrier_inertia"),
        (dict(half_backlash=0.01), "half_backlash"),
        (dict(rayleigh_f2=50.0), "rayleigh_f2"),
        (dict(ramp_duration=0.0), "ramp_duration"),
        (dict(speed_end=float("nan")), "speed_end"),
        (dict(damping_ratio=2.0), "damping_ratio"),
    ],
)
def test_bad_parameters_raise_value_error_naming_them(params, change, name):
    with pytest.raises(ValueError, match=name):
        params.replace(**change)


def test_other_input_errors(params, tmp_path):
    with pytest.raises(ValueError, match="contacts"):
        bb.build(params, contacts="quadratic")
    with pytest.raises(ValueError, match="not found"):
        bb.load_params(tmp_path / "missing.toml")
    with pytest.raises(ValueError, match="window_s"):
        study.stft(np.zeros(100), 1e4, 1.0)
    with pytest.raises(ValueError, match="t_end"):
        study.run_regime(params, "x", t_end=-1.0)
    # a run that ends before the ramp starts would report a second stationary run as the run-up
    with pytest.raises(ValueError, match=r"`--t-end` \(t_end\) must exceed the run-up's start, 0.5 s"):
        study.run_study(params, t_end=0.3, stft_window=0.05, progress=False)


def test_float64_everywhere(stationary, params):
    tr = stationary.trajectory
    for a in (tr.u, tr.v, tr.delta, tr.force, stationary.mesh.hertz_secant, bb.mass_matrix(params)):
        assert jnp.asarray(a).dtype == jnp.float64


def test_stft_of_a_sinusoid():
    fs, f0 = 1e4, 437.3
    t = np.arange(5000) / fs
    ft, f, a = study.stft(2.5 * np.sin(2 * np.pi * f0 * t), fs, 0.1)
    r = study.ridge(f, a, np.full(len(ft), 400.0))
    assert np.allclose(r, f0, rtol=2e-3)
    assert np.allclose(a.max(axis=1), 2.5, rtol=0.02)


def test_run_study_without_t_end_reads_the_run_up_length_of_the_embedded_file(monkeypatch, params):
    """Regression: with ``t_end=None`` the run-up length is the ``[run_up] t_end_s`` of ``back_to_back.toml``,
    read through the shared parameter reader (the study called a removed private reader: AttributeError). The
    integrations are stubbed out: only the lengths handed to them are checked."""

    class Stop(Exception):
        pass

    calls = []

    def fake_run_regime(p, name, *, t_end, dt, save_every):
        calls.append((name, t_end))
        if name == "run_up":
            raise Stop
        return SimpleNamespace(wall_s=0.0)

    monkeypatch.setattr(study, "run_regime", fake_run_regime)
    with pytest.raises(Stop):
        study.run_study(params, stationary_t_end=0.2, progress=False)
    with open(Path(pg.__file__).parent / "params" / "back_to_back.toml", "rb") as fh:
        t_end = tomllib.load(fh)["run_up"]["t_end_s"]
    assert calls == [("stationary", 0.2), ("run_up", t_end)] and isinstance(calls[-1][1], float)


def test_study_load_params_applies_the_operating_point_and_face_width(params):
    p = study.load_params(torque=200.0, speed_end_rpm=1200.0, ramp_duration=2.0, face_width=0.025)
    assert float(p.sun_torque) == 200.0 and float(p.speed_end) == 1200.0 * bb.RPM
    assert float(p.ramp_duration) == 2.0 and study.run_up_end(p) == float(params.ramp_start) + 2.0
    assert float(p.speed_start) == float(params.speed_start)
    assert float(p.torque_end) == float(params.torque_end)
    assert float(p.sun_planet.face_width) == float(p.ring_planet.face_width) == 0.025


def test_cli_modal_json_and_help(capsys):
    parser = argparse.ArgumentParser(prog="pgtjax")
    cli_back_to_back.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["back-to-back-modal", "--json"])
    assert args.func(args) == 0
    rows = json.loads(capsys.readouterr().out)
    assert len(rows) == 12 and rows[0]["frequency_hz"] < 1e-3 < rows[1]["frequency_hz"]
    with pytest.raises(SystemExit) as exc:
        parser.parse_args(["back-to-back", "--help"])
    assert exc.value.code == 0
    assert "--out" in capsys.readouterr().out


def test_figures_of_a_regime_shorter_than_the_running_mean_window(stationary, tmp_path):
    """A regime shorter than the 20 ms running mean used to crash the figures (the window exceeded the series)."""
    short = 120  # 12 ms at dt = 0.1 ms
    clipped = jax.tree.map(
        lambda x: x[:short] if hasattr(x, "shape") and x.ndim and x.shape[0] == len(stationary.times) else x,
        stationary,
    )
    paths = study._figures(clipped, tmp_path, window_s=0.005)
    assert paths and all(p.exists() and p.stat().st_size > 0 for p in paths)


def test_stft_window_is_checked_before_any_simulation(monkeypatch, params):
    """Regression: the bench computed both regimes (19 s at the defaults) and then rejected its STFT window;
    now a window outside [8 saved samples, the shorter regime] is a ValueError naming --stft-window and the
    accepted range before anything is integrated."""

    def no_simulation(*args, **kwargs):
        raise AssertionError("simulated before checking the STFT window")

    monkeypatch.setattr(study, "run_regime", no_simulation)
    for window in (0.5, 3e-4):  # longer than the 0.05 s stationary run; shorter than 8 samples of 0.1 ms
        with pytest.raises(ValueError, match="--stft-window") as err:
            study.run_study(params, t_end=0.4, stationary_t_end=0.05, stft_window=window, progress=False)
        assert "0.0008 s" in str(err.value) and "0.05" in str(err.value)
    assert study.check_stft_window(0.02, dt=1e-4, save_every=1, t_end=0.4, stationary_t_end=0.05) == 0.02


@pytest.mark.slow
def test_cli_run_writes_readme_and_a_summary_with_units(tmp_path, capsys):
    from pgtjax._summary import missing_units

    parser = argparse.ArgumentParser(prog="pgtjax")
    cli_back_to_back.register(parser.add_subparsers(dest="command"))
    out = tmp_path / "bench"
    argv = ["back-to-back", "--t-end", "0.06", "--stationary-t-end", "0.03", "--ramp-start", "0.01"]
    argv += ["--ramp-duration", "0.04", "--stft-window", "0.01", "--out", str(out), "--quiet"]
    args = parser.parse_args(argv)
    assert args.func(args) == 0
    printed = capsys.readouterr().out
    assert "note: Below the paper's values" in printed  # the Hertzian comparison says why it disagrees
    assert_readme_lists_every_file(out)
    summary = json.loads((out / "summary.json").read_text())
    assert missing_units(summary) == []
    ridge = summary["ridges"]["run_up"]["ring_T_acceleration"]
    assert ridge["order"] == 3 and 0.0 <= ridge["max_relative_error_ratio"] < 0.5
    assert (
        summary["settings"]["save_every_count"] == 1 and summary["modes_free_bench"]["rows"][0]["mode"] == 1
    )
    assert summary["hertz"]["quasi_static"]["zone_A"]["sun_planet"]["hertz_secant_N_per_m"] > 0
