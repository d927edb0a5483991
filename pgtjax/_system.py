"""The generic second-order stochastic system every pgtjax model reduces to.

    M q'' + C(t) q' + K(t) q + sum_j g_j(t) f_j(g_j(t)^T q) = F(t) + B w(t)

with ``E[w_i(t) w_i(t + tau)] = 2 pi S0_i delta(tau)`` (the thesis's convention, Eqs. 4.19-4.20), and contacts
``j`` acting along directions ``g_j(t)`` with a contact law ``f_j`` (backlash, Eq. 3.32) of stiffness
``k_j(t)`` and half-clearance ``b_j``. The noise input ``B`` may depend on time too (random *moving* loads,
thesis ch. 6); over a step the mean of its end values is used.

Time dependence: ``C``, ``K``, ``F``, the contact directions and stiffnesses are each either an array or a
callable ``t -> array``. Use an ``equinox.Module`` with a ``__call__`` (e.g. :class:`FourierSeries`) for a
time function whose parameters you want to differentiate or ``vmap``; a plain Python function works too but its
closed-over arrays are constants for JAX. Write time functions with ``jax.numpy``: the solvers trace them, and
Monte Carlo evaluates them for a block of times at once (``jax.vmap``). ``M`` is constant: every model of the
documents has constant mass, and a time-varying mass would need the momentum form of the integrator.

Units are SI (m, kg, N, s) unless a model says otherwise; a DOF may be an angle times a radius (m).
"""

from __future__ import annotations

import os
import weakref
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._config import require_x64
from ._contact import Backlash, ContactLaw

ArrayOrFunction = jax.Array | Callable


def as_float_array(name: str, value) -> jax.Array:
    """``value`` as a float64 array; ``ValueError`` naming ``name`` if it is not numbers (a string, None,
    a ragged list)."""
    try:
        return jnp.asarray(value, dtype=jnp.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"`{name}` must be numbers (an array), got {value!r} ({err})") from None


def check_names(what: str, names: Sequence[str], count: int, per: str = "entry") -> tuple[str, ...]:
    """``names`` as a tuple: ``count`` distinct strings (results are looked up by name)."""
    names = tuple(names)
    if len(names) != count or not all(isinstance(x, str) for x in names):
        raise ValueError(f"`{what}` must be {count} strings (one per {per}), got {names!r}")
    repeated = sorted({x for x in names if names.count(x) > 1})
    if repeated:
        raise ValueError(f"`{what}` must be distinct (results are looked up by name); repeated: {repeated}")
    return names


def at_time(value: ArrayOrFunction, t) -> jax.Array:
    """Evaluate a field that is either an array or a function of time ``t`` (s)."""
    return value(t) if callable(value) else value


@eqx.filter_jit
def _modules_at_compiled(modules: tuple, t) -> tuple:
    return tuple(m(t) for m in modules)


def _compilable(field) -> bool:
    """A module whose leaves hold no plain function: a plain function would be a static argument of the
    compiled program, compiled again for every new function object and kept alive by its cache (with any traced
    value it closes over)."""
    if not (callable(field) and isinstance(field, eqx.Module)):
        return False
    return not any(callable(x) and not isinstance(x, eqx.Module) for x in jax.tree.leaves(field))


