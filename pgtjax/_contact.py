"""Contact laws and their statistical linearization for a Gaussian deflection.

A contact acts along a direction ``g`` with deflection ``delta = g^T q``; its force is ``f(delta)`` with
stiffness ``k`` (N/m) and half-clearance ``b`` (m). The backlash law is thesis Eq. 3.32 (= Eq. 4.9):

    f(delta) = k (delta - b)   for delta >= b
               0               for |delta| < b
               k (delta + b)   for delta <= -b

Statistical linearization replaces ``f`` by ``k_e (delta - mu) + f_0`` for ``delta ~ N(mu, sigma^2)``.

Criteria (the ``criterion`` argument, an :class:`AbstractCriterion` object):

:class:`ForceCriterion`
    Minimum mean-square force error, thesis Eqs. 3.35-3.38: ``k_e = E[f']``, ``f_0 = E[f]``; closed forms
    Eqs. 3.39-3.42 (the erf forms). We evaluate them through the standard-normal quantities below, which are
    algebraically identical to Eqs. 3.39-3.40 but free of the cancellation that ``erf(V1) - erf(V2)`` suffers
    when ``sigma << b``.
:class:`EnergyCriterion`
    Minimum mean-square error of the potential energy of the *fluctuating* part (thesis ch. 4, Eqs. 4.31-4.43,
    as corrected here): minimizing
    ``E[(P(mu + y) - P(mu) - k_e y^2 / 2 - f_0 y)^2]`` over ``(k_e, f_0)`` with ``y ~ N(0, sigma^2)`` gives, by
    Stein's lemma, ``f_0 = E[f]`` (Eq. 4.49) and
    ``k_e = 2/3 (E[f'] + (E[P] - P(mu)) / sigma^2)``.
    For a linear spring (b = 0) or permanent contact this returns ``k`` exactly.

Eq. 4.43 as printed, ``k_e = 2/3 (E[f'] + E[P] / sigma^2)`` with the potential measured about the origin, is
not offered: under a static load it overestimates ``k_e`` by ``(mu - b)^2 / (3 sigma^2)`` relative and its
fixed point can settle on a spurious branch (docs/corrections.md, C1). Where ``|mu| <= b`` it equals
:class:`EnergyCriterion`.

The potential is the continuous one, ``P = k (delta -/+ b)^2 / 2`` outside the gap and 0 inside. Eq. 4.32 as
printed (``k delta^2/2 - k b delta``) differs by the constant ``-k b^2/2`` and is discontinuous at ``+-b``,
which breaks the integration by parts (Stein's lemma) the derivation rests on.

Numerics: with ``z = (mu - b) / sigma`` the expectations are ``sigma`` times functions of ``z`` built from
``Phi`` (via ``erfc``, relatively accurate in the tails) and ``phi``; ``z`` is clipped to +-40 where ``Phi``
and ``phi`` are exactly saturated in float64, so every coefficient is finite and differentiable for every
``sigma >= 0`` (``sigma = 0`` gives the deterministic limit ``k_e = f'(mu)``, ``f_0 = f(mu)``) and for ``b = 0``.
"""

from __future__ import annotations

import abc
import functools
from typing import ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import erfc

from ._numerics import safe_sqrt

_SQRT2 = 1.4142135623730951
_INV_SQRT_2PI = 0.3989422804014327
_Z_SATURATION = 40.0


class Linearization(NamedTuple):
    """Equivalent linear contact ``f ~ k_e (delta - mu) + f_0`` (N/m, N)."""

    k_e: jnp.ndarray
    f_0: jnp.ndarray


class AbstractCriterion(eqx.Module):
    """Strategy: how statistical linearization picks ``(k_e, f_0)`` from the Gaussian expectations of a
    contact law. A law supplies ``E[f]``, ``E[f']`` and, if :attr:`potential_reference` is ``"mean"``, the
    excess potential ``(E[P] - P(mu)) / sigma^2``."""

    name: ClassVar[str]
    potential_reference: ClassVar[str | None]

    @abc.abstractmethod
    def coefficients(self, mean_force, mean_stiffness, excess_potential) -> Linearization:
        """``(k_e, f_0)`` from ``E[f]`` (N), ``E[f']`` (N/m) and the excess potential ratio (N/m, or None)."""


