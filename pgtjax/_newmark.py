"""One step of the (stochastic) average-acceleration Newmark scheme, shared by every solver.

Derivation (thesis Eqs. 3.45-3.51 / 4.52-4.60, rewritten in effective-stiffness form). Over a step
``h = t1 - t0`` the scheme is the trapezoidal rule on the state ``(u, v)``:

    u1 - u0 = h/2 (v0 + v1) + M^-1 B_s (h^(3/2)/sqrt(12)) P                            (kinematics)
    M (v1 - v0) + C_m (u1 - u0) = h/2 [F0 + F1 - K0 u0 - K1 u1 - G0 f0 - G1 f1] + sqrt(h) B_s N  (momentum)

(thesis Eq. 3.47's two block rows; ``C_m = (C0 + C1)/2`` for a time-varying damping), with
``B_s = B diag(sqrt(2 pi S0))`` and ``N``, ``P`` independent standard normal vectors. ``N`` carries the
Wiener increment over the step; ``P`` the Brownian-bridge part of its time integral, i.e. the
``B dt sqrt(dt)/sqrt(12)`` term of Eq. 3.49/4.58 (docs/corrections.md C2: the factor is ``sqrt(dt) B``, not ``sqrt(dt B)``).
The damping term is integrated exactly (``int C u' dt = C (u1 - u0)``), as in Eq. 3.47. Eliminating ``v1``
gives the classic effective-stiffness form

    K_eff u1 + G1 f(G1^T u1) = E u0 + D v0 + F0 + F1 - G0 f0 + B_N N + B_P P
    K_eff = K1 + (2/h) C_m + (4/h^2) M,  (B_s, if time-varying, is the mean of its end values)   E = (4/h^2) M + (2/h) C_m - K0,   D = (4/h) M
    B_N = (2/sqrt(h)) B_s,   B_P = (4/sqrt(12 h)) B_s
    v1 = (2/h)(u1 - u0) - v0 - (2 sqrt(h)/sqrt(12)) M^-1 B_s P

Integrators (the solvers' ``integrator`` argument):
- :class:`NewmarkBridge`: the documents' scheme, with the bridge term ``P``. For a linear system with state matrix A
  and continuous stationary covariance P_c, its stationary covariance is ``P_c + h^2/12 A P_c A^T``: mode
  variances are inflated by ``1 + (omega h)^2/12`` (C2), which matters for stiff meshes.
- :class:`Newmark` (default): drops ``P``. Its stationary covariance equals ``P_c`` exactly for any ``h``.

Without noise this is the deterministic average-acceleration Newmark method (beta = 1/4, gamma = 1/2),
second-order accurate and unconditionally stable.
"""

from __future__ import annotations

import abc
import functools
from typing import ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from ._system import System, at_time


def effective_stiffness(mass, damping, stiffness, h):
    """``K_eff = K + (2/h) C + (4/h^2) M``: the matrix solved at every step (module docstring)."""
    return stiffness + (2.0 / h) * damping + (4.0 / h**2) * mass


def from_displacement(mass, damping, stiffness, h):
    """``E = (4/h^2) M + (2/h) C - K``: the start-of-step displacement's share of the right-hand side."""
    return (4.0 / h**2) * mass + (2.0 / h) * damping - stiffness


def from_velocity(mass, h):
    """``D = (4/h) M``: the start-of-step velocity's share of the right-hand side."""
    return (4.0 / h) * mass