def fields_at(fields: tuple, t) -> tuple:
    """``at_time`` of each field at ``t``, for the checks before a run. Fields that are equinox modules (the
    models' time functions, and bound methods of modules) are evaluated in one compiled program, reused by
    every model of the same structure: evaluated operation by operation, they cost a compilation per
    operation and shape the first time (seconds for the planetary model). Arrays are returned as they are,
    and plain functions (and modules that cannot be traced) are evaluated as written, so that the checks see
    concrete values and raise the model's own errors as before."""
    fields = tuple(fields)
    slots = [i for i, f in enumerate(fields) if _compilable(f)]
    values = [None if i in slots else at_time(f, t) for i, f in enumerate(fields)]
    if slots:
        modules = tuple(fields[i] for i in slots)
        try:
            evaluated = _modules_at_compiled(modules, t)
        except Exception:  # noqa: BLE001 - evaluated as written below, which raises (or passes) as the code does
            evaluated = tuple(m(t) for m in modules)
        for i, value in zip(slots, evaluated):
            values[i] = value
    return tuple(values)


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
        self.mean = as_float_array("mean", mean)
        sin_c = as_float_array("sin_coefficients", sin_coefficients)
        cos_c = as_float_array("cos_coefficients", cos_coefficients)
        phase = as_float_array("phase", phase)
        n_harm = max(sin_c.shape[0] if sin_c.ndim else 0, cos_c.shape[0] if cos_c.ndim else 0)
        shape = (n_harm,) + self.mean.shape
        try:
            self.sin_coefficients = jnp.broadcast_to(sin_c if sin_c.size else 0.0, shape).astype(jnp.float64)
            self.cos_coefficients = jnp.broadcast_to(cos_c if cos_c.size else 0.0, shape).astype(jnp.float64)
            self.phase = jnp.broadcast_to(phase, self.mean.shape)
        except ValueError:
            raise ValueError(
                f"FourierSeries: `sin_coefficients` {sin_c.shape} and `cos_coefficients` {cos_c.shape} must be "
                f"(harmonics,) + the shape of `mean` {self.mean.shape} (or broadcast to it), and `phase` "
                f"{jnp.shape(phase)} broadcast to `mean`"
            ) from None
        self.frequency = as_float_array("frequency", frequency)

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
        self.matrix = matrix if callable(matrix) else as_float_array("Observables matrix", matrix)
        self.offset = (
            offset if (offset is None or callable(offset)) else as_float_array("Observables offset", offset)
        )
        if isinstance(names, str):
            raise ValueError(f"Observables `names` must be a sequence of names, got the string {names!r}")
        names = tuple(names)
        self.names = check_names("Observables names", names, len(names))
        self.units = tuple(units) if units is not None else ("m",) * len(self.names)
        if len(self.units) != len(self.names):
            raise ValueError(f"Observables `units` must have {len(self.names)} entries, got {self.units!r}")
        if not callable(self.matrix) and (self.matrix.ndim != 2 or self.matrix.shape[0] != len(self.names)):
            raise ValueError(
                f"Observables `matrix` must have shape ({len(self.names)}, n_dof) (one row per name), got "
                f"{self.matrix.shape}"
            )

    def check(self, n_dof: int, t0) -> None:
        """``ValueError`` unless ``C(t0)`` is a finite (n_obs, n_dof) matrix and ``d(t0)`` a finite (n_obs,)
        vector (what a solver checks before it runs)."""
        k = len(self.names)
        c, d = fields_at((self, self.shift), jnp.asarray(t0, jnp.float64))
        if jnp.shape(c) != (k, n_dof):
            raise ValueError(
                f"Observables `matrix` must have shape ({k}, {n_dof}) (n_obs, n_dof), got {jnp.shape(c)}"
            )
        _check_finite("Observables matrix", c)
        if jnp.shape(d) != (k,):
            raise ValueError(
                f"Observables `offset` must have shape ({k},) (one per observable), got {jnp.shape(d)}"
            )
        _check_finite("Observables offset", d)

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
            inputs = as_float_array("contact inputs", inputs)
        self.direction = direction if callable(direction) else as_float_array("contact direction", direction)
        self.inputs = (
            inputs
            if callable(inputs)
            else jax.tree.map(lambda x: as_float_array("contact inputs", x), inputs)
        )
        clearance = as_float_array("clearance", clearance)
        if clearance.ndim > 1:
            raise ValueError(
                f"`clearance` must be a number or one per contact (1-D), got shape {clearance.shape}"
            )
        self.clearance = jnp.atleast_1d(clearance)
        n = self.clearance.shape[0]
        self.names = check_names(
            "contact names", names if names is not None else [f"contact{j}" for j in range(n)], n
        )
        if law is not None and not isinstance(law, ContactLaw):
            raise ValueError(f"`law` must be a pgtjax.ContactLaw (e.g. pgtjax.Backlash()), got {law!r}")
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
        require_x64("System")
        self.mass = jnp.atleast_2d(as_float_array("mass", mass))
        if self.mass.ndim != 2 or self.mass.shape[0] != self.mass.shape[1]:
            raise ValueError(f"`mass` must be a square (n_dof, n_dof) matrix, got shape {self.mass.shape}")
        n = self.mass.shape[0]
        as_field = lambda name, x: x if callable(x) else as_float_array(name, x)  # noqa: E731
        self.stiffness = as_field("stiffness", stiffness)
        self.damping = as_field("damping", jnp.zeros((n, n)) if damping is None else damping)
        self.load = as_field("load", jnp.zeros(n) if load is None else load)
        if callable(noise_input):
            self.noise_input = noise_input
            shape = jnp.shape(noise_input(jnp.zeros((), jnp.float64)))
            if len(shape) != 2:
                raise ValueError(f"`noise_input` must return an (n_dof, n_noise) matrix, got shape {shape}")
            m = shape[1]
        else:
            b = as_float_array("noise_input", jnp.zeros((n, 0)) if noise_input is None else noise_input)
            self.noise_input = b[:, None] if b.ndim == 1 else b
            m = self.noise_input.shape[1]
        s0 = as_float_array("spectral_density", spectral_density)
        if s0.ndim > 1 or (s0.ndim == 1 and s0.shape[0] not in (1, m)):
            raise ValueError(
                f"`spectral_density` must be a number or one per noise input ({m}, the columns of "
                f"`noise_input`), got shape {s0.shape}"
            )
        self.spectral_density = jnp.broadcast_to(s0, (m,))
        if contacts is not None and not isinstance(contacts, Contacts):
            raise ValueError(f"`contacts` must be a pgtjax.Contacts or None, got {type(contacts).__name__}")
        self.contacts = contacts
        self.dof_names = check_names(
            "dof_names",
            dof_names if dof_names is not None else [f"q{i}" for i in range(n)],
            n,
            per=f"DOF of the {n} x {n} `mass`",
        )
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


