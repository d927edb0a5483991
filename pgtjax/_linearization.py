"""Statistical linearization (SL) coupled to the stochastic Newmark mean/covariance recursion.

At every step each contact force is replaced by ``k_e (delta - mu) + f_0`` (thesis Eq. 3.33 / 4.25), whose
coefficients depend on the mean ``mu`` and standard deviation ``sigma`` of the deflection at the *end* of the
step (thesis Eqs. 3.39-3.42, or ch. 4's energy criterion; see :mod:`pgtjax._contact`). The linearized system
``M q'' + C q' + (K + G diag(k_e) G^T) q = F - G (f_0 - k_e mu) + B w`` (Eq. 3.43 / 4.51) is advanced one step
with the stochastic Newmark scheme (:mod:`pgtjax._newmark`, Eqs. 3.45-3.51 / 4.52-4.60).

Instead of the raw second moment ``R = <Y Y^T>`` with cross terms (Eqs. 3.52-3.53, 4.61-4.62) we propagate
the mean and the covariance separately (equivalent, better conditioned):

    m_{i+1} = Phi m_i + c_i,     P_{i+1} = Phi P_i Phi^T + Gamma Gamma^T.

The step's fixed point ``(mu, sigma) = T(mu, sigma)`` of the contact deflections is solved by Newton's method
(closed-form Jacobian, see ``_evaluate``; falls back to a plain fixed-point step when a Newton step is not
finite). Only the contact-space moments are iterated, by nc x nc algebra (push-through identity); the last
iteration's linearization and ``(I + S K_e)^-1`` are reused by the full covariance update, done once per step.
Three forms of that update, all exact rewritings of the same step: small systems (n <= 16) form Phi densely;
when K and C are constant the contact-free one-step map is formed once per run and the linearized contacts
enter as rank-nc corrections (``_moment_step_constant``: dense products only, the fast path for the gear-train
models); otherwise one LU of the contact-free ``K_eff`` per step with a Woodbury correction for the contacts.
Gradients through the converged fixed point use the implicit function theorem (a ``custom_jvp`` whose tangent
is ``-J^-1 dR/dtheta``, written in closed form; reverse mode transposes it); the iterations themselves are not
differentiated and cost nothing extra in a forward run, and under ``checkpoint`` their solution is kept rather
than recomputed. The covariance update's dense products have derivative rules of their own (``custom_jvp``,
using the symmetry of P) that refer to the map's displacement increments dX and to P only, so the
checkpointed reverse pass does not recompute them (docs/gradients.md). The update is written with dX rather than
the displacement rows X_u = [I 0] + dX: for a slow DOF the velocity covariance would otherwise be a difference
of terms ~4 m / (h^2 k) times larger than itself (docs/corrections.md, C2d).
"""

from __future__ import annotations

import numbers
from collections.abc import Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.ad_checkpoint import checkpoint_name
from jax.custom_derivatives import SymbolicZero

from ._contact import AbstractCriterion, ForceCriterion, Linearization, check_criterion
from ._failure import SolverError, error_if_nonfinite, is_concrete, raise_if_nonfinite
from ._loop import saved_scan
from ._newmark import (
    AbstractIntegrator,
    ConstantPropagator,
    Snapshot,
    increment_map,
    resolve_integrator,
    snapshot,
)
from ._numerics import safe_sqrt
from ._results import MomentResult
from ._system import (
    Observables,
    System,
    check_contact_stiffness_over_time,
    check_count,
    check_initial_covariance,
    check_memory,
    check_observables,
    check_stability,
    covariance_index,
    initial_state,
    validate_system,
    validate_time_grid,
)

_FIXED_POINT_NAME = "sl_fixed_point"
# small per-step values kept by the checkpointed reverse pass so that it need not redo the covariance update:
# the step-end snapshot, the contact rows x P and the observables' C(t) and C(t) P
_COVARIANCE_NAME = "sl_covariance_inputs"
_DENSE_PHI_MAX_DOF = 16  # below this size the covariance update forms Phi explicitly (overhead-bound regime)


class _StepData(NamedTuple):
    """Contact-space quantities of one step that do not depend on the step-end linearization.

    With ``A`` = K_eff without the contacts and ``W0 = G^T A^-1``: ``coupling`` S = W0 G, ``mean`` W0 r
    (r = the mean right-hand side without contact terms), ``covariance`` W0 (Y + N N^T) W0^T.
    """

    coupling: jax.Array  # (nc, nc)
    mean: jax.Array  # (nc,)
    covariance: jax.Array  # (nc, nc)
    inputs: object  # the contact law's inputs at the step's end, every leaf (nc,)
    clearance: jax.Array  # (nc,)


class _EndTerms(NamedTuple):
    """The step-end linearization at a contact state ``z``: the law's ``(k_e, f_0)`` and ``R^-1``,
    ``R = I + S K_e``. Evaluated by every fixed-point iteration and reused by the covariance update."""

    lin: Linearization
    r_inv: jax.Array  # (nc, nc)


def _linearizer(law, criterion: AbstractCriterion, data: _StepData):
    """``(mu, sigma) -> Linearization`` of the step-end contacts."""
    return lambda mu, sigma: law.linearize(mu, sigma, data.inputs, data.clearance, criterion)


@jax.custom_jvp
def _inverse(a):
    """``a^-1`` (LU with partial pivoting) whose derivative is the product ``-a^-1 da a^-1``: fewer and
    smaller operations than differentiating through the LU solves."""
    return jnp.linalg.inv(a)


@_inverse.defjvp
def _inverse_jvp(primals, tangents):
    (a,), (da,) = primals, tangents
    a_inv = _inverse(a)
    return a_inv, -a_inv @ da @ a_inv


def _end_terms(law, nc: int, criterion: AbstractCriterion, z, data: _StepData) -> _EndTerms:
    lin = _linearizer(law, criterion, data)(z[:nc], z[nc:])
    r_inv = _inverse(jnp.eye(nc, dtype=z.dtype) + data.coupling * lin.k_e[None, :])
    return _EndTerms(lin, r_inv)


class _Moments(NamedTuple):
    """The step-end contact moments implied by a linearization: T(z) of the fixed-point map."""

    mean: jax.Array  # (nc,)
    cov: jax.Array  # (nc, nc)
    std: jax.Array  # (nc,)


def _implied_moments(nc: int, z, terms: _EndTerms, data: _StepData) -> _Moments:
    """``mean = R^-1 (m - S (f_0 - K_e mu))`` and ``cov = R^-1 Y R^-T`` (see :func:`_evaluate`)."""
    lin, r_inv = terms
    mean = r_inv @ (data.mean - data.coupling @ (lin.f_0 - lin.k_e * z[:nc]))
    cov = r_inv @ data.covariance @ r_inv.T
    return _Moments(mean, cov, safe_sqrt(jnp.diagonal(cov)))


