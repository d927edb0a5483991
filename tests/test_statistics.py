"""Statistics users of stationary random vibration ask for: SL's contact-loss probability, and Monte Carlo
statistics time-averaged over a window with batch-means standard errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import pgtjax as pg

M, C, K, S0, B = 1.0, 0.8, 40.0, 0.05, 0.03


def _oscillator():
    """m x'' + c x' + k x = w with a zero-stiffness 'contact' of clearance b: its deflection is exactly
    Gaussian, so SL's P(|x| < b) is exact and Monte Carlo's count is an independent estimate of it."""
    contacts = pg.Contacts(direction=[[1.0]], stiffness=[0.0], clearance=[B], names=["gauge"])
    return pg.System(
        mass=[[M]],
        stiffness=[[K]],
        damping=[[C]],
        noise_input=[[1.0]],
        spectral_density=S0,
        contacts=contacts,
        dof_names=["x"],
    )


KW = dict(dt=0.01, n_steps=4000, save_every=20)


@pytest.mark.slow
def test_sl_contact_loss_probability_matches_monte_carlo_counts():
    system = _oscillator()
    sl = pg.solve_moments(system, **KW)
    mc = pg.monte_carlo(system, n_samples=3000, key=jax.random.key(5), progress=False, **KW)
    p_sl = sl.contact_loss_probability(system)
    assert p_sl.shape == (201, 1) and p_sl.dtype == jnp.float64
    np.testing.assert_array_equal(p_sl, sl.contact_loss_probability(jnp.array([B])))
    assert float(p_sl[0, 0]) == 1.0  # starts at rest, inside the gap
    p_mc = np.asarray(mc.contact_loss_probability)
    se = np.sqrt(np.maximum(p_mc * (1 - p_mc), 1e-4) / mc.n_samples)
    assert np.all(np.abs(np.asarray(p_sl) - p_mc) < 4.5 * se)
    # and it is the stationary Gaussian value at the end: sigma^2 = pi S0 / (c k)
    sigma = np.sqrt(np.pi * S0 / (C * K))
    from scipy.stats import norm

    np.testing.assert_allclose(float(p_sl[-1, 0]), norm.cdf(B / sigma) - norm.cdf(-B / sigma), rtol=1e-3)


def test_time_average_with_batch_means_covers_the_exact_stationary_moments():
    system = _oscillator()
    mc = pg.monte_carlo(system, n_samples=500, key=jax.random.key(11), progress=False, **KW)
    avg = mc.time_average("u", t_start=10.0, n_batches=10)  # the transient decays as exp(-c t / 2m)
    assert avg.n_times == 150 and avg.std.dtype == np.float64  # 151 saved times, trimmed to 10 x 15
    sigma = np.sqrt(np.pi * S0 / (C * K))
    assert abs(float(avg.mean[0])) < 4.0 * float(avg.mean_se[0])
    assert abs(float(avg.std[0]) - sigma) < 4.0 * float(avg.std_se[0])
    # The error of a long time average is set by the zero-frequency spectral density of x, S0 / k^2 (2 pi S0
    # convention): Var = 2 pi S0 / (k^2 T N) for a window T. Saved times are correlated, so the naive
    # sigma / sqrt(N n_times) is wrong (here too large: the oscillation's half-periods cancel); 10 batch means
    # estimate the right value to about 25 %.
    window = 30.0
    expected_se = np.sqrt(2.0 * np.pi * S0 / (K**2 * window * mc.n_samples))
    assert 0.5 * expected_se < float(avg.mean_se[0]) < 2.0 * expected_se


@pytest.mark.slow
@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(what="w"), "what"),
        (dict(n_batches=1), "n_batches"),
        (dict(t_start=50.0), "window"),
        (dict(t_start=3.5), "at least 2 per batch"),
    ],
)
def test_time_average_bad_input(kwargs, match):
    mc = pg.monte_carlo(
        _oscillator(),
        n_samples=10,
        key=jax.random.key(0),
        progress=False,
        dt=0.01,
        n_steps=400,
        save_every=10,
    )
    with pytest.raises(ValueError, match=match):
        mc.time_average(**kwargs)


@pytest.mark.slow
def test_gap_probability_far_from_the_gap_keeps_its_digits():
    from scipy.stats import norm

    result_like = pg.solve_moments(_oscillator(), dt=0.01, n_steps=2)
    mean = jnp.array([[12.0 * B], [-12.0 * B]])
    std = jnp.full((2, 1), B)
    from pgtjax._results import _gaussian_gap_probability

    p = _gaussian_gap_probability(mean, std, jnp.array([[B]]))
    exact = norm.sf(11.0) - norm.sf(13.0)  # P(-b < x < b) for x ~ N(12 b, b^2)
    np.testing.assert_allclose(np.asarray(p)[:, 0], exact, rtol=1e-10)
    assert result_like.contact_loss_probability(_oscillator()).shape == (3, 1)