def validate_system(system: System, t0: float = 0.0, *, time_name: str = "t0") -> None:
    """Raise ``ValueError`` for inconsistent shapes, non-finite values or a mass matrix that is not
    symmetric positive definite. Value checks are skipped for traced arrays (inside ``jit``/``grad``)."""
    require_x64("the solvers")
    if not isinstance(system, System):
        raise ValueError(f"`system` must be a pgtjax.System, got {type(system).__name__}")
    check_time(time_name, t0)
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
                f"DOF {system.dof_names[j]!r} has {float(diag[j]):g}"
            )
        scale = np.max(np.abs(Mn))
        if not np.allclose(Mn, Mn.T, rtol=1e-10, atol=1e-12 * scale):
            raise ValueError("`mass` must be symmetric")
        smallest = float(np.linalg.eigvalsh(0.5 * (Mn + Mn.T)).min())
        if smallest <= 0.0:
            raise ValueError(
                f"`mass` must be positive definite (all eigenvalues > 0), smallest eigenvalue is {smallest:g}"
            )
    t = jnp.asarray(t0, dtype=jnp.float64)
    contacts = () if system.contacts is None else (system.contacts.direction, system.contacts.inputs)
    stiffness, damping, load, b, *contact_fields = fields_at(
        (system.stiffness, system.damping, system.load, system.noise_input, *contacts), t
    )
    for name, value, shape in (
        ("stiffness", stiffness, (n, n)),
        ("damping", damping, (n, n)),
        ("load", load, (n,)),
    ):
        _check_shape(name, value, shape)
        _check_finite(name, value)
    if jnp.ndim(b) != 2 or jnp.shape(b)[0] != n:
        raise ValueError(
            f"`noise_input` must have shape ({n}, n_noise) (one row per DOF), got {jnp.shape(b)}"
        )
    _check_finite("noise_input", b)
    _check_finite("spectral_density", system.spectral_density)
    if _is_concrete(system.spectral_density) and np.any(np.asarray(system.spectral_density) < 0.0):
        density = np.asarray(system.spectral_density)
        got = f"{float(density.ravel()[0]):g}" if density.size == 1 else str(density)
        raise ValueError(f"`spectral_density` must be >= 0, got {got}")
    if len(system.dof_names) != n or len(system.dof_units) != n:
        raise ValueError(f"`dof_names` and `dof_units` must have {n} entries")
    if system.contacts is not None:
        c = system.contacts
        nc = c.count
        _check_finite("clearance", c.clearance)
        if _is_concrete(c.clearance) and np.any(np.asarray(c.clearance) < 0.0):
            raise ValueError(f"`clearance` (half-backlash b) must be >= 0 m, got {np.asarray(c.clearance)}")
        g, raw_inputs = contact_fields
        _check_shape("contact direction", g, (n, nc))
        _check_finite("contact direction", g)
        inputs = c.law.check_inputs(raw_inputs, nc)
        for leaf in jax.tree.leaves(inputs):
            _check_finite(
                "Contacts(stiffness=...)" if isinstance(c.law, Backlash) else "contact-law inputs", leaf
            )
        for leaf in jax.tree.leaves(c.law):
            _check_finite(f"parameters of the contact law {type(c.law).__name__}", leaf)
        if len(c.names) != nc:
            raise ValueError(f"contact `names` must have {nc} entries, got {len(c.names)}")