class AbstractIntegrator(eqx.Module):
    """Strategy: the time discretization every solver uses (SL moments, Monte Carlo, deterministic).

    A subclass gives the step's matrices (:meth:`step_matrices`, :meth:`noise_matrices`) and the number of
    standard normals drawn per step; :meth:`init` forms once per run what does not change from step to step.
    The solvers take one with ``integrator=`` (default :class:`Newmark`). The solvers' state update assumes the
    average-acceleration kinematics ``v1 = (2/h)(u1 - u0) - v0`` (+ the velocity noise), so a subclass varies
    the effective-stiffness matrices and the noise treatment within that family; Monte Carlo's
    eigen-coordinate path is used where :meth:`constant_step_matrices` gives the step's matrices.
    """

    name: ClassVar[str]
    #: whether ``noise_matrices``' velocity correction can be nonzero (else the solvers skip that product)
    has_velocity_noise: ClassVar[bool] = True

    @abc.abstractmethod
    def noise_dimension(self, system: System) -> int:
        """Number of standard normals drawn per step."""

    @abc.abstractmethod
    def noise_matrices(self, system: System, s0: Snapshot, s1: Snapshot, h):
        """``(noise input per draw, velocity correction per draw)``, each (n, n_draws)."""

    @abc.abstractmethod
    def step_matrices(self, system: System, s0: Snapshot, s1: Snapshot, h) -> StepMatrices: ...

    @abc.abstractmethod
    def init(self, system: System, h) -> ConstantPropagator | None:
        """The run's step operators formed once (``None`` where K or C depends on time)."""

    def constant_step_matrices(self, mass, damping, stiffness, h):
        """``(K_eff, E, D)`` of the contact-free step for constant M, C, K (NumPy or JAX arrays, SI units),
        where the step map follows from them alone, as the average-acceleration kinematics makes it: Monte
        Carlo's eigen coordinates diagonalize that map. ``None`` (the default): not known, so Monte Carlo
        steps this integrator in physical coordinates."""
        return None


class _AverageAcceleration(AbstractIntegrator):
    """Average-acceleration Newmark (beta = 1/4, gamma = 1/2) in effective-stiffness form (thesis Eqs.
    3.45-3.51 / 4.52-4.60, module docstring); the subclasses differ in how the noise enters a step."""

    def effective_matrices(self, mass, damping, stiffness0, stiffness1, h):
        """``(K_eff, E, D)`` of a step from the damping over the step and the stiffness at its two ends: the
        one place the scheme's algebra lives (override it for a variant; every solver path uses it)."""
        return (
            effective_stiffness(mass, damping, stiffness1, h),
            from_displacement(mass, damping, stiffness0, h),
            from_velocity(mass, h),
        )

    def displacement_increment(self, stiffness0, stiffness1):
        """``E - K_eff = -(K0 + K1)``, exactly: what ``[E, D]`` becomes when the step map gives the
        displacement increment ``u1 - u0`` instead of ``u1``. Forming it by subtraction would lose the
        digits that the ``(4/h^2) M`` terms of E and K_eff share (``docs/corrections.md`` C2d).

        A subclass that overrides ``effective_matrices``, ``step_matrices`` or ``init`` and not this method
        gets ``E - K_eff`` by subtraction instead (:meth:`_exact_increment`): correct for any variant, with
        the rounding drift of slow DOFs that this method avoids; override this method too to avoid it."""
        return -(stiffness0 + stiffness1)

    def _exact_increment(self) -> bool:
        """Whether :meth:`displacement_increment` matches this integrator's matrices: the built-in ones, or
        a subclass that overrides it along with the methods that form them."""
        base, cls = _AverageAcceleration, type(self)
        if cls.displacement_increment is not base.displacement_increment:
            return True
        return all(
            getattr(cls, m) is getattr(base, m) for m in ("effective_matrices", "step_matrices", "init")
        )

    def constant_step_matrices(self, mass, damping, stiffness, h):
        """``effective_matrices`` at constant K, unless a subclass forms its steps some other way (it
        overrides ``step_matrices`` or ``init``): then ``None``, since these matrices would not be its map."""
        cls, base = type(self), _AverageAcceleration
        if cls.step_matrices is not base.step_matrices or cls.init is not base.init:
            return None
        return self.effective_matrices(mass, damping, stiffness, stiffness, h)

    def step_matrices(self, system: System, s0: Snapshot, s1: Snapshot, h) -> StepMatrices:
        c_mid = 0.5 * (s0.damping + s1.damping)
        k_eff, from_u, from_v = self.effective_matrices(system.mass, c_mid, s0.stiffness, s1.stiffness, h)
        noise, v_noise = self.noise_matrices(system, s0, s1, h)
        increment = (
            self.displacement_increment(s0.stiffness, s1.stiffness) if self._exact_increment() else None
        )
        return StepMatrices(k_eff, from_u, from_v, noise, v_noise, increment)

    def init(self, system: System, h) -> ConstantPropagator | None:
        """:class:`ConstantPropagator` of ``system`` for step ``h``, or None if K or C is time-varying."""
        if callable(system.stiffness) or callable(system.damping):
            return None
        M, C, K = system.mass, system.damping, system.stiffness
        n = M.shape[0]
        k_eff, from_u, from_v = self.effective_matrices(M, C, K, K, h)
        a_inv = jnp.linalg.solve(k_eff, jnp.eye(n, dtype=M.dtype))
        rhs = jnp.concatenate([from_u, from_v], axis=1)
        if not self._exact_increment():  # a variant's matrices: dX by subtraction (increment_map)
            return ConstantPropagator(a_inv, a_inv @ rhs)
        increment = jnp.concatenate([self.displacement_increment(K, K), from_v], axis=1)
        return ConstantPropagator(a_inv, a_inv @ rhs, a_inv @ increment)


