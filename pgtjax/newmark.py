"""One step of the (stochastic) average-acceleration Newmark scheme, shared by every solver.

Derivation (thesis Eqs. 3.45-3.51 / 4.52-4.60, rewritten in effective-stiffness form). Over a step
``h = t1 - t0`` the scheme is the trapezoidal rule on the state ``(u, v)``:

    u1 - u0 = h/2 (v0 + v1) + M^-1 B_s (h^(3/2)/sqrt(12)) P                            (kinematics)
    M (v1 - v0) + C_m (u1 - u0) = h/2 [F0 + F1 - K0 u0 - K1 u1 - G0 f0 - G1 f1] + sqrt(h) B_s N  (momentum)

(thesis Eq. 3.47's two block rows; ``C_m = (C0 + C1)/2`` for a time-varying damping), with
``B_s = B diag(sqrt(2 pi S0))`` and ``N``, ``P`` independent standard normal vectors. ``N`` carries the
Wiener increment over the step; ``P`` the Brownian-bridge part of its time integral, i.e. the
``B dt sqrt(dt)/sqrt(12)`` term of Eq. 3.49/4.58 (ERRATA: the factor is ``sqrt(dt) B``, not ``sqrt(dt B)``).
The damping term is integrated exactly (``int C u' dt = C (u1 - u0)``), as in Eq. 3.47. Eliminating ``v1``
gives the classic effective-stiffness form

    K_eff u1 + G1 f(G1^T u1) = E u0 + D v0 + F0 + F1 - G0 f0 + B_N N + B_P P
    K_eff = K1 + (2/h) C_m + (4/h^2) M,  (B_s, if time-varying, is the mean of its end values)   E = (4/h^2) M + (2/h) C_m - K0,   D = (4/h) M
    B_N = (2/sqrt(h)) B_s,   B_P = (4/sqrt(12 h)) B_s
    v1 = (2/h)(u1 - u0) - v0 - (2 sqrt(h)/sqrt(12)) M^-1 B_s P

Noise schemes (``noise_scheme``):
- ``"newmark"``: the documents' scheme, with the bridge term ``P``. For a linear system with state matrix A
  and continuous stationary covariance P_c, its stationary covariance is ``P_c + h^2/12 A P_c A^T``: mode
  variances are inflated by ``1 + (omega h)^2/12`` (ERRATA), which matters for stiff meshes.
- ``"trapezoidal"`` (default): drops ``P``. Its stationary covariance equals ``P_c`` exactly for any ``h``.

Without noise this is the deterministic average-acceleration Newmark method (beta = 1/4, gamma = 1/2),
second-order accurate and unconditionally stable.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .system import System, at_time

NOISE_SCHEMES = ("trapezoidal", "newmark")


def check_noise_scheme(noise_scheme: str) -> None:
    if noise_scheme not in NOISE_SCHEMES:
        raise ValueError(f"`noise_scheme` must be one of {NOISE_SCHEMES}, got {noise_scheme!r}")


def noise_dimension(system: System, noise_scheme: str) -> int:
    """Number of standard normals drawn per step (N, and P for the documents' scheme)."""
    return system.n_noise * (2 if noise_scheme == "newmark" else 1)


class Snapshot(NamedTuple):
    """The time-dependent matrices of a system at one instant."""

    damping: jax.Array  # (n, n)
    stiffness: jax.Array  # (n, n)
    load: jax.Array  # (n,)
    direction: jax.Array  # (n, nc)
    contact_stiffness: jax.Array  # (nc,)
    noise_input: jax.Array  # B diag(sqrt(2 pi S0)), (n, n_noise)


def snapshot(system: System, t) -> Snapshot:
    return Snapshot(
        at_time(system.damping, t),
        at_time(system.stiffness, t),
        at_time(system.load, t),
        system.contact_direction(t),
        system.contact_stiffness(t),
        system.scaled_noise_input(t),
    )


class StepMatrices(NamedTuple):
    """Right-hand-side blocks of one step before the solve with ``K_eff`` (see module docstring)."""

    effective_stiffness: jax.Array  # K_eff without contact terms (n, n)
    from_displacement: jax.Array  # E (n, n)
    from_velocity: jax.Array  # D (n, n)
    noise: jax.Array  # [B_N, B_P] (n, n_draws)
    velocity_noise: jax.Array  # velocity correction per draw (n, n_draws)


def step_matrices(system: System, s0: Snapshot, s1: Snapshot, h, noise_scheme: str) -> StepMatrices:
    M = system.mass
    c_mid = 0.5 * (s0.damping + s1.damping)
    k_eff = s1.stiffness + (2.0 / h) * c_mid + (4.0 / h**2) * M
    from_u = (4.0 / h**2) * M + (2.0 / h) * c_mid - s0.stiffness
    from_v = (4.0 / h) * M
    b_s = 0.5 * (s0.noise_input + s1.noise_input)  # B at mid-step (exact for constant B)
    b_n = (2.0 / jnp.sqrt(h)) * b_s
    if noise_scheme == "newmark":
        root12 = jnp.sqrt(12.0)
        b_p = (4.0 / (root12 * jnp.sqrt(h))) * b_s
        noise = jnp.concatenate([b_n, b_p], axis=1)
        minv_bs = jnp.linalg.solve(M, b_s)
        v_noise = jnp.concatenate([jnp.zeros_like(b_n), -(2.0 * jnp.sqrt(h) / root12) * minv_bs], axis=1)
    else:
        noise, v_noise = b_n, jnp.zeros_like(b_n)
    return StepMatrices(k_eff, from_u, from_v, noise, v_noise)


def velocity_update(u0, v0, u1, h):
    """v1 = (2/h)(u1 - u0) - v0 (deterministic part of the kinematic relation)."""
    return (2.0 / h) * (u1 - u0) - v0


# --------------------------------------------------------------------------- nonlinear step for samples


class SampleState(NamedTuple):
    """State of a batch of samples: displacement and velocity (batch, n), contact forces (batch, nc)."""

    u: jax.Array
    v: jax.Array
    force: jax.Array


def solve_contacts(delta_lin, coupling, k, b, law, *, tol=1e-12, max_iter=50):
    """Newton solve of ``delta + S f(delta) = delta_lin`` in contact space (one sample).

    ``S = G^T K_eff^-1 G`` couples the contacts. For the piecewise-linear backlash law Newton ends once the
    active set is right (exact to rounding); for one contact it needs at most two steps.
    Returns ``(delta, converged)``.
    """
    nc = delta_lin.shape[0]
    eye = jnp.eye(nc, dtype=delta_lin.dtype)
    scale = jnp.abs(delta_lin) + b + 1e-300

    def residual(d):
        return d + coupling @ law.force(d, k, b) - delta_lin

    def body(state):
        d, it, _ = state
        jac = eye + coupling * law.stiffness(d, k, b)[None, :]
        d = d - jnp.linalg.solve(jac, residual(d))
        return d, it + 1, jnp.max(jnp.abs(residual(d)) / scale)

    def cond(state):
        _, it, err = state
        return (it < max_iter) & (err > tol)

    err0 = jnp.max(jnp.abs(residual(delta_lin)) / scale)
    d, _, err = jax.lax.while_loop(cond, body, (delta_lin, jnp.array(0), err0))
    return d, err <= tol


def sample_step(system: System, state: SampleState, s0: Snapshot, s1: Snapshot, h, draws, noise_scheme: str):
    """Advance a batch of samples of the *nonlinear* system by one step (module docstring).

    ``draws`` are the standard normals of the step, (batch, noise_dimension). The solve with ``K_eff`` is
    done once for all samples (a shared right-hand-side block); per sample only matrix-vector products and the
    contact-space Newton solve remain. Returns the new state and the per-sample contact-solve flag.
    """
    nc = system.n_contacts
    mats = step_matrices(system, s0, s1, h, noise_scheme)
    blocks = [mats.from_displacement, mats.from_velocity, (s0.load + s1.load)[:, None]]
    if draws.shape[1]:
        blocks.append(mats.noise)
    if nc:
        blocks += [s0.direction, s1.direction]
    x = jnp.linalg.solve(mats.effective_stiffness, jnp.concatenate(blocks, axis=1))
    n = system.n_dof
    x_u, x_v, x_load = x[:, :n], x[:, n : 2 * n], x[:, 2 * n]
    col = 2 * n + 1
    u_lin = state.u @ x_u.T + state.v @ x_v.T + x_load[None, :]
    if draws.shape[1]:
        nd = draws.shape[1]
        u_lin = u_lin + draws @ x[:, col : col + nd].T
        col += nd
    ok = jnp.ones(state.u.shape[0], dtype=bool)
    if nc:
        kinv_g0, kinv_g1 = x[:, col : col + nc], x[:, col + nc : col + 2 * nc]
        u_lin = u_lin - state.force @ kinv_g0.T
        coupling = s1.direction.T @ kinv_g1
        k1, b = s1.contact_stiffness, system.contacts.clearance
        law = system.contacts.law
        delta_lin = u_lin @ s1.direction
        if nc == 1:  # scalar contact: the law's own (closed-form where it exists) solve, no vmap
            delta, ok = law.solve_single(delta_lin, coupling[0, 0], k1[None, :], b[None, :])
            ok = ok[:, 0]
        else:
            delta, ok = jax.vmap(lambda dl: solve_contacts(dl, coupling, k1, b, law))(delta_lin)
        force = system.contacts.law.force(delta, k1[None, :], b[None, :])
        u1 = u_lin - force @ kinv_g1.T
    else:
        force = state.force
        u1 = u_lin
    v1 = velocity_update(state.u, state.v, u1, h)
    if noise_scheme == "newmark" and draws.shape[1]:
        v1 = v1 + draws @ mats.velocity_noise.T
    return SampleState(u1, v1, force), ok


def initial_sample_state(system: System, s0: Snapshot, u0, v0) -> SampleState:
    """Batch state at t0 from (batch, n) displacements and velocities."""
    if system.n_contacts:
        k, b = s0.contact_stiffness[None, :], system.contacts.clearance[None, :]
        force = system.contacts.law.force(u0 @ s0.direction, k, b)
    else:
        force = jnp.zeros((u0.shape[0], 0))
    return SampleState(u0, v0, force)