class ForceCriterion(AbstractCriterion):
    """Minimum mean-square force error, thesis Eqs. 3.35-3.42: ``k_e = E[f']``, ``f_0 = E[f]``."""

    name: ClassVar[str] = "force"
    potential_reference: ClassVar[str | None] = None

    def coefficients(self, mean_force, mean_stiffness, excess_potential) -> Linearization:
        return Linearization(mean_stiffness, mean_force)


class EnergyCriterion(AbstractCriterion):
    """Minimum mean-square error of the fluctuating part's potential energy (ch. 4, corrected; module
    docstring): ``k_e = 2/3 (E[f'] + (E[P] - P(mu)) / sigma^2)``, ``f_0 = E[f]``."""

    name: ClassVar[str] = "energy"
    potential_reference: ClassVar[str | None] = "mean"

    def coefficients(self, mean_force, mean_stiffness, excess_potential) -> Linearization:
        return Linearization(2.0 / 3.0 * (mean_stiffness + excess_potential), mean_force)


def check_criterion(criterion) -> AbstractCriterion:
    """``criterion`` itself, checked: an SL criterion object (names such as ``"force"`` are the CLI's, which
    maps them to these objects)."""
    if not isinstance(criterion, AbstractCriterion):
        raise ValueError(
            "`criterion` must be an SL criterion object: pgtjax.ForceCriterion() (thesis Eqs. 3.37-3.42), "
            "pgtjax.EnergyCriterion() (ch. 4, corrected) or a subclass of pgtjax.AbstractCriterion, "
            f"got {criterion!r}"
        )
    if criterion.potential_reference not in (None, "mean"):
        raise ValueError(
            f"`criterion` {type(criterion).__name__}: potential_reference must be None (force-type) or "
            f"'mean' (energy-type), got {criterion.potential_reference!r}"
        )
    return criterion


def _cdf(z):
    return 0.5 * erfc(-z / _SQRT2)


def _pdf(z):
    return _INV_SQRT_2PI * jnp.exp(-0.5 * z * z)


def _second_moment_ratio(z, cdf=None, pdf=None):
    """E[(X+)^2] / s^2 for X ~ N(z s, s^2): (z^2 + 1) Phi(z) + z phi(z) (Phi(z), phi(z) computed here unless
    given)."""
    cdf = _cdf(z) if cdf is None else cdf
    pdf = _pdf(z) if pdf is None else pdf
    return (z * z + 1.0) * cdf + z * pdf


def _standardize(offset, sigma):
    """z = offset / sigma, saturated to +-40 (exact in float64), sigma = 0 allowed."""
    positive = sigma > 0.0
    safe_sigma = jnp.where(positive, sigma, 1.0)
    z = jnp.where(positive, offset / safe_sigma, jnp.where(offset >= 0.0, _Z_SATURATION, -_Z_SATURATION))
    return jnp.clip(z, -_Z_SATURATION, _Z_SATURATION)


def _positive_part_mean(offset, sigma, z, cdf=None, pdf=None):
    """E[X+] for X ~ N(offset, sigma^2) = offset Phi(z) + sigma phi(z) (Phi(z), phi(z) computed here unless
    given)."""
    cdf = _cdf(z) if cdf is None else cdf
    pdf = _pdf(z) if pdf is None else pdf
    return offset * cdf + sigma * pdf


def _flank_values(criterion, offset, sigma):
    """``z``, ``Phi(z)``, ``phi(z)``, the flank statistics (see :func:`_flank_statistics`) and the derivative
    of the excess term with respect to ``z`` (None for the force criterion)."""
    z = _standardize(offset, sigma)
    cdf, pdf = _cdf(z), _pdf(z)
    stats = [cdf, _positive_part_mean(offset, sigma, z, cdf, pdf)]
    d_excess = None
    if criterion == "energy":
        # (E[(X+)^2] - max(E[X], 0)^2) / sigma^2 without cancellation: for z > 0,
        # E[(X+)^2] = E[X^2] - E[(X-)^2], so the excess is 1 - G(-z) (G = _second_moment_ratio);
        # Phi(-z) is shared with the derivative
        cdf_neg = _cdf(-z)  # phi is even: phi(-z) = pdf
        upper = 1.0 - _second_moment_ratio(-z, cdf_neg, pdf)
        stats.append(jnp.where(z > 0.0, upper, _second_moment_ratio(z, cdf, pdf)))
        d_excess = 2.0 * jnp.where(z > 0.0, pdf - z * cdf_neg, z * cdf + pdf)
    return z, cdf, pdf, tuple(stats), d_excess


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _flank_statistics(criterion, offset, sigma):
    """For a flank deflection ``X ~ N(offset, sigma^2)``: ``(P(X > 0), E[X+])`` and, for the energy
    criterion, the excess second moment ``(E[(X+)^2] - max(E[X], 0)^2) / sigma^2``.

    Its derivatives are written in terms of the same ``Phi(z)`` and ``phi(z)`` (no new special-function
    evaluations): with ``dz = (d offset - z d sigma) / sigma`` (zero where ``z`` is saturated, ``|z| = 40``
    included, or sigma = 0), ``dPhi = phi dz``, ``dE[X+] = Phi d offset + phi d sigma`` (exact also where z
    is saturated) and ``d excess = excess'(z) dz``, ``excess' = 2 (z Phi(z) + phi(z))`` (minus ``2 z`` for the
    energy criterion when z > 0, written cancellation-free as ``2 (phi(z) - z Phi(-z))``)."""
    return _flank_values(criterion, offset, sigma)[3]


