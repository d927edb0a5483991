"""Statistical linearization (SL) coupled to the stochastic Newmark mean/covariance recursion.

At every step each contact force is replaced by ``k_e (delta - mu) + f_0`` (thesis Eq. 3.33 / 4.25), whose
coefficients depend on the mean ``mu`` and standard deviation ``sigma`` of the deflection at the *end* of the
step (thesis Eqs. 3.39-3.42, or ch. 4's energy criterion; see :mod:`pgtjax.contact`). The linearized system
``M q'' + C q' + (K + G diag(k_e) G^T) q = F - G (f_0 - k_e mu) + B w`` (Eq. 3.43 / 4.51) is advanced one step
with the stochastic Newmark scheme (:mod:`pgtjax.newmark`, Eqs. 3.45-3.51 / 4.52-4.60).

Instead of the raw second moment ``R = <Y Y^T>`` with cross terms (Eqs. 3.52-3.53, 4.61-4.62) we propagate
the mean and the covariance separately (equivalent, better conditioned):

    m_{i+1} = Phi m_i + c_i,     P_{i+1} = Phi P_i Phi^T + Gamma Gamma^T.

The step's fixed point ``(mu, sigma) = T(mu, sigma)`` of the contact deflections is solved by Newton's method
(Jacobian by forward-mode autodiff; falls back to a plain fixed-point step when a Newton step is not finite).
Only the contact-space moments are iterated, by nc x nc algebra (push-through identity, see
``_contact_moments``); the full covariance update is done once per step. Three forms of that update, all
exact rewritings of the same step: small systems (n <= 16) form Phi densely; when K and C are constant the
contact-free one-step map is formed once per run and the linearized contacts enter as rank-nc corrections
(``_moment_step_constant``: dense products only, the fast path for the gear-train models); otherwise one LU
of the contact-free ``K_eff`` per step with a Woodbury correction for the contacts. Gradients through the
converged fixed point use the implicit function theorem (a ``custom_jvp`` whose tangent is
``-J^-1 dR/dtheta``; reverse mode transposes it); the iterations themselves are not differentiated and cost
nothing extra in a forward run.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._numerics import safe_sqrt
from .contact import check_criterion
from .newmark import (
    ConstantPropagator,
    Snapshot,
    check_noise_scheme,
    constant_propagator,
    noise_matrices,
    snapshot,
    step_matrices,
)
from .results import MomentResult
from .system import Observables, System, initial_state, validate_system, validate_time_grid

_DENSE_PHI_MAX_DOF = 16  # below this size the covariance update forms Phi explicitly (overhead-bound regime)


class _StepData(NamedTuple):
    """Contact-space quantities of one step that do not depend on the step-end linearization.

    With ``A`` = K_eff without the contacts and ``W0 = G^T A^-1``: ``coupling`` S = W0 G, ``mean`` W0 r
    (r = the mean right-hand side without contact terms), ``covariance`` W0 (Y + N N^T) W0^T.
    """

    coupling: jax.Array  # (nc, nc)
    mean: jax.Array  # (nc,)
    covariance: jax.Array  # (nc, nc)
    contact_stiffness: jax.Array
    clearance: jax.Array


def _contact_moments(law, nc: int, criterion: str, z, data: _StepData):
    """The fixed-point map T: step-end contact moments implied by linearizing at ``z = (mu, sigma)``.

    ``G^T (A + G K_e G^T)^-1 = (I + S K_e)^-1 G^T A^-1`` (push-through identity), so the map needs only
    contact-space (nc x nc) algebra.
    """
    mu, sigma = z[:nc], z[nc:]
    lin = law.linearize(mu, sigma, data.contact_stiffness, data.clearance, criterion)
    reduced = jnp.eye(nc, dtype=z.dtype) + data.coupling * lin.k_e[None, :]
    mean = jnp.linalg.solve(reduced, data.mean - data.coupling @ (lin.f_0 - lin.k_e * mu))
    cov = jnp.linalg.solve(reduced, jnp.linalg.solve(reduced, data.covariance).T)
    return jnp.concatenate([mean, safe_sqrt(jnp.diagonal(cov))])


def _residual(law, nc, criterion, z, data):
    return _contact_moments(law, nc, criterion, z, data) - z


class _FixedPointInfo(NamedTuple):
    iterations: jax.Array
    residual: jax.Array
    converged: jax.Array


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1, 2))
def _implicit_solution(law, nc, criterion, z_star, data):
    """Identity on the converged fixed point ``z*``; its derivative is the implicit-function-theorem one,
    ``dz = -J^-1 (dR/ddata) ddata`` with ``J = dR/dz`` at ``z*`` (computed only when differentiating)."""
    return z_star


@_implicit_solution.defjvp
def _implicit_solution_jvp(law, nc, criterion, primals, tangents):
    z_star, data = primals
    _, d_data = tangents
    jac = jax.jacfwd(lambda z: _residual(law, nc, criterion, z, data))(z_star)
    _, d_res = jax.jvp(lambda d: _residual(law, nc, criterion, z_star, d), (data,), (d_data,))
    return z_star, -jnp.linalg.solve(jac, d_res)


def _solve_fixed_point(system, z0, data, criterion, rtol, max_iter):
    """Newton iterations on R(z) = T(z) - z (one linearization per iteration, residual reused)."""
    nc = system.n_contacts
    law = system.contacts.law
    data_const = jax.lax.stop_gradient(data)

    def residual(z):
        return _residual(law, nc, criterion, z, data_const)

    def scaled_norm(r, z):
        scale = jnp.abs(z[:nc]) + z[nc:] + data_const.clearance + 1e-300
        return jnp.max(jnp.abs(r) / jnp.concatenate([scale, scale]))

    def body(state):
        # the Jacobian is formed at the start of an iteration, so none is wasted on the converged point
        z, r, it, _ = state
        z_newton = z + jnp.linalg.solve(jax.jacfwd(residual)(z), -r)
        z_new = jnp.where(jnp.all(jnp.isfinite(z_newton)), z_newton, z + r)  # fixed-point step as fallback
        z_new = z_new.at[nc:].set(jnp.maximum(z_new[nc:], 0.0))
        r_new = residual(z_new)
        return z_new, r_new, it + 1, scaled_norm(r_new, z_new)

    def cond(state):
        *_, it, err = state
        return (it < max_iter) & (err > rtol)

    z0 = jax.lax.stop_gradient(z0)
    r0 = residual(z0)
    z_star, _, iters, err = jax.lax.while_loop(cond, body, (z0, r0, jnp.array(0), scaled_norm(r0, z0)))
    z = _implicit_solution(law, nc, criterion, z_star, data)
    return z, _FixedPointInfo(iters, err, err <= rtol)


class _Carry(NamedTuple):
    mean: jax.Array  # (2n,)
    cov: jax.Array  # (2n, 2n)
    snap: Snapshot
    z: jax.Array  # contact (mu, sigma) at the current time, (2 nc,)


def _linearized_terms(system, snap: Snapshot, z, criterion):
    """Stiffness and load of the linearized system at one instant (Eq. 3.43): K + G k_e G^T, F - G f_tilde."""
    nc = system.n_contacts
    if nc == 0:
        return snap.stiffness, snap.load, None
    mu, sigma = z[:nc], z[nc:]
    lin = system.contacts.law.linearize(mu, sigma, snap.contact_stiffness, system.contacts.clearance, criterion)
    g = snap.direction
    k_lin = snap.stiffness + (g * lin.k_e[None, :]) @ g.T
    f_lin = snap.load - g @ (lin.f_0 - lin.k_e * mu)
    return k_lin, f_lin, lin


def _contact_state(system, snap: Snapshot, mean, cov):
    n = system.n_dof
    g = snap.direction
    mu = g.T @ mean[:n]
    sigma = safe_sqrt(jnp.sum((g.T @ cov[:n, :n]) * g.T, axis=1))
    return jnp.concatenate([mu, sigma])


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


def _record(system, carry: _Carry, criterion, info: _FixedPointInfo, t, observables) -> _Saved:
    nc = system.n_contacts
    n = system.n_dof
    if observables is not None:
        c = observables(t)
        obs_mean = c @ carry.mean[:n]
        obs_std = safe_sqrt(jnp.sum((c @ carry.cov[:n, :n]) * c, axis=1))
    else:
        obs_mean = obs_std = jnp.zeros((0,))
    if nc:
        mu, sigma = carry.z[:nc], carry.z[nc:]
        k, b = carry.snap.contact_stiffness, system.contacts.clearance
        lin = system.contacts.law.linearize(mu, sigma, k, b, criterion)
        f_mean, f_std = system.contacts.law.force_moments(mu, sigma, k, b)
    else:
        lin = f_mean = f_std = None
        empty = jnp.zeros((0,))
    return _Saved(
        obs_mean,
        obs_std,
        carry.mean,
        jnp.diagonal(carry.cov),
        carry.z,
        lin.k_e if nc else empty,
        lin.f_0 if nc else empty,
        f_mean if nc else empty,
        f_std if nc else empty,
        info.iterations,
        info.residual,
        info.converged,
    )


def _moment_step(system: System, carry: _Carry, t1, h, criterion, noise_scheme, rtol, max_iter, lu_const=None):
    """One step of the recursion. The covariance update ``Phi P Phi^T + Gamma Gamma^T`` is done blockwise
    from ``Z = [E D] P`` and ``A = K_eff^-1 Z`` (Phi itself is never formed): with ``X_u = K_eff^-1 [E D]``
    the displacement rows of Phi, ``X_u P = A``, ``X_u P X_u^T = K_eff^-1 Z [E D]^T K_eff^-T`` and the velocity
    rows ``Phi_v = (2/h) X_u - W``, ``W = [(2/h) I, I]``, follow by the algebra spelled out below."""
    n, nc = system.n_dof, system.n_contacts
    s0, mean, cov = carry.snap, carry.mean, carry.cov
    s1 = snapshot(system, t1)
    k0_lin, f0_lin, _ = _linearized_terms(system, s0, carry.z, criterion)
    mats = step_matrices(system, s0._replace(stiffness=k0_lin), s1, h, noise_scheme)
    e_mat, d_mat = mats.from_displacement, mats.from_velocity
    p_top, p_bot = cov[:n, :], cov[n:, :]
    z_mat = e_mat @ p_top + d_mat @ p_bot  # [E D] P, (n, 2n)
    y_mat = z_mat[:, :n] @ e_mat.T + z_mat[:, n:] @ d_mat.T  # [E D] P [E D]^T, (n, n)
    mean_rhs = e_mat @ mean[:n] + d_mat @ mean[n:] + f0_lin + s1.load
    noise_cov = mats.noise @ mats.noise.T
    # A: K_eff without the contacts; factorized once per run when K and C are constant (lu_const)
    lu = jax.scipy.linalg.lu_factor(mats.effective_stiffness) if lu_const is None else lu_const
    solve_a = lambda rhs: jax.scipy.linalg.lu_solve(lu, rhs)  # noqa: E731
    solve = solve_a
    if nc:
        g1 = s1.direction
        w0 = jax.scipy.linalg.lu_solve(lu, g1, trans=1).T  # G^T A^-1, (nc, n)
        v0 = solve_a(g1)  # A^-1 G, (n, nc)
        coupling = w0 @ g1
        data = _StepData(coupling, w0 @ mean_rhs, w0 @ (y_mat + noise_cov) @ w0.T, s1.contact_stiffness,
                         system.contacts.clearance)
        z1, info = _solve_fixed_point(system, carry.z, data, criterion, rtol, max_iter)
        k1_lin, f1_lin, lin1 = _linearized_terms(system, s1, z1, criterion)
        mean_rhs = mean_rhs - s1.load + f1_lin
        ke = lin1.k_e
        reduced = jnp.eye(nc, dtype=ke.dtype) + ke[:, None] * coupling  # I + K_e S

        if n <= _DENSE_PHI_MAX_DOF:  # small systems: factorize the linearized K_eff directly
            lu_eff = jax.scipy.linalg.lu_factor(mats.effective_stiffness + (g1 * ke[None, :]) @ g1.T)
            solve = lambda rhs: jax.scipy.linalg.lu_solve(lu_eff, rhs)  # noqa: E731
        else:

            def solve(rhs):  # Woodbury: (A + G K_e G^T)^-1 = A^-1 - A^-1 G (I + K_e S)^-1 K_e G^T A^-1
                r2 = rhs if rhs.ndim == 2 else rhs[:, None]
                out = solve_a(r2) - v0 @ jnp.linalg.solve(reduced, ke[:, None] * (w0 @ r2))
                return out if rhs.ndim == 2 else out[:, 0]
    else:
        z1 = carry.z
        info = _FixedPointInfo(jnp.array(0), jnp.array(0.0), jnp.array(True))
    u_mean = solve(mean_rhs)
    g_u = solve(mats.noise)  # Gamma_u, (n, draws)
    g_v = (2.0 / h) * g_u + mats.velocity_noise  # Gamma_v
    if n <= _DENSE_PHI_MAX_DOF:
        # small systems: one dense Phi P Phi^T (fewer, larger operations win when each is tiny)
        x_u = solve(jnp.concatenate([e_mat, d_mat], axis=1))  # displacement rows of Phi
        eye_u = jnp.eye(n, 2 * n, dtype=mean.dtype)
        eye_v = jnp.eye(n, 2 * n, k=n, dtype=mean.dtype)
        phi = jnp.concatenate([x_u, (2.0 / h) * (x_u - eye_u) - eye_v], axis=0)
        gamma = jnp.concatenate([g_u, g_v], axis=0)
        new_cov = phi @ cov @ phi.T + gamma @ gamma.T
        new_cov = 0.5 * (new_cov + new_cov.T)
    else:
        a_mat = solve(z_mat)  # X_u P, (n, 2n)
        u_cov = solve(solve(y_mat.T).T)  # X_u P X_u^T
        new_cov = _assemble_covariance(cov, a_mat, u_cov, g_u, g_v, h)
    new_mean = jnp.concatenate([u_mean, (2.0 / h) * (u_mean - mean[:n]) - mean[n:]])
    return _Carry(new_mean, new_cov, s1, z1), info


def _assemble_covariance(cov, a_mat, u_cov, g_u, g_v, h):
    """``Phi P Phi^T + Gamma Gamma^T`` from the displacement rows ``X_u`` of Phi, given ``a_mat = X_u P``
    and ``u_cov = X_u P X_u^T``: the velocity rows are ``Phi_v = (2/h) X_u - W``, ``W = [(2/h) I, I]``
    (the kinematic relation v1 = (2/h)(u1 - u0) - v0), so every block follows without forming Phi."""
    n = a_mat.shape[0]
    a_u, a_v = a_mat[:, :n], a_mat[:, n:]  # X_u P[:, :n], X_u P[:, n:]
    xpw = (2.0 / h) * a_u + a_v  # X_u P W^T
    wpw = (4.0 / h**2) * cov[:n, :n] + (2.0 / h) * (cov[:n, n:] + cov[n:, :n]) + cov[n:, n:]
    p_uu = u_cov + g_u @ g_u.T
    p_vu = (2.0 / h) * u_cov - xpw.T + g_v @ g_u.T  # Phi_v P Phi_u^T + Gamma_v Gamma_u^T
    p_vv = (4.0 / h**2) * u_cov - (2.0 / h) * (xpw + xpw.T) + wpw + g_v @ g_v.T
    new_cov = jnp.block([[p_uu, p_vu.T], [p_vu, p_vv]])
    return 0.5 * (new_cov + new_cov.T)


def _moment_step_constant(system: System, carry: _Carry, t1, h, criterion, noise_scheme, rtol, max_iter,
                          prop: ConstantPropagator):
    """One step of the recursion when K and C are constant (only the contacts, load and noise input vary).

    The contact-free map ``X = A^-1 [E, D]`` is formed once per run (:func:`constant_propagator`); the
    linearized contacts at the two ends of the step are rank-nc corrections of it:

        X_a = X - A^-1 G0 [K_e0 G0^T, 0]                (start-of-step contacts, moved into E)
        X_u = X_a - A^-1 G1 (I + K_e1 S)^-1 K_e1 G1^T X_a  (end-of-step contacts, Woodbury)

    with ``S = G1^T A^-1 G1``. The covariance update then costs two dense products (``X P`` and
    ``(X_u P) X^T``) and matrix products of width nc, instead of triangular solves per step.
    """
    n, nc = system.n_dof, system.n_contacts
    s0, mean, cov = carry.snap, carry.mean, carry.cov
    s1 = snapshot(system, t1)
    noise, v_noise = noise_matrices(system, s0, s1, h, noise_scheme)
    x, a_inv = prop.x, prop.a_inv
    xp = x @ cov  # X P, (n, 2n)
    m_a = x @ mean + a_inv @ (s0.load + s1.load)  # A^-1 (r without contact terms)
    g_a = a_inv @ noise
    if nc:
        g0, g1 = s0.direction, s1.direction
        law, clearance = system.contacts.law, system.contacts.clearance
        lin0 = law.linearize(carry.z[:nc], carry.z[nc:], s0.contact_stiffness, clearance, criterion)
        q0 = lin0.k_e[:, None] * g0.T  # K_e0 G0^T, (nc, n)
        b0 = a_inv @ g0  # A^-1 G0
        m_a = m_a - b0 @ (q0 @ mean[:n] + lin0.f_0 - lin0.k_e * carry.z[:nc])
        xap = xp - b0 @ (q0 @ cov[:n, :])  # X_a P
        w1 = g1.T @ a_inv  # G1^T A^-1
        v1 = a_inv @ g1  # A^-1 G1
        coupling = w1 @ g1
        gx = g1.T @ x - (w1 @ g0) @ jnp.concatenate([q0, jnp.zeros_like(q0)], axis=1)  # G1^T X_a, (nc, 2n)
        gxp = gx @ cov
        wn = w1 @ noise
        data = _StepData(coupling, g1.T @ m_a, gxp @ gx.T + wn @ wn.T, s1.contact_stiffness, clearance)
        z1, info = _solve_fixed_point(system, carry.z, data, criterion, rtol, max_iter)
        lin1 = law.linearize(z1[:nc], z1[nc:], s1.contact_stiffness, clearance, criterion)
        ke1 = lin1.k_e
        reduced = jnp.eye(nc, dtype=ke1.dtype) + ke1[:, None] * coupling  # I + K_e1 S
        f1 = lin1.f_0 - ke1 * z1[:nc]
        u_mean = m_a - v1 @ jnp.linalg.solve(reduced, ke1 * data.mean + f1)
        corr = jnp.linalg.solve(reduced, ke1[:, None] * jnp.concatenate([gx, gxp, g1.T @ g_a], axis=1))
        q1, q1p, q1n = corr[:, : 2 * n], corr[:, 2 * n : 4 * n], corr[:, 4 * n :]
        a_mat = xap - v1 @ q1p  # X_u P
        # X_u P X_u^T = a_mat X_a^T - (a_mat Q1^T) V1^T,  a_mat X_a^T = a_mat X^T - (a_mat[:, :n] Q0^T) B0^T
        u_cov = a_mat @ x.T - (a_mat[:, :n] @ q0.T) @ b0.T - (a_mat @ q1.T) @ v1.T
        g_u = g_a - v1 @ q1n
    else:
        z1 = carry.z
        info = _FixedPointInfo(jnp.array(0), jnp.array(0.0), jnp.array(True))
        u_mean, a_mat, g_u = m_a, xp, g_a
        u_cov = a_mat @ x.T
    g_v = (2.0 / h) * g_u + v_noise
    new_cov = _assemble_covariance(cov, a_mat, u_cov, g_u, g_v, h)
    new_mean = jnp.concatenate([u_mean, (2.0 / h) * (u_mean - mean[:n]) - mean[n:]])
    return _Carry(new_mean, new_cov, s1, z1), info


def solve_moments(
    system: System,
    *,
    t0: float = 0.0,
    dt: float,
    n_steps: int,
    initial_displacement=None,
    initial_velocity=None,
    initial_covariance=None,
    criterion: str = "force",
    noise_scheme: str = "trapezoidal",
    save_every: int = 1,
    rtol: float = 1e-10,
    max_iter: int = 50,
    throw: bool = True,
    checkpoint: bool = True,
    observables: Observables | None = None,
) -> MomentResult:
    """Mean and standard deviation of every DOF, contact deflection and contact force by SL + stochastic
    Newmark (thesis Eqs. 3.43-3.53, 4.51-4.63).

    Args:
        system: the system (:class:`pgtjax.System`).
        t0, dt, n_steps: start time (s), step (s, > 0) and number of steps; ``n_steps`` must be a multiple
            of ``save_every``. Results are saved at ``t0 + k * save_every * dt``, ``k = 0..n_steps/save_every``.
        initial_displacement, initial_velocity: mean initial state (default 0).
        initial_covariance: (2n, 2n) covariance of ``(u, v)`` at ``t0`` (default 0: deterministic start).
        criterion: ``"force"`` (Eqs. 3.37-3.42), ``"energy"`` (ch. 4, corrected) or ``"energy_origin"``.
        noise_scheme: ``"trapezoidal"`` (exact stationary covariance) or ``"newmark"`` (the documents').
        rtol: tolerance of the per-step fixed point, relative to ``|mu| + sigma + b`` of each contact.
        max_iter: Newton iterations allowed per step.
        throw: raise if a step's fixed point does not converge or a NaN appears (works under ``jit``);
            with ``False`` the flags are returned in the result (``converged``, ``iterations``, ``residual``).
        checkpoint: rematerialize each saved block in reverse mode (memory ~ number of saves, not steps).
        observables: optional :class:`pgtjax.Observables` ``y = C(t) u`` whose mean and standard deviation
            are reported (``mean_obs``, ``std_obs``).
    """
    validate_system(system, t0)
    validate_time_grid(dt, n_steps, save_every)
    check_criterion(criterion)
    check_noise_scheme(noise_scheme)
    n = system.n_dof
    u0, v0 = initial_state(system, initial_displacement, initial_velocity)
    p0 = jnp.zeros((2 * n, 2 * n)) if initial_covariance is None else jnp.asarray(initial_covariance, jnp.float64)
    if p0.shape != (2 * n, 2 * n):
        raise ValueError(f"`initial_covariance` must have shape {(2 * n, 2 * n)}, got {p0.shape}")
    if not isinstance(p0, jax.core.Tracer) and not np.all(np.isfinite(np.asarray(p0))):
        raise ValueError("`initial_covariance` must be finite")
    return _solve_moments_jit(
        system, jnp.asarray(t0, jnp.float64), jnp.asarray(dt, jnp.float64), u0, v0, p0,
        n_steps=n_steps, save_every=save_every, criterion=criterion, noise_scheme=noise_scheme,
        rtol=rtol, max_iter=max_iter, throw=throw, checkpoint=checkpoint, observables=observables,
    )


@eqx.filter_jit
def _solve_moments_jit(
    system, t0, dt, u0, v0, p0, *, n_steps, save_every, criterion, noise_scheme, rtol, max_iter, throw, checkpoint,
    observables,
):
    mean0 = jnp.concatenate([u0, v0])
    s0 = snapshot(system, t0)
    carry = _Carry(mean0, p0, s0, _contact_state(system, s0, mean0, p0))
    first = _record(system, carry, criterion, _FixedPointInfo(jnp.array(0), jnp.array(0.0), jnp.array(True)), t0,
                    observables)
    n_blocks = n_steps // save_every
    # K and C constant: the contact-free step operators are formed once per run (and differentiated once)
    prop = constant_propagator(system, dt)
    lu_const = None
    if prop is not None and system.n_dof <= _DENSE_PHI_MAX_DOF:
        k_eff = system.stiffness + (2.0 / dt) * system.damping + (4.0 / dt**2) * system.mass
        lu_const = jax.scipy.linalg.lu_factor(k_eff)

    def block(carry, block_index):
        def inner(c, j):
            t1 = t0 + dt * (block_index * save_every + j + 1)
            if prop is not None and lu_const is None:
                return _moment_step_constant(system, c, t1, dt, criterion, noise_scheme, rtol, max_iter, prop)
            return _moment_step(system, c, t1, dt, criterion, noise_scheme, rtol, max_iter, lu_const)

        carry, infos = jax.lax.scan(inner, carry, jnp.arange(save_every))
        worst = _FixedPointInfo(
            jnp.max(infos.iterations), jnp.max(infos.residual), jnp.all(infos.converged)
        )
        t_end = t0 + dt * (block_index + 1) * save_every
        return carry, _record(system, carry, criterion, worst, t_end, observables)

    if checkpoint:
        block = jax.checkpoint(block)
    _, saved = jax.lax.scan(block, carry, jnp.arange(n_blocks))
    saved = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b], axis=0), first, saved)
    times = t0 + dt * save_every * jnp.arange(n_blocks + 1, dtype=jnp.float64)
    if throw:
        bad_value = ~jnp.all(jnp.isfinite(saved.mean)) | ~jnp.all(jnp.isfinite(saved.var))
        saved = saved._replace(
            mean=eqx.error_if(saved.mean, bad_value, "SL moment recursion produced NaN/inf: check the "
                              "parameters (stiffness, damping, time step)."),
        )
        saved = saved._replace(
            mean=eqx.error_if(saved.mean, ~jnp.all(saved.converged),
                              "SL fixed point did not converge at some step: raise `max_iter`, reduce `dt`, "
                              "or pass throw=False to inspect `converged`/`residual`."),
        )
    return MomentResult.from_saved(system, times, saved, criterion=criterion, observables=observables)
