"""Gear-pair builder (thesis Eqs. 4.5-4.18) and the ch. 4 study at small sizes."""

import runpy
import sys
from importlib import metadata

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _outputs import assert_readme_lists_every_file

import pgtjax as pg
from pgtjax import cli
from pgtjax.models import gear_pair as gp
from pgtjax.studies import gear_pair as study

P = gp.default_params()


def test_matrices_and_contact_direction_match_equations():
    s = gp.build(P)
    r1, r2, i1, i2 = 0.2156, 0.4004, 3.2, 3.2
    m_c = i1 * i2 / (i2 * r1**2 + i1 * r2**2)  # Eq. 4.8
    np.testing.assert_allclose(s.mass, np.diag([181.6, 104.0, m_c]), rtol=1e-14)
    np.testing.assert_allclose(s.stiffness, np.diag([5.9e9, 5.9e9, 0.0]), rtol=1e-14)  # Eq. 4.15
    g = np.asarray(s.contact_direction(0.0))
    np.testing.assert_array_equal(g, [[1.0], [-1.0], [1.0]])  # delta = y1 - y2 + z (Eq. 4.10)
    # F_int = g f reproduces the signs of Eqs. 4.5-4.7: +f, -f, +f
    q = jnp.array([3e-6, -1e-6, 30e-6])
    delta = q[0] - q[1] + q[2]
    f = float(pg.Backlash().force(delta, 16.9e9, 20e-6))
    np.testing.assert_allclose(g[:, 0] * f, [f, -f, f])
    # load on z: T_in / r1 when the torques balance (Eq. 4.7)
    balanced = gp.build(P.replace(torque_out=4e4 * r2 / r1))
    np.testing.assert_allclose(float(balanced.load[2]), 4e4 / r1, rtol=1e-12)
    np.testing.assert_array_equal(np.asarray(s.noise_input)[:, 0], [0.0, 0.0, 100.0])  # Eq. 4.18
    # mesh stiffness: Fourier series of Eq. 4.11 at omega = a1 * speed
    w = 21 * 1500 * 2 * np.pi / 60
    t = 1.234e-3
    np.testing.assert_allclose(float(s.contact_stiffness(t)[0]), 16.9e9 + 1.69e9 * np.sin(w * t), rtol=1e-12)
    # Rayleigh damping: the lowest and highest modes get the requested ratio
    alpha, beta = gp.rayleigh_coefficients(P)
    modes = pg.modal_analysis(s)
    for w_n in (modes.angular_frequencies[0], modes.angular_frequencies[-1]):
        np.testing.assert_allclose(float(alpha / (2 * w_n) + beta * w_n / 2), 0.05, rtol=1e-10)


def test_bad_parameters():
    with pytest.raises(ValueError, match="half_backlash"):
        gp.build(P.replace(half_backlash=-1e-6))
    with pytest.raises(ValueError, match="mass_1"):
        gp.build(P.replace(mass_1=0.0))
    with pytest.raises(ValueError, match="mesh_sin"):
        gp.build(P.replace(mesh_sin=jnp.array([20e9])))
    with pytest.raises(ValueError, match="unknown"):
        P.replace(rim=1.0)


SMALL = dict(dt=1e-5, t_end=0.012, n_saves=12, pdf_times=(0.01,), chunk_size=3000, progress=False)


@pytest.fixture(scope="module")
def small_study():
    regimes = [("heavy", 4e4, 7.4e4), ("light", 800.0, 1480.0)]
    return study.run_study(P, regimes=regimes, n_samples=3000, key=jax.random.key(7), **SMALL)


@pytest.mark.slow
def test_heavy_load_sl_agrees_with_mc(small_study):
    heavy = small_study.regimes[0]
    rows = [r for r in study.error_table(small_study) if r["regime"] == "heavy"]
    for r in rows:  # both criteria within a few percent of MC in the no-impact regime
        assert r["delta_mean_error"] < 0.02 and r["delta_std_error"] < 0.05, r
        assert r["z_std_error"] < 0.05, r
    ks = study.ks_distance(heavy)  # MC distribution indistinguishable from the SL Gaussian (KS, 5 %)
    assert ks["ks"] < ks["critical_5pct"], ks


@pytest.mark.slow
def test_light_load_loses_contact_and_mc_pdf_is_not_gaussian(small_study):
    light = small_study.regimes[1]
    assert float(light.mc.contact_loss_probability[-1, 0]) > 0.5
    shape = study.histogram_shape(light)
    # a Gaussian has excess kurtosis 0; its sampling s.e. with 3000 samples is ~0.09
    assert shape["excess_kurtosis"] < -0.5, shape
    ks = study.ks_distance(light)
    assert ks["ks"] > 3 * ks["critical_5pct"], ks
    rows = [r for r in study.error_table(small_study) if r["regime"] == "light"]
    assert all(r["delta_std_error"] > 0.05 for r in rows)  # SL visibly off where the PDF is not Gaussian


def test_outputs_reload_and_cli(tmp_path, small_study):
    import json

    from pgtjax._summary import missing_units

    written = study.write_outputs(small_study, tmp_path)
    assert (tmp_path / "summary.json").exists() and any(p.suffix == ".png" for p in written)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert missing_units(summary) == []
    # the PDF time the summary lists is the one plotted (in the figure's file name and title)
    plotted = summary["settings"]["pdf_times_plotted_s"]
    assert plotted == [float(t) for t in small_study.regimes[0].mc.histogram_times]
    assert all((tmp_path / f"heavy_pdf_t{t * 1e3:.0f}ms.png").is_file() for t in plotted)
    row = summary["errors"]["rows"][0]
    assert {"torque_in_Nm", "delta_std_error_ratio", "contact_loss_mc_probability"} <= set(row)
    back, attrs = pg.load_results(tmp_path / "heavy_mc.npz")
    assert back.dof_names == ("y1", "y2", "z") and attrs["regime"] == "heavy"
    np.testing.assert_array_equal(back.std_u, small_study.regimes[0].mc.std_u)
    with pytest.raises(SystemExit) as exc:
        cli.main(["--help"])
    assert exc.value.code == 0
    assert cli.main(["gear-pair-modal", "--json"]) == 0
    assert cli.main(["gear-pair", "--params", str(tmp_path / "missing.toml"), "--samples", "0"]) != 0


def test_cli_entry_points(monkeypatch, capsys):
    """``python3 -m pgtjax.cli`` and the ``pgtjax`` console script both run :func:`pgtjax.cli.main`."""
    monkeypatch.setattr(sys, "argv", ["pgtjax", "gear-pair-modal"])
    with pytest.raises(SystemExit) as exc:
        runpy.run_module("pgtjax.cli", run_name="__main__")
    assert exc.value.code == 0
    assert capsys.readouterr().out.startswith(f"{'mode':>4s} {'f (Hz)':>12s}  shape (y1, y2, z)\n")
    scripts = [e for e in metadata.entry_points(group="console_scripts") if e.name == "pgtjax"]
    assert [e.value for e in scripts] == ["pgtjax.cli:main"] and scripts[0].load() is cli.main


@pytest.mark.slow
def test_cli_writes_readme_listing_every_file(tmp_path, capsys):
    out = tmp_path / "gp"
    argv = ["gear-pair", "--samples", "20", "--t-end", "0.002", "--saves", "4", "--quiet", "--out", str(out)]
    assert cli.main(argv) == 0, capsys.readouterr().err
    assert_readme_lists_every_file(out)
    assert any(p.name.endswith("_pdf_t2ms.png") for p in out.iterdir())