def _law_derivatives(law, criterion: AbstractCriterion, z, data: _StepData, wrt):
    """The law's derivatives (one :class:`Linearization` each) along unit tangents of the arguments named
    in ``wrt`` (of ``mu``, ``sigma``, ``inputs``, ``b``; ``inputs`` gives one per leaf of the law's inputs):
    contacts are linearized independently, so these are per contact."""
    nc = data.clearance.shape[0]
    leaves, treedef = jax.tree.flatten(data.inputs)
    args = (z[:nc], z[nc:], *leaves, data.clearance)
    names = ("mu", "sigma", *(("inputs", j) for j in range(len(leaves))), "b")

    def linearize(mu, sigma, *rest):
        return law.linearize(mu, sigma, jax.tree.unflatten(treedef, rest[:-1]), rest[-1], criterion)

    per_name = {"inputs": [("inputs", j) for j in range(len(leaves))]}
    directions = [d for name in wrt for d in per_name.get(name, [name])]
    # one forward-mode pass batched over the unit tangents: the compiled program holds one copy of the law's
    # derivative, not one per direction (smaller to compile, no slower: 2026-11-28, docs/performance.md)
    tangents = [
        jnp.stack([jnp.ones_like(a) if n == d else jnp.zeros_like(a) for d in directions])
        for n, a in zip(names, args)
    ]
    batched = jax.vmap(lambda *t: jax.jvp(linearize, args, t)[1])(*tangents)
    along = iter([jax.tree.map(lambda x, i=i: x[i], batched) for i in range(len(directions))])
    return [[next(along) for _ in leaves] if name == "inputs" else next(along) for name in wrt]


def _jacobian(nc: int, z, terms: _EndTerms, moments: _Moments, data: _StepData, d_mu, d_sigma) -> jax.Array:
    """``dR/dz`` (2 nc, 2 nc) in closed form from the law's derivatives (formulas in :func:`_evaluate`)."""
    d = terms.r_inv @ data.coupling
    gap = moments.mean - z[:nc]
    # D_ij (cov_ij + cov_ji) / (2 sigma_i), zero where sigma_i = 0 (where safe_sqrt's derivative is zero);
    # cov is symmetric up to rounding, and its symmetric part keeps the formula exact regardless
    cov_sym = 0.5 * (moments.cov + moments.cov.T)
    d_cov = d * cov_sym / jnp.where(moments.std > 0.0, moments.std, jnp.inf)[:, None]
    k_e = terms.lin.k_e
    jacobian = -jnp.block(
        [
            [d * (d_mu.k_e * gap + d_mu.f_0 - k_e)[None, :], d * (d_sigma.k_e * gap + d_sigma.f_0)[None, :]],
            [d_cov * d_mu.k_e[None, :], d_cov * d_sigma.k_e[None, :]],
        ]
    )
    return jacobian - jnp.eye(2 * nc, dtype=z.dtype)


def _evaluate(law, nc: int, criterion: AbstractCriterion, z, data: _StepData, with_jacobian: bool = False):
    """The residual ``R(z) = T(z) - z`` of the fixed-point map T (the step-end contact moments implied by
    linearizing at ``z = (mu, sigma)``), the :class:`_EndTerms` at ``z`` and, optionally, ``dR/dz``
    (a (2 nc, 2 nc) matrix).

    ``G^T (A + G K_e G^T)^-1 = (I + S K_e)^-1 G^T A^-1`` (push-through identity), so the map needs only
    contact-space (nc x nc) algebra: with ``R = I + S K_e``, ``mean = R^-1 (m - S (f_0 - K_e mu))`` and
    ``cov = R^-1 Y R^-T``. The Jacobian is closed-form because a contact law linearizes each contact on its
    own (k_e_j, f_0_j depend on mu_j, sigma_j only): with ``D = R^-1 S`` and ``dR^-1 = -R^-1 S dK_e R^-1``,

        d mean_i / d mu_j    = -D_ij (k_e,mu_j (mean_j - mu_j) + f_0,mu_j - k_e_j)
        d mean_i / d sigma_j = -D_ij (k_e,sigma_j (mean_j - mu_j) + f_0,sigma_j)
        d sigma_i / d x_j    = -D_ij cov_ji k_e,x_j / sigma_i          (x = mu or sigma; cov symmetric)

    where ``k_e,x`` and ``f_0,x`` are the law's own derivatives (forward mode, one pass batched over the
    directions).
    """
    terms = _end_terms(law, nc, criterion, z, data)
    moments = _implied_moments(nc, z, terms, data)
    residual = jnp.concatenate([moments.mean, moments.std]) - z
    if not with_jacobian:
        return residual, terms, None
    return residual, terms, _residual_jacobian(law, nc, criterion, z, terms, data, moments)


def _residual_jacobian(
    law, nc: int, criterion: AbstractCriterion, z, terms: _EndTerms, data: _StepData, moments=None
):
    """``dR/dz`` (2 nc, 2 nc) at ``z`` whose end terms are known (the law's derivatives: one forward-mode
    pass batched over ``mu`` and ``sigma``), as in :func:`_evaluate`."""
    moments = _implied_moments(nc, z, terms, data) if moments is None else moments
    d_mu, d_sigma = _law_derivatives(law, criterion, z, data, ("mu", "sigma"))
    return _jacobian(nc, z, terms, moments, data, d_mu, d_sigma)


class _FixedPointInfo(NamedTuple):
    iterations: jax.Array
    residual: jax.Array
    converged: jax.Array


@eqx.filter_custom_jvp
def _implicit_solution(z_star, terms, data, law, nc, criterion):
    """Identity on the converged fixed point ``z*`` and its :class:`_EndTerms` (both computed by the
    iterations, which are not differentiated). The derivative is the implicit-function-theorem one,
    ``dz = -J^-1 (dR/dtheta) dtheta`` with ``J = dR/dz`` at ``z*`` and theta the step data and the contact
    law's own parameters; the end terms' derivative follows from ``dz`` and ``dtheta`` (computed only when
    differentiating)."""
    return z_star, terms


def _materialize(tangent, primal):
    """A tangent pytree with its symbolic zeros (``None``) as zero arrays."""
    return jax.tree.map(
        lambda t, p: jnp.zeros_like(p) if t is None else t, tangent, primal, is_leaf=lambda x: x is None
    )


