"""Peaks of a Gaussian response from its moments: Rice's level crossings, for SL's counterpart of Monte
Carlo's peak counts (:meth:`pgtjax.MomentResult.peak_exceedance`; docs/peaks.md).

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
    random = std > 0.0
    s_safe = jnp.where(random, std, 1.0)
    gaussian = ndtr((mean - a) / s_safe) + ndtr((-a - mean) / s_safe)
    return jnp.where(random, gaussian, (jnp.abs(mean) >= a).astype(a.dtype))


def cumulative_trapezoid(values, times, first=0):
    """``int_{times[first]}^{times[j]} values dt`` for every j (trapezoids; 0 for j <= first), (n, k) from
    (n, k) and (n,); ``first`` may be traced."""
    steps = 0.5 * (values[1:] + values[:-1]) * jnp.diff(times)[:, None]
    steps = jnp.where((jnp.arange(steps.shape[0]) >= first)[:, None], steps, 0.0)
    return jnp.concatenate([jnp.zeros_like(values[:1]), jnp.cumsum(steps, axis=0)])