class Newmark(_AverageAcceleration):
    """Average-acceleration Newmark with the white noise's increment over each step (the default).

    For a linear system its stationary covariance equals the continuous one exactly, for any step."""

    name: ClassVar[str] = "trapezoidal"
    has_velocity_noise: ClassVar[bool] = False

    def noise_dimension(self, system: System) -> int:
        return system.n_noise

    def noise_matrices(self, system: System, s0: Snapshot, s1: Snapshot, h):
        b_s = 0.5 * (s0.noise_input + s1.noise_input)  # B at mid-step (exact for constant B)
        b_n = (2.0 / jnp.sqrt(h)) * b_s
        return b_n, jnp.zeros_like(b_n)


class NewmarkBridge(_AverageAcceleration):
    """The documents' stochastic Newmark scheme: the increment plus the Brownian-bridge term of its time
    integral (``B dt sqrt(dt) / sqrt(12)``, Eq. 3.49 / 4.58 as corrected). Its stationary covariance is
    ``P_c + h^2/12 A P_c A^T``: mode variances inflated by ``1 + (omega h)^2 / 12``."""

    name: ClassVar[str] = "newmark"

    def noise_dimension(self, system: System) -> int:
        return 2 * system.n_noise

    def noise_matrices(self, system: System, s0: Snapshot, s1: Snapshot, h):
        b_s = 0.5 * (s0.noise_input + s1.noise_input)
        b_n = (2.0 / jnp.sqrt(h)) * b_s
        root12 = jnp.sqrt(12.0)
        b_p = (4.0 / (root12 * jnp.sqrt(h))) * b_s
        minv_bs = jnp.linalg.solve(system.mass, b_s)
        v_noise = jnp.concatenate([jnp.zeros_like(b_n), -(2.0 * jnp.sqrt(h) / root12) * minv_bs], axis=1)
        return jnp.concatenate([b_n, b_p], axis=1), v_noise


def resolve_integrator(integrator: AbstractIntegrator | None) -> AbstractIntegrator:
    """The integrator a solver uses: ``integrator``, or :class:`Newmark` where it is None."""
    if integrator is None:
        return Newmark()
    if not isinstance(integrator, AbstractIntegrator):
        raise ValueError(
            "`integrator` must be a pgtjax integrator object, pgtjax.Newmark() (the default) or "
            f"pgtjax.NewmarkBridge() (the documents' scheme), got {integrator!r}"
        )
    return integrator


class Snapshot(NamedTuple):
    """The time-dependent matrices of a system at one instant."""

    damping: jax.Array  # (n, n)
    stiffness: jax.Array  # (n, n)
    load: jax.Array  # (n,)
    direction: jax.Array  # (n, nc)
    contact_inputs: object  # the contact law's inputs, every leaf (nc,)
    noise_input: jax.Array  # B diag(sqrt(2 pi S0)), (n, n_noise)


def snapshot(system: System, t) -> Snapshot:
    return Snapshot(
        at_time(system.damping, t),
        at_time(system.stiffness, t),
        at_time(system.load, t),
        system.contact_direction(t),
        system.contact_inputs(t),
        system.scaled_noise_input(t),
    )


class StepMatrices(NamedTuple):
    """Right-hand-side blocks of one step before the solve with ``K_eff`` (see module docstring)."""

    effective_stiffness: jax.Array  # K_eff without contact terms (n, n)
    from_displacement: jax.Array  # E (n, n)
    from_velocity: jax.Array  # D (n, n)
    noise: jax.Array  # [B_N, B_P] (n, n_draws)
    velocity_noise: jax.Array  # velocity correction per draw (n, n_draws)
    # E - K_eff (n, n), exact (the integrator's displacement_increment); None: formed by subtraction
    displacement_increment: jax.Array | None = None