@_implicit_solution.def_jvp
def _implicit_solution_jvp(primals, tangents):
    """Closed-form tangents. At fixed ``z``, a data tangent ``(dS, dm, dY, dk, db)`` moves the law's
    coefficients by ``dk_e = k_e,k dk + k_e,b db`` (likewise ``df_0``) and ``S K_e`` by
    ``dA = dS K_e + S dK_e``; with ``dR^-1 = -R^-1 dA R^-1`` and ``mean = R^-1 c``:

        d mean = R^-1 (dm - dS f~ - S df~ - dA mean),   f~ = f_0 - K_e mu,  df~ = df_0 - dK_e mu
        d var_i = sum_j (dR^-1)_ij (R^-1 (Y + Y^T))_ij + sum_j (R^-1 dY)_ij (R^-1)_ij
        d std = d var / (2 std)   (zero where std = 0, as safe_sqrt's derivative)

    which is ``dR/ddata``; then ``dz = -J^-1 dR/ddata``, and the end terms move with both ``dz`` and the data:
    ``dK_e = (data part) + k_e,mu dmu + k_e,sigma dsigma`` and ``dR^-1 = -R^-1 (dS K_e + S dK_e) R^-1``.
    The primal quantities used here are named for the reverse pass's checkpoint policy: they are kept, not
    recomputed, so the rematerialized step repeats none of this contact-space algebra."""
    z_star, terms, data, law, nc, criterion = primals
    d_data, d_law = _materialize(tangents[2], data), tangents[3]
    lin, r_inv = terms
    mu = z_star[:nc]
    s_mat = data.coupling
    moments = _implied_moments(nc, z_star, terms, data)
    d_mu, d_sigma, d_k, d_b = _law_derivatives(law, criterion, z_star, data, ("mu", "sigma", "inputs", "b"))
    jac_inv = jnp.linalg.inv(_jacobian(nc, z_star, terms, moments, data, d_mu, d_sigma))
    r_inv_y = r_inv @ (data.covariance + data.covariance.T)  # Y + Y^T: exact even for a rounded, asymmetric Y
    inv_std = jnp.where(moments.std > 0.0, 0.5 / jnp.where(moments.std > 0.0, moments.std, 1.0), 0.0)
    kept = (moments.mean, inv_std, d_mu, d_sigma, d_k, d_b, jac_inv, r_inv_y)
    mean, inv_std, d_mu, d_sigma, d_k, d_b, jac_inv, r_inv_y = checkpoint_name(kept, _FIXED_POINT_NAME)

    d_s, d_b_data = d_data.coupling, d_data.clearance
    # data part at fixed z: the law's inputs (leaf by leaf), the clearance and the law's own parameters
    d_lin = jax.tree.map(lambda b: b * d_b_data, d_b)
    for d_leaf, d_input in zip(d_k, jax.tree.leaves(d_data.inputs)):
        d_lin = jax.tree.map(lambda acc, a: acc + a * d_input, d_lin, d_leaf)
    if any(t is not None for t in jax.tree.leaves(d_law, is_leaf=lambda x: x is None)):
        d_lin = jax.tree.map(jnp.add, d_lin, _law_parameter_tangent(law, criterion, z_star, data, d_law))
    d_a = d_s * lin.k_e[None, :] + s_mat * d_lin.k_e[None, :]
    f_tilde = lin.f_0 - lin.k_e * mu
    d_mean = r_inv @ (d_data.mean - d_s @ f_tilde - s_mat @ (d_lin.f_0 - d_lin.k_e * mu) - d_a @ mean)
    d_r_inv = -r_inv @ d_a @ r_inv  # data part; the part through z is added below
    d_var = jnp.sum(d_r_inv * r_inv_y, axis=1) + jnp.sum((r_inv @ d_data.covariance) * r_inv, axis=1)
    d_z = -jac_inv @ jnp.concatenate([d_mean, d_var * inv_std])
    d_k_e_z = d_mu.k_e * d_z[:nc] + d_sigma.k_e * d_z[nc:]
    d_lin = Linearization(d_lin.k_e + d_k_e_z, d_lin.f_0 + d_mu.f_0 * d_z[:nc] + d_sigma.f_0 * d_z[nc:])
    d_r_inv = d_r_inv - r_inv @ (s_mat * d_k_e_z[None, :]) @ r_inv
    return (z_star, terms), (d_z, _EndTerms(d_lin, d_r_inv))


def _stop_gradient(tree):
    """``lax.stop_gradient`` on the array leaves of a pytree (a contact law may hold non-array fields)."""
    return jax.tree.map(lambda x: jax.lax.stop_gradient(x) if eqx.is_array(x) else x, tree)


def _law_parameter_tangent(law, criterion: AbstractCriterion, z, data: _StepData, d_law) -> Linearization:
    """Tangent of the law's ``(k_e, f_0)`` at fixed ``z`` and step data along a tangent ``d_law`` of the law's
    own parameters (its array fields, e.g. a mesh-stiffness table)."""
    nc = data.clearance.shape[0]

    def linearize(law_params):
        return law_params.linearize(z[:nc], z[nc:], data.inputs, data.clearance, criterion)

    dynamic, static = eqx.partition(law, eqx.is_inexact_array)
    # zero tangents for the law's undifferentiated arrays; none for its non-array fields (floats, strings)
    d_dynamic = jax.tree.map(
        lambda p, t: None if p is None else (jnp.zeros_like(p) if t is None else t),
        dynamic,
        d_law,
        is_leaf=lambda x: x is None,
    )
    return jax.jvp(lambda dyn: linearize(eqx.combine(dyn, static)), (dynamic,), (d_dynamic,))[1]


def _solve_fixed_point(system, z0, data, criterion, rtol, max_iter):
    """Newton iterations on R(z) = T(z) - z. Returns the converged ``z``, its :class:`_EndTerms` and the
    convergence information."""
    nc = system.n_contacts
    law = system.contacts.law
    law_const = _stop_gradient(law)  # the iterations are not differentiated: see _implicit_solution
    data_const = jax.lax.stop_gradient(data)

    def evaluate(z):
        residual, terms, _ = _evaluate(law_const, nc, criterion, z, data_const)
        return residual, terms

    def scaled_norm(r, z):
        scale = jnp.abs(z[:nc]) + z[nc:] + data_const.clearance + 1e-300
        return jnp.max(jnp.abs(r) / jnp.concatenate([scale, scale]))

    def body(state):
        # a Newton step from z, whose residual and end terms the state holds: only the Jacobian is formed
        # here, so none is formed at the converged point; the first iteration is the loop's, so the program
        # holds the map twice (before the loop and here), not four times
        z, r, terms, it, _ = state
        jac = _residual_jacobian(law_const, nc, criterion, z, terms, data_const)
        z_newton = z + jnp.linalg.solve(jac, -r)
        z_new = jnp.where(jnp.all(jnp.isfinite(z_newton)), z_newton, z + r)  # fixed-point step as fallback
        z_new = z_new.at[nc:].set(jnp.maximum(z_new[nc:], 0.0))
        r_new, terms_new = evaluate(z_new)
        return z_new, r_new, terms_new, it + 1, scaled_norm(r_new, z_new)

    def cond(state):
        *_, it, err = state
        return (it < max_iter) & (err > rtol)

    # started from the previous step's solution, one iteration usually converges
    z0 = jax.lax.stop_gradient(z0)
    r0, terms0 = evaluate(z0)
    state = (z0, r0, terms0, jnp.asarray(0, jnp.int32), scaled_norm(r0, z0))
    z_star, _, terms, iters, err = jax.lax.while_loop(cond, body, state)
    # named so that the reverse pass's rematerialization keeps them instead of re-running the iterations
    z_star, terms = checkpoint_name((z_star, terms), _FIXED_POINT_NAME)
    z, terms = _implicit_solution(z_star, terms, data, law, nc, criterion)
    return z, terms, _FixedPointInfo(iters, err, err <= rtol)