def check_count(name: str, value, minimum: int = 1, maximum: int | None = None, why: str = "") -> int:
    """``value`` as an int if it is an integer (Python or NumPy; not a bool) from ``minimum`` to ``maximum``
    (``None``: unbounded), else a ``ValueError`` naming ``name``, the accepted range and ``why`` it is that."""
    if (
        isinstance(value, bool)
        or not isinstance(value, int | np.integer)
        or value < minimum
        or (maximum is not None and value > maximum)
    ):
        accepted = f">= {minimum}" if maximum is None else f"in [{minimum}, {maximum}]"
        raise ValueError(f"`{name}` must be an integer {accepted}{why}, got {value!r}")
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


def check_time(name: str, value) -> None:
    """``ValueError`` naming ``name`` unless ``value`` is one finite real number (s); traced values pass."""
    if isinstance(value, jax.core.Tracer):
        return
    if isinstance(value, bool | str | complex) or np.ndim(value) != 0:
        raise ValueError(f"`{name}` must be one real number (s), got {value!r}")
    try:
        finite = np.isfinite(float(value))
    except (TypeError, ValueError):
        finite = False
    if not finite:
        raise ValueError(f"`{name}` must be a finite number (s), got {value!r}")


#: the largest step count: times t0 + k dt stay exact integers multiples of dt in float64 below 2^53
MAX_STEPS = 2**53


