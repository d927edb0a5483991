"""Elastic ring gear under N equally spaced random moving mesh loads (thesis ch. 6, Eqs. 6.11-6.27).

Model. The supported ring of :mod:`pgtjax.models.ring` (curved-beam FE, bolts Eq. 6.24) carries N loads that
rotate with the carrier at ``omega_c`` [rad/s]. Load ``n = 1..N`` sits at the angle

    theta_n(t) = theta_0 + omega_c t + 2 pi (n - 1) / N                                  [rad]

and has the magnitude (Eqs. 6.16-6.17)

    F_n(t) = F_0 + f_a sin(omega (t + 2 pi (n - 1) / (N omega_c))) + b_n W_n(t)           [N]

with independent unit white noises ``E[W_n(t) W_m(t + tau)] = delta_nm delta(tau)`` (the thesis's noise
increment ``sqrt(dt) B`` of Eq. 6.32 is that of a unit-intensity white noise, so the engine's spectral density
is ``S0 = 1 / (2 pi)``; ``b_n`` [N sqrt(s)] is the "noise level" b-bar of Sec. 6.4). The mesh frequency is
``omega = z_m omega_c`` (``mesh_frequency_ratio`` z_m): the thesis's 100.8 rad/s at 2.8 rad/s gives z_m = 36;
the Eq. 6.16 time shift then becomes the phase ``2 pi z_m (n - 1) / N`` (zero for z_m = 36, N = 3).

Each load pushes the ring outward along the line of action of the planet-ring mesh, pressure angle alpha
(Eqs. 6.13-6.14): components ``F_r = -F_n sin(alpha)`` along the element's radial DOF, which is positive
*inward* (so ``F_r < 0`` pushes outward, as a planet does), and ``F_tau = -F_n cos(alpha)`` (clockwise for a
counter-clockwise carrier). Correction C9 (docs/corrections.md): Eq. 3.21 writes these components with another sign convention; we use
ch. 6's, which matches the ring's inward-positive ``u_r``. The nodal forces are the work-equivalent transfer
through the shape functions (Eq. 6.11, ``F_l = a(theta_n)^T (F_r, F_tau)``; :func:`ring_load_vector`), so the
global load vector and the noise input are

    F(t) = sum_n F_d,n(t) g(theta_n(t)),   B(t)[:, n] = b_n g(theta_n(t)),
    g(theta) = -(sin(alpha) a_r(theta) + cos(alpha) a_tau(theta))                       [1]

and the equation of motion is Eq. 6.27, ``M U'' + C U' + K U = F(t) + B(t) W(t)`` (M, K: Eq. 6.23-6.24).

Damping. Eq. 6.23 uses Rayleigh damping ``C = lambda_M M + lambda_K K`` but ch. 6 gives no values (correction C10).
Default (``ring_ch6.toml``): 2 % of critical at the two ends of the band that matters, the first natural
frequency of the supported ring (8,590 rad/s, 1,367 Hz: first flexural mode of the 60-degree bolt spans) and
its fourth mode group (33,000 rad/s, 3.8 times higher), i.e. ``lambda_M = 2 zeta w_a w_b / (w_a + w_b)``,
``lambda_K = 2 zeta / (w_a + w_b)``. 2 % is a usual value for a bolted steel gear rim; between the two
frequencies the ratio stays between 1.6 % and 2 %, above them it grows (the FE-discretisation modes up to
8.7e6 rad/s are overdamped, which is harmless). Alternatively ``modal_damping_ratio`` (scalar or one per
mode) gives ``C = M Phi diag(2 zeta_k w_k) Phi^T M`` (computed with ``eigh``; prefer Rayleigh damping when
differentiating: ``eigh``'s derivative is ill-conditioned at the ring's nearly degenerate mode pairs).

Contact-point output. The response *under* load 1, ``u_r(theta_1(t)) = a_r(theta_1(t)) U`` (what
:func:`ring_displacement_at` evaluates), is a time-varying combination of nodal DOFs: :func:`observables`
gives it (and the mid-node's u_r) as :class:`pgtjax.Observables` ``y = c(t) U``, whose mean and standard
deviation the solvers evaluate exactly at every saved time. (Earlier versions appended an "observer" DOF
with a 1e-16 s^2 mass-to-stiffness ratio that tracked ``y`` to ~1e-8 relative.)

Reported points: the contact point and the mid-node between the first two bolts
(:func:`mid_node`; node 3 of the thesis's 36-element ring, i.e. 30 degrees).

Units: SI (m, kg, N, s, rad); nodal rotations in rad, nodal moments in N m.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import Observables, System, symmetric_eigen
from .. import params as _params
from .._system import check_count
from .._validate import check_range
from .ring import (
    RingParams,
    ring_dof_names,
    ring_interpolation,
    ring_load_vector,
    ring_matrices,
    ring_nodal_inverse,
)
from .ring import validate as validate_ring

__all__ = [
    "RingMovingLoadParams",
    "validate",
    "MovingLoads",
    "build",
    "observables",
    "ring_moving_load_system",
    "load_params",
    "default_params",
    "support_case",
    "mid_node",
    "contact_angle",
    "static_initial_state",
    "rayleigh_coefficients",
    "OBSERVER_NAME",
    "MID_NAME",
    "SPECTRAL_DENSITY",
]

#: spectral density of the engine's convention ``E[w w] = 2 pi S0 delta`` that makes W a unit white noise.
SPECTRAL_DENSITY = 1.0 / (2.0 * math.pi)
#: name of the output "radial ring displacement under load 1" (:func:`observables`).
OBSERVER_NAME = "contact1_radial"
#: name of the output "radial displacement of the mid-node" (:func:`observables`).
MID_NAME = "mid_node_radial"


class RingMovingLoadParams(eqx.Module):
    """Ring + moving-load data of thesis ch. 6 (Sec. 6.4). Array leaves are differentiable (float64).

    Attributes:
        ring: the supported ring (:class:`pgtjax.models.ring.RingParams`).
        carrier_speed: omega_c, angular speed of the loads [rad/s], > 0.
        mean_force: F_0 [N], finite.
        force_amplitude: f_a [N], >= 0.
        mesh_frequency_ratio: z_m, mesh frequency omega = z_m omega_c [-], >= 0 (thesis: 100.8 / 2.8 = 36).
        noise_intensity: b_n [N sqrt(s)], >= 0, scalar or one per load.
        pressure_angle: alpha [rad], 0 <= alpha < pi / 2.
        initial_angle: theta_0, angle of load 1 at t = 0 [rad], finite (0 = on the first bolt).
        rayleigh_mass: lambda_M [1/s], >= 0.
        rayleigh_stiffness: lambda_K [s], >= 0.
        modal_damping_ratio: None (Rayleigh) or zeta >= 0, scalar or one per ring mode (3 L,) [-].
        n_loads: N, number of loads (planets), integer >= 1 (static).
    """

    ring: RingParams
    carrier_speed: jax.Array
    mean_force: jax.Array
    force_amplitude: jax.Array
    mesh_frequency_ratio: jax.Array
    noise_intensity: jax.Array
    pressure_angle: jax.Array
    initial_angle: jax.Array
    rayleigh_mass: jax.Array
    rayleigh_stiffness: jax.Array
    modal_damping_ratio: jax.Array | None
    n_loads: int = eqx.field(static=True)

    def __init__(
        self,
        ring: RingParams,
        *,
        carrier_speed=2.8,
        n_loads: int = 3,
        mean_force=1.0e6,
        force_amplitude=6.5e5,
        mesh_frequency_ratio=36.0,
        noise_intensity=1.0e5,
        pressure_angle=math.radians(20.0),
        initial_angle=0.0,
        rayleigh_mass=None,
        rayleigh_stiffness=None,
        modal_damping_ratio=None,
    ):
        if not isinstance(ring, RingParams):
            raise ValueError(f"`ring` must be a pgtjax.models.ring.RingParams, got {type(ring).__name__}")
        if isinstance(n_loads, bool) or not isinstance(n_loads, int | np.integer) or n_loads < 1:
            raise ValueError(f"`n_loads` must be an integer >= 1, got {n_loads!r}")
        if rayleigh_mass is None or rayleigh_stiffness is None:
            lm, lk = rayleigh_coefficients(0.02, 8590.0, 33000.0)
            rayleigh_mass = lm if rayleigh_mass is None else rayleigh_mass
            rayleigh_stiffness = lk if rayleigh_stiffness is None else rayleigh_stiffness
        if np.shape(noise_intensity) not in ((), (n_loads,)):
            raise ValueError(
                f"`noise_intensity` must be a scalar or have shape ({n_loads},) (one per load), "
                f"got {np.shape(noise_intensity)}"
            )
        f = lambda x: jnp.asarray(x, dtype=jnp.float64)  # noqa: E731
        self.ring = ring
        self.carrier_speed = f(carrier_speed)
        self.mean_force = f(mean_force)
        self.force_amplitude = f(force_amplitude)
        self.mesh_frequency_ratio = f(mesh_frequency_ratio)
        self.noise_intensity = jnp.broadcast_to(f(noise_intensity), (n_loads,))
        self.pressure_angle = f(pressure_angle)
        self.initial_angle = f(initial_angle)
        self.rayleigh_mass = f(rayleigh_mass)
        self.rayleigh_stiffness = f(rayleigh_stiffness)
        self.modal_damping_ratio = None if modal_damping_ratio is None else f(modal_damping_ratio)
        self.n_loads = int(n_loads)

    def __check_init__(self):
        validate(self)

    def replace(self, **changes) -> RingMovingLoadParams:
        """A copy with some fields changed (the result is validated again)."""
        kw = dict(
            carrier_speed=self.carrier_speed,
            n_loads=self.n_loads,
            mean_force=self.mean_force,
            force_amplitude=self.force_amplitude,
            mesh_frequency_ratio=self.mesh_frequency_ratio,
            noise_intensity=self.noise_intensity,
            pressure_angle=self.pressure_angle,
            initial_angle=self.initial_angle,
            rayleigh_mass=self.rayleigh_mass,
            rayleigh_stiffness=self.rayleigh_stiffness,
            modal_damping_ratio=self.modal_damping_ratio,
        )
        ring = changes.pop("ring", self.ring)
        unknown = set(changes) - set(kw)
        if unknown:
            raise ValueError(f"unknown parameter(s) {sorted(unknown)}; known: ring, {', '.join(sorted(kw))}")
        if "n_loads" in changes and "noise_intensity" not in changes:
            kw["noise_intensity"] = self.noise_intensity[0]
        kw.update(changes)
        return RingMovingLoadParams(ring, **kw)

    @property
    def mesh_frequency(self):
        """omega = z_m omega_c [rad/s] (Eq. 6.17)."""
        return self.mesh_frequency_ratio * self.carrier_speed

    @property
    def revolution_time(self):
        """2 pi / omega_c [s]: one revolution of the loads."""
        return 2.0 * math.pi / self.carrier_speed


def rayleigh_coefficients(zeta, omega_a, omega_b):
    """(lambda_M [1/s], lambda_K [s]) giving damping ratio ``zeta`` at ``omega_a`` and ``omega_b`` [rad/s]:
    ``zeta(w) = lambda_M / (2 w) + lambda_K w / 2``."""
    return 2.0 * zeta * omega_a * omega_b / (omega_a + omega_b), 2.0 * zeta / (omega_a + omega_b)


class MovingLoads(eqx.Module):
    """The N moving loads as functions of time (Eqs. 6.11-6.17): angles, nodal load vector, noise input."""

    params: RingMovingLoadParams
    # the ring elements' shape-function inverse, formed once with the system (not at every t); derived from
    # ``params.ring`` when built
    nodal_inverse: jax.Array | None = None

    def angles(self, t):
        """theta_n(t) [rad], (N,)."""
        p = self.params
        n = jnp.arange(p.n_loads, dtype=jnp.float64)
        return p.initial_angle + p.carrier_speed * t + 2.0 * math.pi * n / p.n_loads

    def deterministic_forces(self, t):
        """F_d,n(t) = F_0 + f_a sin(omega t + 2 pi z_m (n-1) / N) [N], (N,) (Eqs. 6.16-6.17)."""
        p = self.params
        n = jnp.arange(p.n_loads, dtype=jnp.float64)
        phase = 2.0 * math.pi * p.mesh_frequency_ratio * n / p.n_loads
        return p.mean_force + p.force_amplitude * jnp.sin(p.mesh_frequency * t + phase)

    def unit_load_vectors(self, t):
        """g(theta_n(t)) for every load, (N, 3 L): nodal forces of a unit mesh force (Eqs. 6.11, 6.13-6.14)."""
        p = self.params
        s, c = jnp.sin(p.pressure_angle), jnp.cos(p.pressure_angle)
        return jax.vmap(lambda th: ring_load_vector(p.ring, th, -s, -c, self.nodal_inverse))(self.angles(t))

    def nodal_forces(self, t):
        """Deterministic global load vector F_d(t) [N, N, N m], (3 L,)."""
        return self.deterministic_forces(t) @ self.unit_load_vectors(t)

    def noise_matrix(self, t):
        """B(t) (3 L, N): column n is b_n g(theta_n(t)) [N sqrt(s) per unit-noise component]."""
        return self.unit_load_vectors(t).T * self.params.noise_intensity[None, :]


class _OutputRows(eqx.Module):
    """``C(t)`` (n_obs, n_q) of the outputs in the system's coordinates: u_r under load 1 and/or the mid-node
    u_r, as rows ``c(t)`` over the ring DOFs times the modal basis T (identity for the full model)."""

    loads: MovingLoads
    basis: jax.Array | None  # T (3 L, n_q) or None (identity)
    mid_dof: int = eqx.field(static=True)
    contact: bool = eqx.field(static=True)
    mid: bool = eqx.field(static=True)

    def ring_rows(self, t):
        """c(t) over the ring's nodal DOFs, (n_obs, 3 L)."""
        ring = self.loads.params.ring
        rows = []
        if self.contact:
            rows.append(ring_interpolation(ring, self.loads.angles(t)[0], self.loads.nodal_inverse)[0])
        if self.mid:
            rows.append(jnp.zeros((ring.n_dof,)).at[self.mid_dof].set(1.0))
        return jnp.stack(rows)

    def __call__(self, t):
        c = self.ring_rows(t)
        return c if self.basis is None else c @ self.basis


