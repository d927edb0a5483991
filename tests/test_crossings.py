"""SL's peaks of a displacement from Rice's crossing rate (pgtjax._crossings, MomentResult.peak_exceedance):
the rate against a direct integration of the joint Gaussian density, and the probabilities against Monte
Carlo's peaks counted over every step."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import pgtjax as pg
from pgtjax._crossings import crossing_rate

OMEGA = 2 * np.pi * 10.0  # rad/s: a 10 Hz oscillator


def oscillator(zeta=0.3, stiffness=OMEGA**2):
    """A linear oscillator (1 kg) under white noise: its response is Gaussian, so Rice's rate is exact."""
    return pg.System(mass=[[1.0]], stiffness=[[stiffness]], damping=[[2 * zeta * OMEGA]], load=[0.0],
                     noise_input=[[1.0]], spectral_density=1.0, dof_names=["x"])  # fmt: skip


def test_crossing_rate_equals_the_integral_of_the_joint_density():
    """nu(a) = int_0^inf y p(a, y) dy + int_-inf^0 |y| p(-a, y) dy for (X, dX/dt) jointly Gaussian, here by
    quadrature on a fine grid, for moments with a mean, a mean rate and a correlation (non-stationary)."""
    rng = np.random.default_rng(4)
    for _ in range(5):
        m, md = rng.normal(0, 1.0), rng.normal(0, 3.0)
        s, sd = rng.uniform(0.5, 2.0), rng.uniform(1.0, 5.0)
        c = rng.uniform(-0.9, 0.9) * s * sd
        levels = np.array([0.0, 0.7, 1.5, 3.0, 5.0])
        got = np.asarray(crossing_rate(levels, np.array([m]), np.array([s]), np.array([md]), np.array([sd]),
                                       np.array([c])))[0]  # fmt: skip
        cov = np.array([[s * s, c], [c, sd * sd]])
        inv, det = np.linalg.inv(cov), np.linalg.det(cov)
        y = np.linspace(0.0, md + 12 * sd + abs(md), 200_001)

        def density(x, y):
            d = np.stack([np.full_like(y, x - m), y - md])
            return np.exp(-0.5 * np.einsum("i...,ij,j...->...", d, inv, d)) / (2 * np.pi * np.sqrt(det))

        for a, rate in zip(levels, got):
            up = np.trapezoid(y * density(a, y), y)  # dX/dt > 0 through +a
            down = np.trapezoid(y * density(-a, -y), y)  # dX/dt < 0 through -a
            np.testing.assert_allclose(rate, up + down, rtol=1e-7, atol=1e-12)
    assert got.dtype == np.float64


def test_sl_peaks_of_an_oscillator_match_monte_carlo_in_the_tail_and_bound_it():
    """An oscillator started at rest: SL's moments are exact for a linear system, and the peaks are taken
    from 1 s on (about 6 decay times, stationary by then). Stationary, the expected crossings grow at the
    textbook rate sigma_v / (pi sigma_u) exp(-a^2 / 2 sigma_u^2). Monte Carlo's peaks (every step) stay below
    the bound P0 + N at every level (up to sampling error: 3 standard errors), and in the tail (3 and 3.5
    std) lie within 3 standard errors plus 5 % of the Poisson estimate 1 - (1 - P0) exp(-N). The 5 % is that
    estimate's own error for this bandwidth (zeta = 0.3): with 200,000 samples it was above Monte Carlo by
    3.9-4.4 % of itself at 3 std and 1.0-2.5 % at 3.5 std over the three windows
    (benchmarks/compare_peaks_rice.py, results/peaks_rice.json)."""
    system = oscillator()
    dt, n_steps = 1e-3, 3000
    sl = pg.solve_moments(system, dt=dt, n_steps=n_steps, save_every=1, covariance_dofs="all")
    s, sv = float(sl.std_u[-1, 0]), float(sl.std_v[-1, 0])
    levels = s * np.array([2.0, 2.5, 3.0, 3.5])
    rice = sl.peak_exceedance("u:x", levels, start=1.0)
    assert float(rice.start) == pytest.approx(1.0) and rice.probability.dtype == jnp.float64
    assert rice.times.shape == (3001,) and rice.probability.shape == (3001, 4)
    assert not np.any(np.asarray(rice.probability[:1000])) and np.all(np.asarray(rice.probability[1000]) > 0)
    slope = np.asarray(rice.expected_crossings[-1] - rice.expected_crossings[-1001])  # over the last second
    np.testing.assert_allclose(slope, sv / (np.pi * s) * np.exp(-0.5 * (levels / s) ** 2), rtol=1e-3)
    edges = np.concatenate([[0.0], levels, [10 * s]])
    mc = pg.monte_carlo(system, n_samples=40_000, key=jax.random.key(1), dt=dt, n_steps=n_steps,
                        save_every=500, peaks={"u:x": edges}, peak_start=1.0, histogram_times=[1.5, 2.0, 3.0],
                        progress=False)  # fmt: skip
    mc_peaks = mc.peak_exceedance("u:x")
    for row, t in enumerate([1.5, 2.0, 3.0]):
        k = int(np.argmin(np.abs(np.asarray(rice.times) - t)))
        p_mc, se = mc_peaks.probability[row, :4], mc_peaks.standard_error[row, :4]
        poisson, bound = np.asarray(rice.probability[k]), np.asarray(rice.upper_bound[k])
        assert np.all(p_mc <= bound + 3 * se), (t, p_mc, bound)
        tail = slice(2, 4)
        assert np.all(np.abs(p_mc[tail] - poisson[tail]) <= 3 * se[tail] + 0.05 * poisson[tail]), (
            t,
            p_mc,
            poisson,
        )
        assert poisson[1] > p_mc[1] + 3 * se[1]  # 2.5 std: crossings come in clumps, Poisson counts more
    assert 0.05 < float(rice.probability[-1, 3]) < 0.2  # the tail tested is neither empty nor certain


