"""SL's peaks of a displacement (Rice's crossing rate), a contact deflection or a contact force (crossings
between consecutive steps) (pgtjax._crossings, MomentResult.peak_exceedance): the rate against a direct
integration of the joint Gaussian density, the step-crossing probability against a closed form, the step
covariances against the one-step map, and the probabilities against Monte Carlo's peaks counted over every
step."""

import re

import equinox as eqx
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


@pytest.mark.slow
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


@pytest.mark.slow
@pytest.mark.parametrize("start", [None, 0.3])
def test_sl_peak_probability_has_the_gradient_of_a_central_difference_and_runs_jitted(start):
    """d P(peak >= a) / d log k through the SL recursion and Rice's rate, against a central difference, with
    the window from rest (where u and v start fully correlated) and from 0.3 s, jitted as a design's objective
    runs (the same program gives the central difference's values; op-by-op gradients through SL are checked in
    test_api.py)."""
    level = 0.01

    def probability(log_k):
        sl = pg.solve_moments(oscillator(stiffness=jnp.exp(log_k)), dt=1e-3, n_steps=600, save_every=1,
                              covariance_dofs="all")  # fmt: skip
        return sl.peak_exceedance("u:x", [level], start=start).probability[-1, 0]

    x, h = np.log(OMEGA**2), 1e-5
    with_values = jax.jit(jax.value_and_grad(probability))
    value, grad = (float(v) for v in with_values(x))
    fd = (float(with_values(x + h)[0]) - float(with_values(x - h)[0])) / (2 * h)
    assert 0.01 < value < 0.99
    np.testing.assert_allclose(grad, fd, rtol=1e-5)


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
        (lambda: sl.peak_exceedance("v:x", [0.1]), "must be a displacement 'u:<dof>', a contact deflection"),
        (lambda: sl.peak_exceedance("u:y", [0.1]), "unknown DOF 'y'"),
        (
            lambda: plain.peak_exceedance("u:x", [0.1]),
            "`deflection_lag=True`.*`covariance_dofs` including 'x'",
        ),
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


def mesh_oscillator(zeta=0.3, variation=0.4, mesh_hz=7.0, clearance=0.0, load=0.0):
    """The oscillator held by a contact (Backlash) whose stiffness varies as k0 (1 + variation sin(2 pi f t)):
    without clearance the system is linear (time-varying), so its response is Gaussian and SL exact. The
    force k(t) delta reaches F where |delta| = F / k(t): a barrier that moves with the stiffness."""
    stiffness = pg.FourierSeries(
        OMEGA**2, sin_coefficients=[variation * OMEGA**2], frequency=2 * np.pi * mesh_hz
    )
    return pg.System(mass=[[1.0]], stiffness=[[0.0]], damping=[[2 * zeta * OMEGA]], load=[load],
                     noise_input=[[1.0]], spectral_density=1.0, dof_names=["x"],
                     contacts=pg.Contacts([[1.0]], stiffness, [clearance], names=["c"]))  # fmt: skip