class _StaticCorrection(eqx.Module):
    """``d(t) = c(t) R F_d(t)``: the dropped modes' quasi-static response at the outputs (modal model)."""

    rows: _OutputRows
    residual: jax.Array  # R (3 L, 3 L)

    def __call__(self, t):
        return self.rows.ring_rows(t) @ (self.residual @ self.rows.loads.nodal_forces(t))


class _Field(eqx.Module):
    """``t -> array`` of the ring system in its coordinates ``q`` (``U = T q``): ``load`` ``T^T F_d(t)``,
    ``noise`` ``T^T B(t)``."""

    loads: MovingLoads
    basis: jax.Array | None  # T (3 L, n_q) or None (identity)
    kind: str = eqx.field(static=True)

    def _project(self, x):
        return x if self.basis is None else self.basis.T @ x

    def __call__(self, t):
        if self.kind == "load":
            return self._project(self.loads.nodal_forces(t))
        return self._project(self.loads.noise_matrix(t))


def _modes(M, K):
    """M-orthonormal modes (columns) and angular frequencies [rad/s], ascending."""
    eig = symmetric_eigen(M, K)
    return eig.shapes, jnp.sqrt(jnp.maximum(eig.values, 0.0))


def _damping_matrix(p: RingMovingLoadParams, M, K):
    if p.modal_damping_ratio is None:
        return p.rayleigh_mass * M + p.rayleigh_stiffness * K
    phi, w = _modes(M, K)
    mphi = M @ phi
    return (mphi * (2.0 * jnp.broadcast_to(p.modal_damping_ratio, w.shape) * w)[None, :]) @ mphi.T


