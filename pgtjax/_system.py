"""The generic second-order stochastic system every pgtjax model reduces to.

    M q'' + C(t) q' + K(t) q + sum_j g_j(t) f_j(g_j(t)^T q) = F(t) + B w(t)

with ``E[w_i(t) w_i(t + tau)] = 2 pi S0_i delta(tau)`` (the thesis's convention, Eqs. 4.19-4.20), and contacts
``j`` acting along directions ``g_j(t)`` with a contact law ``f_j`` (backlash, Eq. 3.32) of stiffness
``k_j(t)`` and half-clearance ``b_j``. The noise input ``B`` may depend on time too (random *moving* loads,
thesis ch. 6); over a step the mean of its end values is used.

Time dependence: ``C``, ``K``, ``F``, the contact directions and stiffnesses are each either an array or a
callable ``t -> array``. Use an ``equinox.Module`` with a ``__call__`` (e.g. :class:`FourierSeries`) for a
time function whose parameters you want to differentiate or ``vmap``; a plain Python function works too but its
closed-over arrays are constants for JAX. ``M`` is constant: every model of the documents has constant mass,
and a time-varying mass would need the momentum form of the integrator.

Units are SI (m, kg, N, s) unless a model says otherwise; a DOF may be an angle times a radius (m).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._contact import Backlash, ContactLaw

ArrayOrFunction = jax.Array | Callable


def at_time(value: ArrayOrFunction, t) -> jax.Array:
    """Evaluate a field that is either an array or a function of time ``t`` (s)."""
    return value(t) if callable(value) else value


class FourierSeries(eqx.Module):
    """``k(t) = k0 + sum_j [a_j sin(j w t + phase) + c_j cos(j w t + phase)]``, thesis Eq. 4.11 / Eq. 3.1.

    ``mean``, ``sin_coefficients`` and ``cos_coefficients`` broadcast together: a leading axis of the
    coefficients (shape ``(harmonics, ...)``) is the harmonic order. ``frequency`` is the fundamental (rad/s),
    ``phase`` a phase shift (rad) per output entry (mesh phasing).
    """

    mean: jax.Array
    sin_coefficients: jax.Array
    cos_coefficients: jax.Array
    frequency: jax.Array
    phase: jax.Array

    def __init__(self, mean, sin_coefficients=(), cos_coefficients=(), frequency=0.0, phase=0.0):
        self.mean = jnp.asarray(mean, dtype=jnp.float64)
        sin_c = jnp.asarray(sin_coefficients, dtype=jnp.float64)
        cos_c = jnp.asarray(cos_coefficients, dtype=jnp.float64)
        n_harm = max(sin_c.shape[0] if sin_c.ndim else 0, cos_c.shape[0] if cos_c.ndim else 0)
        shape = (n_harm,) + self.mean.shape
        self.sin_coefficients = jnp.broadcast_to(sin_c if sin_c.size else 0.0, shape).astype(jnp.float64)
        self.cos_coefficients = jnp.broadcast_to(cos_c if cos_c.size else 0.0, shape).astype(jnp.float64)
        self.frequency = jnp.asarray(frequency, dtype=jnp.float64)
        self.phase = jnp.broadcast_to(jnp.asarray(phase, dtype=jnp.float64), self.mean.shape)

    def __call__(self, t):
        order = jnp.arange(1, self.sin_coefficients.shape[0] + 1, dtype=jnp.float64)
        order = order.reshape((-1,) + (1,) * self.mean.ndim)
        angle = order * (self.frequency * t + self.phase)[None, ...]
        return self.mean + jnp.sum(
            self.sin_coefficients * jnp.sin(angle) + self.cos_coefficients * jnp.cos(angle), axis=0
        )


class Observables(eqx.Module):
    """Linear outputs ``y = C(t) u + d(t)`` of the displacements whose moments the solvers report (e.g. the
    ring displacement at a moving contact point). ``matrix``: (n_obs, n_dof) array or ``t -> array``;
    ``offset``: optional deterministic part d, (n_obs,) array or ``t -> array`` (a static correction, say),
    which moves the mean only."""

    matrix: ArrayOrFunction
    offset: ArrayOrFunction | None
    names: tuple[str, ...] = eqx.field(static=True)
    units: tuple[str, ...] = eqx.field(static=True)

    def __init__(self, matrix, names: Sequence[str], units: Sequence[str] | None = None, offset=None):
        self.matrix = matrix if callable(matrix) else jnp.asarray(matrix, dtype=jnp.float64)
        self.offset = offset if (offset is None or callable(offset)) else jnp.asarray(offset, jnp.float64)
        self.names = tuple(names)
        self.units = tuple(units) if units is not None else ("m",) * len(self.names)

    def __call__(self, t):
        """C(t), (n_obs, n_dof)."""
        return at_time(self.matrix, t)

    def shift(self, t):
        """d(t), (n_obs,) (zeros without an offset)."""
        if self.offset is None:
            return jnp.zeros((len(self.names),))
        return at_time(self.offset, t)


class Contacts(eqx.Module):
    """A group of contacts sharing one contact law.

    ``direction``: (n_dof, n_contacts) array or ``t -> array``; column j is g_j (deflection = g_j^T q).
    ``inputs``: the law's inputs at time t (:class:`pgtjax.ContactLaw`): an array (each leaf a scalar or
    (n_contacts,)), a pytree of them, or a function of time returning one. For :class:`pgtjax.Backlash` it is
    the mesh stiffness (N/m), which may also be given as ``stiffness=``.
    ``clearance``: (n_contacts,) half-clearances b >= 0 (m).
    """

    direction: ArrayOrFunction
    inputs: Any
    clearance: jax.Array
    names: tuple[str, ...] = eqx.field(static=True)
    law: ContactLaw = Backlash()

    def __init__(
        self,
        direction,
        inputs=None,
        clearance=None,
        names: Sequence[str] | None = None,
        law=None,
        *,
        stiffness=None,
    ):
        if (inputs is None) == (stiffness is None):
            raise ValueError(
                "Contacts: give the law's inputs either as `inputs` or (for Backlash) `stiffness`, once"
            )
        if clearance is None:
            raise ValueError("Contacts: `clearance` (half-backlash b >= 0 per contact, m) is required")
        inputs = stiffness if inputs is None else inputs
        # a plain list or tuple of numbers is one array; of arrays, a pytree of inputs
        plain = isinstance(inputs, list | tuple) and not hasattr(inputs, "_fields")
        if plain and all(np.ndim(x) == 0 for x in inputs):
            inputs = jnp.asarray(inputs, dtype=jnp.float64)
        self.direction = direction if callable(direction) else jnp.asarray(direction, dtype=jnp.float64)
        self.inputs = (
            inputs if callable(inputs) else jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), inputs)
        )
        self.clearance = jnp.atleast_1d(jnp.asarray(clearance, dtype=jnp.float64))
        n = self.clearance.shape[0]
        self.names = tuple(names) if names is not None else tuple(f"contact{j}" for j in range(n))
        self.law = Backlash() if law is None else law

    @property
    def count(self) -> int:
        return self.clearance.shape[0]

    @property
    def stiffness(self):
        """Deprecated alias of :attr:`inputs` (the mesh stiffness of a :class:`pgtjax.Backlash` contact)."""
        return self.inputs


class System(eqx.Module):
    """``M q'' + C q' + K q + G f(G^T q) = F + B w``; see the module docstring.

    ``noise_input`` (B) is (n_dof, n_noise); ``spectral_density`` (S0) is a scalar or (n_noise,).
    ``dof_names``/``dof_units`` label the results.
    """

    mass: jax.Array
    damping: ArrayOrFunction
    stiffness: ArrayOrFunction
    load: ArrayOrFunction
    noise_input: ArrayOrFunction
    spectral_density: jax.Array
    contacts: Contacts | None
    dof_names: tuple[str, ...] = eqx.field(static=True)
    dof_units: tuple[str, ...] = eqx.field(static=True)

    def __init__(
        self,
        mass,
        stiffness,
        damping=None,
        load=None,
        noise_input=None,
        spectral_density=1.0,
        contacts: Contacts | None = None,
        dof_names: Sequence[str] | None = None,
        dof_units: Sequence[str] | None = None,
    ):
        self.mass = jnp.atleast_2d(jnp.asarray(mass, dtype=jnp.float64))
        n = self.mass.shape[0]
        as_field = lambda x: x if callable(x) else jnp.asarray(x, dtype=jnp.float64)  # noqa: E731
        self.stiffness = as_field(stiffness)
        self.damping = as_field(jnp.zeros((n, n)) if damping is None else damping)
        self.load = as_field(jnp.zeros(n) if load is None else load)
        if callable(noise_input):
            self.noise_input = noise_input
            m = jnp.shape(noise_input(jnp.zeros((), jnp.float64)))[1]
        else:
            b = jnp.asarray(jnp.zeros((n, 0)) if noise_input is None else noise_input, jnp.float64)
            self.noise_input = b[:, None] if b.ndim == 1 else b
            m = self.noise_input.shape[1]
        self.spectral_density = jnp.broadcast_to(jnp.asarray(spectral_density, dtype=jnp.float64), (m,))
        self.contacts = contacts
        self.dof_names = tuple(dof_names) if dof_names is not None else tuple(f"q{i}" for i in range(n))
        self.dof_units = tuple(dof_units) if dof_units is not None else ("m",) * n

    @property
    def n_dof(self) -> int:
        return self.mass.shape[0]

    @property
    def n_contacts(self) -> int:
        return 0 if self.contacts is None else self.contacts.count

    @property
    def n_noise(self) -> int:
        return self.spectral_density.shape[0]

    def contact_direction(self, t) -> jax.Array:
        if self.contacts is None:
            return jnp.zeros((self.n_dof, 0))
        return at_time(self.contacts.direction, t)

    def contact_inputs(self, t):
        """The contact law's inputs at time ``t`` (every leaf (nc,)); empty for a system without contacts."""
        if self.contacts is None:
            return jnp.zeros((0,))
        nc = self.n_contacts
        return jax.tree.map(lambda x: jnp.broadcast_to(x, (nc,)), at_time(self.contacts.inputs, t))

    def contact_stiffness(self, t) -> jax.Array:
        """Stiffness (N/m) of each contact taken as closed at time ``t`` (the law's ``closed_stiffness``)."""
        if self.contacts is None:
            return jnp.zeros((0,))
        return self.contacts.law.closed_stiffness(self.contact_inputs(t), self.contacts.clearance)

    def contact_clearance(self) -> jax.Array:
        return jnp.zeros((0,)) if self.contacts is None else self.contacts.clearance

    def scaled_noise_input(self, t) -> jax.Array:
        """B(t) diag(sqrt(2 pi S0)): the matrix multiplying unit Wiener increments (N / sqrt(s))."""
        return at_time(self.noise_input, t) * jnp.sqrt(2.0 * jnp.pi * self.spectral_density)[None, :]

    def contact_names(self) -> tuple[str, ...]:
        return () if self.contacts is None else self.contacts.names


