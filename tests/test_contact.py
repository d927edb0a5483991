"""SL coefficients of the backlash law against independent quadrature and minimization."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate, stats

import pgtjax as pg
from pgtjax._contact import Backlash

pytestmark = pytest.mark.filterwarnings("ignore::scipy.integrate.IntegrationWarning")

LAW = Backlash()
K, B = 3.0e9, 2.0e-5
MU_OVER_B = [-6.0, -2.0, -1.0, -0.4, 0.0, 0.3, 0.99, 1.5, 3.0, 8.0]
SIGMA_OVER_B = [1e-3, 1e-2, 0.1, 0.5, 1.0, 3.0, 10.0, 100.0, 1e3]
GRID = list(itertools.product(MU_OVER_B, SIGMA_OVER_B))


def _gauss_expect(fun, mu, sigma, lo, hi):
    """E[fun(delta) 1{lo<delta<hi}] for delta ~ N(mu, sigma^2), by adaptive quadrature in z."""
    zlo, zhi = (lo - mu) / sigma, (hi - mu) / sigma
    zlo, zhi = max(zlo, -60.0), min(zhi, 60.0)
    if zlo >= zhi:
        return 0.0
    val, _ = integrate.quad(
        lambda z: fun(mu + sigma * z) * stats.norm.pdf(z), zlo, zhi, epsabs=0.0, epsrel=1e-13, limit=400
    )
    return val


def _reference(mu, sigma, b=B, k=K):
    up = _gauss_expect(lambda d: k * (d - b), mu, sigma, b, np.inf)
    lo = _gauss_expect(lambda d: k * (-b - d), mu, sigma, -np.inf, -b)
    p_out = stats.norm.sf((b - mu) / sigma) + stats.norm.cdf((-b - mu) / sigma)
    pot = lambda d: 0.5 * k * (max(d - b, 0.0) ** 2 + max(-b - d, 0.0) ** 2)  # noqa: E731
    pot_mu = pot(mu)
    # E[P] - P(mu) by quadrature of the difference (no cancellation in the reference either)
    excess = sum(
        _gauss_expect(lambda d: pot(d) - pot_mu, mu, sigma, a, c)
        for a, c in ((-np.inf, -b), (-b, b), (b, np.inf))
    )
    return dict(k_force=k * p_out, f0=up - lo, f0_scale=up + lo, excess=excess)


@pytest.mark.slow
@pytest.mark.parametrize("mu_b,sigma_b", GRID)
def test_force_coefficients_match_quadrature(mu_b, sigma_b):
    mu, sigma = mu_b * B, sigma_b * B
    ref = _reference(mu, sigma)
    lin = LAW.linearize(jnp.array(mu), jnp.array(sigma), K, B, pg.ForceCriterion())
    assert lin.k_e.dtype == jnp.float64 and lin.f_0.dtype == jnp.float64
    assert abs(float(lin.k_e) - ref["k_force"]) <= 1e-8 * max(ref["k_force"], 1e-300)
    # f_0 = E[A] - E[B] is a difference of two positive expectations: relative to their sum.
    assert abs(float(lin.f_0) - ref["f0"]) <= 1e-8 * max(ref["f0_scale"], 1e-300)


@pytest.mark.slow
@pytest.mark.parametrize("mu_b,sigma_b", GRID)
def test_energy_coefficients_match_quadrature(mu_b, sigma_b):
    mu, sigma = mu_b * B, sigma_b * B
    ref = _reference(mu, sigma)
    expected = 2.0 / 3.0 * (ref["k_force"] + ref["excess"] / sigma**2)
    lin = LAW.linearize(jnp.array(mu), jnp.array(sigma), K, B, pg.EnergyCriterion())
    assert abs(float(lin.k_e) - expected) <= 1e-8 * max(expected, 1e-300)


@pytest.mark.parametrize(
    "mu_b,sigma_b", [(-1.0, 0.5), (0.0, 1.0), (0.5, 0.3), (1.5, 1.0), (3.0, 0.2), (0.0, 5.0)]
)
def test_energy_criterion_is_the_minimizer_of_the_potential_error(mu_b, sigma_b):
    """The minimizer of E[(P(mu+y) - P(mu) - k_e y^2/2 - f_0 y)^2] over (k_e, f_0), y ~ N(0, sigma^2).

    The error is linear in (k_e, f_0), so its mean square is a quadratic whose minimizer solves the normal
    equations: with y = sigma z and g(z) = P(mu + sigma z) - P(mu), and E[z^3] = 0, E[z^4] = 3, they decouple
    into k_e = (2/3) E[g z^2] / sigma^2 and f_0 = E[g z] / sigma. The two means are integrated numerically
    (adaptive quadrature, break points at the flanks), independently of the library's closed form; the mean
    square itself is checked to grow when the minimizer is perturbed."""
    mu, sigma = mu_b * B, sigma_b * B
    pot = lambda d: 0.5 * K * (max(d - B, 0.0) ** 2 + max(-B - d, 0.0) ** 2)  # noqa: E731
    g = lambda z: pot(mu + sigma * z) - pot(mu)  # noqa: E731

    def gaussian_mean(f):
        val, _ = integrate.quad(
            lambda z: f(z) * stats.norm.pdf(z),
            -12,
            12,
            points=[(-B - mu) / sigma, (B - mu) / sigma],
            epsabs=0,
            epsrel=1e-12,
            limit=200,
        )
        return val

    ke = 2.0 / 3.0 * gaussian_mean(lambda z: g(z) * z * z) / sigma**2
    f0 = gaussian_mean(lambda z: g(z) * z) / sigma

    def mean_square_error(ke_, f0_):
        err = lambda z: g(z) - 0.5 * ke_ * (sigma * z) ** 2 - f0_ * sigma * z  # noqa: E731
        return gaussian_mean(lambda z: err(z) ** 2) / (K * sigma**2) ** 2

    best = mean_square_error(ke, f0)
    for dk, df in ((1e-3, 0.0), (-1e-3, 0.0), (0.0, 1e-3), (0.0, -1e-3), (1e-3, -1e-3)):
        assert mean_square_error(ke + dk * K, f0 + df * K * sigma) > best
    lin = LAW.linearize(jnp.array(mu), jnp.array(sigma), K, B, pg.EnergyCriterion())
    np.testing.assert_allclose(float(lin.k_e) / K, ke / K, rtol=0, atol=1e-9)
    np.testing.assert_allclose(float(lin.f_0) / (K * sigma), f0 / (K * sigma), rtol=0, atol=1e-9)


def test_exact_cases():
    """Linear spring (b = 0) and permanent contact: both criteria give k; deep in the gap: 0."""
    for crit in (pg.ForceCriterion(), pg.EnergyCriterion()):
        lin = LAW.linearize(jnp.array(3e-6), jnp.array(2e-6), K, 0.0, crit)
        np.testing.assert_allclose(float(lin.k_e), K, rtol=1e-14)
        np.testing.assert_allclose(float(lin.f_0), K * 3e-6, rtol=1e-14)
        lin = LAW.linearize(jnp.array(50 * B), jnp.array(0.1 * B), K, B, crit)
        np.testing.assert_allclose(float(lin.k_e), K, rtol=1e-14)
        np.testing.assert_allclose(float(lin.f_0), K * 49 * B, rtol=1e-14)
        lin = LAW.linearize(jnp.array(0.0), jnp.array(0.01 * B), K, B, crit)
        assert float(lin.k_e) == 0.0 and float(lin.f_0) == 0.0
    # The printed Eq. 4.43 (potential about the origin) overestimates k_e in permanent contact by
    # (mu-b)^2/(3 sigma^2) (docs/corrections.md C1), which is why it is not offered: its E[P] by quadrature.
    mu, sigma = 5 * B, 1 * B
    force_ke = float(LAW.linearize(jnp.array(mu), jnp.array(sigma), K, B, pg.ForceCriterion()).k_e)
    mean_potential = float(LAW.gaussian_expectation(LAW.potential, jnp.array(mu), jnp.array(sigma), K, B))
    printed_ke = 2 / 3 * (force_ke + mean_potential / sigma**2)
    assert printed_ke > 5.0 * K
    np.testing.assert_allclose(
        printed_ke, 2 / 3 * (force_ke + 0.5 * K * ((mu - B) ** 2 + sigma**2) / sigma**2), rtol=1e-6
    )
    with pytest.raises(ValueError, match="`criterion` must be an SL criterion object"):
        LAW.linearize(jnp.array(mu), jnp.array(sigma), K, B, "energy_origin")


def test_zero_sigma_is_the_deterministic_limit():
    for mu in (-3 * B, -0.5 * B, 0.7 * B, 2 * B):
        lin = LAW.linearize(jnp.array(mu), jnp.array(0.0), K, B, pg.ForceCriterion())
        np.testing.assert_allclose(float(lin.f_0), float(LAW.force(mu, K, B)), rtol=1e-15, atol=0)
        assert float(lin.k_e) == float(LAW.stiffness(jnp.array(mu), K, B))


@pytest.mark.slow
@pytest.mark.parametrize("crit", [pg.ForceCriterion(), pg.EnergyCriterion()], ids=["force", "energy"])
def test_gradients_finite_on_grid_and_match_finite_differences(crit):
    """The coefficients' derivatives (hand-written in terms of Phi and phi, see contact._flank_statistics)
    against central differences in (mu, sigma, k, b), in reverse and forward mode."""

    def coeffs(p):
        lin = LAW.linearize(p[0] * B, p[1] * B, p[2] * K, p[3] * B, crit)
        return jnp.stack([lin.k_e / K, lin.f_0 / (K * B)])

    jac = jax.jit(jax.jacrev(coeffs))
    jac_fwd = jax.jit(jax.jacfwd(coeffs))
    for mu_b, sigma_b in GRID:
        p = jnp.array([mu_b, sigma_b, 1.0, 1.0])
        J = np.asarray(jac(p))
        assert np.all(np.isfinite(J)), (mu_b, sigma_b)
        np.testing.assert_allclose(np.asarray(jac_fwd(p)), J, rtol=1e-13, atol=1e-15)
        if 0.05 <= sigma_b <= 20:
            h = 1e-6
            fd = np.stack(
                [
                    (np.asarray(coeffs(p + h * e)) - np.asarray(coeffs(p - h * e))) / (2 * h)
                    for e in np.eye(4)
                ],
                axis=1,
            )
            np.testing.assert_allclose(J, fd, rtol=1e-5, atol=1e-7 * (1 + np.abs(fd).max()))


@pytest.mark.slow
@pytest.mark.parametrize("crit", [pg.ForceCriterion(), pg.EnergyCriterion()], ids=["force", "energy"])
def test_hand_written_flank_derivatives_equal_plain_autodiff(crit):
    """The custom JVP of contact._flank_statistics against plain autodiff of the same primal
    (contact._flank_values), on edge cases the finite-difference grid does not reach: sigma = 0, b = 0,
    z = 0 (mu = +-b), deep saturation and tiny sigma."""
    from pgtjax._contact import _flank_statistics, _flank_values

    mu = jnp.array([0.0, 1.0, -1.0, 0.3, 2.5, -45.0, 1e-3, 0.0, 1.0, 0.7])
    sigma = jnp.array([0.0, 0.0, 1.0, 0.5, 1e-3, 1.0, 1e-9, 2.0, 3.0, 30.0])
    b = jnp.array([1.0, 0.0, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 1.0])

    def stacked(stats_fn):
        def f(mu, sigma, b):
            offset = jnp.stack([mu - b, -b - mu])
            return jnp.concatenate(stats_fn(crit, offset, sigma[None]))

        return f

    plain = stacked(lambda c, o, s: _flank_values(c, o, s)[3])
    custom = stacked(_flank_statistics)
    np.testing.assert_array_equal(np.asarray(custom(mu, sigma, b)), np.asarray(plain(mu, sigma, b)))
    for argnum in range(3):
        j_custom = np.asarray(jax.jacfwd(custom, argnums=argnum)(mu, sigma, b))
        j_plain = np.asarray(jax.jacfwd(plain, argnums=argnum)(mu, sigma, b))
        assert j_custom.dtype == np.float64 and np.all(np.isfinite(j_custom))
        scale = np.maximum(np.abs(j_plain).max(axis=1, keepdims=True), 1e-300)
        np.testing.assert_allclose(j_custom / scale, j_plain / scale, rtol=0, atol=1e-12)


def test_force_moments_match_quadrature():
    for mu_b, sigma_b in [(-1.0, 0.5), (0.0, 1.0), (2.0, 0.7), (10.0, 0.2), (0.0, 30.0)]:
        mu, sigma = mu_b * B, sigma_b * B
        f = lambda d: float(LAW.force(d, K, B))  # noqa: E731
        m1 = sum(_gauss_expect(f, mu, sigma, a, c) for a, c in ((-np.inf, -B), (B, np.inf)))
        m2 = sum(_gauss_expect(lambda d: f(d) ** 2, mu, sigma, a, c) for a, c in ((-np.inf, -B), (B, np.inf)))
        mean, std = LAW.force_moments(jnp.array(mu), jnp.array(sigma), K, B)
        np.testing.assert_allclose(float(mean), m1, rtol=1e-9, atol=1e-12 * K * B)
        np.testing.assert_allclose(float(std), np.sqrt(max(m2 - m1**2, 0.0)), rtol=1e-6)


def test_bad_criterion():
    with pytest.raises(ValueError, match="criterion"):
        LAW.linearize(jnp.array(0.0), jnp.array(1.0), K, B, "energetic")