class _Reduction(NamedTuple):
    """The ring system in its coordinates: matrices, modal basis T and residual flexibility R (or None)."""

    mass: jax.Array
    stiffness: jax.Array
    damping: jax.Array
    basis: jax.Array | None
    residual: jax.Array | None
    names: list
    units: list


def _check_n_modes(p, n_modes):
    if not isinstance(p, RingMovingLoadParams):
        raise ValueError(f"`p` must be a RingMovingLoadParams, got {type(p).__name__}")
    L3 = p.ring.n_dof
    if n_modes is not None and (
        isinstance(n_modes, bool) or not isinstance(n_modes, int | np.integer) or not 1 <= n_modes <= L3
    ):
        raise ValueError(f"`n_modes` must be None (full model) or an integer in [1, {L3}], got {n_modes!r}")


def _reduction(p: RingMovingLoadParams, n_modes: int | None) -> _Reduction:
    M, K = ring_matrices(p.ring)
    C = _damping_matrix(p, M, K)
    if n_modes is None:
        names = ring_dof_names(p.ring)
        units = [{"radial": "m", "tangential": "m", "rotation": "rad"}[n.rsplit("_", 1)[1]] for n in names]
        return _Reduction(M, K, C, None, None, names, units)
    phi, w = _modes(M, K)
    basis, wk = phi[:, :n_modes], w[:n_modes]
    residual = jnp.linalg.inv(K) - (basis / wk[None, :] ** 2) @ basis.T
    names = [f"mode{k + 1}" for k in range(n_modes)]
    return _Reduction(
        jnp.eye(n_modes),
        jnp.diag(wk**2),
        basis.T @ C @ basis,
        basis,
        residual,
        names,
        ["m sqrt(kg)"] * n_modes,
    )


