"""Peaks of a Gaussian response from its moments: Rice's level crossings, for SL's counterpart of Monte
Carlo's peak counts (:meth:`pgtjax.MomentResult.peak_exceedance`; docs/peaks.md). Two forms: Rice's
continuous-time rate (a displacement, from the displacement-velocity covariance) and its discrete-time
counterpart, the probability of crossing between consecutive steps (a displacement, contact deflection or
force, or an observable, from the covariance of each step with the one before: the peaks Monte Carlo takes,
whatever the step resolves).

For a Gaussian process ``X(t)`` with the joint moments of ``(X, dX/dt)`` at each time, the mean rate at which
``|X|`` reaches a level ``a`` (up-crossings of ``+a`` and down-crossings of ``-a``) is Rice's expected rate of
crossings (S. O. Rice, Mathematical analysis of random noise, Bell Syst. Tech. J. 24, 1945, part III), written
with the moments of each time (Y. K. Lin, Probabilistic Theory of Structural Dynamics, 1967):

    nu(a, t) = p_X(a) E[(dX/dt)^+ | X = a] + p_X(-a) E[(dX/dt)^- | X = -a]

with ``dX/dt | X = x ~ N(m' + c (x - m) / s^2, s'^2 - c^2 / s^2)`` (``m, s``: mean and std of X; ``m', s'``:
of its rate; ``c`` their covariance). Its integral over a window is the expected number of crossings N. Then
``P0 + N`` bounds the probability that the peak over the window reaches ``a`` (``P0``: already at ``t_start``),
and ``1 - (1 - P0) exp(-N)`` is the estimate that treats the crossings as a Poisson stream: accurate for high
levels, where crossings are rare and independent; above the truth for lower levels of a narrow-band response,
whose crossings come in clumps.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jax.scipy.special import ndtr

from ._numerics import safe_sqrt

_INV_SQRT_2PI = 0.3989422804014327


def _normal_density(z):
    return _INV_SQRT_2PI * jnp.exp(-0.5 * z * z)


def _positive_part_mean(mean, std):
    """E[Y^+] for Y ~ N(mean, std^2), elementwise (``max(mean, 0)`` where std = 0)."""
    positive = std > 0.0
    safe = jnp.where(positive, std, 1.0)
    z = mean / safe
    return jnp.where(positive, safe * _normal_density(z) + mean * ndtr(z), jnp.maximum(mean, 0.0))


def crossing_rate(levels, mean, std, rate_mean, rate_std, covariance):
    """Rice's mean rate (1/s) at which ``|X|`` reaches each level: up-crossings of ``+a`` and down-crossings
    of ``-a``. ``levels`` (k,) >= 0 in X's unit; the moments of X and of its rate dX/dt, (n,) each: mean,
    std, rate mean, rate std and their covariance. Returns (n, k); 0 where X is deterministic (std = 0)."""
    a = jnp.asarray(levels)[None, :]
    m, s, md, sd, c = (jnp.asarray(x)[:, None] for x in (mean, std, rate_mean, rate_std, covariance))
    random = s > 0.0
    s_safe = jnp.where(random, s, 1.0)
    # the rate given X = x: mean md + c (x - m) / s^2, std sqrt(sd^2 - c^2 / s^2) (Cauchy-Schwarz: >= 0)
    # safe_sqrt: the variance is exactly 0 where u and v are fully correlated (the first Newmark step from
    # rest, u1 = dt v1 / 2), and a plain sqrt's derivative there turned gradients into NaN
    conditional_std = safe_sqrt(sd * sd - (c / s_safe) ** 2)
    total = 0.0
    for x, sign in ((a, 1.0), (-a, -1.0)):  # up through +a; down through -a (the rate's negative part)
        density = _normal_density((x - m) / s_safe) / s_safe
        conditional_mean = md + c * (x - m) / (s_safe * s_safe)
        total = total + density * _positive_part_mean(sign * conditional_mean, conditional_std)
    return jnp.where(random, total, 0.0)


def exceedance_at_start(levels, mean, std):
    """P(|X| >= a) for X ~ N(mean, std^2) (scalars), each level (k,); for std = 0, whether |mean| >= a."""
    a = jnp.asarray(levels)
    return outside_probability(a, -a, mean, std)


def outside_probability(upper, lower, mean, std):
    """P(X >= upper or X <= lower) for X ~ N(mean, std^2) (scalars), barriers (k,) with lower <= upper; for
    std = 0, whether the mean lies outside."""
    random = std > 0.0
    s_safe = jnp.where(random, std, 1.0)
    # a barrier at infinity is never reached; kept finite inside, so that no inf meets a derivative
    finite_upper, finite_lower = jnp.isfinite(upper), jnp.isfinite(lower)
    upper_safe, lower_safe = jnp.where(finite_upper, upper, mean), jnp.where(finite_lower, lower, mean)
    above = jnp.where(finite_upper, ndtr((mean - upper_safe) / s_safe), 0.0)
    below = jnp.where(finite_lower, ndtr((lower_safe - mean) / s_safe), 0.0)
    outside = (finite_upper & (mean >= upper_safe)) | (finite_lower & (mean <= lower_safe))
    return jnp.where(random, above + below, outside.astype(jnp.result_type(upper, float)))


# Gauss-Legendre nodes on (0, 1) for _correlation_tail; the substitution s = sqrt(1 - rho) u^3 gathers them where
# the integrand rises steeply (near s = |h - k| / 2 for close levels). 32 nodes: within 1e-5 of the
# probability (relative) against adaptive high-precision quadrature (tests/test_crossings.py).
_GAUSS_LEGENDRE = np.polynomial.legendre.leggauss(32)
_NODES, _WEIGHTS = 0.5 * (_GAUSS_LEGENDRE[0] + 1.0), 0.5 * _GAUSS_LEGENDRE[1]


def _correlation_tail(h, k, rho):
    """``Phi2(h, k; 1) - Phi2(h, k; rho) = int_rho^1 phi2(h, k; r) dr`` for standard bivariate normals with
    correlation ``rho`` in [0, 1] (Plackett's identity d Phi2 / d rho = phi2), written with ``r = 1 - s^2`` so
    that the integrand is bounded:
    ``(1 / pi) int_0^sqrt(1 - rho) exp(-(h - k)^2 / (2 s^2 (2 - s^2)) - h k / (2 - s^2)) / sqrt(2 - s^2) ds``.
    Elementwise; >= 0."""
    top = safe_sqrt(1.0 - rho)[..., None]
    shape = (1,) * (top.ndim - 1) + (-1,)  # the nodes on a trailing axis (no implicit rank promotion)
    u, weights = jnp.asarray(_NODES).reshape(shape), jnp.asarray(_WEIGHTS).reshape(shape)
    s = top * u**3
    s2 = s * s
    # s > 0 at every node (and top > 0); where top = 0 the weights are 0 and so is the sum
    s2_safe = jnp.where(s2 > 0.0, s2, 1.0)
    exponent = -((h - k)[..., None] ** 2) / (2.0 * s2_safe * (2.0 - s2)) - (h * k)[..., None] / (2.0 - s2)
    integrand = jnp.where(s2 > 0.0, jnp.exp(exponent), 0.0) / jnp.sqrt(2.0 - s2)
    return jnp.sum(weights * 3.0 * u**2 * top * integrand, axis=-1) / np.pi


def step_crossing_probability(before, after, rho):
    """P(X < before, Y >= after) for standard normals X, Y with correlation ``rho`` (elementwise, broadcast):
    the probability that a level is crossed upwards between two steps, the levels standardized by each step's
    moments. Written as sums of non-negative terms, so that a small probability (close levels, rho near 1)
    keeps its relative accuracy."""
    before, after, rho = jnp.broadcast_arrays(*(jnp.asarray(x, jnp.float64) for x in (before, after, rho)))
    rho = jnp.clip(rho, -1.0, 1.0)
    positive = rho >= 0.0
    # rho >= 0: Phi(-b) - Phi2(-a, -b; rho) = (Phi(-b) - Phi(-a))^+ + tail(-a, -b, rho)
    same = jnp.where(before > after, ndtr(-after) - ndtr(-before), 0.0) + _correlation_tail(
        -before, -after, jnp.where(positive, rho, 0.0)
    )
    # rho < 0: Phi2(a, -b; -rho) = Phi(min(a, -b)) - tail(a, -b, -rho)
    opposite = ndtr(jnp.minimum(before, -after)) - _correlation_tail(
        before, -after, jnp.where(positive, 0.0, -rho)
    )
    return jnp.where(positive, same, jnp.maximum(opposite, 0.0))


def step_crossings(upper, lower, mean, std, lag_covariance):
    """Probability that ``X`` leaves the band between ``lower`` and ``upper`` between each pair of consecutive
    steps: up through ``upper`` or down through ``lower`` (each (n, k), barriers that may move from step to
    step), from X's mean and std at each step and the covariance of each step with the one before
    (``lag_covariance``, (n,); the first unused). Returns (n - 1, k), row j for the step from j to j + 1. A
    deterministic step (std 0) enters through its value. An up-crossing counts every X0 below ``upper``, those
    below ``lower`` too (a jump across the band: conservative, and negligible at the levels of interest)."""
    m, s, lag = (jnp.asarray(x) for x in (mean, std, lag_covariance))
    s0, s1 = s[:-1, None], s[1:, None]
    m0, m1 = m[:-1, None], m[1:, None]
    random0, random1 = s0 > 0.0, s1 > 0.0
    safe0, safe1 = jnp.where(random0, s0, 1.0), jnp.where(random1, s1, 1.0)
    rho = jnp.where(random0 & random1, lag[1:, None] / (safe0 * safe1), 0.0)

    def up(barrier0, barrier1, sign):
        # a barrier at infinity (a force level of a contact without stiffness) is never reached: none is
        # crossed at the step's end, and every value lies inside it at the start (kept finite inside, so that
        # no inf meets a derivative)
        finite0, finite1 = jnp.isfinite(barrier0), jnp.isfinite(barrier1)
        barrier0, barrier1 = jnp.where(finite0, barrier0, m0), jnp.where(finite1, barrier1, m1)
        # the levels standardized (sign -1: the lower barrier, as an upper one of -X)
        a = sign * (barrier0 - m0) / safe0
        b = sign * (barrier1 - m1) / safe1
        both = step_crossing_probability(a, b, rho)
        # a deterministic step: its side of the barrier is known
        inside0 = (sign * (m0 - barrier0) < 0.0).astype(a.dtype)
        outside1 = (sign * (m1 - barrier1) >= 0.0).astype(a.dtype)
        below0 = jnp.where(random0, ndtr(a), inside0)  # P(X0 inside), for a step 1 known
        above1 = jnp.where(random1, ndtr(-b), outside1)  # P(X1 outside), for a step 0 certainly inside
        crossing = jnp.where(random0 & random1, both, below0 * above1)
        crossing = jnp.where(finite0, crossing, above1)
        return jnp.where(finite1, crossing, 0.0)

    return up(upper[:-1], upper[1:], 1.0) + up(lower[:-1], lower[1:], -1.0)


def cumulative_trapezoid(values, times, first=0):
    """``int_{times[first]}^{times[j]} values dt`` for every j (trapezoids; 0 for j <= first), (n, k) from
    (n, k) and (n,); ``first`` may be traced."""
    steps = 0.5 * (values[1:] + values[:-1]) * jnp.diff(times)[:, None]
    steps = jnp.where((jnp.arange(steps.shape[0]) >= first)[:, None], steps, 0.0)
    return jnp.concatenate([jnp.zeros_like(values[:1]), jnp.cumsum(steps, axis=0)])