@_flank_statistics.defjvp
def _flank_statistics_jvp(criterion, primals, tangents):
    offset, sigma = primals
    d_offset, d_sigma = tangents
    z, cdf, pdf, stats, d_excess = _flank_values(criterion, offset, sigma)
    active = (sigma > 0.0) & (jnp.abs(z) < _Z_SATURATION)
    dz = jnp.where(active, (d_offset - z * d_sigma) / jnp.where(active, sigma, 1.0), 0.0)
    d_stats = [pdf * dz, cdf * d_offset + pdf * d_sigma]
    if d_excess is not None:
        d_stats.append(d_excess * dz)
    return stats, tuple(d_stats)


_GAUSS_HERMITE_POINTS = 24


def check_law_inputs(law: ContactLaw, inputs, n_contacts: int):
    """``inputs`` with every leaf broadcast to ``(n_contacts,)``; ``ValueError`` naming the law if a leaf cannot be."""

    def broadcast(x):
        x = jnp.asarray(x, dtype=jnp.float64)
        if jnp.ndim(x) > 1 or (jnp.ndim(x) == 1 and x.shape[0] not in (1, n_contacts)):
            raise ValueError(
                f"contact-law inputs of {type(law).__name__} must be scalars or have shape ({n_contacts},) "
                f"(one entry per contact), got shape {jnp.shape(x)}"
            )
        return jnp.broadcast_to(x, (n_contacts,))

    return jax.tree.map(broadcast, inputs)