# ----------------------------------------------------------------------------------------------- checks


def _is_concrete(x) -> bool:
    """A value we can check in Python (checks use NumPy: under ``jit`` even jnp ops on constants are staged)."""
    return eqx.is_array(x) and not isinstance(x, jax.core.Tracer)


def _check_finite(name: str, value) -> None:
    if _is_concrete(value) and not np.all(np.isfinite(np.asarray(value))):
        raise ValueError(f"`{name}` must contain only finite numbers (no NaN or inf)")


def _check_shape(name: str, value, shape: tuple[int, ...]) -> None:
    if tuple(jnp.shape(value)) != shape:
        raise ValueError(f"`{name}` must have shape {shape}, got {tuple(jnp.shape(value))}")


def validate_system(system: System, t0: float = 0.0) -> None:
    """Raise ``ValueError`` for inconsistent shapes, non-finite values or a mass matrix that is not
    symmetric positive definite. Value checks are skipped for traced arrays (inside ``jit``/``grad``)."""
    if not jax.config.jax_enable_x64:
        raise ValueError(
            "pgtjax needs 64-bit floats, but `jax_enable_x64` was switched off after pgtjax was imported "
            "(mesh stiffness times deflection is beyond float32); call jax.config.update('jax_enable_x64', True)"
        )
    if not isinstance(system, System):
        raise ValueError(f"`system` must be a pgtjax.System, got {type(system).__name__}")
    n = system.n_dof
    M = system.mass
    _check_shape("mass", M, (n, n))
    _check_finite("mass", M)
    if _is_concrete(M):
        Mn = np.asarray(M)
        diag = np.diag(Mn)
        if np.any(diag <= 0.0):
            j = int(np.argmin(diag))
            raise ValueError(
                f"`mass` must have positive diagonal entries (masses/inertias > 0); "
                f"DOF {system.dof_names[j]!r} has {diag[j]!r}"
            )
        scale = np.max(np.abs(Mn))
        if not np.allclose(Mn, Mn.T, rtol=1e-10, atol=1e-12 * scale):
            raise ValueError("`mass` must be symmetric")
        smallest = float(np.linalg.eigvalsh(0.5 * (Mn + Mn.T)).min())
        if smallest <= 0.0:
            raise ValueError(
                f"`mass` must be positive definite (all eigenvalues > 0), smallest eigenvalue is {smallest!r}"
            )
    for name, field, shape in (
        ("stiffness", system.stiffness, (n, n)),
        ("damping", system.damping, (n, n)),
        ("load", system.load, (n,)),
    ):
        value = at_time(field, jnp.asarray(t0, dtype=jnp.float64))
        _check_shape(name, value, shape)
        _check_finite(name, value)
    b = at_time(system.noise_input, jnp.asarray(t0, dtype=jnp.float64))
    if jnp.ndim(b) != 2 or jnp.shape(b)[0] != n:
        raise ValueError(
            f"`noise_input` must have shape ({n}, n_noise) (one row per DOF), got {jnp.shape(b)}"
        )
    _check_finite("noise_input", b)
    _check_finite("spectral_density", system.spectral_density)
    if _is_concrete(system.spectral_density) and np.any(np.asarray(system.spectral_density) < 0.0):
        raise ValueError("`spectral_density` must be >= 0")
    if len(system.dof_names) != n or len(system.dof_units) != n:
        raise ValueError(f"`dof_names` and `dof_units` must have {n} entries")
    if system.contacts is not None:
        c = system.contacts
        nc = c.count
        _check_finite("clearance", c.clearance)
        if _is_concrete(c.clearance) and np.any(np.asarray(c.clearance) < 0.0):
            raise ValueError(f"`clearance` (half-backlash b) must be >= 0 m, got {np.asarray(c.clearance)}")
        g = system.contact_direction(jnp.asarray(t0, dtype=jnp.float64))
        _check_shape("contact direction", g, (n, nc))
        _check_finite("contact direction", g)
        inputs = c.law.check_inputs(at_time(c.inputs, jnp.asarray(t0, dtype=jnp.float64)), nc)
        for leaf in jax.tree.leaves(inputs):
            _check_finite("contact stiffness" if isinstance(c.law, Backlash) else "contact-law inputs", leaf)
        for leaf in jax.tree.leaves(c.law):
            _check_finite(f"parameters of the contact law {type(c.law).__name__}", leaf)
        if len(c.names) != nc:
            raise ValueError(f"contact `names` must have {nc} entries, got {len(c.names)}")