class ConstantPropagator(NamedTuple):
    """Step operators of a system whose K and C do not depend on time (contacts excluded), formed once
    per run: ``A^-1`` with ``A = K + (2/h) C + (4/h^2) M`` (the contact-free K_eff) and
    ``X = A^-1 [E, D]``, the displacement rows of the contact-free one-step map of ``(u, v)``, and
    ``dX = X - [I 0] = A^-1 [E - A, D]``, the map of the displacement increment, formed without the
    subtraction (None: :func:`increment_map` subtracts)."""

    a_inv: jax.Array  # (n, n)
    x: jax.Array  # (n, 2n)
    dx: jax.Array | None = None  # (n, 2n)


def increment_map(prop: ConstantPropagator) -> jax.Array:
    """``dX = X - [I 0]`` of ``prop``: its exact ``dx`` where given (a custom integrator's propagator may
    have only ``x``), else by subtraction."""
    if prop.dx is not None:
        return prop.dx
    n = prop.x.shape[0]
    return prop.x - jnp.eye(n, 2 * n, dtype=prop.x.dtype)


def velocity_update(u0, v0, u1, h):
    """v1 = (2/h)(u1 - u0) - v0 (deterministic part of the kinematic relation)."""
    return (2.0 / h) * (u1 - u0) - v0


# --------------------------------------------------------------------------- nonlinear step for samples


class SampleState(NamedTuple):
    """State of a batch of samples: displacement and velocity (batch, n), contact forces (batch, nc)."""

    u: jax.Array
    v: jax.Array
    force: jax.Array


def _batched(inputs):
    """Law inputs (every leaf (nc,)) as a batch of one, every leaf (1, nc)."""
    return jax.tree.map(lambda x: x[None, :], inputs)


def _residual_scale(delta_lin, b):
    """Per-contact scale of the contact solve's residual (..., nc): ``|delta_lin| + b``, floored at 1e-4 of
    the sample's largest. Without the floor a contact whose deflection is rounding-level (a symmetric mode,
    say) can never reach a relative residual of 1e-12, so the solve ran to ``max_iter`` and was flagged
    unconverged; contacts above the floor keep their own relative criterion."""
    own = jnp.abs(delta_lin) + b
    # the largest as a chain of elementwise maxima: XLA fuses it with its neighbours, where a reduction over
    # a few contacts became a separate XNNPACK kernel
    nc = own.shape[-1]
    if 0 < nc <= _ELEMENTWISE_MAX_CONTACTS:
        largest = functools.reduce(jnp.maximum, [own[..., j : j + 1] for j in range(nc)])
    else:  # initial: a maximum over no contacts is 0, not an error (own >= 0 since clearances are >= 0)
        largest = jnp.max(own, axis=-1, keepdims=True, initial=0.0)
    return jnp.maximum(own, 1e-4 * largest) + 1e-300


def solve_contacts(delta_lin, coupling, k, b, law, *, tol=1e-12, max_iter=50):
    """Newton solve of ``delta + S f(delta) = delta_lin`` in contact space (one sample).

    ``S = G^T K_eff^-1 G`` couples the contacts. For the piecewise-linear backlash law Newton ends once the
    active set is right (exact to rounding); for one contact it needs at most two steps.
    Returns ``(delta, converged)``.
    """
    nc = delta_lin.shape[0]
    eye = jnp.eye(nc, dtype=delta_lin.dtype)
    scale = _residual_scale(delta_lin, b)

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


_TABLE_MAX_CONTACTS = 6  # up to here every pattern's inverse is formed once per solve (2^6 = 64)
_MAX_ODD_PATTERNS = 16  # other patterns than the majority's inverted per Newton step before the fallback
_UNROLLED_ELIMINATION_MAX_CONTACTS = 8  # beyond, a fori_loop: the unrolled loop's compile time grows with nc
_ELEMENTWISE_MAX_CONTACTS = 16  # up to here a sample's largest residual scale is a chain of maxima