class _Carry(NamedTuple):
    mean: jax.Array  # (2n,)
    cov: jax.Array  # (2n, 2n)
    snap: Snapshot
    z: jax.Array  # contact (mu, sigma) at the current time, (2 nc,)
    lin: Linearization  # the contacts' (k_e, f_0) at z, (nc,) each
    # with deflection_lag: each contact deflection's (nc,), displacement's (n,) and observable's (n_obs,)
    # covariance with its value one step before
    lag: jax.Array | None = None
    u_lag: jax.Array | None = None
    obs_lag: jax.Array | None = None
    # with deflection_lag and observables: C(t) at the current time, (n_obs, n), for the next step's lag
    obs_matrix: jax.Array | None = None


def _linearize_contacts(system, snap: Snapshot, z, criterion) -> Linearization:
    nc = system.n_contacts
    if nc == 0:
        return Linearization(jnp.zeros((0,)), jnp.zeros((0,)))
    return system.contacts.law.linearize(
        z[:nc], z[nc:], snap.contact_inputs, system.contacts.clearance, criterion
    )


def _linearized_terms(system, snap: Snapshot, z, lin: Linearization):
    """Stiffness and load of the linearized system at one instant (Eq. 3.43): K + G k_e G^T, F - G f_tilde."""
    nc = system.n_contacts
    if nc == 0:
        return snap.stiffness, snap.load
    g = snap.direction
    k_lin = snap.stiffness + (g * lin.k_e[None, :]) @ g.T
    f_lin = snap.load - g @ (lin.f_0 - lin.k_e * z[:nc])
    return k_lin, f_lin


def _contact_state(system, snap: Snapshot, mean, cov):
    n = system.n_dof
    g = snap.direction
    mu = g.T @ mean[:n]
    sigma = safe_sqrt(jnp.sum((g.T @ cov[:n, :n]) * g.T, axis=1))
    return jnp.concatenate([mu, sigma])


def _diagonal(a):
    """The diagonal of a square matrix as a strided slice of its elements: its transpose in reverse mode is a
    padding that fuses with the sum of the matrix's other cotangents (``jnp.diagonal``'s is a scatter, a pass
    over a (2n, 2n) array of its own)."""
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise ValueError(f"_diagonal takes a square matrix, got shape {a.shape}")
    return a.reshape(-1)[:: a.shape[0] + 1]


class _Saved(NamedTuple):
    obs_mean: jax.Array
    obs_std: jax.Array
    mean: jax.Array
    var: jax.Array
    z: jax.Array
    k_e: jax.Array
    f_0: jax.Array
    force_mean: jax.Array
    force_std: jax.Array
    iterations: jax.Array
    residual: jax.Array
    converged: jax.Array
    covariance: jax.Array  # (2m, 2m) of the selected (u, v), m = len(covariance_dofs)
    delta_lag: jax.Array | None  # (nc,) each deflection's covariance with its value one step earlier
    u_lag: jax.Array | None  # (n,) each displacement's covariance with its value one step earlier
    obs_lag: jax.Array | None  # (n_obs,) each observable's covariance with its value one step earlier


def _deflection_lag(g0, g1, cross) -> jax.Array:
    """Covariance of each contact deflection at a step's end with its value at the step's start, (nc,):
    ``g1^T Cov(u1, u0) g0``; ``cross`` = Cov(u1, u0) = (X_u P)[:, :n] = P_uu + (dX P)[:, :n] (n, n) (the
    step's noise is independent of its start); ``g0``, ``g1`` the directions at the two ends (n, nc)."""
    return jnp.sum(g1 * (cross @ g0), axis=0)