def test_step_crossing_probability_equals_the_closed_form_with_owens_t():
    """P(X < a, Y >= b) for standard normals with correlation rho, against Phi(-b) - Phi2(-a, -b; rho) with
    Phi2 in closed form by Owen's T function (scipy), over correlations of both signs up to 0.999 and levels
    close together and apart: within 2e-5 (the Gauss-Legendre rule's error, about 1e-5 at worst against
    high-precision quadrature, is largest for close levels at small correlations); and the limits rho = 0 and
    rho = 1."""
    from scipy.special import ndtr, owens_t

    from pgtjax._crossings import step_crossing_probability

    def phi2(h, k, rho):  # P(X <= h, Y <= k)
        r = np.sqrt(1 - rho * rho)
        beta = 0.0 if h * k > 0 or (h * k == 0 and h + k >= 0) else 0.5
        th = (
            owens_t(h, (k - rho * h) / (h * r))
            if h != 0
            else 0.25 - np.arctan((k - rho * h) / r) / (2 * np.pi)
        )
        tk = (
            owens_t(k, (h - rho * k) / (k * r))
            if k != 0
            else 0.25 - np.arctan((h - rho * k) / r) / (2 * np.pi)
        )
        return 0.5 * ndtr(h) + 0.5 * ndtr(k) - th - tk - beta

    pairs = [(3.0, 3.0), (3.0, 3.001), (3.001, 3.0), (3.0, 3.1), (4.0, 4.5), (0.5, 0.2), (2.0, 5.0), (5.0, 2.0),
             (-1.0, 1.0), (4.5, 4.4), (4.0, 4.0001)]  # fmt: skip
    for rho in [-0.99, -0.5, 0.3, 0.7, 0.9, 0.99, 0.999]:
        for a, b in pairs:
            want = ndtr(-b) - phi2(-a, -b, rho)
            got = step_crossing_probability(a, b, rho)
            assert got.dtype == jnp.float64
            # atol: the closed form is a difference of probabilities near Phi(-b), so it keeps ~1e-16 absolute
            np.testing.assert_allclose(
                float(got), want, rtol=2e-5, atol=1e-14, err_msg=f"rho={rho}, a={a}, b={b}"
            )
    for a, b in pairs:
        np.testing.assert_allclose(float(step_crossing_probability(a, b, 0.0)), ndtr(a) * ndtr(-b), rtol=2e-5)
        np.testing.assert_allclose(float(step_crossing_probability(a, b, 1.0)), max(ndtr(-b) - ndtr(-a), 0.0),
                                   atol=1e-300)  # fmt: skip


@pytest.mark.slow
def test_step_crossings_of_known_steps_and_barriers_at_infinity():
    """step_crossings' limits in closed form: a barrier that comes down from infinity (a contact gaining
    stiffness) is crossed with the probability of being beyond it after the step, one that goes to infinity is
    not crossed; a deterministic value that passes a level crosses it with probability 1; a random step
    followed by a known one crosses with the probability of having been inside."""
    from scipy.special import ndtr

    from pgtjax._crossings import step_crossings

    inf = np.inf
    lag = np.array([0.0, 0.5, 0.0])
    upper = np.array([[inf], [2.0], [inf]])
    got = np.asarray(step_crossings(upper, np.full((3, 1), -inf), np.zeros(3), np.ones(3), lag))
    np.testing.assert_allclose(got[:, 0], [ndtr(-2.0), 0.0], rtol=1e-14)
    lower = np.array([[-inf], [-2.0], [-2.0]])
    got = np.asarray(step_crossings(np.full((3, 1), inf), lower, np.zeros(3), np.ones(3), lag))
    np.testing.assert_allclose(got[0, 0], ndtr(-2.0), rtol=1e-14)
    known = np.asarray(step_crossings(np.full((3, 1), 2.0), np.full((3, 1), -2.0), np.array([1.0, 3.0, 1.0]),
                                      np.zeros(3), np.zeros(3)))  # fmt: skip
    np.testing.assert_array_equal(known[:, 0], [1.0, 0.0])
    then_known = np.asarray(step_crossings(np.full((2, 1), 2.0), np.full((2, 1), -2.0), np.array([0.0, 3.0]),
                                           np.array([1.0, 0.0]), np.zeros(2)))  # fmt: skip
    np.testing.assert_allclose(then_known[0, 0], ndtr(2.0), rtol=1e-14)


def turning_pair():
    """Two DOFs, two contacts without clearance (linear) along directions that turn with time."""
    w = 2 * np.pi * 3.0

    def direction(t):
        return jnp.array([[1.0 + 0.3 * jnp.sin(w * t), 1.0], [0.5 * jnp.cos(w * t), -1.0]])

    return pg.System(
        mass=np.diag([1.0, 2.0]), stiffness=[[300.0, -50.0], [-50.0, 400.0]], damping=[[3.0, 0.0], [0.0, 2.0]],
        load=[5.0, 0.0], noise_input=[[1.0], [0.5]], spectral_density=1.0, dof_names=["x", "y"],
        contacts=pg.Contacts(direction, [2000.0, 500.0], [0.0, 0.0], names=["a", "b"]),
    )  # fmt: skip