def validate_time_grid(dt, n_steps, save_every: int = 1, t0=0.0) -> tuple[int, int]:
    """``dt`` > 0 s and finite, ``n_steps`` >= 1, ``save_every`` >= 1 (integers) dividing ``n_steps``, and
    a grid on which time advances (``t0 + dt != t0`` in float64). Returns ``(n_steps, save_every)`` as Python
    ints: the solvers' jitted cores take them as static sizes (a NumPy integer would be traced as an array)."""
    check_time("dt", dt)
    if not isinstance(dt, jax.core.Tracer) and float(dt) <= 0.0:
        raise ValueError(f"`dt` must be a finite time step > 0 s, got {dt!r}")
    n_steps, save_every = check_count("n_steps", n_steps), check_count("save_every", save_every)
    if n_steps >= MAX_STEPS:
        raise ValueError(f"`n_steps` must be < 2^53 (= {MAX_STEPS}), got {n_steps}")
    if n_steps % save_every:
        raise ValueError(f"`n_steps` ({n_steps}) must be a multiple of `save_every` ({save_every})")
    check_time("t0", t0)
    if not any(isinstance(x, jax.core.Tracer) for x in (t0, dt)):
        t0, dt = float(t0), float(dt)
        if t0 + dt == t0:
            raise ValueError(
                f"`dt` ({dt!r} s) is below the float64 resolution of the time `t0` ({t0!r} s): time would not "
                "advance; start nearer 0 (shift t0) or take a larger step"
            )
    return n_steps, save_every


def check_memory(what: str, n_saved: int, values_per_save: int, knob: str = "raise `save_every`") -> None:
    """``ValueError`` before a run whose saved results (``n_saved`` times ``values_per_save`` float64
    numbers) would not fit in half of this machine's memory (an out-of-memory error from XLA otherwise);
    ``knob``: what the message suggests raising."""
    needed = 8.0 * n_saved * values_per_save
    try:
        available = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not POSIX: no estimate
        return
    if needed > 0.5 * available:
        raise ValueError(
            f"{what}: the saved results would take {needed / 1e9:.3g} GB ({n_saved} saved times x "
            f"{values_per_save} numbers), more than half of this machine's {available / 1e9:.3g} GB; save less "
            f"often ({knob}) or shorten the run (`n_steps`)"
        )


def check_observables(system: System, observables, t0) -> None:
    """``observables`` is None or a :class:`Observables` whose ``C(t0)`` is (n_obs, n_dof) and finite."""
    if observables is None:
        return
    if not isinstance(observables, Observables):
        raise ValueError(
            f"`observables` must be a pgtjax.Observables or None, got {type(observables).__name__}"
        )
    observables.check(system.n_dof, t0)


_SCAN_CHUNK = 4096  # step times evaluated at once by check_contact_stiffness_over_time


@eqx.filter_jit
def _first_bad_contact_step(system: System, t0, dt, n_steps, n_chunks: int):
    """Index of the first step time ``t0 + k dt`` (k = 0..n_steps) at which a contact's closed stiffness is
    negative or not finite; ``n_steps + 1`` if none."""
    none = n_steps + 1

    def chunk(first, c):
        k = c * _SCAN_CHUNK + jnp.arange(_SCAN_CHUNK)
        stiff = jax.vmap(system.contact_stiffness)(t0 + dt * k.astype(jnp.float64))
        bad = jnp.any(~jnp.isfinite(stiff) | (stiff < 0.0), axis=1) & (k <= n_steps)
        return jnp.minimum(first, jnp.where(jnp.any(bad), k[jnp.argmax(bad)], none)), None

    first, _ = jax.lax.scan(chunk, jnp.asarray(none), jnp.arange(n_chunks))
    return first


def check_contact_stiffness_over_time(system: System, t0, dt, n_steps: int) -> None:
    """``ValueError`` naming the contact and the first step time at which its stiffness taken as closed (the
    law's ``closed_stiffness`` of the inputs at t: the mesh stiffness for backlash) is negative or not finite,
    for contact inputs given as a function of time (checked at every step time before the run; constant
    inputs are checked by :func:`validate_system`). Traced systems pass."""
    if system.contacts is None or not callable(system.contacts.inputs):
        return
    if any(isinstance(x, jax.core.Tracer) for x in (*jax.tree.leaves(system), t0, dt)):
        return
    n_chunks = n_steps // _SCAN_CHUNK + 1
    first = _first_bad_contact_step(system, jnp.float64(t0), jnp.float64(dt), jnp.asarray(n_steps), n_chunks)
    if isinstance(first, jax.core.Tracer):  # the time function closes over a traced value
        return
    first = int(first)
    if first > n_steps:
        return
    t = float(t0) + float(dt) * first
    stiff = np.asarray(system.contact_stiffness(jnp.float64(t)))
    j = int(np.argmax(~np.isfinite(stiff) | (stiff < 0.0)))
    raise ValueError(
        f"the stiffness of contact {system.contacts.names[j]!r} (its law's closed stiffness, from the contacts' "
        f"time-dependent inputs) is {float(stiff[j])!r} N/m at t = {t:.6g} s (step {first}), first there; a contact "
        "stiffness must stay finite and >= 0 over the whole run: check the function given as the contacts' "
        "stiffness/inputs"
    )