def _pattern_inverses(coupling, k_on, active):
    """Inverses of the Newton Jacobians ``J = I + S diag(k_on * active)`` (m, nc, nc) of contact patterns
    ``active`` (m, nc), 1.0 where a contact is closed: one formula for every route of
    :func:`solve_contacts_batch`.

    Gauss-Jordan elimination in place, without pivoting, vectorized over the patterns (elementwise work, no
    LAPACK call: such calls can hang on several devices on jaxlib 0.10.0-0.11.0, and for these small
    matrices they cost more, docs/performance.md). No pivoting is needed when the symmetric part of S is
    positive semidefinite, as it is for ``S = G^T K_eff^-1 G`` whenever K_eff's symmetric part is positive
    definite (sym(A^-1) = A^-T sym(A) A^-1): if ``(I + S_11 K_1) x = 0`` for a leading block, ``y = K_1 x``
    gives ``x^T K_1 x + y^T S_11 y = 0``, so y = 0 and x = 0, and every leading block is nonsingular. For a
    symmetric S every pivot is at least 1. An S with an indefinite symmetric part is not supported: a
    zero pivot gives NaN, and the sample is flagged unconverged."""
    nc = coupling.shape[0]
    eye = jnp.eye(nc, dtype=coupling.dtype)
    jacobians = eye[None] + coupling[None] * (active * k_on[None, :])[:, None, :]

    def eliminate(j, inverse):  # pivot j of the elimination; `inverse` holds J, inverted in place
        inv_pivot = 1.0 / inverse[:, j, j]
        row = inverse[:, j, :] * inv_pivot[:, None]
        column = inverse[:, :, j]
        inverse = inverse - column[:, :, None] * row[:, None, :]
        inverse = inverse.at[:, j, :].set(row).at[:, :, j].set(-column * inv_pivot[:, None])
        return inverse.at[:, j, j].set(inv_pivot)

    if nc > _UNROLLED_ELIMINATION_MAX_CONTACTS:
        return jax.lax.fori_loop(0, nc, eliminate, jacobians)
    inverse = jacobians
    for j in range(nc):
        inverse = eliminate(j, inverse)
    return inverse


def _apply_inverses(inverses, r):
    """Rows ``inverses @ r`` for ``inverses`` (batch or 1, nc, nc) and ``r`` (batch, nc): column sums, which
    beat a batched matrix-vector product on CPU."""
    return sum(inverses[:, :, j] * r[:, j : j + 1] for j in range(r.shape[1]))


def _all_patterns(nc: int, dtype):
    """Every contact pattern (2^nc, nc), pattern i closing the contacts of i's set bits, and those bits."""
    bits = 2 ** jnp.arange(nc)
    return ((jnp.arange(2**nc)[:, None] & bits[None, :]) > 0).astype(dtype), bits


def _table_newton_step(coupling, k_on, nc, dtype):
    """Newton steps from the inverses of all 2^nc patterns, formed once per solve (few contacts)."""
    patterns, bits = _all_patterns(nc, dtype)
    table = _pattern_inverses(coupling, k_on, patterns)

    def step(r, active, moving=None):
        return _apply_inverses(table[jnp.sum(jnp.where(active > 0, bits[None, :], 0), axis=1)], r)

    return step


def _majority_newton_step(coupling, k_on, majority):
    """Newton steps ``J(p_i)^-1 r_i`` for many contacts. ``majority`` (nc,) closes each contact closed in
    more than half the samples at the start of the solve (in the usual case the pattern most samples have);
    it is inverted once and applied to every sample. If some samples still ``moving`` (batch,) have another
    pattern, up to ``_MAX_ODD_PATTERNS`` of those patterns are found (one pass over the batch each) and
    inverted; with more, the inverses of all 2^nc patterns or one per sample, whichever are fewer (formed
    again at each such Newton step). The steps of samples not moving are not used."""
    majority_step = _pattern_inverses(coupling, k_on, majority[None])

    def step(r, active, moving):
        batch, nc = r.shape
        shared = _apply_inverses(majority_step, r)
        odd = moving & jnp.any(active != majority[None, :], axis=1)

        def every_pattern(shared):
            if 2**nc <= batch:
                return _table_newton_step(coupling, k_on, nc, r.dtype)(r, active)
            return _apply_inverses(_pattern_inverses(coupling, k_on, active), r)

        def odd_patterns(shared):
            def find_next(state):  # the first sample not yet matched gives the next pattern
                patterns, index, left, found = state
                pattern = active[jnp.argmax(left)]
                match = left & jnp.all(active == pattern[None, :], axis=1)
                return (
                    patterns.at[found].set(pattern),
                    jnp.where(match, found, index),
                    left & ~match,
                    found + 1,
                )

            def more_to_find(state):
                _, _, left, found = state
                return jnp.any(left) & (found < _MAX_ODD_PATTERNS)

            start = (
                jnp.zeros((_MAX_ODD_PATTERNS, nc), r.dtype),
                jnp.zeros(batch, jnp.int32),
                odd,
                jnp.array(0),
            )
            patterns, index, left, _ = jax.lax.while_loop(more_to_find, find_next, start)

            def few(shared):  # unused rows of `patterns` stay all-open: an identity Jacobian, harmless
                own = _apply_inverses(_pattern_inverses(coupling, k_on, patterns)[index], r)
                return jnp.where(odd[:, None], own, shared)

            return jax.lax.cond(jnp.any(left), every_pattern, few, shared)

        return jax.lax.cond(jnp.any(odd), odd_patterns, lambda shared: shared, shared)

    return step


