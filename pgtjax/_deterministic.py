"""Deterministic response: average-acceleration Newmark (beta = 1/4, gamma = 1/2) with the contact forces
solved implicitly by Newton's method at every step (the noise-free case of :mod:`pgtjax._newmark`; the
paper's Eqs. 34-42 are the same scheme written with a full Newton-Raphson on all DOFs, which we reduce to a
solve in contact space because the contacts are the only nonlinearity)."""

from __future__ import annotations

import numbers
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._failure import SolverError, error_if_nonfinite, is_concrete, raise_if_nonfinite
from ._loop import saved_scan
from ._newmark import AbstractIntegrator, initial_sample_state, resolve_integrator, sample_step, snapshot
from ._results import Trajectory
from ._system import (
    System,
    as_float_array,
    check_contact_stiffness_over_time,
    check_count,
    check_memory,
    check_stability,
    initial_state,
    validate_system,
    validate_time_grid,
)


def simulate(
    system: System,
    *,
    t0: float = 0.0,
    dt: float,
    n_steps: int,
    initial_displacement=None,
    initial_velocity=None,
    save_every: int = 1,
    integrator: AbstractIntegrator | None = None,
    throw: bool = True,
) -> Trajectory:
    """Integrate the noise-free system from a given state; returns a labelled :class:`Trajectory` saved at
    ``t0 + k * save_every * dt``. The noise input ``B`` is ignored. ``integrator``: the time discretization
    (default :class:`pgtjax.Newmark`, average acceleration). ``throw``: raise :class:`pgtjax.SolverError`
    naming the first time and quantity that is not finite, or if a contact solve did not converge (with
    ``False`` the trajectory is returned as it is; ``unconverged`` counts the failed steps)."""
    validate_system(system, t0)
    n_steps, save_every = validate_time_grid(dt, n_steps, save_every, t0)
    check_memory("simulate", n_steps // save_every + 1, 3 * system.n_dof + 2 * system.n_contacts)
    check_contact_stiffness_over_time(system, t0, dt, n_steps)
    check_stability(system, t0, horizon=None if isinstance(dt, jax.core.Tracer) else n_steps * float(dt))
    u0, v0 = initial_state(system, initial_displacement, initial_velocity)
    result = _simulate_jit(
        system,
        jnp.asarray(t0, jnp.float64),
        jnp.asarray(dt, jnp.float64),
        u0,
        v0,
        n_steps=n_steps,
        save_every=save_every,
        integrator=resolve_integrator(integrator),
    )
    if not throw:
        return result
    solver = "simulate"
    fields = {
        "displacement": (result.u, result.dof_names),
        "velocity": (result.v, result.dof_names),
        "contact force": (result.force, result.contact_names),
    }
    if not is_concrete(result):
        return error_if_nonfinite(solver, result, [a for a, _ in fields.values()])
    raise_if_nonfinite(solver, result.times, fields)
    if int(result.unconverged):
        raise SolverError(
            f"{solver}: the contact Newton solve did not converge in {int(result.unconverged)} steps; "
            "reduce `dt` or check the contact law, or pass throw=False to read `unconverged`"
        )
    return result


@eqx.filter_jit
def _simulate_jit(system, t0, dt, u0, v0, *, n_steps, save_every, integrator):
    s0 = snapshot(system, t0)
    state = initial_sample_state(system, s0, u0[None], v0[None])
    no_noise = jnp.zeros((1, 0))

    def record(state, snap):
        return state.u[0], state.v[0], (state.u @ snap.direction)[0], state.force[0]

    def step(c, step_number, _):
        state, snap0, bad = c
        snap1 = snapshot(system, t0 + dt * step_number)
        state, ok = sample_step(system, state, snap0, snap1, dt, no_noise, integrator)
        return (state, snap1, bad + jnp.sum(~ok)), None

    (_, _, bad), saved = saved_scan(
        step,
        lambda c, _, __: record(c[0], c[1]),
        (state, s0, jnp.array(0)),
        record(state, s0),
        n_blocks=n_steps // save_every,
        save_every=save_every,
    )
    times = t0 + dt * save_every * jnp.arange(n_steps // save_every + 1, dtype=jnp.float64)
    return Trajectory(
        times=times,
        dof_names=system.dof_names,
        dof_units=system.dof_units,
        contact_names=system.contact_names(),
        u=saved[0],
        v=saved[1],
        delta=saved[2],
        force=saved[3],
        unconverged=bad,
    )


def static_equilibrium(
    system: System,
    t: float = 0.0,
    *,
    velocity=None,
    initial_guess=None,
    tol: float = 1e-12,
    max_iter: int = 100,
) -> jax.Array:
    """Displacement (n,) of the static state at time ``t`` (s): ``K u + G f(G^T u) = F - C v``, with ``v``
    the prescribed ``velocity`` (default 0; a rigid rotation at constant speed, say, whose damping load then
    enters). Newton's method with the law's tangent stiffness, from ``initial_guess`` or by default from the
    solution with every contact closed (the law's ``closed_stiffness``) on the flank the load pushes it to.

    Works under ``jit``, ``vmap`` and ``grad``: the derivative is the implicit-function one,
    ``du = -J^-1 dR`` at the solution (J the tangent stiffness), with respect to every array of the system,
    the contact law's parameters included. Raises ``RuntimeError`` (also under ``jit``) if Newton does not
    reach a relative residual ``tol`` in ``max_iter`` iterations, e.g. for a mechanism held only by open
    contacts."""
    validate_system(system, t, time_name="t")
    if isinstance(tol, bool) or not isinstance(tol, numbers.Real) or not 0.0 < tol < 1.0:
        raise ValueError(f"`tol` must be a number in (0, 1), got {tol!r}")
    max_iter = check_count("max_iter", max_iter)
    n = system.n_dof
    v, initial_guess = (
        None if value is None else as_float_array(name, value)
        for name, value in (("velocity", velocity), ("initial_guess", initial_guess))
    )
    v = jnp.zeros(n) if v is None else v
    for name, value in (("velocity", v), ("initial_guess", initial_guess)):
        if value is None:
            continue
        if value.shape != (n,):
            raise ValueError(f"`{name}` must have shape ({n},), got {value.shape}")
        if is_concrete(value) and not np.all(np.isfinite(np.asarray(value))):
            raise ValueError(f"`{name}` must contain only finite numbers (no NaN or inf)")
    u, err, iterations = _static_solve(
        system, jnp.asarray(t, jnp.float64), v, initial_guess, tol=float(tol), max_iter=max_iter
    )
    failure = (
        f"static_equilibrium: Newton did not reach a relative residual of {tol:g} in {max_iter} iterations "
        "(a NaN, a mechanism held only by open contacts, or a load no contact can carry); check the loads and "
        "stiffnesses, or raise `max_iter`"
    )
    if not is_concrete((u, err)):
        return eqx.error_if(u, ~(err <= tol), failure)
    if not float(err) <= tol:
        raise SolverError(
            f"{failure} (at t = {float(t):.6g} s: {float(err):.3g} after {int(iterations)} iterations)"
        )
    return u


class _StaticProblem(NamedTuple):
    """``K u + G f(G^T u; inputs, b) = F`` at one instant: the system's time functions already evaluated, so
    that their parameters (closed over or not) are differentiated through the arrays here."""

    stiffness: jax.Array  # (n, n) K(t), N/m
    load: jax.Array  # (n,) F(t) - C(t) v, N
    direction: jax.Array  # (n, nc)
    inputs: object  # the contact law's inputs at t, every leaf (nc,)
    clearance: jax.Array  # (nc,) m


def _static_problem(system: System, t, v) -> _StaticProblem:
    snap = snapshot(system, t)
    return _StaticProblem(
        snap.stiffness,
        snap.load - snap.damping @ v,
        snap.direction,
        snap.contact_inputs,
        system.contact_clearance(),
    )


def _static_residual(u, prob: _StaticProblem, law):
    """``K u + G f(G^T u) - F`` (N)."""
    r = prob.stiffness @ u - prob.load
    if law is not None:
        g = prob.direction
        r = r + g @ law.force(g.T @ u, prob.inputs, prob.clearance)
    return r


def _static_tangent(u, prob: _StaticProblem, law):
    """The tangent stiffness ``K + G diag(f'(G^T u)) G^T`` (N/m)."""
    if law is None:
        return prob.stiffness
    g = prob.direction
    return prob.stiffness + (g * law.stiffness(g.T @ u, prob.inputs, prob.clearance)[None, :]) @ g.T


@eqx.filter_custom_jvp
def _static_implicit(u_star, prob, law):
    """Identity on the converged static solution; its tangent is ``-J^-1 dR`` (implicit function theorem)."""
    return u_star


@_static_implicit.def_jvp
def _static_implicit_jvp(primals, tangents):
    u_star, prob, law = primals
    dynamic, static = eqx.partition((prob, law), eqx.is_inexact_array)
    d_dynamic = jax.tree.map(
        lambda p, d: None if p is None else (jnp.zeros_like(p) if d is None else d),
        dynamic,
        tangents[1:],
        is_leaf=lambda x: x is None,
    )

    def residual(dyn):
        return _static_residual(u_star, *eqx.combine(dyn, static))

    _, d_residual = jax.jvp(residual, (dynamic,), (d_dynamic,))
    return u_star, -jnp.linalg.solve(_static_tangent(u_star, prob, law), d_residual)


def _stop_gradient(tree):
    return jax.tree.map(lambda x: jax.lax.stop_gradient(x) if eqx.is_array(x) else x, tree)


@eqx.filter_jit
def _static_solve(system, t, v, u_init, *, tol, max_iter):
    """``(u, relative residual, iterations)``; ``u`` differentiable through :func:`_static_implicit`."""
    prob = _static_problem(system, t, v)
    law = system.contacts.law if system.n_contacts else None
    prob_c, law_c = _stop_gradient((prob, law))
    scale = jnp.max(jnp.abs(prob_c.load)) + 1e-300
    if u_init is None:
        k = prob_c.stiffness
        if law_c is not None:
            g, b = prob_c.direction, prob_c.clearance
            kc = law_c.closed_stiffness(prob_c.inputs, b)
            closed = k + (g * kc[None, :]) @ g.T
            u_init = jnp.linalg.solve(closed, prob_c.load)
            # close every contact on the flank it is pushed to, offset by the clearance: k (delta - b sign)
            u_init = jnp.linalg.solve(closed, prob_c.load + g @ (kc * b * jnp.sign(g.T @ u_init)))
        else:
            u_init = jnp.linalg.solve(k, prob_c.load)
    u_init = jax.lax.stop_gradient(u_init)

    def error(u):
        return jnp.max(jnp.abs(_static_residual(u, prob_c, law_c))) / scale

    def body(state):
        u, it, _ = state
        u = u - jnp.linalg.solve(_static_tangent(u, prob_c, law_c), _static_residual(u, prob_c, law_c))
        return u, it + 1, error(u)

    def cond(state):
        _, it, err = state
        return (it < max_iter) & (err > tol)  # a NaN residual stops the loop too, and is reported

    u, iterations, err = jax.lax.while_loop(cond, body, (u_init, jnp.array(0), error(u_init)))
    return _static_implicit(u, prob, law), err, iterations