@pytest.mark.parametrize("start", [None, 0.3])
def test_sl_peak_probability_has_the_gradient_of_a_central_difference_and_runs_jitted(start):
    """d P(peak >= a) / d log k through the SL recursion and Rice's rate, against a central difference, with
    the window from rest (where u and v start fully correlated) and from 0.3 s; and the same value and
    gradient under jax.jit, as a design's objective runs."""
    level = 0.01

    def probability(log_k):
        sl = pg.solve_moments(oscillator(stiffness=jnp.exp(log_k)), dt=1e-3, n_steps=600, save_every=1,
                              covariance_dofs="all")  # fmt: skip
        return sl.peak_exceedance("u:x", [level], start=start).probability[-1, 0]

    x, h = np.log(OMEGA**2), 1e-5
    grad = float(jax.grad(probability)(x))
    fd = float((probability(x + h) - probability(x - h)) / (2 * h))
    assert 0.01 < float(probability(x)) < 0.99
    np.testing.assert_allclose(grad, fd, rtol=1e-5)
    jitted = jax.jit(jax.value_and_grad(probability))(x)
    np.testing.assert_allclose(float(jitted[0]), float(probability(x)), rtol=1e-12)
    np.testing.assert_allclose(float(jitted[1]), grad, rtol=1e-10)


def test_start_probability_and_trapezoids():
    """P0 = P(|X| >= a) on both sides (math.erfc), and its deterministic limit; the crossings' integral is
    exact for a linear rate and starts at the chosen index."""
    import math

    from pgtjax._crossings import cumulative_trapezoid, exceedance_at_start

    m, s = 0.4, 1.3
    levels = np.array([0.0, 0.5, 1.0, 3.0])
    want = [
        0.5 * math.erfc((a - m) / (s * math.sqrt(2))) + 0.5 * math.erfc((a + m) / (s * math.sqrt(2)))
        for a in levels
    ]
    np.testing.assert_allclose(np.asarray(exceedance_at_start(levels, m, s)), want, rtol=1e-14)
    np.testing.assert_array_equal(np.asarray(exceedance_at_start(levels, -0.7, 0.0)), [1.0, 1.0, 0.0, 0.0])
    times = np.array([0.0, 0.5, 1.5, 2.0, 4.0])
    rate = np.stack([2 * times, 3.0 + 0 * times], axis=1)  # integrals t^2 and 3 t
    np.testing.assert_allclose(
        np.asarray(cumulative_trapezoid(rate, times)), np.stack([times**2, 3 * times], 1)
    )
    from_second = np.asarray(cumulative_trapezoid(rate, times, 2))
    np.testing.assert_allclose(from_second[:, 0], np.maximum(times**2 - 1.5**2, 0.0) * (times >= 1.5))
    # a rate that is 0 where X is deterministic (std 0), and finite with a degenerate rate (std' = |c| / s)
    zero = crossing_rate(
        levels, np.zeros(2), np.array([0.0, 1.0]), np.zeros(2), np.array([1.0, 1.0]), np.array([0.0, 1.0])
    )
    assert np.all(np.asarray(zero[0]) == 0.0) and np.all(np.isfinite(np.asarray(zero)))


def test_sl_peaks_refuse_what_they_cannot_estimate():
    sl = pg.solve_moments(oscillator(), dt=1e-3, n_steps=20, covariance_dofs="all")
    plain = pg.solve_moments(oscillator(), dt=1e-3, n_steps=20)
    cases = [
        (lambda: sl.peak_exceedance("v:x", [0.1]), "must be a displacement 'u:<dof>'"),
        (lambda: sl.peak_exceedance("u:y", [0.1]), "unknown DOF 'y'"),
        (lambda: plain.peak_exceedance("u:x", [0.1]), "solve with `covariance_dofs` including 'x'"),
        (lambda: sl.peak_exceedance("u:x", [-0.1]), "`levels` must be a 1-D array of finite levels >= 0"),
        (lambda: sl.peak_exceedance("u:x", [[0.1]]), "`levels`"),
        (lambda: sl.peak_exceedance("u:x", [np.nan]), "`levels`"),
        (lambda: sl.peak_exceedance("u:x", [0.1], start=5.0), "`start` must lie within the run"),
        (lambda: sl.peak_exceedance("u:x", [0.1], start="soon"), "`start` must be a time"),
        (lambda: sl.peak_exceedance("u:x", ["high"]), "`levels`"),
        (lambda: sl.peak_exceedance(3, [0.1]), "`quantity` must be a name"),
    ]
    for call, message in cases:
        with pytest.raises(ValueError, match=message):
            call()