def validate(p: RingMovingLoadParams) -> None:
    """``ValueError`` naming the parameter and its range (concrete values; traced values pass). Called by
    ``__check_init__`` and again by :func:`build`, since ``eqx.tree_at`` bypasses ``__check_init__``; the
    ring's values are named ``ring.<attribute>``."""
    validate_ring(p.ring, prefix="ring.")
    check_range("carrier_speed", p.carrier_speed, lo=0.0, lo_closed=False, unit="rad/s")
    check_range("mean_force", p.mean_force, unit="N")
    check_range("force_amplitude", p.force_amplitude, lo=0.0, unit="N")
    check_range("mesh_frequency_ratio", p.mesh_frequency_ratio, lo=0.0)
    check_range("noise_intensity", p.noise_intensity, lo=0.0, unit="N sqrt(s)")
    check_range("pressure_angle", p.pressure_angle, lo=0.0, hi=math.pi / 2, hi_closed=False, unit="rad")
    check_range("initial_angle", p.initial_angle, unit="rad")
    check_range("rayleigh_mass", p.rayleigh_mass, lo=0.0, unit="1/s")
    check_range("rayleigh_stiffness", p.rayleigh_stiffness, lo=0.0, unit="s")
    if np.shape(p.noise_intensity) != (p.n_loads,):
        raise ValueError(
            f"`noise_intensity` must have shape ({p.n_loads},) (one per load; the constructor broadcasts a scalar), "
            f"got {np.shape(p.noise_intensity)}"
        )
    if p.modal_damping_ratio is not None:
        check_range("modal_damping_ratio", p.modal_damping_ratio, lo=0.0)
        if np.shape(p.modal_damping_ratio) not in ((), (p.ring.n_dof,)):
            raise ValueError(
                f"`modal_damping_ratio` must be a scalar or have shape ({p.ring.n_dof},) "
                f"(one per ring mode), got {np.shape(p.modal_damping_ratio)}"
            )