class ContactLaw(eqx.Module):
    """Extension point: a scalar contact law ``f(delta; inputs, b)`` (N) of the deflection ``delta`` (m).

    ``inputs`` are the law's *inputs at time t*, any pytree whose leaves have one entry per contact (shape
    ``(nc,)``): the mesh stiffness (N/m) for :class:`Backlash`, the mesh phase for a Hertzian mesh law. They come
    from :attr:`pgtjax.Contacts.inputs` (an array, a pytree or a function of time). ``b`` (m) is the
    half-clearance. The law's own array fields are parameters: they are differentiable (``jax.grad`` through
    every solver), and must not depend on time.

    A subclass implements ``force``, ``stiffness`` (df/ddelta) and ``potential`` (P with P' = f, P(0) = 0).
    Everything else has a generic default: the Gaussian expectations that statistical linearization needs
    (``linearize``, ``force_moments``) by Gauss-Hermite quadrature (:attr:`quadrature_points` nodes), the
    single-contact implicit solve by Newton, and :meth:`closed_stiffness` (modal analysis, the start of the
    static solve) as the tangent stiffness at the edge of the clearance. Override them where closed forms
    exist (see :class:`Backlash`). Arguments may carry leading batch axes (``(..., nc)``: samples, quadrature
    nodes), so a parameter field with one entry per contact broadcasts on the last axis. Every method acts
    contact by contact (the coefficients of contact j depend
    only on contact j's arguments): the SL solver's closed-form Newton Jacobian relies on it. The methods must
    also work under ``jax.vmap`` (Monte Carlo maps them over samples; SL maps the derivatives of ``linearize``
    over tangent directions): jax.numpy code does, a ``jax.pure_callback`` needs a ``vmap_method``.

    A law whose ``stiffness`` is always either 0 or the stiffness input sets ``on_off_stiffness = True``: Monte
    Carlo then inverts the contact-space Newton Jacobians of contact patterns (all 2^nc of them for few
    contacts, else the batch's majority pattern and the few others present) instead of one per sample and
    iteration. Such a law may also implement ``affine_piece`` (piecewise-affine laws): a Newton step that stays
    inside one affine piece is then exact, which that batched solve checks instead of evaluating the residual.
    """

    on_off_stiffness: ClassVar[bool] = False
    quadrature_points: ClassVar[int] = _GAUSS_HERMITE_POINTS
    single_solve_iterations: ClassVar[int] = 40

    @abc.abstractmethod
    def force(self, delta, inputs, b): ...

    @abc.abstractmethod
    def stiffness(self, delta, inputs, b): ...

    @abc.abstractmethod
    def potential(self, delta, inputs, b): ...

    def check_inputs(self, inputs, n_contacts: int):
        """Validated inputs, every leaf broadcast to ``(n_contacts,)`` (overridden to add range checks)."""
        return check_law_inputs(self, inputs, n_contacts)

    def closed_stiffness(self, inputs, b):
        """Stiffness (N/m) of each contact taken as a closed linear spring: what :func:`pgtjax.modal_analysis`
        uses for the contacts, and the static solve's starting point. Default: the tangent stiffness just past
        the clearance, ``f'(b+)`` (taken a relative 1e-9 past it, so that a law with a kink at ``b`` gives the
        closed flank's stiffness)."""
        b = jnp.asarray(b, jnp.float64)
        return self.stiffness(b * (1.0 + 1e-9) + 1e-30, inputs, b)

    def deflections_at_force(self, force, inputs, b):
        """The deflections (m) at which the force reaches ``+force`` and ``-force`` (``force`` >= 0, N),
        ``(upper, lower)``: the barriers that ``|f| >= force`` sets on the deflection, which SL's peak estimate
        of a contact force needs (:meth:`pgtjax.MomentResult.peak_exceedance`). Only for a law whose force
        grows with the deflection's magnitude outside the clearance; the default raises NotImplementedError."""
        raise NotImplementedError(f"{type(self).__name__} does not give the deflections at a force level")

    def affine_piece(self, delta, inputs, b):
        """Integer label of the interval of ``delta`` on which the law is affine, elementwise; ``None`` if the
        law is not piecewise affine (the default)."""
        return None

    def gaussian_expectation(self, fun, mu, sigma, inputs, b):
        """``E[fun(delta, inputs, b)]`` for ``delta ~ N(mu, sigma^2)`` elementwise, by Gauss-Hermite quadrature
        (exact for polynomials of degree < 2 x :attr:`quadrature_points`)."""
        z, w = np.polynomial.hermite.hermgauss(self.quadrature_points)
        mu, sigma = jnp.asarray(mu, jnp.float64), jnp.asarray(sigma, jnp.float64)
        z = jnp.reshape(jnp.asarray(z), (-1,) + (1,) * jnp.ndim(mu))
        w = jnp.reshape(jnp.asarray(w / np.sqrt(np.pi)), (-1,) + (1,) * jnp.ndim(mu))
        d = mu[None] + np.sqrt(2.0) * sigma[None] * z
        per_node = jax.tree.map(lambda x: jnp.broadcast_to(x, jnp.shape(mu))[None], inputs)
        bb = jnp.broadcast_to(b, jnp.shape(mu))[None]
        return jnp.sum(w * fun(d, per_node, bb), axis=0)

    def linearize(
        self, mu, sigma, inputs, b, criterion: AbstractCriterion = ForceCriterion()
    ) -> Linearization:
        """Equivalent linear contact for ``delta ~ N(mu, sigma^2)`` (module docstring): ``f_0 = E[f]`` and
        ``k_e = E[f']`` (force criterion) or ``2/3 (E[f'] + (E[P] - P(mu)) / sigma^2)`` (energy), by quadrature;
        ``sigma = 0`` gives ``k_e = f'(mu)``. The energy form's ``E[P] - P(mu)`` is a difference: it keeps
        about ``eps (mu / sigma)^2`` relative accuracy, ample for SL's sigma but not for sigma -> 0."""
        criterion = check_criterion(criterion)
        f_0 = self.gaussian_expectation(self.force, mu, sigma, inputs, b)
        k_force = self.mean_stiffness(mu, sigma, inputs, b)
        if criterion.potential_reference is None:
            return criterion.coefficients(f_0, k_force, None)
        pot = self.potential
        excess = self.gaussian_expectation(pot, mu, sigma, inputs, b)
        if criterion.potential_reference == "mean":
            excess = excess - pot(jnp.asarray(mu, jnp.float64), inputs, b)
        safe = jnp.where(sigma > 0.0, sigma, 1.0)
        lin = criterion.coefficients(f_0, k_force, excess / safe**2)
        return Linearization(jnp.where(sigma > 0.0, lin.k_e, k_force), lin.f_0)

    def mean_stiffness(self, mu, sigma, inputs, b):
        """``E[f'(delta)]`` (N/m) for ``delta ~ N(mu, sigma^2)``. Default: Stein's identity
        ``E[(delta - mu) f(delta)] / sigma^2`` by quadrature of the force, which is continuous where a law's
        stiffness jumps (the flank edge), so the result and its derivatives are continuous in ``(mu, sigma)``
        as the SL Newton iteration needs (quadrature of a jumping ``f'`` is not); ``f'(mu)`` at ``sigma = 0``."""
        mu, sigma = jnp.asarray(mu, jnp.float64), jnp.asarray(sigma, jnp.float64)
        positive = sigma > 0.0
        safe = jnp.where(positive, sigma, 1.0)
        moment = self.gaussian_expectation(
            lambda d, i, bb: (d - mu[None]) * self.force(d, i, bb), mu, safe, inputs, b
        )
        return jnp.where(positive, moment / safe**2, self.stiffness(mu, inputs, b))

    def force_moments(self, mu, sigma, inputs, b) -> tuple[jnp.ndarray, jnp.ndarray]:
        """Mean and standard deviation of f(delta) for delta ~ N(mu, sigma^2) (default: quadrature)."""
        m1 = self.gaussian_expectation(self.force, mu, sigma, inputs, b)
        m2 = self.gaussian_expectation(lambda d, i, bb: self.force(d, i, bb) ** 2, mu, sigma, inputs, b)
        return m1, jnp.sqrt(jnp.maximum(m2 - m1**2, 0.0))

    def solve_single(self, delta_lin, coupling, inputs, b):
        """Solve ``delta + s f(delta) = delta_lin`` elementwise for one contact (``s >= 0``): the implicit
        contact equation of a Newmark step in contact space. Returns ``(delta, converged)``. Default: Newton
        from ``delta_lin`` (:attr:`single_solve_iterations` steps; the left side is increasing for a law with
        ``f' >= 0``)."""

        def body(_, d):
            return d - (d + coupling * self.force(d, inputs, b) - delta_lin) / (
                1.0 + coupling * self.stiffness(d, inputs, b)
            )

        d = jax.lax.fori_loop(0, self.single_solve_iterations, body, delta_lin)
        res = jnp.abs(d + coupling * self.force(d, inputs, b) - delta_lin)
        return d, res <= 1e-10 * (jnp.abs(delta_lin) + b + 1e-300)