def solve_contacts_batch(delta_lin, coupling, k, b, law, *, tol=1e-12, max_iter=50):
    """:func:`solve_contacts` for a batch ``delta_lin`` (batch, nc) sharing ``coupling``, ``k`` and ``b``.

    For a law with on/off stiffness (backlash) the Newton Jacobian ``I + S diag(k * active)`` depends only on
    the contact pattern. Up to ``_TABLE_MAX_CONTACTS`` contacts the inverses of all 2^nc patterns are formed
    once and each sample looks its pattern's up; with more, the batch's majority pattern is inverted once and
    the samples with another pattern get their own (:func:`_majority_newton_step`). Both routes form and apply
    a pattern's inverse alike, and a sample stops iterating once it has converged, so its result depends on
    the route and the rest of the batch only at rounding level. A law
    without on/off stiffness runs a Newton solve per sample. For a piecewise-affine law (``law.affine_piece``)
    the first Newton step, taken from ``delta_lin``, is exact for every sample whose contacts all stay in their
    affine piece, and such a sample counts as converged; the others iterate on the residual. Returns
    ``(delta, converged)`` of shapes (batch, nc) and (batch,); a NaN sample is not converged.
    """
    if not law.on_off_stiffness:
        return jax.vmap(lambda dl: solve_contacts(dl, coupling, k, b, law, tol=tol, max_iter=max_iter))(
            delta_lin
        )
    batch, nc = delta_lin.shape
    k_on = law.closed_stiffness(k, b)  # an on/off law's stiffness is 0 or this
    scale = _residual_scale(delta_lin, b[None, :])
    k_rows = _batched(k)

    def pattern(d):
        return (law.stiffness(d, k_rows, b[None, :]) > 0.0).astype(d.dtype)

    if nc <= _TABLE_MAX_CONTACTS:
        pattern_step = _table_newton_step(coupling, k_on, nc, delta_lin.dtype)
    else:
        majority = (2 * jnp.sum(pattern(delta_lin), axis=0) > batch).astype(delta_lin.dtype)
        pattern_step = _majority_newton_step(coupling, k_on, majority)

    def residual(d):
        return d + law.force(d, k_rows, b[None, :]) @ coupling.T - delta_lin

    def newton_step(d, r, moving):
        return d - pattern_step(r, pattern(d), moving)

    def body(state):  # a sample that has converged stops, so its result does not depend on the batch
        d, r, it, moving = state
        d = jnp.where(moving[:, None], newton_step(d, r, moving), d)
        r = residual(d)
        return d, r, it + 1, moving & (jnp.max(jnp.abs(r) / scale, axis=1) > tol)

    def cond(state):
        _, _, it, moving = state
        return (it < max_iter) & jnp.any(moving)

    def iterate(d, done):
        """Newton steps from ``d`` for the samples not ``done`` until each has converged."""
        r = residual(d)
        moving = ~done & (jnp.max(jnp.abs(r) / scale, axis=1) > tol)
        d, r, _, _ = jax.lax.while_loop(cond, body, (d, r, jnp.array(0), moving))
        return d, done | (jnp.max(jnp.abs(r) / scale, axis=1) <= tol)  # a NaN is neither

    piece0 = law.affine_piece(delta_lin, k_rows, b[None, :])
    if piece0 is None:
        return iterate(delta_lin, jnp.zeros(batch, dtype=bool))
    d1 = newton_step(delta_lin, residual(delta_lin), jnp.ones(batch, dtype=bool))
    same_piece = law.affine_piece(d1, k_rows, b[None, :]) == piece0
    exact = jnp.all(same_piece & jnp.isfinite(d1), axis=1)  # a NaN compares as "in the gap": not exact
    return jax.lax.cond(jnp.all(exact), lambda d, exact: (d, exact), iterate, d1, exact)