def build(p: RingMovingLoadParams | None = None, *, n_modes: int | None = None) -> System:
    """The ch. 6 system (Eq. 6.27) as a :class:`pgtjax.System` (differentiable in every array leaf of ``p``;
    ``None``: the embedded defaults).

    DOFs: the ring's ``3 L`` nodal DOFs (:func:`ring_dof_names`) or, with ``n_modes``, the modal coordinates
    ``mode1..modeK`` of the K lowest modes of the supported ring (``U = Phi_K q``, M-orthonormal; damping
    ``Phi^T C Phi``). The ring under the moving load and at the mid-node are reported through
    :func:`observables`. ``load`` and ``noise_input`` are ``equinox.Module`` callables of t;
    ``spectral_density`` = 1 / (2 pi) (unit white noises W_n).
    """
    if p is not None and not isinstance(p, RingMovingLoadParams):
        raise ValueError(f"`p` must be RingMovingLoadParams (ring_moving_load.load_params), got {p!r}")
    p = default_params() if p is None else p
    validate(p)
    _check_n_modes(p, n_modes)
    red = _reduction(p, n_modes)
    loads = MovingLoads(p, ring_nodal_inverse(p.ring))
    return System(
        mass=red.mass,
        stiffness=red.stiffness,
        damping=red.damping,
        load=_Field(loads, red.basis, "load"),
        noise_input=_Field(loads, red.basis, "noise"),
        spectral_density=SPECTRAL_DENSITY,
        dof_names=red.names,
        dof_units=red.units,
    )


