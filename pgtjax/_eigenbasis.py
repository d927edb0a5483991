"""The Monte Carlo step of a system with constant K and C, in the real eigenbasis of its contact-free map.

With K and C constant, the contact-free part of a Newmark step (:mod:`pgtjax._newmark`) is one fixed linear
map of the state x = (u, v). In the scaled state ``x~ = (u, (h/2) v)`` (u and (h/2) v in the same units,
so that neither half of the state dominates the basis's rounding) one step reads

    x~1 = T x~0 + [I; I] A^-1 (F0 + F1 + B_N N + B_P P - G0 f0 - G1 f1) + [0; (h/2) v_noise P]
    T = [[X_u, (2/h) X_v], [X_u - I, (2/h) X_v - I]],   X = A^-1 [E, D],   A = K + (2/h) C + (4/h^2) M

(substitute u1 from the effective-stiffness form into ``v1 = (2/h)(u1 - u0) - v0``). Average acceleration
is the trapezoidal rule, so T is the Cayley transform ``(I - hS/2)^-1 (I + hS/2)`` of the state matrix S and
shares its eigenvectors. In the real eigenbasis ``x~ = W z`` the map T is block diagonal: a 1x1 block per
real eigenvalue and a 2x2 block ``[[a, b], [-b, a]]`` per complex pair ``a +- ib`` (columns Re w, Im w of
the eigenvector w). A sample's step then costs O(n (nc + n_draws)) instead of the dense O(n^2) product: an
elementwise update plus products with the (2n, nc) images of the contact directions and the noise input.
The recorded quantities (u, v, contact deflections and forces, observables) are formed from the
eigen-coordinates, with one product per sample, only at the saved times.

It is the same discretization, not an approximation: the results agree with the physical-coordinate step to
rounding amplified by at most cond(W). cond(W) grows as the step shrinks (about 2 / (omega h) for a lightly
damped mode of frequency omega; a damped rigid-body mode, eigenvalue near 1, behaves alike), so the basis is
checked where it is formed: it is accepted only if ``W Lambda W^-1`` reproduces one step of T on random
states to ``MAX_MAP_ERROR`` (relative) and cond(W) <= ``MAX_CONDITION``; otherwise Monte Carlo keeps the
physical coordinates (``propagation="auto"``) or says why (``"eigen"``). A defective T (e.g. a critically
damped mode, or an undamped rigid-body mode) has no eigenbasis; LAPACK returns a nearly singular one
(cond(W) of order 1e8 or more), which the cap refuses. Measured: over 500-2,000 forced steps the eigen
recursion stays within 5e-13 (planetary model, h = 2.7 ms, cond 2e4) and 1e-10 (h = 2.7 us, cond 2e7) of the
physical one, relative.

The decomposition runs once per run on the host (NumPy/LAPACK): ``jnp.linalg.eig`` exists only on the CPU
backend and Monte Carlo is not differentiated.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._newmark import (
    AbstractIntegrator,
    Newmark,
    Snapshot,
    solve_contact_forces,
)
from ._system import System

MAX_MAP_ERROR = 1e-10  # relative error of W Lambda W^-1 x against T x accepted on random states x
MAX_CONDITION = 1e8  # cond(W) beyond this is refused whatever the test states show


class EigenPropagator(eqx.Module):
    """The contact-free Newmark map of a constant-K, C system for step ``h``, in its real eigenbasis.

    Coordinates ``z`` are ordered ``[Re parts of the pairs, Im parts of the pairs, real eigenvalues]``.
    """

    basis: jax.Array  # W with (u, (h/2) v) = W z, (2n, 2n)
    basis_inverse: jax.Array  # W^-1, (2n, 2n)
    force_input: jax.Array  # W^-1 [I; I] A^-1: z-increment per unit force (N), (2n, n)
    a_inv: jax.Array  # A^-1 (m/N), (n, n): the contact coupling G^T A^-1 G
    scale: jax.Array  # diagonal of the block-diagonal map: a (pairs, twice) and the real eigenvalues, (2n,)
    cross: jax.Array  # off-diagonal b of the 2x2 blocks (+b on Re rows, -b on Im rows), (n_pairs,)
    condition: jax.Array  # cond(W), 0-d: a leaf, since a static value would recompile the sampler per design
    h: float = eqx.field(static=True)  # step (s) the map was formed for

    @property
    def n_pairs(self) -> int:
        return self.cross.shape[0]

    def advance(self, z):
        """``z -> Lambda z`` for rows ``z`` (k, 2n), e.g. the contact directions' images: elementwise, the 2x2
        blocks pairing Re and Im. (A batch's state is advanced part by part, :func:`eigen_advance`.)"""
        cut = 2 * self.n_pairs
        return jnp.concatenate([self.advance_pairs(z[:, :cut]), z[:, cut:] * self.scale[None, cut:]], axis=1)

    def advance_pairs(self, pairs):
        """The complex pairs' part of :meth:`advance`: ``pairs`` (batch, 2 n_pairs), Re parts then Im parts."""
        m = self.n_pairs
        re, im = pairs[:, :m], pairs[:, m:]
        b = self.cross[None, :]
        return pairs * self.scale[None, : 2 * m] + jnp.concatenate([b * im, -b * re], axis=1)

    def from_physical(self, u, v):
        """Eigen-coordinates (batch, 2n) of displacements and velocities (batch, n) each."""
        return jnp.concatenate([u, (0.5 * self.h) * v], axis=1) @ self.basis_inverse.T


def eigen_propagator(
    system: System, h: float, integrator: AbstractIntegrator | None = None
) -> tuple[EigenPropagator | None, str]:
    """The :class:`EigenPropagator` of ``system`` for step ``h`` (s) under ``integrator`` (default
    :class:`~pgtjax.Newmark`), or ``(None, reason)`` where the eigenbasis cannot be used (time-varying K or
    C, traced arrays, an integrator whose step matrices are not known, a defective or ill-conditioned basis)."""
    integrator = Newmark() if integrator is None else integrator
    if callable(system.stiffness) or callable(system.damping):
        return None, "K or C depends on time"
    if any(isinstance(a, jax.core.Tracer) for a in (system.mass, system.damping, system.stiffness, h)):
        return None, "the system's matrices or the step are traced"
    h = float(h)
    M, C, K = (np.asarray(a, dtype=np.float64) for a in (system.mass, system.damping, system.stiffness))
    matrices = integrator.constant_step_matrices(M, C, K, h)
    if matrices is None:
        return None, (
            f"the integrator {type(integrator).__name__} does not give its contact-free step's matrices "
            "(constant_step_matrices)"
        )
    k_eff, from_u, from_v = (np.asarray(a, dtype=np.float64) for a in matrices)
    n = M.shape[0]
    eye = np.eye(n)
    a_inv = np.linalg.solve(k_eff, eye)
    x_u = a_inv @ from_u
    x_v = a_inv @ from_v
    t_map = np.block([[x_u, (2.0 / h) * x_v], [x_u - eye, (2.0 / h) * x_v - eye]])
    if not np.all(np.isfinite(t_map)):
        return None, "the step map is not finite"
    lam, vec = np.linalg.eig(t_map)
    pairs, real = np.flatnonzero(lam.imag > 0.0), np.flatnonzero(lam.imag == 0.0)
    if 2 * pairs.size + real.size != 2 * n:  # LAPACK returns real eigenvalues with imag exactly 0
        return None, "eigenvalues do not come in conjugate pairs"
    basis = np.concatenate([vec[:, pairs].real, vec[:, pairs].imag, vec[:, real].real], axis=1)
    a, b = lam[pairs].real, lam[pairs].imag
    scale = np.concatenate([a, a, lam[real].real])
    block = np.diag(scale)
    m = pairs.size
    block[np.arange(m) + m, np.arange(m)] = -b  # T Re w = a Re w - b Im w
    block[np.arange(m), np.arange(m) + m] = b  # T Im w = b Re w + a Im w
    condition = float(np.linalg.cond(basis))
    if not condition <= MAX_CONDITION:
        return None, f"eigenbasis rejected (cond(W) {condition:.3g} > {MAX_CONDITION:.0e})"
    inverse = np.linalg.inv(basis)
    states = np.random.default_rng(0).standard_normal((2 * n, 8))  # fixed: the decision is reproducible
    exact = t_map @ states
    error = np.max(
        np.linalg.norm(basis @ (block @ (inverse @ states)) - exact, axis=0) / np.linalg.norm(exact, axis=0)
    )
    if not error <= MAX_MAP_ERROR:
        return None, f"eigenbasis rejected (one step off by {error:.3g} relative, cond(W) {condition:.3g})"
    force_input = inverse @ np.concatenate([a_inv, a_inv], axis=0)
    prop = EigenPropagator(
        jnp.asarray(basis),
        jnp.asarray(inverse),
        jnp.asarray(force_input),
        jnp.asarray(a_inv),
        jnp.asarray(scale),
        jnp.asarray(b),
        jnp.asarray(condition, jnp.float64),
        h,
    )
    return prop, ""


class EigenSampleState(NamedTuple):
    """A batch of samples in eigen-coordinates. ``y`` (batch, 2n) is the state before the contact forces
    ``force`` (batch, nc) of its time ``t`` are applied: ``z = y - force Q(t)^T`` with ``Q(t) = W^-1 [I; I]
    A^-1 G(t)``. Carrying ``y`` folds the end-of-step force of one step and the start-of-step force of the
    next (the same forces along the same directions) into one product per step.

    ``y`` is kept as three arrays: the Re and the Im parts of its complex pairs, and its real eigenvalues'
    columns. The real part's update reads each column only, so XLA updates it in place; in one array with
    it, the pairs' 2x2 blocks (which read each other's columns) made XLA write the whole state to a new
    buffer and copy it back every step. Re and Im apart, a block's update is two elementwise expressions
    without the concatenation a single pairs array needed (docs/performance.md)."""

    re: jax.Array  # y's Re parts of the complex pairs, (batch, n_pairs)
    im: jax.Array  # y's Im parts of the complex pairs, (batch, n_pairs)
    real: jax.Array  # y's other columns, (batch, 2n - 2 n_pairs)
    force: jax.Array  # the contact forces at the state's time, (batch, nc)


def _split_state(prop: EigenPropagator, y, force) -> EigenSampleState:
    m = prop.n_pairs
    return EigenSampleState(y[:, :m], y[:, m : 2 * m], y[:, 2 * m :], force)


def _contact_input(prop: EigenPropagator, snap: Snapshot):
    """``Q(t)^T = (W^-1 [I; I] A^-1 G(t))^T``, (nc, 2n): z-increment per unit contact force."""
    return (prop.force_input @ snap.direction).T


def eigen_initial_state(prop: EigenPropagator, u, v, force, snap: Snapshot) -> EigenSampleState:
    """State of a batch at time ``t`` (``snap``) from displacements, velocities and contact forces."""
    return _split_state(prop, prop.from_physical(u, v) + force @ _contact_input(prop, snap), force)


def eigen_recorded(prop: EigenPropagator, state: EigenSampleState, snap: Snapshot, observation):
    """``[u, v, u G(t), force, u C]`` (batch, 2n + 2 nc + k) of a state at the time of ``snap``: Monte Carlo's
    recorded quantities (displacements, velocities, contact deflections, contact forces and observables
    ``u C``, ``observation`` C (n, k)), in the order of ``pgtjax._montecarlo.quantity_names``.

    They are linear in the state, so they are formed straight from the eigen-coordinates with rows
    ``W_u^T [I, 0, G, 0, C]`` and ``(2/h) W_v^T [0, I, 0, 0, 0]`` part by part (:func:`_parts_times`: a
    matrix product per wide part, fused outer products for the narrow ones). Forming ``(u, v)`` first took
    four more passes over the batch (the state's concatenation, the force correction, the velocity scaling and the quantities'
    concatenation; docs/performance.md). Results agree with that route to rounding."""
    n = prop.basis.shape[0] // 2
    nc = state.force.shape[1]
    to_u = prop.basis[:n].T  # (2n, n): u per eigen-coordinate
    to_v = (2.0 / prop.h) * prop.basis[n:].T
    rows = jnp.concatenate(
        [to_u, to_v, to_u @ snap.direction, jnp.zeros((2 * n, nc), to_u.dtype), to_u @ observation], axis=1
    )
    # z = y - force Q(t)^T, and the force columns are the forces themselves
    force_rows = (-_contact_input(prop, snap) @ rows).at[:, 2 * n + nc : 2 * n + 2 * nc].add(jnp.eye(nc))
    return eigen_outputs(prop, state, rows, force_rows)


def eigen_output_rows(prop: EigenPropagator, snap: Snapshot, u_map, v_map):
    """Rows of linear outputs ``u A + v B`` (``u_map`` A and ``v_map`` B, (n, k)) at the time of ``snap``
    in eigen-coordinates, for :func:`eigen_outputs`: (2n, k) for ``y`` and (nc, k) for the forces
    (``z = y - force Q(t)^T``)."""
    n = prop.basis.shape[0] // 2
    rows = prop.basis[:n].T @ u_map + (2.0 / prop.h) * (prop.basis[n:].T @ v_map)
    return rows, -_contact_input(prop, snap) @ rows


def eigen_outputs(prop: EigenPropagator, state: EigenSampleState, rows, force_rows):
    """``y rows + force force_rows`` (batch, k): outputs of a batch's state, the rows as from
    :func:`eigen_output_rows` (or :func:`eigen_recorded`'s)."""
    m = prop.n_pairs
    return _parts_times(
        (state.re, state.im, state.real, state.force), (rows[:m], rows[m : 2 * m], rows[2 * m :], force_rows)
    )


_FUSED_PRODUCT_MAX_TERMS = 16
_FUSED_DEFLECTION_MAX_COLUMNS = 8  # a part of the state this narrow enters the contact deflections fused


def _outer_products(columns, rows):
    """``concatenate(columns, 1) @ concatenate(rows, 0)``: (batch, k) times (k, w). For few terms (the
    1 + n_draws + nc inputs of a step, or a narrow part of the state in the contact deflections) it is
    written as a sum of outer products, which XLA fuses with the elementwise work around it into one pass
    over the batch (as a matrix product the state was read and written twice more per step: planetary 267
    against 229 ns per sample-step, gear pair 18.5 against 15.9, two CPU devices; docs/performance.md).
    Results agree with the product's to rounding."""
    k = sum(c.shape[1] for c in columns)
    if k > _FUSED_PRODUCT_MAX_TERMS:
        return jnp.concatenate(columns, axis=1) @ jnp.concatenate(rows, axis=0)
    total = None
    for column, row in zip(columns, rows):
        for j in range(column.shape[1]):
            term = column[:, j : j + 1] * row[j][None, :]
            total = term if total is None else total + term
    return total


def _parts_times(parts, rows):
    """``sum_i parts[i] @ rows[i]`` (batch, w) over the parts of a state with any columns (Re, Im, real
    eigenvalues' columns, forces). A narrow part (at most ``_FUSED_DEFLECTION_MAX_COLUMNS`` columns) enters
    as outer products, which fuse with the sum into one pass over the batch (as a small matrix product and
    an add, each was a kernel of its own); a wide part as a matrix product."""
    total = None
    for part, part_rows in zip(parts, rows):
        if not part.shape[1]:
            continue
        if part.shape[1] <= _FUSED_DEFLECTION_MAX_COLUMNS:
            term = _outer_products([part], [part_rows])
        else:
            term = part @ part_rows
        total = term if total is None else total + term
    return total


class EigenStepInputs(NamedTuple):
    """What a step from ``s0`` to ``s1`` needs besides the batch's state and draws (:func:`eigen_step_inputs`):
    the same for every sample, so Monte Carlo forms it for a whole block of steps at once, outside the step
    loop (a step's own small matrix products were about a dozen tiny kernels per step; docs/performance.md)."""

    rows: jax.Array  # z-increment per unit of [1, draws, start-of-step forces], (1 + n_draws + nc, 2n)
    to_contacts: jax.Array  # end-of-step contact deflections per eigen-coordinate, (2n, nc)
    coupling: jax.Array  # G1^T A^-1 G1, (nc, nc)
    contact_inputs: object  # the contact law's inputs at the step's end, every leaf (nc,)


def eigen_step_inputs(
    system: System, prop: EigenPropagator, s0: Snapshot, s1: Snapshot, integrator: AbstractIntegrator
) -> EigenStepInputs:
    """:class:`EigenStepInputs` of the step from ``s0`` to ``s1`` (step ``prop.h``): with
    :func:`eigen_advance`, :func:`pgtjax._newmark.sample_step` in eigen-coordinates (module docstring).

    With ``z0 = y0 - f0 Q0^T`` the contact-free update ``Lambda z0 + inputs - f0 Q0^T`` is
    ``Lambda y0 + inputs - f0 (Lambda Q0 + Q0)^T``: loads, noise and the start-of-step forces enter through
    one product with the rows ``[load; noise; -(Lambda Q0 + Q0)]``."""
    h = prop.h
    rows = [((s0.load + s1.load) @ prop.force_input.T)[None, :]]
    if integrator.noise_dimension(system):
        noise, v_noise = integrator.noise_matrices(system, s0, s1, h)
        z_noise = prop.force_input @ noise
        if integrator.has_velocity_noise:
            z_noise = z_noise + (0.5 * h) * (prop.basis_inverse[:, system.n_dof :] @ v_noise)
        rows.append(z_noise.T)
    if system.n_contacts:
        q0 = _contact_input(prop, s0)
        rows.append(-(prop.advance(q0) + q0))
    g1 = s1.direction
    return EigenStepInputs(
        jnp.concatenate(rows, axis=0),
        prop.basis[: system.n_dof].T @ g1,
        g1.T @ prop.a_inv @ g1,
        s1.contact_inputs,
    )


def eigen_advance(
    system: System, prop: EigenPropagator, state: EigenSampleState, inputs: EigenStepInputs, draws
):
    """One step of a batch with the step's :class:`EigenStepInputs` and its standard normals ``draws``
    (batch, n_draws): the elementwise map ``Lambda y0`` plus the rows' outer products (:func:`_outer_products`,
    fused into one pass over the batch), then the contact solve; the end-of-step forces are left in ``y1``.
    Returns the new state and the per-sample contact-solve flag."""
    nd = draws.shape[1]
    if inputs.rows.shape[-2] != 1 + nd + state.force.shape[1]:  # static: the rows of another noise dimension
        raise ValueError(
            f"eigen_advance: {inputs.rows.shape[-2]} input rows for 1 + {nd} draws + {state.force.shape[1]} "
            "contact forces"
        )
    columns = [jnp.ones((state.real.shape[0], 1), state.real.dtype)]
    rows = [inputs.rows[:1]]
    if nd:
        columns.append(draws)
        rows.append(inputs.rows[1 : 1 + nd])
    ok = jnp.ones(columns[0].shape[0], dtype=bool)
    if system.n_contacts:
        columns.append(state.force)
        rows.append(inputs.rows[1 + nd :])
    m = prop.n_pairs
    a, b = prop.scale[None, :m], prop.cross[None, :]
    re = a * state.re + b * state.im + _outer_products(columns, [r[:, :m] for r in rows])
    im = a * state.im - b * state.re + _outer_products(columns, [r[:, m : 2 * m] for r in rows])
    real = state.real * prop.scale[None, 2 * m :] + _outer_products(columns, [r[:, 2 * m :] for r in rows])
    if not system.n_contacts:
        return EigenSampleState(re, im, real, state.force), ok
    to_contacts = inputs.to_contacts
    delta_lin = _parts_times((re, im, real), (to_contacts[:m], to_contacts[m : 2 * m], to_contacts[2 * m :]))
    force, ok = solve_contact_forces(system, delta_lin, inputs.coupling, inputs.contact_inputs)
    return EigenSampleState(re, im, real, force), ok