def _step_lags(
    s0: Snapshot, s1: Snapshot, cross, nc: int, obs_rows
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Each contact deflection's (nc,), displacement's (n,) and observable's (n_obs,) covariance with its value
    at the step's start, from ``cross`` = Cov(u1, u0) (n, n); ``obs_rows``: the observables' matrices ``(C(t0),
    C(t1))``, (n_obs, n) each (``Cov(y1, y0) = C1 Cov(u1, u0) C0^T``; an offset does not enter), or None."""
    delta = _deflection_lag(s0.direction, s1.direction, cross) if nc else jnp.zeros((0,))
    obs = jnp.zeros((0,)) if obs_rows is None else jnp.sum((obs_rows[1] @ cross) * obs_rows[0], axis=1)
    return delta, _diagonal(cross), obs


def _record(system, carry: _Carry, info: _FixedPointInfo, t, observables, cov_index=()) -> _Saved:
    nc = system.n_contacts
    n = system.n_dof
    if observables is not None:
        # with the lags, the carry holds C(t) already (saved every step)
        c = checkpoint_name(
            observables(t) if carry.obs_matrix is None else carry.obs_matrix, _COVARIANCE_NAME
        )
        obs_mean = (
            c @ carry.mean[:n] if observables.offset is None else c @ carry.mean[:n] + observables.shift(t)
        )
        # kept by the checkpointed reverse pass, which then need not recompute the covariance update
        c_cov = checkpoint_name(c @ carry.cov[:n, :n], _COVARIANCE_NAME)
        obs_std = safe_sqrt(jnp.sum(c_cov * c, axis=1))
    else:
        obs_mean = obs_std = jnp.zeros((0,))
    if nc:
        mu, sigma = carry.z[:nc], carry.z[nc:]
        k, b = carry.snap.contact_inputs, system.contacts.clearance
        f_mean, f_std = system.contacts.law.force_moments(mu, sigma, k, b)
    else:
        f_mean = f_std = None
        empty = jnp.zeros((0,))
    return _Saved(
        obs_mean,
        obs_std,
        carry.mean,
        _diagonal(carry.cov),
        carry.z,
        carry.lin.k_e if nc else empty,
        carry.lin.f_0 if nc else empty,
        f_mean if nc else empty,
        f_std if nc else empty,
        info.iterations,
        info.residual,
        info.converged,
        carry.cov[np.ix_(cov_index, cov_index)] if cov_index else jnp.zeros((0, 0)),
        carry.lag,
        carry.u_lag,
        carry.obs_lag,
    )


def _moment_step(
    system: System,
    carry: _Carry,
    t1,
    h,
    criterion,
    integrator,
    rtol,
    max_iter,
    lu_const=None,
    with_lag=False,
    obs_rows=None,
):
    """One step of the recursion. The covariance update ``Phi P Phi^T + Gamma Gamma^T`` is done blockwise
    from the displacement increments ``dX = K_eff^-1 [E - K_eff, D]`` of the one-step map (Phi itself is
    never formed): with ``Z = [E - K_eff, D] P``, ``dX P = K_eff^-1 Z`` and ``dX P dX^T = K_eff^-1 Z
    [E - K_eff, D]^T K_eff^-T`` (K_eff with the linearized contacts), and :func:`_assemble_covariance`
    gives every block. ``E - K_eff`` is formed exactly (the integrator's ``displacement_increment``)."""
    n, nc = system.n_dof, system.n_contacts
    s0, mean, cov = carry.snap, carry.mean, carry.cov
    s1 = snapshot(system, t1)
    k0_lin, f0_lin = _linearized_terms(system, s0, carry.z, carry.lin)
    mats = integrator.step_matrices(system, s0._replace(stiffness=k0_lin), s1, h)
    e_mat, d_mat = mats.from_displacement, mats.from_velocity
    increment = mats.displacement_increment  # E - K_eff, contacts at the step's end excluded
    if increment is None:  # a custom integrator's step matrices: by subtraction
        increment = e_mat - mats.effective_stiffness
    mean_rhs = e_mat @ mean[:n] + d_mat @ mean[n:] + f0_lin + s1.load
    # A: K_eff without the contacts; factorized once per run when K and C are constant (lu_const)
    lu = jax.scipy.linalg.lu_factor(mats.effective_stiffness) if lu_const is None else lu_const
    solve_a = lambda rhs: jax.scipy.linalg.lu_solve(lu, rhs)  # noqa: E731
    solve = solve_a
    if nc:
        g1 = s1.direction
        w0 = jax.scipy.linalg.lu_solve(lu, g1, trans=1).T  # G^T A^-1, (nc, n)
        v0 = solve_a(g1)  # A^-1 G, (n, nc)
        coupling = w0 @ g1
        w_noise = w0 @ mats.noise
        data = _StepData(
            coupling,
            w0 @ mean_rhs,
            _congruence(w0 @ jnp.concatenate([e_mat, d_mat], axis=1), cov) + w_noise @ w_noise.T,
            s1.contact_inputs,
            system.contacts.clearance,
        )
        z1, terms, info = _solve_fixed_point(system, carry.z, data, criterion, rtol, max_iter)
        lin1 = terms.lin
        _, f1_lin = _linearized_terms(system, s1, z1, lin1)
        mean_rhs = mean_rhs - s1.load + f1_lin
        ke = lin1.k_e
        increment = increment - (g1 * ke[None, :]) @ g1.T  # the end-of-step contacts join K_eff

        if n <= _DENSE_PHI_MAX_DOF:  # small systems: factorize the linearized K_eff directly
            lu_eff = jax.scipy.linalg.lu_factor(mats.effective_stiffness + (g1 * ke[None, :]) @ g1.T)
            solve = lambda rhs: jax.scipy.linalg.lu_solve(lu_eff, rhs)  # noqa: E731
        else:

            def solve(rhs):  # Woodbury: (A + G K_e G^T)^-1 = A^-1 - A^-1 G K_e (I + S K_e)^-1 G^T A^-1
                r2 = rhs if rhs.ndim == 2 else rhs[:, None]
                out = solve_a(r2) - v0 @ (ke[:, None] * (terms.r_inv @ (w0 @ r2)))
                return out if rhs.ndim == 2 else out[:, 0]
    else:
        z1, lin1 = carry.z, carry.lin
        info = _FixedPointInfo(jnp.array(0), jnp.array(0.0), jnp.array(True))
    u_mean = solve(mean_rhs)
    g_u = solve(mats.noise)  # Gamma_u, (n, draws)
    g_v = (2.0 / h) * g_u + mats.velocity_noise  # Gamma_v
    rhs_increment = jnp.concatenate([increment, d_mat], axis=1)  # [E - K_eff, D]
    if n <= _DENSE_PHI_MAX_DOF:
        # small systems: one dense Phi P Phi^T (fewer, larger operations win when each is tiny)
        dx_u = solve(rhs_increment)  # displacement increments' rows of Phi
        eye_u = jnp.eye(n, 2 * n, dtype=mean.dtype)
        eye_v = jnp.eye(n, 2 * n, k=n, dtype=mean.dtype)
        phi = jnp.concatenate([dx_u + eye_u, (2.0 / h) * dx_u - eye_v], axis=0)
        gamma = jnp.concatenate([g_u, g_v], axis=0)
        phi_cov = phi @ cov
        new_cov = phi_cov @ phi.T + gamma @ gamma.T
        new_cov = 0.5 * (new_cov + new_cov.T)
        cross = phi_cov[:n, :n]  # Cov(u1, u0)
    else:
        z_mat = rhs_increment @ cov  # [E - K_eff, D] P, (n, 2n)
        c_mat = solve(z_mat)  # dX P
        d_cov = solve(solve((z_mat @ rhs_increment.T).T).T)  # dX P dX^T
        new_cov = _assemble_covariance(cov, d_cov, c_mat, g_u, g_v, h)
        cross = cov[:n, :n] + c_mat[:, :n]  # Cov(u1, u0)
    new_mean = jnp.concatenate([u_mean, (2.0 / h) * (u_mean - mean[:n]) - mean[n:]])
    lags = (None, None, None)
    if with_lag:
        lags = _step_lags(s0, s1, cross, nc, obs_rows)
    return _Carry(new_mean, new_cov, s1, z1, lin1, *lags), info


def _assemble_covariance(cov, d_cov, c_mat, g_u, g_v, h):
    """``Phi P Phi^T + Gamma Gamma^T`` from the displacement increments ``dX = X_u - [I 0]`` of the one-step
    map, given ``d_cov = dX P dX^T`` and ``c_mat = dX P`` (n, 2n): the velocity rows are
    ``Phi_v = (2/h) dX - [0 I]`` (v1 = (2/h)(u1 - u0) - v0), so every block follows without forming Phi.

    Written with the increments, not ``X_u`` itself: for a slow DOF (omega h << 1) the velocity block would
    otherwise be a difference of terms ~4 m / (h^2 k) times larger than the result, and rounding would drift
    the variances step after step (docs/corrections.md). The block formulas assume a symmetric ``P``; the
    result is symmetrized so that rounding cannot feed an antisymmetric part (which they would propagate
    unstably) into the next step."""
    n = d_cov.shape[0]
    c_u, c_v = c_mat[:, :n], c_mat[:, n:]  # dX P [I 0]^T, dX P [0 I]^T
    p_uu = cov[:n, :n] + c_u + c_u.T + d_cov + g_u @ g_u.T
    # Phi_v P Phi_u^T + Gamma_v Gamma_u^T
    p_vu = (2.0 / h) * (c_u + d_cov) - cov[n:, :n] - c_v.T + g_v @ g_u.T
    p_vv = (4.0 / h**2) * d_cov - (2.0 / h) * (c_v + c_v.T) + cov[n:, n:] + g_v @ g_v.T
    new_cov = jnp.block([[p_uu, p_vu.T], [p_vu, p_vv]])
    return 0.5 * (new_cov + new_cov.T)


@jax.custom_jvp
def _quadratic_forms(dx, cov):
    """``(dX P dX^T, dX P)`` for the displacement increments ``dX`` (n, 2n) of the one-step map and a
    symmetric ``P`` (2n, 2n): the two dense products of the covariance update (``dX P``, then
    ``(dX P) dX^T``).

    The derivative rule refers to ``dX`` and ``P`` only, never to ``dX P``: the checkpointed reverse pass
    then skips both products when it recomputes the step, and its transpose costs three products of the size
    of ``dX P`` or smaller (autodiff of the plain products recomputes both, then transposes each: six).
    ``P`` symmetric, and so its tangents: the recursion keeps it exactly so (each step is symmetrized); a
    cotangent of ``P`` is meaningful up to its antisymmetric part (docs/gradients.md)."""
    a_mat = dx @ cov
    return a_mat @ dx.T, a_mat


def _quadratic_forms_jvp(primals, tangents):
    dx, cov = primals
    ddx, dcov = (None if isinstance(t, SymbolicZero) else t for t in tangents)
    d_cov, a_mat = _quadratic_forms(dx, cov)
    dxp = jnp.zeros_like(dx) if ddx is None else ddx @ cov  # d(dX) P
    if dcov is None:
        da, half = dxp, dxp
    else:
        dx_dcov = dx @ dcov
        da, half = dxp + dx_dcov, dxp + 0.5 * dx_dcov  # d(dX P); half of it where dP enters
    # d(dX P dX^T) = E + E^T with E = (d(dX) P + dX dP / 2) dX^T (P, dP symmetric): one product, so that the
    # transpose needs one (Dbar + Dbar^T) dX rather than both Dbar dX and Dbar^T dX
    e_mat = half @ dx.T
    return (d_cov, a_mat), (e_mat + e_mat.T, da)


_quadratic_forms.defjvp(_quadratic_forms_jvp, symbolic_zeros=True)


@jax.custom_jvp
def _congruence(x, cov):
    """``x P x^T`` for a symmetric ``P`` (2n, 2n) and a few rows ``x`` (m, 2n), m << 2n. The derivative rule
    uses the symmetry of ``P`` and keeps ``x P`` (m x 2n) for the checkpointed reverse pass, so that reverse
    mode needs no product with ``P`` (autodiff's transpose takes one)."""
    return (x @ cov) @ x.T


@_congruence.defjvp
def _congruence_jvp(primals, tangents):
    x, cov = primals
    dx, dcov = tangents
    xp = checkpoint_name(x @ cov, _COVARIANCE_NAME)
    dxp = dx @ xp.T  # dx P x^T (= (x P dx^T)^T)
    return xp @ x.T, dxp + dxp.T + (x @ dcov) @ x.T


def _varying_snapshot(system: System, t) -> Snapshot:
    """The snapshot without the (constant) K and C, for the constant-propagator path: K and C are then
    not part of the scan's carry, so reverse mode does not store a copy of them per saved block."""
    return snapshot(system, t)._replace(damping=None, stiffness=None)


def _moment_step_constant(
    system: System,
    carry: _Carry,
    t1,
    h,
    criterion,
    integrator,
    rtol,
    max_iter,
    prop: ConstantPropagator,
    with_lag=False,
    obs_rows=None,
):
    """One step of the recursion when K and C are constant (only the contacts, load and noise input vary).

    The contact-free map ``X = A^-1 [E, D]`` is formed once per run (the integrator's ``init``); the
    linearized contacts at the two ends of the step are rank-nc corrections of it:

        X_a = X - A^-1 G0 [K_e0 G0^T, 0]                   (start-of-step contacts, moved into E)
        X_u = X_a - A^-1 G1 (I + K_e1 S)^-1 K_e1 G1^T X_a  (end-of-step contacts, Woodbury)

    with ``S = G1^T A^-1 G1``. The covariance update uses the increments ``X_u - [I 0]``: they follow from the
    propagator's ``dx = X - [I 0]`` by the same two corrections (the second still built from ``G1^T X_a``,
    whose rows are ``G1^T (X_a - [I 0]) + [G1^T, 0]``). The fixed point needs only the contact rows
    ``G1^T X_a P`` (nc x 2n); once ``K_e1`` is known the covariance update costs two dense products
    (``dX_u P`` and ``(dX_u P) dX_u^T``) and matrix products of width nc, instead of triangular solves per step.
    """
    n, nc = system.n_dof, system.n_contacts
    s0, mean, cov = carry.snap, carry.mean, carry.cov
    # kept by the checkpointed reverse pass: the model's time functions are not evaluated again there
    s1 = checkpoint_name(_varying_snapshot(system, t1), _COVARIANCE_NAME)
    noise, v_noise = integrator.noise_matrices(system, s0, s1, h)
    dx, a_inv = increment_map(prop), prop.a_inv
    if nc:
        g0, g1 = s0.direction, s1.direction
        clearance = system.contacts.clearance
        lin0 = carry.lin
        inv_g = a_inv @ jnp.concatenate([g0, g1, noise, (s0.load + s1.load)[:, None]], axis=1)
        b0, v1, g_a, m_load = inv_g[:, :nc], inv_g[:, nc : 2 * nc], inv_g[:, 2 * nc : -1], inv_g[:, -1]
        dx_a = dx - jnp.pad(b0 @ (lin0.k_e[:, None] * g0.T), ((0, 0), (0, n)))  # X_a - [I 0]
        # the mean of A^-1 (rhs without K_e1)
        m_a = mean[:n] + dx_a @ mean + m_load - b0 @ (lin0.f_0 - lin0.k_e * carry.z[:nc])
        gx = g1.T @ dx_a + jnp.pad(g1.T, ((0, 0), (0, n)))  # G1^T X_a, (nc, 2n)
        proj = g1.T @ jnp.concatenate([g_a, m_a[:, None], v1], axis=1)  # G1^T [Gamma_a, m_a, A^-1 G1]
        gn, coupling = proj[:, : -1 - nc], proj[:, -nc:]
        # the contacts' covariance needs G1^T X_a P only (nc rows), not X_a P itself
        cov_c = _congruence(gx, cov) + gn @ gn.T
        data = _StepData(coupling, proj[:, -1 - nc], cov_c, s1.contact_inputs, clearance)
        z1, terms, info = _solve_fixed_point(system, carry.z, data, criterion, rtol, max_iter)
        lin1 = terms.lin
        ke1, f1 = lin1.k_e, lin1.f_0 - lin1.k_e * z1[:nc]
        # (I + K_e1 S)^-1 K_e1 = K_e1 (I + S K_e1)^-1, and the mean column (I + K_e1 S)^-1 (K_e1 m + f1)
        # = K_e1 (I + S K_e1)^-1 (m - S f1) + f1: both from the fixed point's R^-1 = (I + S K_e1)^-1
        rhs = jnp.concatenate([gx, gn, (data.mean - coupling @ f1)[:, None]], axis=1)
        q = ke1[:, None] * (terms.r_inv @ rhs)
        corr = v1 @ q.at[:, -1].add(f1)
        dx_u = dx_a - corr[:, : 2 * n]
        g_u = g_a - corr[:, 2 * n : -1]
        u_mean = m_a - corr[:, -1]
    else:
        z1, lin1 = carry.z, carry.lin
        info = _FixedPointInfo(jnp.array(0), jnp.array(0.0), jnp.array(True))
        inv_g = a_inv @ jnp.concatenate([noise, (s0.load + s1.load)[:, None]], axis=1)
        dx_u, g_u = dx, inv_g[:, :-1]
        u_mean = mean[:n] + dx @ mean + inv_g[:, -1]
    d_cov, c_mat = _quadratic_forms(dx_u, cov)  # dX_u P dX_u^T, dX_u P
    g_v = (2.0 / h) * g_u + v_noise
    new_cov = _assemble_covariance(cov, d_cov, c_mat, g_u, g_v, h)
    new_mean = jnp.concatenate([u_mean, (2.0 / h) * (u_mean - mean[:n]) - mean[n:]])
    lags = (None, None, None)
    if with_lag:
        lags = _step_lags(s0, s1, cov[:n, :n] + c_mat[:, :n], nc, obs_rows)  # Cov(u1, u0)
    return _Carry(new_mean, new_cov, s1, z1, lin1, *lags), info


def solve_moments(
    system: System,
    *,
    t0: float = 0.0,
    dt: float,
    n_steps: int,
    initial_displacement=None,
    initial_velocity=None,
    initial_covariance=None,
    criterion: AbstractCriterion = ForceCriterion(),
    integrator: AbstractIntegrator | None = None,
    save_every: int = 1,
    rtol: float = 1e-10,
    max_iter: int = 50,
    throw: bool = True,
    checkpoint: bool = True,
    checkpoint_blocks: int = 1,
    observables: Observables | None = None,
    covariance_dofs: Sequence[str] | str | None = None,
    deflection_lag: bool = False,
) -> MomentResult:
    """Mean and standard deviation of every DOF, contact deflection and contact force by SL + stochastic
    Newmark (thesis Eqs. 3.43-3.53, 4.51-4.63).

    Args:
        system: the system (:class:`pgtjax.System`).
        t0, dt, n_steps: start time (s), step (s, > 0) and number of steps; ``n_steps`` must be a multiple
            of ``save_every``. Results are saved at ``t0 + k * save_every * dt``, ``k = 0..n_steps/save_every``.
        initial_displacement, initial_velocity: mean initial state (default 0).
        initial_covariance: (2n, 2n) covariance of ``(u, v)`` at ``t0`` (default 0: deterministic start).
        criterion: the SL criterion, :class:`pgtjax.ForceCriterion` (default, Eqs. 3.37-3.42) or
            :class:`pgtjax.EnergyCriterion` (ch. 4, corrected: equals Eq. 4.43 where ``|mu| <= b``, and stays
            sensible under a static load), or a user's :class:`pgtjax.AbstractCriterion`.
        integrator: the time discretization, :class:`pgtjax.Newmark` (default: exact stationary covariance)
            or :class:`pgtjax.NewmarkBridge` (the documents' scheme).
        rtol: tolerance of the per-step fixed point, relative to ``|mu| + sigma + b`` of each contact.
        max_iter: Newton iterations allowed per step.
        throw: raise :class:`pgtjax.SolverError` naming the first time and quantity where a value is not
            finite or a step's fixed point did not converge (under ``jit``, an error without the time); with
            ``False`` the flags are returned in the result (``converged``, ``iterations``, ``residual``).
        checkpoint: rematerialize each saved block in reverse mode: the state is kept once per saved block,
            plus, per step, the fixed point's solution and its tangent rule's contact-space quantities (about
            6 nc^2 + 16 nc numbers), the step-end snapshot, the contact rows of ``X_a P`` (2 n nc) and, with
            observables, ``C(t)`` and ``C(t) P`` (2 n n_obs), so that the rematerialization repeats neither the
            iterations, nor that algebra, nor (when K and C are constant) the covariance update's dense
            products. With ``save_every = 1`` each rematerialized step and its transpose form one loop body;
            longer blocks also stack each step's residuals for the block's reverse loop, which costs more
            (``benchmarks/bench_planetary.py`` times both).
        checkpoint_blocks: with ``checkpoint``, keep the state once per group of this many saved blocks
            (1 to ``n_steps / save_every``; default 1, once per block). Reverse mode then recomputes each group's
            blocks once more (0.6 to 1.5 forward runs more, measured) and keeps their states while it
            transposes them: memory for about ``n_blocks / k + k`` states (each (2n)^2 numbers; plus the blocks
            left over after the last whole group) instead of ``n_blocks``, least near ``k = sqrt(n_blocks)``.
            For gradients of long runs of large models (docs/gradients.md).
        observables: optional :class:`pgtjax.Observables` ``y = C(t) u`` whose mean and standard deviation
            are reported (``mean_obs``, ``std_obs``).
        covariance_dofs: DOF names (or ``"all"``) whose joint covariance of displacements and velocities is
            saved, ``result.covariance`` (n_times, 2m, 2m) ordered ``(u_1..u_m, v_1..v_m)``, with the blocks
            ``cov_uu``, ``cov_uv``, ``cov_vv`` (m, 2m and m^2 numbers per saved time, so select what you need
            for a large model).
        deflection_lag: also save each contact deflection's, displacement's and observable's covariance with
            its value one step earlier (``cov_delta_lag``, m^2, ``cov_u_lag`` and ``cov_obs_lag``, the
            quantity's unit squared; needs ``save_every = 1``): what SL's peak estimates over every step need
            (:meth:`pgtjax.MomentResult.peak_exceedance`).
    """
    validate_system(system, t0)
    cov_index = covariance_index(system, covariance_dofs)
    n_steps, save_every = validate_time_grid(dt, n_steps, save_every, t0)
    blocks = n_steps // save_every
    checkpoint_blocks = check_count("checkpoint_blocks", checkpoint_blocks, 1, blocks, " (the saved blocks)")
    if checkpoint_blocks > 1 and not checkpoint:
        raise ValueError("`checkpoint_blocks` > 1 groups rematerialized blocks: it needs `checkpoint=True`")
    check_observables(system, observables, t0)
    n_obs = 0 if observables is None else len(observables.names)
    if not isinstance(deflection_lag, bool):
        raise ValueError(f"`deflection_lag` must be True or False, got {deflection_lag!r}")
    if deflection_lag and save_every != 1:
        raise ValueError(
            "`deflection_lag` pairs each saved time with the step before it, for peaks taken over every step: it "
            f"needs save_every = 1, got {save_every}"
        )
    per_save = (4 + deflection_lag) * system.n_dof + (6 + deflection_lag) * system.n_contacts
    per_save += (2 + deflection_lag) * n_obs
    per_save += len(cov_index) ** 2 + 3
    # the step lags pair every step with the one before: saved every step
    knob = "`deflection_lag=False`, then raise `save_every`" if deflection_lag else "raise `save_every`"
    check_memory("solve_moments", n_steps // save_every + 1, per_save, knob)
    check_contact_stiffness_over_time(system, t0, dt, n_steps)
    check_stability(system, t0, horizon=None if isinstance(dt, jax.core.Tracer) else n_steps * float(dt))
    criterion = check_criterion(criterion)
    integrator = resolve_integrator(integrator)
    if isinstance(rtol, bool) or not isinstance(rtol, numbers.Real) or not 0.0 < rtol < 1.0:
        raise ValueError(f"`rtol` must be a number in (0, 1), got {rtol!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, numbers.Integral) or max_iter < 1:
        raise ValueError(f"`max_iter` must be an integer >= 1, got {max_iter!r}")
    u0, v0 = initial_state(system, initial_displacement, initial_velocity)
    p0 = check_initial_covariance(system, initial_covariance)
    result = _solve_moments_jit(
        system,
        jnp.asarray(t0, jnp.float64),
        jnp.asarray(dt, jnp.float64),
        u0,
        v0,
        p0,
        n_steps=n_steps,
        save_every=save_every,
        criterion=criterion,
        integrator=integrator,
        rtol=rtol,
        max_iter=max_iter,
        checkpoint=checkpoint,
        checkpoint_blocks=checkpoint_blocks,
        observables=observables,
        cov_index=cov_index,
        deflection_lag=deflection_lag,
    )
    return _checked(result) if throw else result


def _checked(result: MomentResult) -> MomentResult:
    """The result, or a :class:`pgtjax.SolverError` naming the first time and quantity that is not finite or
    whose fixed point did not converge (an in-``jit`` error where the result is traced)."""
    solver = "solve_moments (SL)"
    fields = {
        "mean displacement": (result.mean_u, result.dof_names),
        "std of displacement": (result.std_u, result.dof_names),
        "mean velocity": (result.mean_v, result.dof_names),
        "std of velocity": (result.std_v, result.dof_names),
        "mean contact force": (result.force_mean, result.contact_names),
        "std of contact force": (result.force_std, result.contact_names),
    }
    not_converged = "the fixed point of the step linearization did not converge"
    knobs = "raise `max_iter`, reduce `dt`, or pass throw=False to inspect `converged`, `residual` and `iterations`"
    if is_concrete(result):
        raise_if_nonfinite(solver, result.times, fields)
        converged = np.asarray(result.converged)
        if not converged.all():
            k = int(np.argmin(converged))
            raise SolverError(
                f"{solver}: {not_converged} in the block ending at t = {float(result.times[k]):.6g} s (scaled "
                f"residual {float(result.residual[k]):.3g} after {int(result.iterations[k])} iterations); {knobs}"
            )
        return result
    # every leaf of the result carries the checks, so no use of any part of it escapes them
    result = error_if_nonfinite(solver, result, [a for a, _ in fields.values()])
    return eqx.error_if(result, ~jnp.all(result.converged), f"{solver}: {not_converged}; {knobs}")


@eqx.filter_jit
def _solve_moments_jit(
    system,
    t0,
    dt,
    u0,
    v0,
    p0,
    *,
    n_steps,
    save_every,
    criterion,
    integrator,
    rtol,
    max_iter,
    checkpoint,
    checkpoint_blocks,
    observables,
    cov_index,
    deflection_lag,
):
    mean0 = jnp.concatenate([u0, v0])
    # the recursion and its derivative rules take P symmetric (each step ends symmetrized); so is the start
    p0 = 0.5 * (p0 + p0.T)
    # K and C constant: the contact-free step operators are formed once per run (and differentiated once)
    prop = integrator.init(system, dt)
    constant_path = prop is not None and system.n_dof > _DENSE_PHI_MAX_DOF
    s0 = _varying_snapshot(system, t0) if constant_path else snapshot(system, t0)
    z0 = _contact_state(system, s0, mean0, p0)
    n_obs = 0 if observables is None else len(observables.names)
    sizes = (system.n_contacts, system.n_dof, n_obs)
    lags0 = tuple(jnp.zeros((k,)) for k in sizes) if deflection_lag else (None,) * 3  # no step before t0
    obs_matrix0 = observables(t0) if deflection_lag and observables is not None else None
    carry = _Carry(mean0, p0, s0, z0, _linearize_contacts(system, s0, z0, criterion), *lags0, obs_matrix0)
    no_iterations = _FixedPointInfo(jnp.array(0), jnp.array(0.0), jnp.array(True))
    first = _record(system, carry, no_iterations, t0, observables, cov_index)
    n_blocks = n_steps // save_every
    lu_const = None
    if prop is not None and not constant_path:
        lu_const = jax.scipy.linalg.lu_factor(
            integrator.effective_matrices(
                system.mass, system.damping, system.stiffness, system.stiffness, dt
            )[0]
        )

    def step(c, step_number, _):
        t1 = t0 + dt * step_number
        obs_rows = None
        if c.obs_matrix is not None:  # C(t) at the step's two ends, each evaluated once
            # named as the save's C(t) is: kept by the checkpointed reverse pass, not evaluated again there
            obs_rows = (c.obs_matrix, checkpoint_name(observables(t1), _COVARIANCE_NAME))
        if constant_path:
            new, info = _moment_step_constant(
                system, c, t1, dt, criterion, integrator, rtol, max_iter, prop, deflection_lag, obs_rows
            )
        else:
            new, info = _moment_step(
                system, c, t1, dt, criterion, integrator, rtol, max_iter, lu_const, deflection_lag, obs_rows
            )
        return (new if obs_rows is None else new._replace(obs_matrix=obs_rows[1])), info

    def record(c, infos, block_index):
        worst = _FixedPointInfo(jnp.max(infos.iterations), jnp.max(infos.residual), jnp.all(infos.converged))
        return _record(system, c, worst, t0 + dt * (block_index + 1) * save_every, observables, cov_index)

    names = (_FIXED_POINT_NAME, _COVARIANCE_NAME)
    policy = jax.checkpoint_policies.save_only_these_names(*names) if checkpoint else None
    _, saved = saved_scan(
        step,
        record,
        carry,
        first,
        n_blocks=n_blocks,
        save_every=save_every,
        remat_policy=policy,
        blocks_per_checkpoint=checkpoint_blocks,
    )
    times = t0 + dt * save_every * jnp.arange(n_blocks + 1, dtype=jnp.float64)
    return MomentResult.from_saved(
        system,
        times,
        saved,
        criterion=criterion.name,
        observables=observables,
        covariance_dofs=tuple(system.dof_names[i] for i in cov_index[: len(cov_index) // 2]),
    )