class Backlash(ContactLaw):
    """Piecewise-linear backlash (dead-zone) law, thesis Eq. 3.32 / Eq. 4.9; ``b = 0`` is a linear spring."""

    on_off_stiffness: ClassVar[bool] = True

    def check_inputs(self, inputs, n_contacts: int):
        """The mesh stiffness ``k`` (N/m), scalar or (n_contacts,), must be >= 0 where it can be checked."""
        k = check_law_inputs(self, inputs, n_contacts)
        if not isinstance(k, jax.Array):
            raise ValueError(
                f"Backlash takes the mesh stiffness (one array) as its input, got {type(inputs).__name__}"
            )
        # NumPy on a concrete k: a jnp comparison inside a caller's trace would be traced itself
        if not isinstance(k, jax.core.Tracer) and bool(np.any(np.asarray(k) < 0.0)):
            raise ValueError(
                f"`Contacts(stiffness=...)` (mesh stiffness) must be >= 0 N/m, got {np.asarray(k)}"
            )
        return k

    def closed_stiffness(self, k, b):
        return k

    def force(self, delta, k, b):
        return k * (jnp.maximum(delta - b, 0.0) - jnp.maximum(-b - delta, 0.0))

    def stiffness(self, delta, k, b):
        return k * ((delta > b) | (delta < -b)).astype(jnp.result_type(delta, k))

    def potential(self, delta, k, b):
        return 0.5 * k * (jnp.maximum(delta - b, 0.0) ** 2 + jnp.maximum(-b - delta, 0.0) ** 2)

    def linearize(self, mu, sigma, k, b, criterion: AbstractCriterion = ForceCriterion()) -> Linearization:
        criterion = check_criterion(criterion)
        # distances into the upper and lower contact flanks, stacked so that each special function is
        # evaluated once for both flanks (fewer, larger operations)
        upper, lower, sigma = jnp.broadcast_arrays(mu - b, -b - mu, sigma)
        offset, sigma = jnp.stack([upper, lower]), sigma[None]
        # per flank: P(contact), E[(flank deflection)+] and, for the energy criterion, the excess second
        # moment ((E[P] - P(mu)) / sigma^2, cancellation-free)
        flank_mode = {None: "force", "mean": "energy"}[criterion.potential_reference]
        stats = _flank_statistics(flank_mode, offset, sigma)
        cdf, mean_part = stats[0], stats[1]
        contact_probability = cdf[0] + cdf[1]  # Eq. 3.39 / k
        f_0 = k * (mean_part[0] - mean_part[1])
        k_force = k * contact_probability
        if criterion.potential_reference is None:
            return criterion.coefficients(f_0, k_force, None)
        excess = stats[2]
        return criterion.coefficients(f_0, k_force, 0.5 * k * (excess[0] + excess[1]))

    def deflections_at_force(self, force, k, b):
        # |f| >= F where |delta| >= b + F / k; a contact without stiffness never reaches F (barrier at infinity)
        positive = k > 0.0
        upper = jnp.where(positive, b + force / jnp.where(positive, k, 1.0), jnp.inf)
        return upper, -upper

    def affine_piece(self, delta, k, b):
        # 0: inside the backlash (f = 0), 1: upper flank (k (delta - b)), 2: lower flank (k (delta + b))
        return jnp.where(delta > b, 1, jnp.where(delta < -b, 2, 0))

    def solve_single(self, delta_lin, coupling, k, b):
        # Closed form: delta + s k (delta - b) = delta_lin on the upper flank iff delta_lin > b (s k >= 0).
        sk = coupling * k
        upper = (delta_lin + sk * b) / (1.0 + sk)
        lower = (delta_lin - sk * b) / (1.0 + sk)
        delta = jnp.where(delta_lin > b, upper, jnp.where(delta_lin < -b, lower, delta_lin))
        return delta, jnp.ones(jnp.shape(delta), dtype=bool)

    def force_moments(self, mu, sigma, k, b):
        upper, lower = mu - b, -b - mu
        z_up, z_lo = _standardize(upper, sigma), _standardize(lower, sigma)
        # Phi(z) and Phi(-z) of both flanks from one erfc evaluation (not 1 - Phi: the tails keep their
        # relative accuracy) and phi(z) = phi(-z) from one exp: each special function is a large expansion in
        # the compiled program of every SL run and its gradient
        cdf = _cdf(jnp.stack([z_up, z_lo, -z_up, -z_lo]))
        pdf = _pdf(jnp.stack([z_up, z_lo]))
        mean_up = _positive_part_mean(upper, sigma, z_up, cdf[0], pdf[0])
        mean_lo = _positive_part_mean(lower, sigma, z_lo, cdf[1], pdf[1])
        var = _positive_part_variance(upper, sigma, z_up, cdf[0], cdf[2], pdf[0]) + _positive_part_variance(
            lower, sigma, z_lo, cdf[1], cdf[3], pdf[1]
        )
        # A = (delta-b)+ and B = (-b-delta)+ are never both nonzero: Cov(A, B) = -E[A] E[B].
        var = var + 2.0 * mean_up * mean_lo
        return k * (mean_up - mean_lo), k * safe_sqrt(var)


def _positive_part_variance(offset, sigma, z, cdf, cdf_neg, pdf):
    """Var[X+] for X ~ N(offset, sigma^2), without cancellation for z >> 0, given ``Phi(z)``, ``Phi(-z)`` and
    ``phi(z)``.

    For z > 0 use X+ = X + X- (X- = (-X)+, small): Var = s^2 - E[(X-)^2] - 2 m E[X-] - E[X-]^2.
    """
    neg_mean = _positive_part_mean(-offset, sigma, -z, cdf_neg, pdf)
    neg_second = sigma * sigma * _second_moment_ratio(-z, cdf_neg, pdf)
    var_pos_z = sigma * sigma - neg_second - 2.0 * offset * neg_mean - neg_mean**2
    pos_mean = _positive_part_mean(offset, sigma, z, cdf, pdf)
    var_neg_z = sigma * sigma * _second_moment_ratio(z, cdf, pdf) - pos_mean**2
    return jnp.maximum(jnp.where(z > 0.0, var_pos_z, var_neg_z), 0.0)