def solve_contact_forces(system: System, delta_lin, coupling, k):
    """Contact forces (batch, nc) at the end of a step from the contact-free deflections ``delta_lin``
    (batch, nc): solves ``delta + S f(delta) = delta_lin`` with ``S = G1^T K_eff^-1 G1`` (``coupling``) and
    the law's inputs ``k`` (every leaf (nc,)). Returns ``(force, converged)``, converged of shape (batch,)."""
    b, law = system.contacts.clearance, system.contacts.law
    if delta_lin.shape[1] == 1:  # scalar contact: the law's own (closed-form where it exists) solve, no vmap
        delta, ok = law.solve_single(delta_lin, coupling[0, 0], _batched(k), b[None, :])
        ok = ok[:, 0]
    else:
        delta, ok = solve_contacts_batch(delta_lin, coupling, k, b, law)
    return law.force(delta, _batched(k), b[None, :]), ok


def sample_step(
    system: System,
    state: SampleState,
    s0: Snapshot,
    s1: Snapshot,
    h,
    draws,
    integrator: AbstractIntegrator,
    prop: ConstantPropagator | None = None,
):
    """Advance a batch of samples of the *nonlinear* system by one step (module docstring).

    ``draws`` are the standard normals of the step, (batch, noise_dimension). The solve with ``K_eff`` is
    done once for all samples (with ``prop``, the contact-free map of a system with constant K and C, once per
    run); per sample only matrix products and the contact-space Newton solve remain. Returns the new state and
    the per-sample contact-solve flag.
    """
    n, nc = system.n_dof, system.n_contacts
    noise, v_noise = integrator.noise_matrices(system, s0, s1, h)
    blocks = [(s0.load + s1.load)[:, None]]
    if draws.shape[1]:
        blocks.append(noise)
    if nc:
        blocks += [s0.direction, s1.direction]
    if prop is None:
        mats = integrator.step_matrices(system, s0, s1, h)
        x = jnp.linalg.solve(
            mats.effective_stiffness,
            jnp.concatenate([mats.from_displacement, mats.from_velocity] + blocks, axis=1),
        )
        x_state, x = x[:, : 2 * n], x[:, 2 * n :]
    else:
        x_state, x = prop.x, prop.a_inv @ jnp.concatenate(blocks, axis=1)
    u_lin = jnp.concatenate([state.u, state.v], axis=1) @ x_state.T + x[None, :, 0]
    col = 1
    if draws.shape[1]:
        nd = draws.shape[1]
        u_lin = u_lin + draws @ x[:, col : col + nd].T
        col += nd
    ok = jnp.ones(state.u.shape[0], dtype=bool)
    if nc:
        kinv_g0, kinv_g1 = x[:, col : col + nc], x[:, col + nc : col + 2 * nc]
        u_lin = u_lin - state.force @ kinv_g0.T
        force, ok = solve_contact_forces(
            system, u_lin @ s1.direction, s1.direction.T @ kinv_g1, s1.contact_inputs
        )
        u1 = u_lin - force @ kinv_g1.T
    else:
        force = state.force
        u1 = u_lin
    v1 = velocity_update(state.u, state.v, u1, h)
    if integrator.has_velocity_noise and draws.shape[1]:
        v1 = v1 + draws @ v_noise.T
    return SampleState(u1, v1, force), ok


def initial_sample_state(system: System, s0: Snapshot, u0, v0) -> SampleState:
    """Batch state at t0 from (batch, n) displacements and velocities."""
    if system.n_contacts:
        k, b = _batched(s0.contact_inputs), system.contacts.clearance[None, :]
        force = system.contacts.law.force(u0 @ s0.direction, k, b)
    else:
        force = jnp.zeros((u0.shape[0], 0))
    return SampleState(u0, v0, force)