def check_initial_covariance(system: System, value) -> jax.Array:
    """The initial covariance of ``(u, v)``: (2n, 2n), finite, symmetric and positive semi-definite
    (default: zeros); checked where it is concrete."""
    n2 = 2 * system.n_dof
    if value is None:
        return jnp.zeros((n2, n2))
    p0 = as_float_array("initial_covariance", value)
    if p0.shape != (n2, n2):
        raise ValueError(f"`initial_covariance` must have shape {(n2, n2)} (u then v), got {p0.shape}")
    if isinstance(p0, jax.core.Tracer):
        return p0
    a = np.asarray(p0)
    if not np.all(np.isfinite(a)):
        raise ValueError("`initial_covariance` must contain only finite numbers (no NaN or inf)")
    scale = float(np.max(np.abs(a))) if a.size else 0.0
    if not np.allclose(a, a.T, rtol=0.0, atol=1e-6 * scale):  # rounding (float32 included) passes
        i, j = np.unravel_index(int(np.argmax(np.abs(a - a.T))), a.shape)
        raise ValueError(
            f"`initial_covariance` must be symmetric: entry ({i}, {j}) is {a[i, j]!r} but ({j}, {i}) is {a[j, i]!r}"
        )
    smallest = float(np.linalg.eigvalsh(0.5 * (a + a.T)).min()) if a.size else 0.0
    if smallest < -1e-10 * scale:
        raise ValueError(
            f"`initial_covariance` must be positive semi-definite (a covariance), smallest eigenvalue {smallest!r}"
        )
    return p0


#: (id(system), t) -> (weak reference to the system, what _first_order_spectrum returned). A system whose
#: plain-function fields read state that changes between solves should be rebuilt, as elsewhere.
_FIRST_ORDER_SPECTRA: dict = {}

_TRACED = "traced"  # a time function closes over a traced value: nothing can be checked here


def _first_order_spectrum(system: System, t0):
    """``(growth tolerance, rightmost eigenvalue)`` of ``A = [[0, I], [-M^-1 K, -M^-1 C]]`` at ``t0`` with the
    contacts closed; None if ``A`` is not finite, :data:`_TRACED` if a field evaluates to a traced value. The
    tolerance, ``10 sqrt(eps ||A||_1)``, is the size of the rounding of a defective (rigid-body) pair."""
    t = jnp.asarray(t0, jnp.float64)
    contact_fields = (system.contact_direction, system.contact_stiffness) if system.n_contacts else ()
    fields = fields_at((system.stiffness, system.damping, *contact_fields), t)
    if any(isinstance(x, jax.core.Tracer) for x in fields):
        return _TRACED
    k, c, *contacts = (np.asarray(x) for x in fields)
    if contacts:
        g, stiffness = contacts
        k = k + (g * stiffness[None, :]) @ g.T
    m = np.asarray(system.mass)
    n = m.shape[0]
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-np.linalg.solve(m, k), -np.linalg.solve(m, c)]])
    if not np.all(np.isfinite(a)):
        return None
    lam = np.linalg.eigvals(a)
    tolerance = 10.0 * float(np.sqrt(np.finfo(np.float64).eps * np.linalg.norm(a, 1)))
    return tolerance, complex(lam[int(np.argmax(lam.real))])


