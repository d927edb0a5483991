"""Saved displacement-velocity covariances (``covariance_dofs``) against exact stationary values and MC."""

import math

import jax
import numpy as np
import pytest

import pgtjax as pg

M, C, K, S0 = 2.0, 0.8, 50.0, 1e-3  # kg, N s/m, N/m, (N^2 s) of E[w w] = 2 pi S0 delta


def oscillator(n_extra=0):
    """A linear oscillator ``M x'' + C x' + K x = w`` (plus uncoupled copies, to test the DOF selection)."""
    n = 1 + n_extra
    return pg.System(
        mass=np.eye(n) * M,
        stiffness=np.diag([K] + [K * (2.0 + i) for i in range(n_extra)]),
        damping=np.eye(n) * C,
        noise_input=np.eye(n)[:, :1],
        spectral_density=S0,
        dof_names=["x"] + [f"y{i}" for i in range(n_extra)],
    )


def test_sl_stationary_covariance_equals_the_lyapunov_solution():
    """Stationary ``Var x = pi S0 / (K C)``, ``Var v = pi S0 / (M C)``, ``E[x v] = 0`` (from the Lyapunov
    equation of the first-order system; e.g. Lin, Probabilistic Theory of Structural Dynamics, Sec. 5.2)."""
    system = oscillator(n_extra=2)
    period = 2 * math.pi / math.sqrt(K / M)
    dt = period / 400
    n_steps = 400 * 40  # 40 periods = 50 s: the variance decays as exp(-C t / M), e-folding 2.5 s
    r = pg.solve_moments(system, dt=dt, n_steps=n_steps, save_every=400, covariance_dofs=["x", "y1"])
    assert r.covariance.dtype == np.float64 and r.covariance.shape == (41, 4, 4)
    assert r.covariance_dofs == ("x", "y1")
    var_x, var_v = math.pi * S0 / (K * C), math.pi * S0 / (M * C)
    np.testing.assert_allclose(float(r.cov_uu[-1, 0, 0]), var_x, rtol=2e-4)
    np.testing.assert_allclose(float(r.cov_vv[-1, 0, 0]), var_v, rtol=2e-4)
    assert abs(float(r.cov_uv[-1, 0, 0])) < 1e-3 * math.sqrt(var_x * var_v)
    # the diagonal is what std_u / std_v report; the unexcited copy stays at zero
    x, y1 = r.dof("x"), r.dof("y1")
    np.testing.assert_allclose(np.sqrt(np.asarray(r.cov_uu[:, 0, 0])), r.std_u[:, x], rtol=1e-12)
    np.testing.assert_allclose(np.sqrt(np.asarray(r.cov_vv[:, 0, 0])), r.std_v[:, x], rtol=1e-12)
    assert np.all(np.asarray(r.covariance[:, 1, :]) == 0.0) and np.all(r.std_u[:, y1] == 0.0)
    # symmetric at every saved time
    cov = np.asarray(r.covariance)
    np.testing.assert_allclose(cov, np.swapaxes(cov, 1, 2), rtol=0, atol=1e-12 * np.abs(cov).max())


def test_transient_cross_covariance_is_half_the_derivative_of_the_variance():
    """From a deterministic start, ``d Var x / dt = 2 E[x v]`` at every time: checked by central differences
    of the saved variance (a second, independent route to the cross term)."""
    system = oscillator()
    dt = 2e-3
    r = pg.solve_moments(system, dt=dt, n_steps=3000, save_every=1, covariance_dofs="all")
    var = np.asarray(r.cov_uu[:, 0, 0])
    cross = np.asarray(r.cov_uv[:, 0, 0])
    slope = (var[2:] - var[:-2]) / (2 * dt)
    scale = np.abs(cross).max()
    assert scale > 0
    np.testing.assert_allclose(slope, 2 * cross[1:-1], rtol=0, atol=2e-3 * 2 * scale)


@pytest.mark.slow
def test_monte_carlo_covariance_agrees_with_sl_within_standard_errors():
    system = oscillator()
    var_x, var_v = math.pi * S0 / (K * C), math.pi * S0 / (M * C)
    p0 = np.diag([var_x, var_v])  # stationary start
    kw = dict(dt=5e-3, n_steps=200, save_every=50, initial_covariance=p0, covariance_dofs=["x"])
    sl = pg.solve_moments(system, **kw)
    n = 4000
    mc = pg.monte_carlo(system, n_samples=n, key=jax.random.key(3), chunk_size=1500, progress=False, **kw)
    assert mc.covariance.dtype == np.float64 and mc.covariance.shape == sl.covariance.shape
    # the diagonal agrees with the sample std (same 1/(N-1) normalisation), to rounding
    np.testing.assert_allclose(np.sqrt(np.asarray(mc.cov_uu[:, 0, 0])), mc.std_u[:, 0], rtol=1e-10)
    # standard errors of a covariance of Gaussian variables: sqrt((s_ij^2 + s_ii s_jj) / N)
    s_sl = np.asarray(sl.covariance)
    se = np.sqrt((s_sl**2 + np.einsum("tii,tjj->tij", s_sl, s_sl)) / n)
    z = np.abs(np.asarray(mc.covariance) - s_sl) / se
    assert z.max() < 4.5, z.max()


def test_bad_covariance_dofs_raise_naming_the_option():
    system = oscillator()
    with pytest.raises(ValueError, match="covariance_dofs.*unknown DOF 'z'"):
        pg.solve_moments(system, dt=1e-3, n_steps=2, covariance_dofs=["z"])
    with pytest.raises(ValueError, match="covariance_dofs.*twice"):
        pg.solve_moments(system, dt=1e-3, n_steps=2, covariance_dofs=["x", "x"])
    with pytest.raises(ValueError, match="covariance_dofs"):
        pg.monte_carlo(system, n_samples=4, key=jax.random.key(0), dt=1e-3, n_steps=2, covariance_dofs="x")
    r = pg.solve_moments(system, dt=1e-3, n_steps=2)
    with pytest.raises(ValueError, match="covariance_dofs"):
        r.cov_uv


def test_covariance_survives_save_and_load(tmp_path):
    r = pg.solve_moments(oscillator(), dt=1e-3, n_steps=20, save_every=10, covariance_dofs="all")
    path = pg.save_results(tmp_path / "r.npz", r)
    back, _ = pg.load_results(path)
    assert back.covariance_dofs == ("x",)
    np.testing.assert_array_equal(np.asarray(back.covariance), np.asarray(r.covariance))