def chain_of_18(varying_stiffness: bool, n: int = 18):
    """18 (or ``n``) masses in a chain, two contacts without clearance; constant K and C take the step path with
    the contact-free map formed once (n > 16), a time-varying K the path with a Woodbury correction per step;
    n <= 16 masses the path that forms the step map densely."""
    k = 400.0 * (2 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1))
    stiffness = (lambda t: k * (1.0 + 0.2 * jnp.sin(2 * np.pi * 5.0 * t))) if varying_stiffness else k
    g = np.zeros((n, 2))
    g[3, 0], g[n - 8, 0], g[n - 3, 1] = 1.0, -1.0, 1.0
    return pg.System(mass=np.eye(n), stiffness=stiffness, damping=0.5 * np.eye(n) + 1e-3 * k, load=np.ones(n),
                     noise_input=np.eye(n)[:, :2], spectral_density=1.0,
                     contacts=pg.Contacts(g, [1000.0, 800.0], [0.0, 0.0], names=["a", "b"]))  # fmt: skip


def moving_observables(n: int) -> pg.Observables:
    """Two observables y = C(t) u whose rows move with time (as the ring's contact point does), with an offset
    (which does not enter a covariance)."""
    w = 2 * np.pi * 4.0
    base = np.zeros((2, n))
    base[0, 0], base[1, -1], base[1, n // 2] = 1.0, 0.5, -1.0

    def matrix(t):
        return jnp.asarray(base) * (1.0 + 0.4 * jnp.sin(w * t)) + 0.3 * jnp.cos(w * t) * jnp.eye(2, n, k=1)

    return pg.Observables(matrix, names=["p", "q"], offset=[0.01, -0.02])


@pytest.mark.slow
@pytest.mark.parametrize("which", ["turning pair", "chain", "chain, varying K"])
def test_deflection_lag_is_the_covariance_with_the_step_before(which):
    """cov_delta_lag, cov_u_lag and cov_obs_lag from solve_moments(deflection_lag=True) against
    g(t1)^T L g(t0), the diagonal of L and C(t1) L C(t0)^T (observables whose rows move), where
    L = [I 0] Phi P0 [I 0]^T, with SL's full covariance P0 at the step's start and the one-step map Phi of the
    linear system taken column by column from deterministic one-step runs of pg.simulate (unit initial states,
    minus the run from rest); for each of the three step paths (a small system's dense map, the contact-free
    map formed once, a Woodbury correction per step). every_nth_save drops the lags (they no longer pair the
    kept times)."""
    from pgtjax._results import every_nth_save

    system = {"turning pair": turning_pair, "chain": lambda: chain_of_18(False),
              "chain, varying K": lambda: chain_of_18(True)}[which]()  # fmt: skip
    n, dt = system.n_dof, 1e-3
    observables = moving_observables(n)
    sl = pg.solve_moments(
        system, dt=dt, n_steps=30, covariance_dofs="all", deflection_lag=True, observables=observables
    )
    assert sl.cov_delta_lag.shape == (31, 2) and sl.cov_delta_lag.dtype == jnp.float64
    assert sl.cov_u_lag.shape == (31, n) and sl.cov_u_lag.dtype == jnp.float64
    assert sl.cov_obs_lag.shape == (31, 2) and sl.cov_obs_lag.dtype == jnp.float64
    np.testing.assert_array_equal(np.asarray(sl.cov_delta_lag[0]), 0.0)
    np.testing.assert_array_equal(np.asarray(sl.cov_u_lag[0]), 0.0)
    for k in (1, 30):
        t0 = float(sl.times[k - 1])

        def one_step(x):
            run = pg.simulate(
                system, t0=t0, dt=dt, n_steps=1, initial_displacement=x[:n], initial_velocity=x[n:]
            )
            return np.concatenate([np.asarray(run.u[-1]), np.asarray(run.v[-1])])

        rest = one_step(np.zeros(2 * n))
        phi = np.stack([one_step(e) - rest for e in np.eye(2 * n)], axis=1)
        lag = (phi @ np.asarray(sl.covariance[k - 1]))[:n, :n]  # Cov(u1, u0)
        g0, g1 = (np.asarray(system.contact_direction(t)) for t in (t0, t0 + dt))
        np.testing.assert_allclose(
            np.asarray(sl.cov_delta_lag[k]), np.sum(g1 * (lag @ g0), axis=0), rtol=1e-8
        )
        np.testing.assert_allclose(
            np.asarray(sl.cov_u_lag[k]), np.diag(lag), rtol=1e-8, atol=1e-12 * np.abs(lag).max()
        )
        c0, c1 = (np.asarray(observables(t)) for t in (t0, t0 + dt))
        np.testing.assert_allclose(np.asarray(sl.cov_obs_lag[k]), np.diag(c1 @ lag @ c0.T), rtol=1e-8)
    plain = pg.solve_moments(system, dt=dt, n_steps=30, observables=observables)
    assert plain.cov_delta_lag is None and plain.cov_u_lag is None and plain.cov_obs_lag is None
    np.testing.assert_array_equal(np.asarray(plain.std_u), np.asarray(sl.std_u))  # the run itself unchanged
    np.testing.assert_array_equal(np.asarray(plain.std_obs), np.asarray(sl.std_obs))
    halved = every_nth_save(sl, 2)
    assert halved.cov_delta_lag is None and halved.cov_u_lag is None and halved.cov_obs_lag is None
    assert every_nth_save(sl, 1).cov_delta_lag is not None and every_nth_save(sl, 1).cov_u_lag is not None


@pytest.mark.slow
@pytest.mark.parametrize("dt", [1e-3, 0.05])
def test_sl_contact_peaks_under_a_varying_mesh_stiffness_match_monte_carlo(dt):
    """Peaks of the deflection and of the force k(t) delta of a contact whose stiffness varies by +-40 % at
    7 Hz (10 Hz oscillator, zeta 0.3), from a third of the run on: Monte Carlo (40,000 samples, every step)
    within 3 standard errors plus 6 % of SL's estimate at 3.5 and 4 std, and under its bound at every level
    (at 3 std, with the coarse step, the Poisson estimate was 10 % above Monte Carlo: crossings clump there).
    With a fine step (omega dt = 0.06) and with a step that does not resolve the oscillator (omega dt = 3.1),
    where Rice's continuous-time rate from the velocity is off by a factor of 5 and more (asserted): the
    estimate counts crossings between consecutive steps, as Monte Carlo takes the peaks. The same for the
    displacement of the DOF (its own step lag, here equal to the deflection's) and for an observable
    (1 + 0.3 sin(2 pi 3 t)) x, whose row moves, with an offset. The moving barrier matters:
    with the fine step the deflection's estimate at the mean stiffness's barrier F / k0 (about half the truth)
    fails the same test."""
    system = mesh_oscillator()
    observables = pg.Observables(lambda t: jnp.reshape(1.0 + 0.3 * jnp.sin(2 * np.pi * 3.0 * t), (1, 1)),
                                 names=["y"], offset=[0.001])  # fmt: skip
    n_steps = 3000 if dt < 0.01 else 600
    sl = pg.solve_moments(system, dt=dt, n_steps=n_steps, deflection_lag=True, covariance_dofs="all",
                          observables=observables)  # fmt: skip
    k0 = n_steps // 3
    start = float(sl.times[k0])
    scales = {
        "delta:c": float(jnp.max(sl.std_delta[k0:, 0])),
        "force:c": float(jnp.max(sl.force_std[k0:, 0])),
        "u:x": float(jnp.max(sl.std_u[k0:, 0])),
        # its std varies by +-30 %: levels in its largest std are rarely met
        "obs:y": float(jnp.mean(sl.std_obs[k0:, 0]) + jnp.max(sl.std_obs[k0:, 0])) / 2,
    }
    sigmas = np.array([2.0, 3.5, 4.0])
    peaks = {q: np.concatenate([[0.0], s * sigmas, [20 * s]]) for q, s in scales.items()}
    mc = pg.monte_carlo(system, n_samples=40_000, key=jax.random.key(3), dt=dt, n_steps=n_steps, save_every=k0,
                        peaks=peaks, peak_start=start, histogram_times=[float(sl.times[-1])],
                        observables=observables, progress=False)  # fmt: skip
    tail = slice(1, 3)

    def agrees(estimate, p_mc, se):
        return np.all(np.abs(p_mc[tail] - estimate[tail]) <= 3 * se[tail] + 0.06 * estimate[tail])

    for q, s in scales.items():
        sl_peaks = sl.peak_exceedance(q, s * sigmas, start=start, system=system)
        p_mc, se = (np.asarray(x[0, :3]) for x in (mc.peak_exceedance(q).probability,
                                                     mc.peak_exceedance(q).standard_error))  # fmt: skip
        poisson, bound = np.asarray(sl_peaks.probability[-1]), np.asarray(sl_peaks.upper_bound[-1])
        assert sl_peaks.probability.dtype == jnp.float64 and 0.01 < poisson[1] < 0.2
        assert np.all(p_mc <= bound + 3 * se), (q, p_mc, bound)
        assert np.all(np.asarray(sl_peaks.lower_bound[-1]) <= p_mc + 3 * se), q
        assert agrees(poisson, p_mc, se), (q, p_mc, poisson)
    if dt < 0.01:  # with the coarse step the frozen barrier is off by only 10-15 % (too close to tell here)
        p_force = np.asarray(mc.peak_exceedance("force:c").probability[0, :3])
        se_force = np.asarray(mc.peak_exceedance("force:c").standard_error[0, :3])
        fixed = sl.peak_exceedance("delta:c", scales["force:c"] * sigmas / OMEGA**2, start=start)
        assert not agrees(np.asarray(fixed.probability[-1]), p_force, se_force)
    else:  # the continuous-time rate of the same deflection (= the DOF), from the run without the step lags
        rice = np.asarray(
            sl.peak_exceedance("u:x", scales["delta:c"] * sigmas, start=start, method="rice").probability[-1]
        )
        p_delta = np.asarray(mc.peak_exceedance("delta:c").probability[0, :3])
        assert np.all(rice[tail] > 5 * p_delta[tail]), (rice, p_delta)


@pytest.mark.slow
@pytest.mark.parametrize("path", ["constant map", "Woodbury", "dense"])
def test_displacement_and_observable_peaks_between_steps_have_the_gradient_of_a_central_difference(path):
    """d P(peak >= a) / d log s, s scaling the chain's stiffness and an observable's moving rows, counted
    between steps (cov_u_lag, cov_obs_lag), against a central difference, on the three step paths (18 masses:
    the contact-free map formed once, a Woodbury correction per step; 12 masses: the step map formed densely),
    whose derivative rules differ; jitted, as a design objective runs."""
    base = chain_of_18(path == "Woodbury", n=12 if path == "dense" else 18)
    dof = base.dof_names[8]

    class Rows(eqx.Module):  # C(t) = s (1 + 0.4 sin(w t)) e_3^T: moving, and a function of the variable
        scale: jax.Array

        def __call__(self, t):
            return self.scale * (1.0 + 0.4 * jnp.sin(2 * np.pi * 4.0 * t)) * jnp.eye(1, base.n_dof, k=3)

    def solve(log_s):
        system = eqx.tree_at(lambda sy: sy.stiffness, base, _scaled(base.stiffness, jnp.exp(log_s)))
        observables = pg.Observables(Rows(jnp.exp(log_s)), names=["y"])
        return pg.solve_moments(system, dt=2e-3, n_steps=150, deflection_lag=True, observables=observables)

    # the levels: max |mean| + 1.5 std of the displacement and + 2 std of the observable at s = 1, rounded (taken
    # from a run once rather than compiling a forward solve here; the check of the values below keeps them apt)
    level_u, level_y = {
        "constant map": (0.0546, 0.1003),
        "Woodbury": (0.0548, 0.1015),
        "dense": (0.0219, 0.1307),
    }[path]

    def probabilities(log_s):
        sl = solve(log_s)
        p_u = sl.peak_exceedance(f"u:{dof}", [level_u], start=0.1).probability[-1, 0]
        return jnp.stack([p_u, sl.peak_exceedance("obs:y", [level_y], start=0.1).probability[-1, 0]])

    def objective(log_s):  # both probabilities, weighted as a design's objective might (one gradient program)
        p = probabilities(log_s)
        return p[0] + 3.7 * p[1], p

    # jitted, as a design runs it; the same program gives the values for the central difference
    with_values = jax.jit(jax.value_and_grad(objective, has_aux=True))
    x, h = 0.0, 1e-5
    (_, value), grad = with_values(x)
    value = np.asarray(value)
    assert np.all((0.01 < value) & (value < 0.99)), value
    fd = (np.asarray(with_values(x + h)[0][1]) - np.asarray(with_values(x - h)[0][1])) / (2 * h)
    assert np.all(np.abs(fd) > 1e-3 * value)  # the levels' probabilities move with the variable
    np.testing.assert_allclose(float(grad), fd[0] + 3.7 * fd[1], rtol=1e-5)


@pytest.mark.slow
@pytest.mark.parametrize("initially", ["at rest", "spread"])
@pytest.mark.parametrize("method", ["steps", "rice"])
def test_lower_bound_is_the_largest_exceedance_at_one_time_since_the_start(method, initially):
    """``lower_bound``: the largest P(|X(t)| >= a) over the saved times from ``start`` (0 before), against
    SciPy's normal distribution from SL's moments, for an oscillator under a static load whose response grows
    from rest, or decays from a spread initial state (larger before ``start`` than after: the maximum is
    taken from the start, not from t = 0); at or under ``upper_bound`` and the Poisson estimate; and, from
    rest, its derivative in the stiffness (jitted) against a central difference."""
    from scipy.stats import norm

    spread = None if initially == "at rest" else np.diag([0.01**2, (0.01 * OMEGA) ** 2])

    def solve(k):
        system = pg.System(mass=[[1.0]], stiffness=[[k]], damping=[[2 * 0.3 * OMEGA]], load=[1.0],
                           noise_input=[[1.0]], spectral_density=1.0, dof_names=["x"])  # fmt: skip
        return pg.solve_moments(system, dt=1e-3, n_steps=300, deflection_lag=True, covariance_dofs=["x"],
                                initial_covariance=spread)  # fmt: skip

    levels, start = np.array([0.01, 0.02]), 0.05
    sl = solve(OMEGA**2)
    estimate = sl.peak_exceedance("u:x", levels, start=start, method=method)
    bound = estimate.lower_bound
    if method == "steps":  # Rice's count is integrated by trapezoids: a bound only up to their error
        assert np.all(np.asarray(estimate.upper_bound) >= np.asarray(bound) * (1 - 1e-12))
    assert np.all(np.asarray(estimate.probability) >= np.asarray(bound) * (1 - 1e-12))
    m, s, t = (np.asarray(x) for x in (sl.mean_u[:, 0], sl.std_u[:, 0], sl.times))
    with np.errstate(divide="ignore"):  # std 0 at the start from rest, before the window
        outside = norm.sf((levels - m[:, None]) / s[:, None]) + norm.cdf((-levels - m[:, None]) / s[:, None])
    if spread is not None:  # the spread decays: every time before the start is beyond the window's largest
        before, after = outside[t < start - 1e-12], outside[t >= start - 1e-12]
        assert np.all(np.min(before, axis=0) > np.max(after, axis=0))
    outside[t < start - 1e-12] = 0.0
    assert bound.dtype == jnp.float64 and 1e-6 < float(bound[-1, 1]) < float(bound[-1, 0]) < 0.5
    np.testing.assert_allclose(
        np.asarray(bound), np.maximum.accumulate(outside, axis=0), rtol=1e-10, atol=1e-15
    )

    if spread is not None:
        return  # the derivative once per method (its compilation is most of this test's time)

    def lower(log_k):
        sl = solve(OMEGA**2 * jnp.exp(log_k))
        return sl.peak_exceedance("u:x", levels, start=start, method=method).lower_bound[-1, 0]

    h = 1e-5
    fd = (float(lower(h)) - float(lower(-h))) / (2 * h)
    np.testing.assert_allclose(float(jax.jit(jax.grad(lower))(0.0)), fd, rtol=1e-5)


@pytest.mark.slow
def test_lower_bound_of_a_force_follows_its_moving_barrier():
    """A contact force's ``lower_bound`` at a level F: P(|delta| >= F / k(t)) with the mesh stiffness k(t) at
    each saved time, against SciPy from SL's deflection moments; a level of 0 N is reached at once (1 from the
    start, 0 before); at or under ``upper_bound``."""
    from scipy.stats import norm

    system, start = mesh_oscillator(), 0.1
    sl = pg.solve_moments(system, dt=1e-3, n_steps=400, deflection_lag=True)
    force = float(jnp.max(jnp.abs(sl.force_mean[:, 0])) + 2.5 * jnp.max(sl.force_std[:, 0]))
    estimate = sl.peak_exceedance("force:c", [0.0, force], start=start, system=system)
    t, m, s = (np.asarray(x) for x in (sl.times, sl.mean_delta[:, 0], sl.std_delta[:, 0]))
    barrier = force / (OMEGA**2 * (1.0 + 0.4 * np.sin(2 * np.pi * 7.0 * t)))  # the mesh_oscillator's k(t)
    assert np.isclose(barrier[100], force / float(system.contact_inputs(t[100])[0]), rtol=1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):  # std 0 at the start from rest
        outside = norm.sf((barrier - m) / s) + norm.cdf((-barrier - m) / s)
    counted = t >= start - 1e-12
    outside[~counted] = 0.0
    bound = np.asarray(estimate.lower_bound)
    np.testing.assert_allclose(bound[:, 1], np.maximum.accumulate(outside), rtol=1e-10, atol=1e-15)
    assert 1e-3 < bound[-1, 1] < 0.2  # a level that is neither certain nor out of reach
    np.testing.assert_array_equal(bound[:, 0], counted.astype(float))
    assert np.all(np.asarray(estimate.upper_bound) >= bound * (1 - 1e-12))


def _scaled(stiffness, factor):
    """A system's stiffness field (an array or a function of time) times ``factor``."""
    if callable(stiffness):
        return lambda t: factor * stiffness(t)
    return factor * jnp.asarray(stiffness)


@pytest.mark.slow
def test_sl_contact_peaks_refuse_what_they_cannot_estimate():
    system = mesh_oscillator(clearance=0.01, load=50.0)
    solve = dict(dt=1e-3, n_steps=20, deflection_lag=True, observables=pg.Observables([[2.0]], names=["y"]))
    sl = pg.solve_moments(system, **solve)
    unloaded = pg.solve_moments(mesh_oscillator(clearance=0.01), **solve)  # no mean force; the same program
    # as solved without the step lags (one compiled solve for the whole test)
    plain = eqx.tree_at(lambda r: (r.cov_u_lag, r.cov_delta_lag, r.cov_obs_lag), sl, (None, None, None))

    class Cubic(pg.ContactLaw):  # a law that does not give its deflection at a force level
        def force(self, delta, k, b):
            return k * delta**3

        def stiffness(self, delta, k, b):
            return 3 * k * delta**2

        def potential(self, delta, k, b):
            return 0.25 * k * delta**4

    cubic = eqx.tree_at(lambda s: s.contacts.law, system, Cubic())
    # |f| >= 0 N holds from the start, whatever the clearance (here 0.01 m)
    np.testing.assert_array_equal(
        np.asarray(sl.peak_exceedance("force:c", [0.0], system=system).probability), 1.0
    )
    # the systems solved pass the check, also under a jit closing over the result and the system
    levels = [0.5 * float(jnp.max(jnp.abs(sl.force_mean)))]
    eager = sl.peak_exceedance("force:c", levels, system=system).probability
    jitted = jax.jit(lambda: sl.peak_exceedance("force:c", levels, system=system).probability)()
    np.testing.assert_allclose(np.asarray(jitted), np.asarray(eager), rtol=1e-12)
    assert 0.0 < float(eager[-1, 0]) < 1.0
    assert np.isfinite(
        unloaded.peak_exceedance("force:c", [0.1], system=mesh_oscillator(clearance=0.01)).probability
    ).all()
    cases = [
        (lambda: plain.peak_exceedance("delta:c", [0.1]), r"solve with `deflection_lag=True` \(and save_every=1\)"),
        (lambda: sl.peak_exceedance("delta:d", [0.1]), "unknown contact 'd'"),
        (lambda: sl.peak_exceedance("obs:z", [0.1]), "unknown observable 'z'"),
        (lambda: plain.peak_exceedance("obs:y", [0.1]), r"solve with `deflection_lag=True` \(and save_every=1\)"),
        (lambda: sl.peak_exceedance("velocity:x", [0.1]), "or an observable 'obs:<observable>'"),
        (lambda: sl.peak_exceedance("delta:c", [0.1], method="rice"), "estimates displacements .* only"),
        (lambda: sl.peak_exceedance("u:x", [0.1], method="exact"), "`method` must be 'auto', 'steps' or"),
        (lambda: sl.peak_exceedance("u:x", [0.1], method="rice"), "solve with `covariance_dofs` including 'x'"),
        (lambda: plain.peak_exceedance("u:x", [0.1], method="steps"), r"`deflection_lag=True` \(and save_every"),
        (lambda: sl.peak_exceedance("force:c", [0.1]), "needs the `system` solved"),
        (lambda: sl.peak_exceedance("force:c", [0.1], system=oscillator()), "pass the system that was solved"),
        (lambda: sl.peak_exceedance("force:c", [0.1], system=mesh_oscillator(0.3, 0.3, clearance=0.01, load=50.0)),
         "`system` gives the force on contact 'c' at t = .* s a mean of .* for the deflection solved"),
        (lambda: sl.peak_exceedance("force:c", [0.1], system=cubic), "Cubic does not give"),
        (lambda: pg.solve_moments(system, dt=1e-3, n_steps=20, deflection_lag=1), "`deflection_lag` must"),
        (lambda: pg.solve_moments(system, dt=1e-3, n_steps=20, save_every=2, deflection_lag=True),
         "needs save_every = 1, got 2"),
    ]  # fmt: skip
    for call, message in cases:
        with pytest.raises(ValueError, match=message):
            call()
    # without a mean load, the force's std tells the stiffness
    with pytest.raises(ValueError, match="for the deflection solved, the result saved") as refused:
        unloaded.peak_exceedance("force:c", [0.1], system=mesh_oscillator(0.3, 0.3, clearance=0.01))
    saved_mean, saved_std = (
        float(x) for x in re.search(r"saved (\S+) N and (\S+) N", str(refused.value)).groups()
    )
    assert abs(saved_mean) < 1e-9 * saved_std, str(refused.value)
