"""Deterministic response: average-acceleration Newmark (beta = 1/4, gamma = 1/2) with the contact forces
solved implicitly by Newton's method at every step (the noise-free case of :mod:`pgtjax.newmark`; the
paper's Eqs. 34-42 are the same scheme written with a full Newton-Raphson on all DOFs, which we reduce to a
solve in contact space because the contacts are the only nonlinearity)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .newmark import initial_sample_state, sample_step, snapshot
from .results import Trajectory
from .system import System, initial_state, validate_system, validate_time_grid


def simulate(
    system: System,
    *,
    t0: float = 0.0,
    dt: float,
    n_steps: int,
    initial_displacement=None,
    initial_velocity=None,
    save_every: int = 1,
) -> Trajectory:
    """Integrate the noise-free system from a given state; returns a labelled :class:`Trajectory` saved at
    ``t0 + k * save_every * dt``. The noise input ``B`` is ignored."""
    validate_system(system, t0)
    n_steps, save_every = validate_time_grid(dt, n_steps, save_every)
    u0, v0 = initial_state(system, initial_displacement, initial_velocity)
    return _simulate_jit(
        system, jnp.asarray(t0, jnp.float64), jnp.asarray(dt, jnp.float64), u0, v0,
        n_steps=n_steps, save_every=save_every,
    )


@eqx.filter_jit
def _simulate_jit(system, t0, dt, u0, v0, *, n_steps, save_every):
    s0 = snapshot(system, t0)
    state = initial_sample_state(system, s0, u0[None], v0[None])
    no_noise = jnp.zeros((1, 0))

    def record(state, snap):
        return state.u[0], state.v[0], (state.u @ snap.direction)[0], state.force[0]

    def block(carry, block_index):
        def inner(c, j):
            state, snap0, bad = c
            snap1 = snapshot(system, t0 + dt * (block_index * save_every + j + 1))
            state, ok = sample_step(system, state, snap0, snap1, dt, no_noise, "trapezoidal")
            return (state, snap1, bad + jnp.sum(~ok)), None

        carry, _ = jax.lax.scan(inner, carry, jnp.arange(save_every))
        return carry, record(carry[0], carry[1])

    (_, _, bad), saved = jax.lax.scan(block, (state, s0, jnp.array(0)), jnp.arange(n_steps // save_every))
    saved = jax.tree.map(lambda a, b: jnp.concatenate([a[None], b], axis=0), record(state, s0), saved)
    times = t0 + dt * save_every * jnp.arange(n_steps // save_every + 1, dtype=jnp.float64)
    return Trajectory(
        times=times, dof_names=system.dof_names, dof_units=system.dof_units,
        contact_names=system.contact_names(), u=saved[0], v=saved[1], delta=saved[2], force=saved[3],
        unconverged=bad,
    )


def static_equilibrium(system: System, t: float = 0.0, *, tol: float = 1e-12, max_iter: int = 100):
    """Solve ``K u + G f(G^T u) = F`` at time ``t`` by Newton's method (the deterministic static state;
    velocities zero). Starts from the solution with every contact closed at its stiffness. Raises
    ``RuntimeError`` if Newton does not converge (e.g. a mechanism held only by open contacts). The start
    closes each contact on the flank the load pushes it to (``f = k (delta - b sign delta)``)."""
    validate_system(system, t)
    u, converged, iterations = _static_jit(system, jnp.asarray(t, jnp.float64), tol, max_iter)
    if not bool(converged):
        raise RuntimeError(f"static equilibrium: Newton did not converge in {int(iterations)} iterations")
    return u


@eqx.filter_jit
def _static_jit(system, t, tol, max_iter):
    from .newmark import snapshot as _snapshot

    snap = _snapshot(system, t)
    k, f, g = snap.stiffness, snap.load, snap.direction
    kc, b = snap.contact_stiffness, system.contact_clearance()
    law = system.contacts.law if system.n_contacts else None

    def residual(u):
        r = k @ u - f
        return r + g @ law.force(g.T @ u, kc, b) if law is not None else r

    def jacobian(u):
        return k + (g * law.stiffness(g.T @ u, kc, b)[None, :]) @ g.T if law is not None else k

    closed = k + (g * kc[None, :]) @ g.T
    u0 = jnp.linalg.solve(closed, f)
    # close every contact on the flank it is pushed to, offset by the clearance: k (delta - b sign)
    u0 = jnp.linalg.solve(closed, f + g @ (kc * b * jnp.sign(g.T @ u0)))
    scale = jnp.max(jnp.abs(f)) + 1e-300

    def body(state):
        u, it, _ = state
        u = u - jnp.linalg.solve(jacobian(u), residual(u))
        return u, it + 1, jnp.max(jnp.abs(residual(u))) / scale

    def cond(state):
        _, it, err = state
        return (it < max_iter) & (err > tol)

    u, it, err = jax.lax.while_loop(cond, body, (u0, jnp.array(0), jnp.max(jnp.abs(residual(u0))) / scale))
    return u, err <= tol, it