_STABILITY_INSTANTS = 8  # instants of a time-varying system checked over the horizon


def _spectrum_at(system: System, t):
    """Cached :func:`_first_order_spectrum` (a system solved again pays no second eigen-solve)."""
    key = (id(system), float(t))
    cached = _FIRST_ORDER_SPECTRA.get(key)
    if cached is not None and cached[0]() is system:
        return cached[1]
    spectrum = _first_order_spectrum(system, t)
    if len(_FIRST_ORDER_SPECTRA) >= 256:
        _FIRST_ORDER_SPECTRA.clear()
    _FIRST_ORDER_SPECTRA[key] = (weakref.ref(system), spectrum)
    return spectrum


def check_stability(system: System, t0, horizon=None) -> None:
    """``ValueError`` if the system with its contacts closed (their ``closed_stiffness``) is unstable: an
    eigenvalue of ``[[0, I], [-M^-1 K, -M^-1 C]]`` whose growth rate exceeds the rounding of a defective
    (rigid-body) pair, ``10 sqrt(eps ||A||)``, and amplifies the response by more than 1 % over ``horizon``
    (s; default: any). Checked at ``t0`` and, when K, C or the contacts depend on time, at 8 instants spread
    over the horizon (frozen-time stability: the message names the first unstable instant; a parametric
    resonance of a system stable at every instant is not predicted). Negative damping, a negative-definite
    stiffness or a non-symmetric damping that feeds energy in are caught here, before they return finite
    nonsense. Skipped where anything is traced (under ``jit``/``grad``/``vmap``)."""
    if any(isinstance(x, jax.core.Tracer) for x in (*jax.tree.leaves(system), t0, horizon)):
        return
    varying = [system.stiffness, system.damping]
    if system.contacts is not None:
        varying += [system.contacts.direction, system.contacts.inputs]
    instants = [float(t0)]
    if horizon is not None and any(callable(f) for f in varying):
        step = float(horizon) / (_STABILITY_INSTANTS - 1)
        instants += [float(t0) + step * j for j in range(1, _STABILITY_INSTANTS)]
    for t in instants:
        spectrum = _spectrum_at(system, t)
        if spectrum is None or spectrum is _TRACED:
            return  # not finite (the finiteness checks name the culprit), or not checkable here
        tolerance, worst = spectrum
        growth = float(worst.real)
        if growth <= tolerance or (horizon is not None and growth * float(horizon) <= 0.01):
            continue
        cause = (
            "the damping feeds energy in (negative, or non-symmetric with an indefinite symmetric part), or a "
            "non-symmetric (circulatory) stiffness does: check `damping` and `stiffness`"
            if abs(worst.imag) > 0.0
            else "a negative stiffness (a statically unstable mode) or negative damping: check `stiffness`, the "
            "contacts' stiffness and `damping`"
        )
        raise ValueError(
            f"the system is unstable at t = {t:.6g} s (contacts closed): a mode"
            f"{f' of {abs(worst.imag) / (2 * np.pi):.4g} Hz' if worst.imag else ''} grows like exp(s t) with "
            f"s = {growth:.4g} 1/s (e-folding time {1.0 / growth:.4g} s); {cause}"
        )


def initial_state(system: System, initial_displacement=None, initial_velocity=None):
    """Validated mean initial displacement and velocity, (n,) float64 each (default 0)."""
    n = system.n_dof
    out = []
    for name, value in (
        ("initial_displacement", initial_displacement),
        ("initial_velocity", initial_velocity),
    ):
        value = jnp.zeros(n) if value is None else as_float_array(name, value)
        if value.shape != (n,):
            raise ValueError(f"`{name}` must have shape ({n},), got {value.shape}")
        _check_finite(name, value)
        out.append(value)
    return tuple(out)