def ring_moving_load_system(p: RingMovingLoadParams, *, n_modes: int | None = None) -> System:
    """The builder's former name (:func:`build`), kept for existing scripts."""
    return build(p, n_modes=n_modes)


def observables(
    p: RingMovingLoadParams | None = None,
    *,
    contact: bool = True,
    mid: bool = True,
    n_modes: int | None = None,
) -> Observables:
    """The radial ring displacement [m, inward positive] under load 1 (``contact1_radial``, with ``contact``)
    and at :func:`mid_node` (``mid_node_radial``, with ``mid``), as :class:`pgtjax.Observables` of the system
    :func:`build` returns for the same ``p`` and ``n_modes``: ``y = c(t) T q`` exactly at every saved time, in
    SL and Monte Carlo alike. In a modal model the mean also includes the static correction ``c(t) R F_d(t)``
    of the dropped modes (residual flexibility ``R = K^-1 - Phi_K Omega^-2 Phi_K^T``); their noise part is
    neglected (its variance falls like ``1 / (lambda_K omega^4)``)."""
    p = default_params() if p is None else p
    _check_n_modes(p, n_modes)
    if not (contact or mid):
        raise ValueError("`contact` and `mid` cannot both be False: no output would be reported")
    red = _reduction(p, n_modes)
    rows = _OutputRows(
        MovingLoads(p, ring_nodal_inverse(p.ring)), red.basis, 3 * mid_node(p.ring), contact, mid
    )
    offset = None if red.residual is None else _StaticCorrection(rows, red.residual)
    names = [OBSERVER_NAME] * contact + [MID_NAME] * mid
    return Observables(rows, names=names, units=["m"] * len(names), offset=offset)


def static_initial_state(system: System, t0: float = 0.0):
    """``(u0, v0)``: the quasi-static state ``u = K(t)^-1 F(t)`` at ``t0`` and its time derivative.

    Starting a moving-load run here removes the start-up transient of suddenly applied loads (which would
    otherwise dominate the maximum of the mean over the first revolution)."""

    def static(t):
        k = system.stiffness(t) if callable(system.stiffness) else system.stiffness
        f = system.load(t) if callable(system.load) else system.load
        return jnp.linalg.solve(k, f)

    t0 = jnp.asarray(t0, jnp.float64)
    return jax.jvp(static, (t0,), (jnp.ones_like(t0),))