def check_count(name: str, value, minimum: int = 1) -> int:
    """``value`` as an int if it is an integer (Python or NumPy; not a bool) >= ``minimum``, else a
    ``ValueError`` naming ``name`` and the accepted range."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < minimum:
        raise ValueError(f"`{name}` must be an integer >= {minimum}, got {value!r}")
    return int(value)


def covariance_index(system: System, dofs) -> tuple[int, ...]:
    """State indices ``(u_d..., v_d...)`` of the DOFs named in ``dofs`` (a sequence of names, ``"all"`` or
    ``None`` for none), for the solvers' ``covariance_dofs``; ``ValueError`` naming an unknown or repeated
    DOF."""
    if dofs is None:
        return ()
    if isinstance(dofs, str):
        if dofs != "all":
            raise ValueError(f"`covariance_dofs` must be a sequence of DOF names or 'all', got {dofs!r}")
        dofs = system.dof_names
    names = list(dofs)
    for name in names:
        if name not in system.dof_names:
            raise ValueError(f"`covariance_dofs`: unknown DOF {name!r}; known: {', '.join(system.dof_names)}")
    if len(set(names)) != len(names):
        raise ValueError(f"`covariance_dofs` names a DOF twice: {names}")
    idx = [system.dof_names.index(name) for name in names]
    return tuple(idx + [system.n_dof + i for i in idx])


def validate_time_grid(dt, n_steps, save_every: int = 1) -> tuple[int, int]:
    """``dt`` > 0 s and finite, ``n_steps`` >= 1, ``save_every`` >= 1 (integers) dividing ``n_steps``.
    Returns ``(n_steps, save_every)`` as Python ints: the solvers' jitted cores take them as static sizes
    (a NumPy integer would be traced as an array)."""
    if not isinstance(dt, jax.core.Tracer):
        if not np.isfinite(float(dt)) or float(dt) <= 0.0:
            raise ValueError(f"`dt` must be a finite time step > 0 s, got {dt!r}")
    n_steps, save_every = check_count("n_steps", n_steps), check_count("save_every", save_every)
    if n_steps % save_every:
        raise ValueError(f"`n_steps` ({n_steps}) must be a multiple of `save_every` ({save_every})")
    return n_steps, save_every


def initial_state(system: System, initial_displacement=None, initial_velocity=None):
    """Validated mean initial displacement and velocity, (n,) float64 each (default 0)."""
    n = system.n_dof
    out = []
    for name, value in (
        ("initial_displacement", initial_displacement),
        ("initial_velocity", initial_velocity),
    ):
        value = jnp.zeros(n) if value is None else jnp.asarray(value, jnp.float64)
        if value.shape != (n,):
            raise ValueError(f"`{name}` must have shape ({n},), got {value.shape}")
        _check_finite(name, value)
        out.append(value)
    return tuple(out)