def mid_node(ring: RingParams) -> int:
    """Node half-way between the first two bolts (thesis Fig. 6.4's "mid-node"; node 3 of 36 with 6 bolts).
    Without supports: node ``L // 12`` (30 degrees)."""
    s = sorted(ring.support_nodes)
    if len(s) >= 2:
        return (s[0] + s[1]) // 2
    if len(s) == 1:
        return (s[0] + ring.n_elements // 2) // 2
    return ring.n_elements // 12


def contact_angle(p: RingMovingLoadParams, t):
    """theta_1(t) [rad]: the angle of load 1 (the contact point), wrapped to [0, 2 pi)."""
    return jnp.mod(p.initial_angle + p.carrier_speed * jnp.asarray(t, jnp.float64), 2.0 * math.pi)


# ------------------------------------------------------------------------------------------ parameter files

#: the three support cases of Sec. 6.4.3: (k_r [N/m], k_tau [N/m], k_theta [N m/rad])
SUPPORT_CASES = {
    1: (1.362e12, 1.362e12, 3.405e10),  # bolts
    2: (1.362e12, 1.362e12, 0.0),  # pins
    3: (5e10, 5e10, 0.0),  # soft pins
}


def load_params(
    source=None, *, n_elements: int | None = None, support: int | None = None
) -> RingMovingLoadParams:
    """Read a ring/moving-load parameter file (TOML, layout of the embedded ``ring_ch6.toml``) or a dict.

    ``n_elements`` overrides the mesh (bolts stay equally spaced, so it must be a multiple of the bolt count);
    ``support`` selects a ``[support_cases]`` entry (1, 2, 3) instead of ``[supports]``.
    """
    data = _params.read_params(source, "ring_ch6")  # ValueError naming table.key for a bad entry
    try:
        r, s, ld, d = data["ring"], data["supports"], data["loads"], data.get("damping", {})
        L = int(r["n_elements"]) if n_elements is None else check_count("n_elements", n_elements, minimum=3)
        n_bolts = int(s["n_bolts"])
        if n_bolts < 0 or (n_bolts and L % n_bolts):
            raise ValueError(
                f"`n_elements` ({L}) must be a multiple of `n_bolts` ({n_bolts}) so that the bolts "
                f"sit on nodes"
            )
        if support is not None:
            cases = data.get("support_cases", {})
            key = f"case{support}"
            if key not in cases:
                raise ValueError(
                    f"`support` must be one of {sorted(int(k[4:]) for k in cases)}, got {support!r}"
                )
            s = {**s, **cases[key]}
        ro, ri = float(r["outer_radius"]), float(r["root_radius"])
        if not 0.0 < ri < ro:
            raise ValueError(f"`root_radius` must be > 0 m and < `outer_radius` ({ro} m), got {ri}")
        nodes = tuple(range(0, L, L // n_bolts)) if n_bolts else ()
        ring = RingParams(
            0.5 * (ro + ri),
            ro - ri,
            float(r["face_width"]),
            float(r["youngs_modulus"]),
            float(r["density"]),
            n_elements=L,
            support_nodes=nodes,
            k_support_radial=float(s["k_radial"]),
            k_support_tangential=float(s["k_tangential"]),
            k_support_torsional=float(s["k_torsional"]),
            rotary_inertia=bool(r.get("rotary_inertia", True)),
        )
        if "rayleigh_mass" in d:
            lm, lk = float(d["rayleigh_mass"]), float(d["rayleigh_stiffness"])
        elif "damping_ratio" in d:
            lm, lk = rayleigh_coefficients(
                float(d["damping_ratio"]), float(d["omega_a"]), float(d["omega_b"])
            )
        else:
            lm = lk = None
        zeta = d.get("modal_damping_ratio")
        return RingMovingLoadParams(
            ring,
            carrier_speed=float(ld["carrier_speed"]),
            n_loads=int(ld["n_loads"]),
            mean_force=float(ld["mean_force"]),
            force_amplitude=float(ld["force_amplitude"]),
            mesh_frequency_ratio=float(ld["mesh_frequency_ratio"]),
            noise_intensity=float(ld["noise_intensity"]),
            pressure_angle=math.radians(float(ld["pressure_angle_deg"])),
            initial_angle=math.radians(float(ld.get("initial_angle_deg", 0.0))),
            rayleigh_mass=lm,
            rayleigh_stiffness=lk,
            modal_damping_ratio=None if zeta is None else float(zeta),
        )
    except KeyError as err:
        raise ValueError(f"parameter file is missing the entry {err}") from None
    except (TypeError,) as err:
        raise ValueError(f"parameter file has a value of the wrong type: {err}") from None


def default_params(**kw) -> RingMovingLoadParams:
    """The embedded ch. 6 data (``pgtjax/params/ring_ch6.toml``); keywords as :func:`load_params`."""
    return load_params(None, **kw)


def support_case(p: RingMovingLoadParams, case: int) -> RingMovingLoadParams:
    """``p`` with the bolts of support case 1 (bolts), 2 (pins) or 3 (soft pins) of Sec. 6.4.3."""
    if case not in SUPPORT_CASES:
        raise ValueError(f"`case` must be 1, 2 or 3 (Sec. 6.4.3), got {case!r}")
    kr, kt, kth = SUPPORT_CASES[case]
    r = p.ring
    ring = RingParams(
        r.radius,
        r.thickness,
        r.face_width,
        r.youngs_modulus,
        r.density,
        n_elements=r.n_elements,
        n_teeth=r.n_teeth,
        tooth_mass=r.tooth_mass,
        tooth_inertia=r.tooth_inertia,
        support_nodes=r.support_nodes,
        k_support_radial=kr,
        k_support_tangential=kt,
        k_support_torsional=kth,
        rotary_inertia=r.rotary_inertia,
    )
    return p.replace(ring=ring)
