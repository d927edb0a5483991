"""Back-to-back planetary test bench: 12-DOF torsional model with geometry-based nonlinear mesh stiffness.

Source: Hammami et al., *Dynamic behavior of non-linear planetary gear model in non-stationary conditions*
("paper" below), section 4 (Eqs. 14-33), Tables 1 and 3, with the corrections of the printed equations
stated where they are used (docs/corrections.md C11-C14). The mesh stiffness (tooth bending, fillet foundation, Harsha/Hertz contact in
series, Eqs. 1-13) comes from :mod:`pgtjax.models.mesh_stiffness`; this module puts it on the twelve meshes of
the bench and writes the equations of motion in the form every pgtjax solver takes (:class:`pgtjax.System`).

Bench (paper section 2, Fig. 3)
-------------------------------
Two identical planetary sets with three planets: the *reaction* set (suffix ``_R``), whose ring is free and
loaded by an arm (weights), and the *test* set (``_T``), whose ring is bolted to the housing. The two suns are
joined by the sun shaft (``k_st``), the two carriers by the hollow carrier shaft (``k_ct``); the motor drives
the reaction sun. The arm torque makes torque circulate around the closed loop; the motor only supplies
what the loop's inertia and damping need.

Coordinates (Eq. 15 order) and units
------------------------------------
``q = (c, r, s, p1, p2, p3)_R + (c, r, s, p1, p2, p3)_T`` with ``u_j = r_bj theta_j`` in metres (the paper's
Eq. 17 scaling): ``theta_j`` is the absolute rotation (rad) of member j, ``r_bj`` its base radius
(``m Z cos(alpha) / 2``, consistent with the mesh-stiffness model), and for the carrier
``r_bc = r_bs + r_bp`` (the carrier radius projected on the sun-planet line of action). :func:`dof_radii` gives
the radii to turn ``u`` back into angles.

Kinematics of a mesh (derived, not transcribed). In the carrier frame a planet turns by
``phi_p = theta_p - theta_c``; rolling without deflection requires ``r_bs (theta_s - theta_c) = -r_bp phi_p``
(external) and ``r_br (theta_r - theta_c) = r_bp phi_p`` (internal). The mesh deflections along the lines of
action (the transmission errors of Eqs. 30-33, now with the carrier term) are therefore::

    delta_sn = r_bs theta_s + r_bp theta_pn - (r_bs + r_bp) theta_c = u_s + u_pn - u_c
    delta_rn = r_br theta_r - r_bp theta_pn - (r_br - r_bp) theta_c = u_r - u_pn - kappa u_c

with ``kappa = (r_br - r_bp) / (r_bs + r_bp) = (Z_r - Z_p) / (Z_s + Z_p)``. For standard gears
(``Z_r = Z_s + 2 Z_p``) kappa = 1 and ``G diag(k) G^T`` is exactly the paper's Eqs. 19-20 (tested). Table 1
has ``Z_r = 65 = Z_s + 2 Z_p + 1`` (shifted teeth), so kappa = 41/40: the printed matrices hold only
approximately, the energy form above holds exactly. (Eq. 19 as printed is not symmetric: its (1, 3) entry
``-sum K_rr`` must read ``-sum K_sr``, as its (3, 1) entry does.) The rigid rotation of the train then makes every
``delta`` vanish identically (tested), so ``u`` can hold total rotations. Their cost: the
velocity update ``v1 = 2 (u1 - u0) / dt - v0`` loses ``|u| eps`` per step (``|u|`` ~ 10 m after a few seconds),
which bounds the energy drift of a spinning undamped bench to ~1e-7 over 1,000 mesh periods (tested); a
non-spinning one conserves energy to rounding.

Sign of the deflection. Torque circulates in opposite senses through the two sets: the test sun drives its
planets, the reaction sun is driven by its planets. The contact direction of every reaction-set mesh is
therefore reversed (``g -> -g``) so that ``delta > 0`` means "loaded flank in contact" in both sets.

Mass (Eq. 17, corrected form C14 ``I_c/r_c^2 + N m_p`` for a carrier coordinate ``r_c theta_c``) from the kinetic
energy ``T = 1/2 sum I_j theta_j'^2 + 1/2 N m_p (r_c theta_c')^2``: ``M = diag(I_j / r_bj^2)`` and for the
carrier ``(I_c + N m_p r_c^2) / r_bc^2`` [kg]. Stiffness of the shafts (Eq. 18's ``K_c``) from the potential
``1/2 k_st (theta_sR - theta_sT)^2 + 1/2 k_ct (theta_cR - theta_cT)^2 + 1/2 k_rt theta_rT^2
+ 1/2 k_m (theta_m(t) - theta_sR)^2`` [N/m after the scaling]. M and K are Hessians of these energies and the
contact directions the Jacobian of the deflections (``jax.hessian``/``jax.jacobian``).

Prescribed speed (regimes A and B)
----------------------------------
A torsional model with a free rigid-body rotation cannot be "given a speed" by a torque unless that torque is
tuned by a controller. We model what the bench does: a speed-controlled motor (frequency converter) whose
rotor angle ``theta_m(t)`` follows the prescribed profile, coupled to the reaction sun by the motor shaft of
stiffness ``k_m``. ``theta_m(t)`` is the exact integral of the piecewise-linear speed (:class:`OperatingProfile`),
so the train turns at the prescribed speed on average, the motor torque ``k_m (theta_m - theta_sR)`` is an
output (it balances inertia and damping; it is 0 at constant speed without damping), and the mesh phase,
which the engine needs as a function of time, is the same integral: ``c(t) = Z_r theta_c(t) / 2 pi`` with the
rigid-body carrier angle ``theta_c = Z_s / (Z_s + Z_r) theta_m`` (corrected Eq. 2, C12: ``f_m = Z_r f_c``). The
mesh period thus shortens as the speed rises because the phase advances faster. The circulating torque
(the test-sun torque ``T``, set by the arm: ``C_r = -(Z_r / Z_s) T`` on the reaction ring) may ramp with the
speed (the paper's abstract: "motor torque and external load variation are taken into account").

Damping (Eq. 21) ``C = alpha M + beta K0`` (``K0``: shafts + meshes at their mean stiffness), applied to the
motion *relative to the prescribed rigid rotation*: ``C (q' - phi theta_m')``. ``alpha M`` acting on absolute
velocities would brake the spinning train like a viscous drag (tens of N m here); relative to the rigid
rotation it damps vibration only. For the motor shaft term this is exactly a dashpot between motor rotor and
sun. The ``C phi theta_m'(t)`` part is a known load (in :class:`BenchLoad`).

Mesh contacts
-------------
Each of the 12 meshes is a contact of the law :class:`HertzianMesh`: up to three tooth pairs at the
line-of-action positions given by the mesh phase, each pair a series of the load-independent tooth compliance
(bending + fillet foundation of both teeth, Eqs. 3-10, tabulated along the path of contact) and the Harsha
contact (Eq. 12, ``F_h = 5.6065703e10 l^0.92 delta_h^1.08`` in SI); all pairs share the mesh deflection. The
engine evaluates ``law.force(delta, k, b)`` with ``k = stiffness(t)``: here ``k`` is the *mesh phase*
``lambda_j(t)`` in [0, 1) of each contact (:class:`MeshPhase`), not a stiffness. Half-backlash ``b``: dead zone
``|delta| < b``; the back flank (``delta < -b``) uses the same pair compliances (symmetric teeth; an
approximation, reached only after a complete loss of contact).

Mesh phasing inside a set follows Parker & Lin (2004) (:func:`mesh_stiffness.planet_mesh_phases`) and the
sun/ring phase of :func:`mesh_stiffness.sun_ring_phase`, both written for the test set's flank pattern (sun
drives planet, planet drives ring). The reaction set loads the other flanks; it is the mirror image of a test
set run backwards in time, so its phases are ``frac(-c(t) + gamma_sn)`` and ``frac(-c(t) + gamma_rn +
gamma_rs)`` evaluated with the test set's flank flags, plus an assembly offset (parameter, 0 by default).

Parameters: :class:`BackToBackParams`, defaults in ``pgtjax/params/back_to_back.toml`` (assumed values marked).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import Backlash, ContactLaw, Contacts, System, at_time
from .. import params as _params
from .._deterministic import static_equilibrium as solve_static
from .._validate import check_range
from . import mesh_stiffness as ms

Array = jax.Array

SETS = ("R", "T")
MEMBERS = ("carrier", "ring", "sun", "planet1", "planet2", "planet3")
DOF_NAMES = tuple(f"{m}_{s}" for s in SETS for m in MEMBERS)
DOF_UNITS = ("m",) * 12
CONTACT_NAMES = tuple(f"{g}-planet{n}_{s}" for s in SETS for g in ("sun", "ring") for n in (1, 2, 3))
N_PLANETS = 3
RPM = 2.0 * math.pi / 60.0  # rad/s per rpm

_HERTZ_ITERATIONS = 8
_STATIC_TOL = 1e-12  # relative residual of the quasi-static solve
_STATIC_MAX_ITER = 40


def _index(member: str, s: str) -> int:
    return SETS.index(s) * 6 + MEMBERS.index(member)


# ------------------------------------------------------------------------------------------------ parameters


def _concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _f64(x) -> Array:
    return jnp.asarray(x, dtype=jnp.float64)


class BackToBackParams(eqx.Module):
    """Parameters of the bench (SI units). Both planetary sets are identical (paper Table 1).

    Attributes:
        sun_planet, ring_planet: the two meshes (:class:`mesh_stiffness.SpurMesh`; tooth numbers, module,
            pressure angle, face width, material).
        sun_inertia, planet_inertia, carrier_inertia, ring_inertia: I [kg m^2] (Table 1).
        planet_mass: m_p [kg] (Table 1); carrier_radius: r_c, planet-centre radius [m] (carrier mass term).
        sun_shaft_stiffness, carrier_shaft_stiffness: k_st, k_ct [N m/rad] (Table 3; k_st assumed).
        motor_shaft_stiffness: k_m [N m/rad] (assumed); ring_support_stiffness: k_rt of the test ring [N m/rad].
        half_backlash: b [m]; reaction_phase_offset: assembly mesh phase of the reaction set [cycles].
        damping_ratio [-], rayleigh_f1, rayleigh_f2 [Hz]: Eq. 21 fitted to that ratio at the two frequencies.
        sun_torque: circulating test-sun torque in regime A [N m]; torque_end: at the end of the run-up [N m].
        speed_start, speed_end: motor (= reaction sun) speed before and after the ramp [rad/s];
        ramp_start, ramp_duration: [s].
        table_points: points of the pair-compliance table (static).
    """

    sun_planet: ms.SpurMesh
    ring_planet: ms.SpurMesh
    sun_inertia: Array
    planet_inertia: Array
    carrier_inertia: Array
    ring_inertia: Array
    planet_mass: Array
    carrier_radius: Array
    sun_shaft_stiffness: Array
    carrier_shaft_stiffness: Array
    motor_shaft_stiffness: Array
    ring_support_stiffness: Array
    half_backlash: Array
    reaction_phase_offset: Array
    damping_ratio: Array
    rayleigh_f1: Array
    rayleigh_f2: Array
    sun_torque: Array
    torque_end: Array
    speed_start: Array
    speed_end: Array
    ramp_start: Array
    ramp_duration: Array
    table_points: int = eqx.field(static=True, default=257)

    def __check_init__(self):
        validate(self)

    def replace(self, **changes) -> BackToBackParams:
        """A copy with some fields changed (validated); scalars are converted to float64 arrays."""
        conv = {
            k: (v if isinstance(v, ms.SpurMesh) or k == "table_points" else _f64(v))
            for k, v in changes.items()
        }
        return dataclasses.replace(self, **conv)

    @property
    def z_sun(self) -> int:
        return self.sun_planet.z_gear

    @property
    def z_ring(self) -> int:
        return self.ring_planet.z_gear

    @property
    def z_planet(self) -> int:
        return self.sun_planet.z_pinion

    @property
    def planet_angles(self) -> Array:
        return jnp.arange(N_PLANETS, dtype=jnp.float64) * (2.0 * jnp.pi / N_PLANETS)


def validate(p: BackToBackParams) -> None:
    """Raise ``ValueError`` naming the parameter and its accepted range (traced values are skipped)."""
    if not isinstance(p.sun_planet, ms.SpurMesh) or not isinstance(p.ring_planet, ms.SpurMesh):
        raise ValueError("`sun_planet` and `ring_planet` must be mesh_stiffness.SpurMesh instances")
    if p.sun_planet.internal or not p.ring_planet.internal:
        raise ValueError("`sun_planet` must be an external mesh and `ring_planet` an internal one")
    if p.sun_planet.z_pinion != p.ring_planet.z_pinion:
        raise ValueError("`sun_planet` and `ring_planet` must share the planet (same `z_pinion`)")
    if p.z_ring <= p.z_sun + p.z_planet:
        raise ValueError(
            f"`ring_planet.z_gear` ({p.z_ring}) must exceed z_sun + z_planet ({p.z_sun + p.z_planet})"
        )
    for name in ("sun_inertia", "planet_inertia", "carrier_inertia", "ring_inertia"):
        check_range(name, getattr(p, name), lo=0.0, hi=1e3, lo_closed=False, unit="kg m^2")
    check_range("planet_mass", p.planet_mass, lo=0.0, hi=1e4, lo_closed=False, unit="kg")
    check_range("carrier_radius", p.carrier_radius, lo=0.0, hi=10.0, lo_closed=False, unit="m")
    for name in ("sun_shaft_stiffness", "carrier_shaft_stiffness"):
        check_range(name, getattr(p, name), lo=0.0, hi=1e12, lo_closed=False, unit="N m/rad")
    check_range(
        "motor_shaft_stiffness",
        p.motor_shaft_stiffness,
        lo=0.0,
        hi=1e12,
        lo_closed=True,
        unit="N m/rad (0 detaches the motor)",
    )
    check_range(
        "ring_support_stiffness",
        p.ring_support_stiffness,
        lo=0.0,
        hi=1e14,
        lo_closed=True,
        unit="N m/rad (0 frees the test ring)",
    )
    check_range("half_backlash", p.half_backlash, lo=0.0, hi=1e-3, lo_closed=True, unit="m")
    check_range(
        "reaction_phase_offset", p.reaction_phase_offset, lo=-1e6, hi=1e6, lo_closed=False, unit="mesh cycles"
    )
    check_range(
        "damping_ratio", p.damping_ratio, lo=0.0, hi=1.0, lo_closed=True, unit="(fraction of critical)"
    )
    check_range("rayleigh_f1", p.rayleigh_f1, lo=0.0, hi=1e6, lo_closed=False, unit="Hz")
    check_range("rayleigh_f2", p.rayleigh_f2, lo=0.0, hi=1e6, lo_closed=False, unit="Hz")
    if (
        _concrete(p.rayleigh_f1)
        and _concrete(p.rayleigh_f2)
        and not float(p.rayleigh_f2) > float(p.rayleigh_f1)
    ):
        raise ValueError(
            f"`rayleigh_f2` must exceed `rayleigh_f1`; got {p.rayleigh_f2!r} <= {p.rayleigh_f1!r}"
        )
    check_range(
        "sun_torque", p.sun_torque, lo=0.0, hi=1e5, lo_closed=True, unit="N m (circulating test-sun torque)"
    )
    check_range("torque_end", p.torque_end, lo=0.0, hi=1e5, lo_closed=True, unit="N m")
    check_range("speed_start", p.speed_start, lo=0.0, hi=2e3, lo_closed=True, unit="rad/s")
    check_range("speed_end", p.speed_end, lo=0.0, hi=2e3, lo_closed=True, unit="rad/s")
    check_range("ramp_start", p.ramp_start, lo=0.0, hi=1e4, lo_closed=True, unit="s")
    check_range("ramp_duration", p.ramp_duration, lo=0.0, hi=1e4, lo_closed=False, unit="s")
    if not isinstance(p.table_points, int | np.integer) or not 16 <= int(p.table_points) <= 100_000:
        raise ValueError(f"`table_points` must be an integer in [16, 100000]; got {p.table_points!r}")


def load_params(path: str | Path | None = None, **overrides) -> BackToBackParams:
    """Parameters from a TOML file with the layout of ``pgtjax/params/back_to_back.toml`` (default: that file).

    ``overrides`` replace fields of :class:`BackToBackParams` (e.g. ``sun_torque=200.0``).
    """
    data = _params.read_params(path, "back_to_back")  # ValueError naming table.key for a bad entry
    try:
        meshes = ms.back_to_back_meshes(data)
        g, b, d, run = data["gears"], data["bench"], data["damping"], data["run_up"]
        fields = dict(
            sun_planet=meshes.sun_planet,
            ring_planet=meshes.ring_planet,
            sun_inertia=g["inertia_kgm2"]["sun"],
            planet_inertia=g["inertia_kgm2"]["planet"],
            carrier_inertia=g["inertia_kgm2"]["carrier"],
            ring_inertia=g["inertia_kgm2"]["ring"],
            planet_mass=g["mass_kg"]["planet"],
            carrier_radius=b["carrier_radius_m"],
            sun_shaft_stiffness=b["sun_shaft_stiffness_Nm_per_rad"],
            carrier_shaft_stiffness=b["carrier_shaft_stiffness_Nm_per_rad"],
            motor_shaft_stiffness=b["motor_shaft_stiffness_Nm_per_rad"],
            ring_support_stiffness=b["test_ring_support_stiffness_Nm_per_rad"],
            half_backlash=b["half_backlash_m"],
            reaction_phase_offset=b["reaction_phase_offset"],
            damping_ratio=d["damping_ratio"],
            rayleigh_f1=d["rayleigh_f1_hz"],
            rayleigh_f2=d["rayleigh_f2_hz"],
            sun_torque=data["operating"]["sun_torque_Nm"],
            torque_end=run["torque_end_Nm"],
            speed_start=run["speed_start_rpm"] * RPM,
            speed_end=run["speed_end_rpm"] * RPM,
            ramp_start=run["ramp_start_s"],
            ramp_duration=run["ramp_duration_s"],
        )
        table_points = int(b.get("stiffness_table_points", 257))
        if int(g["n_planets"]) != N_PLANETS:
            raise ValueError(f"`n_planets` must be {N_PLANETS} for the bench model; got {g['n_planets']!r}")
    except KeyError as err:
        raise ValueError(f"parameter file {path} lacks the entry {err}") from None
    unknown = set(overrides) - set(fields)
    if unknown:
        raise ValueError(
            f"unknown override(s) {sorted(unknown)} of load_params; known: {', '.join(sorted(fields))}"
        )
    fields.update(overrides)
    fields = {k: (v if isinstance(v, ms.SpurMesh) else _f64(v)) for k, v in fields.items()}
    return BackToBackParams(**fields, table_points=table_points)


def default_params(**overrides) -> BackToBackParams:
    """Paper Tables 1 and 3 with the documented assumptions of ``back_to_back.toml``."""
    return load_params(None, **overrides)


def stationary(params: BackToBackParams, speed_rpm=None, torque=None) -> BackToBackParams:
    """Regime A only: constant speed (default ``speed_start``) and torque (default ``sun_torque``)."""
    speed = params.speed_start if speed_rpm is None else _f64(speed_rpm) * RPM
    torque = params.sun_torque if torque is None else _f64(torque)
    return params.replace(speed_start=speed, speed_end=speed, sun_torque=torque, torque_end=torque)


# ------------------------------------------------------------------------------------------------ geometry


class Radii(NamedTuple):
    """Base radii [m] (``m Z cos(alpha) / 2``), the carrier's line-of-action radius and the ring-mesh factor."""

    sun: Array
    planet: Array
    ring: Array
    carrier: Array  # r_bs + r_bp
    kappa: Array  # (r_br - r_bp) / (r_bs + r_bp)


def radii(p: BackToBackParams) -> Radii:
    m, a = p.sun_planet.module, p.sun_planet.pressure_angle
    rb = lambda z: 0.5 * m * z * jnp.cos(a)  # noqa: E731
    r_s, r_p, r_r = rb(p.z_sun), rb(p.z_planet), rb(p.z_ring)
    return Radii(r_s, r_p, r_r, r_s + r_p, (r_r - r_p) / (r_s + r_p))


def dof_radii(p: BackToBackParams) -> Array:
    """(12,) radii [m] with ``theta = u / radius`` for every DOF."""
    r = radii(p)
    one = jnp.stack([r.carrier, r.ring, r.sun, r.planet, r.planet, r.planet])
    return jnp.concatenate([one, one])


def carrier_ratio(p: BackToBackParams) -> float:
    """theta_c / theta_s of the rigid train with fixed rings: Z_s / (Z_s + Z_r)."""
    return p.z_sun / (p.z_sun + p.z_ring)


def mesh_cycles_per_radian(p: BackToBackParams) -> float:
    """Mesh cycles per radian of the motor (= sun) rotation: Z_r Z_s / ((Z_s + Z_r) 2 pi) (corrected Eq. 2, C12)."""
    return p.z_ring * carrier_ratio(p) / (2.0 * math.pi)


def mesh_frequency(p: BackToBackParams, motor_speed) -> Array:
    """Mesh frequency [Hz] at a motor speed [rad/s]."""
    return mesh_cycles_per_radian(p) * motor_speed


def kinetic_energy(p: BackToBackParams, u_dot) -> Array:
    """T = 1/2 sum I_j theta_j'^2 + 1/2 N m_p (r_c theta_c')^2 [J] for velocities ``u_dot`` (12,) [m/s]."""
    th = u_dot / dof_radii(p)
    total = 0.0
    for s in SETS:
        o = SETS.index(s) * 6
        total = (
            total + 0.5 * (p.carrier_inertia + N_PLANETS * p.planet_mass * p.carrier_radius**2) * th[o] ** 2
        )
        total = total + 0.5 * p.ring_inertia * th[o + 1] ** 2 + 0.5 * p.sun_inertia * th[o + 2] ** 2
        total = total + 0.5 * p.planet_inertia * jnp.sum(th[o + 3 : o + 6] ** 2)
    return total


def shaft_energy(p: BackToBackParams, u, *, motor: bool = True) -> Array:
    """Potential energy [J] of the shafts and the test-ring support; the motor shaft with its rotor at 0."""
    th = u / dof_radii(p)
    cR, sR, cT, rT, sT = (
        th[_index(m, s)]
        for m, s in (("carrier", "R"), ("sun", "R"), ("carrier", "T"), ("ring", "T"), ("sun", "T"))
    )
    e = 0.5 * p.sun_shaft_stiffness * (sR - sT) ** 2 + 0.5 * p.carrier_shaft_stiffness * (cR - cT) ** 2
    e = e + 0.5 * p.ring_support_stiffness * rT**2
    if motor:
        e = e + 0.5 * p.motor_shaft_stiffness * sR**2
    return e


def mesh_deflections(p: BackToBackParams, u) -> Array:
    """(12,) mesh deflections [m] along the lines of action (module docstring), reaction set sign-reversed."""
    r = radii(p)
    out = []
    for s, sign in (("R", -1.0), ("T", 1.0)):
        o = SETS.index(s) * 6
        c, ring, sun, planets = u[o], u[o + 1], u[o + 2], u[o + 3 : o + 6]
        out.append(sign * (sun + planets - c))
        out.append(sign * (ring - planets - r.kappa * c))
    return jnp.concatenate(out)


@eqx.filter_jit
def mass_matrix(p: BackToBackParams) -> Array:
    """M [kg] = Hessian of the kinetic energy (Eq. 17)."""
    return jax.hessian(lambda v: kinetic_energy(p, v))(jnp.zeros(12))


@eqx.filter_jit
def shaft_stiffness_matrix(p: BackToBackParams, *, motor: bool = True) -> Array:
    """K_c [N/m] = Hessian of the shaft potential (Eq. 18's K_c)."""
    return jax.hessian(lambda u: shaft_energy(p, u, motor=motor))(jnp.zeros(12))


@eqx.filter_jit
def contact_directions(p: BackToBackParams) -> Array:
    """G (12 DOF, 12 meshes): column j is d delta_j / d u (Eq. 23's {X})."""
    return jax.jacobian(lambda u: mesh_deflections(p, u))(jnp.zeros(12)).T


def rigid_rotation(p: BackToBackParams) -> Array:
    """u (12,) [m] of the rigid train per radian of the motor: sun 1 rad, rings fixed, meshes undeformed."""
    r = radii(p)
    th_c = r.sun / (r.sun + r.ring)
    th_p = th_c - (r.sun / r.planet) * (1.0 - th_c)
    one = jnp.stack([th_c, 0.0 * th_c, jnp.ones_like(th_c), th_p, th_p, th_p])
    return jnp.concatenate([one, one]) * dof_radii(p)


def rayleigh_coefficients(p: BackToBackParams) -> tuple[Array, Array]:
    """(alpha [1/s], beta [s]) of Eq. 21 giving ``damping_ratio`` at ``rayleigh_f1`` and ``rayleigh_f2``."""
    w1, w2 = 2.0 * jnp.pi * p.rayleigh_f1, 2.0 * jnp.pi * p.rayleigh_f2
    return 2.0 * p.damping_ratio * w1 * w2 / (w1 + w2), 2.0 * p.damping_ratio / (w1 + w2)


# ------------------------------------------------------------------------------------------- time functions


class OperatingProfile(eqx.Module):
    """Speed and circulating torque: constant (regime A) until ``ramp_start``, linear ramp over
    ``ramp_duration`` (regime B), constant after. Speeds in rad/s (motor = reaction sun), torques in N m."""

    speed_start: Array
    speed_end: Array
    torque_start: Array
    torque_end: Array
    ramp_start: Array
    ramp_duration: Array

    def fraction(self, t):
        return jnp.clip((t - self.ramp_start) / self.ramp_duration, 0.0, 1.0)

    def speed(self, t):
        """Motor speed [rad/s]."""
        return self.speed_start + (self.speed_end - self.speed_start) * self.fraction(t)

    def acceleration(self, t):
        """Motor angular acceleration [rad/s^2] (0 outside the ramp)."""
        inside = (t > self.ramp_start) & (t < self.ramp_start + self.ramp_duration)
        return jnp.where(inside, (self.speed_end - self.speed_start) / self.ramp_duration, 0.0)

    def angle(self, t):
        """Motor angle [rad] = exact integral of :meth:`speed` from 0."""
        d = self.ramp_duration
        tau = jnp.clip(t - self.ramp_start, 0.0, None)
        ramp_integral = jnp.where(tau < d, 0.5 * tau**2 / d, tau - 0.5 * d)
        return self.speed_start * t + (self.speed_end - self.speed_start) * ramp_integral

    def torque(self, t):
        """Circulating test-sun torque [N m]."""
        return self.torque_start + (self.torque_end - self.torque_start) * self.fraction(t)


def operating_profile(p: BackToBackParams) -> OperatingProfile:
    return OperatingProfile(
        p.speed_start, p.speed_end, p.sun_torque, p.torque_end, p.ramp_start, p.ramp_duration
    )


class MeshPhase(eqx.Module):
    """Mesh phases lambda_j(t) in [0, 1) of the 12 contacts: ``frac(sign_j c(t) + offset_j)`` with
    ``c(t) = cycles_per_radian * theta_m(t)`` (module docstring). Used as the contacts' ``stiffness`` field."""

    profile: OperatingProfile
    cycles_per_radian: Array
    sign: Array  # (12,)
    offset: Array  # (12,)

    def cycles(self, t):
        """Mesh cycles elapsed in the test set, c(t) [-]."""
        return self.cycles_per_radian * self.profile.angle(t)

    def __call__(self, t):
        return jnp.mod(self.sign * self.cycles(t) + self.offset, 1.0)


@eqx.filter_jit
def mesh_phase_function(p: BackToBackParams, profile: OperatingProfile | None = None) -> MeshPhase:
    profile = operating_profile(p) if profile is None else profile
    gs, gr = ms.planet_mesh_phases(p.z_sun, p.z_ring, p.planet_angles)
    grs = ms.sun_ring_phase(p.sun_planet, p.ring_planet)
    phi = p.reaction_phase_offset
    offset_r = jnp.concatenate([gs + phi, gr + grs + phi])
    offset_t = jnp.concatenate([-gs, -gr + grs])
    sign = jnp.concatenate([-jnp.ones(6), jnp.ones(6)])
    return MeshPhase(profile, _f64(mesh_cycles_per_radian(p)), sign, jnp.concatenate([offset_r, offset_t]))


class BenchLoad(eqx.Module):
    """F(t) [N]: arm torque on the reaction ring, motor-shaft spring towards the prescribed rotor angle and the
    damping of the prescribed rigid rotation (module docstring)."""

    profile: OperatingProfile
    per_torque: Array  # (12,) load per N m of circulating torque
    per_motor_angle: Array  # (12,) load per rad of motor angle (k_m / r_bs on the reaction sun)
    per_motor_speed: Array  # (12,) C phi, per rad/s of motor speed

    def __call__(self, t):
        pr = self.profile
        return (
            self.per_torque * pr.torque(t)
            + self.per_motor_angle * pr.angle(t)
            + self.per_motor_speed * pr.speed(t)
        )


# --------------------------------------------------------------------------------------------- contact law


def _last_axis(x: Array, like: Array) -> Array:
    """Reshape a per-contact (nc,) array to broadcast against ``like`` (..., nc) without rank promotion."""
    return jnp.reshape(x, (1,) * (jnp.ndim(like) - 1) + (x.shape[-1],))


class PairState(NamedTuple):
    """Per contact and pair (..., nc, 3): load [N], Hertz deflection [m], tangent pair stiffness [N/m],
    tangent and secant (Eq. 13) Hertz stiffness [N/m], linear compliance [m/N], in-contact mask."""

    force: Array
    hertz_deflection: Array
    stiffness: Array
    hertz_tangent: Array
    hertz_secant: Array
    compliance: Array
    in_contact: Array


class HertzianMesh(ContactLaw):
    """Nonlinear mesh law (paper Eqs. 1-13); its input at time t is the mesh phase of each contact (cycles).

    Per contact (arrays with a trailing contact axis): the active path ``[s_start, s_end]`` [m] along the line
    of action, base pitch [m], contact ratio, a flag for "gear drives" (contact enters at the pinion tip), the
    Harsha coefficient ``C_h = 5.6065703e10 W^0.92`` [N/m^1.08] and a table of the load-independent pair
    compliance [m/N] (bending + fillet of both teeth, Eqs. 3-10) on a uniform grid of the path.

    A pair at position s with compliance c under mesh deflection d > 0 carries ``F = C_h x^1.08`` where the
    Hertz deflection x solves ``x + c C_h x^1.08 = d`` (series, Eq. 1); Newton from x = d converges
    monotonically (convex increasing), 8 steps reach rounding (tested). Pairs in contact add.
    """

    s_start: Array
    s_end: Array
    base_pitch: Array
    contact_ratio: Array
    gear_drives: Array  # 1.0 where the gear drives (positions mirrored), else 0.0
    hertz_coef: Array
    table: Array  # (nc, n)
    reference_stiffness: Array | None = None  # (nc,) mean tangent mesh stiffness under the nominal load [N/m]

    def pair_state(self, d, phase) -> PairState:
        """Pair quantities for the flank deflection ``d`` [m] (>0: compression) at mesh phase ``phase``."""
        s0, s1 = _last_axis(self.s_start, d), _last_axis(self.s_end, d)
        pb, eps = _last_axis(self.base_pitch, d), _last_axis(self.contact_ratio, d)
        gd = _last_axis(self.gear_drives, d)
        lam = jnp.mod(phase, 1.0)
        lam = jnp.where(gd > 0.5, jnp.mod(eps - lam, 1.0), lam)
        k = jnp.reshape(jnp.arange(3, dtype=jnp.float64), (1,) * jnp.ndim(lam) + (3,))
        s = s0[..., None] + (lam[..., None] + k) * pb[..., None]
        on = s <= s1[..., None]
        s = jnp.minimum(s, s1[..., None])
        n = self.table.shape[-1]
        x = (s - s0[..., None]) / (s1 - s0)[..., None] * (n - 1)
        i0 = jnp.clip(jnp.floor(x), 0, n - 2).astype(jnp.int32)
        w = x - i0
        row = jnp.reshape(jnp.arange(self.table.shape[0]) * n, (1,) * (jnp.ndim(d) - 1) + (-1, 1))
        flat = self.table.reshape(-1)
        c = (1.0 - w) * flat[row + i0] + w * flat[row + i0 + 1]
        coef = _last_axis(self.hertz_coef, d)[..., None]
        p = ms.HARSHA_DEFLECTION_EXP
        pos = d > 0.0
        dp = jnp.where(pos, d, 1.0)[..., None]
        a = c * coef
        xh = jnp.broadcast_to(dp, jnp.broadcast_shapes(dp.shape, a.shape))
        for _ in range(_HERTZ_ITERATIONS):
            xh = xh - (xh + a * xh**p - dp) / (1.0 + a * p * xh ** (p - 1.0))
        active = on & pos[..., None]
        f = jnp.where(active, coef * xh**p, 0.0)
        kh = coef * p * xh ** (p - 1.0)
        k_pair = jnp.where(active, 1.0 / (c + 1.0 / kh), 0.0)
        return PairState(
            f,
            jnp.where(active, xh, 0.0),
            k_pair,
            jnp.where(active, kh, 0.0),
            jnp.where(active, kh / p, 0.0),
            c,
            on,
        )

    def _flank(self, delta, phase, b, what):
        bb = jnp.broadcast_to(b, jnp.shape(delta)) if jnp.ndim(b) == jnp.ndim(delta) else _last_axis(b, delta)
        ph = phase if jnp.ndim(phase) == jnp.ndim(delta) else _last_axis(phase, delta)
        up, lo = delta - bb, -delta - bb
        st_up, st_lo = self.pair_state(up, ph), self.pair_state(lo, ph)
        return what(st_up, up), what(st_lo, lo)

    def force(self, delta, k, b):
        up, lo = self._flank(delta, k, b, lambda st, d: jnp.sum(st.force, axis=-1))
        return up - lo

    def stiffness(self, delta, k, b):
        up, lo = self._flank(delta, k, b, lambda st, d: jnp.sum(st.stiffness, axis=-1))
        return up + lo

    def potential(self, delta, k, b):
        # Pair: int F d(d) with d = c F + (F/C_h)^(1/p): c F^2/2 + F x / (1 + p).
        p = ms.HARSHA_DEFLECTION_EXP

        def energy(st, d):
            return jnp.sum(
                st.compliance * st.force**2 / 2.0 + st.force * st.hertz_deflection / (1.0 + p), axis=-1
            )

        up, lo = self._flank(delta, k, b, energy)
        return up + lo

    def mean_stiffness(self, mu, sigma, phase, b):
        """``E[f']`` by quadrature of the tangent stiffness itself, as this law has always done (the bench's
        published comparisons were made with it); the base class's Stein form is smoother in ``mu``."""
        return self.gaussian_expectation(self.stiffness, mu, sigma, phase, b)

    def closed_stiffness(self, phase, b):
        """The mean tangent mesh stiffness under the nominal load (N/m): what modal analysis uses for a mesh
        (the modes of the mean mesh stiffness) and the start of the static solve."""
        if self.reference_stiffness is None:
            raise ValueError(
                "this HertzianMesh has no `reference_stiffness`; build it with "
                "`back_to_back.hertzian_mesh_law(params)`, which sets the mean mesh stiffness"
            )
        return jnp.broadcast_to(self.reference_stiffness, jnp.shape(b))


def _compliance_table(mesh: ms.SpurMesh, n: int) -> tuple[Array, ms.ContactPath]:
    path = ms.contact_path(mesh)
    s = jnp.linspace(path.s_start, path.s_end, n)
    return jax.vmap(lambda si: ms.pair_linear_compliance(mesh, si))(s), path


def hertzian_mesh_law(p: BackToBackParams) -> HertzianMesh:
    """The 12-contact law of the bench, contacts ordered as :data:`CONTACT_NAMES`, with its reference
    (closed-contact) stiffness: the mean tangent mesh stiffness under the nominal load of ``sun_torque``
    (:func:`mean_mesh_stiffness`)."""
    law = _hertzian_mesh_tables(p)
    k_sun, k_ring = _mean_stiffness(law, nominal_mesh_load(p, jnp.maximum(p.sun_torque, 1.0)), 64)
    reference = jnp.concatenate([jnp.full(3, k_sun), jnp.full(3, k_ring)] * 2)
    return eqx.tree_at(lambda law: law.reference_stiffness, law, reference, is_leaf=lambda x: x is None)


@eqx.filter_jit
def _hertzian_mesh_tables(p: BackToBackParams) -> HertzianMesh:
    tab_s, path_s = _compliance_table(p.sun_planet, p.table_points)
    tab_r, path_r = _compliance_table(p.ring_planet, p.table_points)
    # Test-set flank pattern: the sun drives the planet (gear drives), the planet drives the ring.
    kinds = [0, 0, 0, 1, 1, 1] * 2
    pick = lambda a, b: jnp.stack([(a, b)[j] for j in kinds])  # noqa: E731
    coef = lambda mesh: ms.HARSHA_FORCE_COEF_SI * mesh.face_width**ms.HARSHA_LENGTH_EXP  # noqa: E731
    return HertzianMesh(
        s_start=pick(path_s.s_start, path_r.s_start),
        s_end=pick(path_s.s_end, path_r.s_end),
        base_pitch=pick(path_s.base_pitch, path_r.base_pitch),
        contact_ratio=pick(path_s.contact_ratio, path_r.contact_ratio),
        gear_drives=pick(jnp.array(1.0), jnp.array(0.0)),
        hertz_coef=pick(coef(p.sun_planet), coef(p.ring_planet)),
        table=pick(tab_s, tab_r),
    )


# ------------------------------------------------------------------------------------------------- builder


def nominal_mesh_load(p: BackToBackParams, torque=None) -> Array:
    """Normal load per mesh [N] = T / (N r_bs) for a circulating test-sun torque T (default ``sun_torque``)."""
    torque = p.sun_torque if torque is None else torque
    return torque / (N_PLANETS * radii(p).sun)


def mean_mesh_stiffness(
    p: BackToBackParams, torque=None, n_points: int = 64, law: HertzianMesh | None = None
) -> tuple[Array, Array]:
    """Mean tangent mesh stiffness dF/d delta [N/m] over a mesh cycle of the sun-planet and ring-planet meshes
    under the quasi-static mesh load of ``torque`` (default ``sun_torque``; at least 1 N m), from
    :class:`HertzianMesh` (equal to :func:`mesh_stiffness.mesh_cycle`'s up to the table interpolation; tested)."""
    torque = p.sun_torque if torque is None else _f64(torque)
    law = _hertzian_mesh_tables(p) if law is None else law
    return _mean_stiffness(law, nominal_mesh_load(p, jnp.maximum(torque, 1.0)), n_points)


@eqx.filter_jit
def _mean_stiffness(law: HertzianMesh, load, n_points: int):
    st = quasi_static_mesh(law, load, n_points)
    k = jnp.mean(st.mesh_stiffness, axis=0)
    return k[0], k[3]


class QuasiStaticMesh(NamedTuple):
    """Each (n_points, 12) over one mesh cycle: deflection [m], tangent mesh stiffness, Hertz secant (Eq. 13)
    and tangent stiffness summed over the pairs in contact [N/m]."""

    phase: Array
    deflection: Array
    mesh_stiffness: Array
    hertz_secant: Array
    hertz_tangent: Array


def quasi_static_mesh(law: HertzianMesh, load, n_points: int = 64) -> QuasiStaticMesh:
    """Every contact of ``law`` under the normal load ``load`` [N] at phases arange(n)/n (Newton on the
    deflection, monotone from the single-pair deflection)."""
    nc = law.table.shape[0]
    phase = jnp.broadcast_to((jnp.arange(n_points, dtype=jnp.float64) / n_points)[:, None], (n_points, nc))
    zero = jnp.zeros((n_points, nc))
    load = jnp.broadcast_to(jnp.asarray(load, jnp.float64), (n_points, nc))

    def body(_, d):
        st = law.pair_state(d, phase)
        return d - (jnp.sum(st.force, -1) - load) / jnp.sum(st.stiffness, -1)

    d0 = jnp.full((n_points, nc), 1e-4) + zero
    d = jax.lax.fori_loop(0, 30, body, d0)
    st = law.pair_state(d, phase)
    return QuasiStaticMesh(
        phase, d, jnp.sum(st.stiffness, -1), jnp.sum(st.hertz_secant, -1), jnp.sum(st.hertz_tangent, -1)
    )


class BenchModel(NamedTuple):
    """Everything the studies need about one bench configuration."""

    params: BackToBackParams
    system: System
    profile: OperatingProfile
    phase: MeshPhase
    law: ContactLaw
    rigid: Array  # (12,) u per rad of motor
    radii: Array  # (12,) theta = u / radii
    mean_stiffness: Array  # (12,) mean tangent mesh stiffness used for K0 (damping, linear contacts) [N/m]
    directions: Array  # (12, 12)


def build(params: BackToBackParams | None = None, **options) -> System:
    """The bench's :class:`pgtjax.System` (Eq. 14); ``None``: the embedded defaults. ``options`` as
    :func:`build_model`, which also returns the operating profile, mesh law and other derived data."""
    return build_model(params, **options).system


def build_model(
    params: BackToBackParams | None = None,
    *,
    contacts: str = "hertz",
    motor: bool = True,
    damping: bool = True,
    loads: bool = True,
) -> BenchModel:
    """Build the bench as a :class:`pgtjax.System` (Eq. 14) with its time functions.

    ``contacts``: ``"hertz"`` (the nonlinear law :class:`HertzianMesh`, phases from :class:`MeshPhase`) or
    ``"linear"`` (linear springs of the mean tangent mesh stiffness, ``Backlash`` law with b = 0).
    ``motor``: include the motor shaft (speed-driven bench); without it the train has a free rigid rotation.
    ``damping``: Eq. 21 (else C = 0). ``loads``: arm torque, motor rotor angle and damping of the rigid rotation.
    """
    if params is not None and not isinstance(params, BackToBackParams):
        raise ValueError(f"`params` must be BackToBackParams (back_to_back.load_params), got {params!r}")
    p = default_params() if params is None else params
    validate(p)  # again: values set with eqx.tree_at bypass __check_init__
    if contacts not in ("hertz", "linear"):
        raise ValueError(f"`contacts` must be 'hertz' or 'linear'; got {contacts!r}")
    M = mass_matrix(p)
    Kc = shaft_stiffness_matrix(p, motor=motor)
    G = contact_directions(p)
    hertz_law = hertzian_mesh_law(p)
    k_mean = hertz_law.reference_stiffness  # mean tangent stiffness of each mesh (mean_mesh_stiffness)
    K0 = Kc + (G * k_mean[None, :]) @ G.T
    alpha, beta = rayleigh_coefficients(p)
    C = alpha * M + beta * K0 if damping else jnp.zeros((12, 12))
    profile = operating_profile(p)
    phase = mesh_phase_function(p, profile)
    rigid = rigid_rotation(p)
    r = radii(p)
    zero = jnp.zeros(12)
    per_torque = zero.at[_index("ring", "R")].set(-(p.z_ring / p.z_sun) / r.ring)
    per_angle = zero.at[_index("sun", "R")].set(p.motor_shaft_stiffness / r.sun) if motor else zero
    per_speed = C @ rigid
    load = BenchLoad(profile, per_torque, per_angle, per_speed) if loads else zero
    b = jnp.full(12, p.half_backlash)
    if contacts == "hertz":
        law = hertz_law
        cont = Contacts(G, phase, b, names=CONTACT_NAMES, law=law)
    else:
        law = Backlash()
        cont = Contacts(G, k_mean, jnp.zeros(12), names=CONTACT_NAMES, law=law)
    system = System(
        mass=M, stiffness=Kc, damping=C, load=load, contacts=cont, dof_names=DOF_NAMES, dof_units=DOF_UNITS
    )
    return BenchModel(p, system, profile, phase, law, rigid, dof_radii(p), k_mean, G)


def linear_system(params: BackToBackParams | None = None, *, motor: bool = False) -> System:
    """Linear bench for modal analysis: meshes as linear springs of their mean stiffness, no damping/loads."""
    return build(params, contacts="linear", motor=motor, damping=False, loads=False)


# ------------------------------------------------------------------------------------------ static solution


def static_equilibrium(model: BenchModel, t: float = 0.0) -> Array:
    """Displacement [m] of the quasi-static state at time t: ``K u + G f(G^T u) = F(t) - C v_rigid(t)`` with
    the train turning rigidly at the prescribed speed (:func:`pgtjax.static_equilibrium` with that velocity;
    differentiable, raises ``RuntimeError`` if Newton does not converge). Newton starts from the linear
    solution with the meshes at their mean stiffness, offset by the backlash."""
    s = model.system
    t = jnp.asarray(t, jnp.float64)
    v = model.rigid * model.profile.speed(t)
    K, G = at_time(s.stiffness, t), s.contact_direction(t)
    F = at_time(s.load, t) - at_time(s.damping, t) @ v
    if isinstance(model.law, HertzianMesh):
        b = s.contact_clearance()
        k = model.mean_stiffness
        u0 = jnp.linalg.solve(K + (G * k[None, :]) @ G.T, F + G @ (k * b))
    else:
        u0 = jnp.zeros(s.n_dof)
    return solve_static(s, t, velocity=v, initial_guess=u0, tol=_STATIC_TOL, max_iter=_STATIC_MAX_ITER)


def initial_state(model: BenchModel, t: float = 0.0) -> tuple[Array, Array]:
    """(u0, v0): quasi-static state at t (:func:`static_equilibrium`, which includes the rigid rotation's
    angle through the motor spring) and the velocity of the rigid train at the prescribed speed."""
    u = static_equilibrium(model, t)
    v = model.rigid * model.profile.speed(jnp.asarray(t, jnp.float64))
    return u, v


class MeshHistory(NamedTuple):
    """Mesh quantities over time, each (n_t, 12): phase [-], transmission error ``delta - b`` [m], force [N],
    total tangent mesh stiffness dF/d delta [N/m], Hertzian stiffness summed over the pairs in contact
    (secant F_h/delta_h, the paper's Eq. 13) and its tangent [N/m], pairs in contact [-]."""

    phase: Array
    transmission_error: Array
    force: Array
    mesh_stiffness: Array
    hertz_secant: Array
    hertz_tangent: Array
    pairs_in_contact: Array


def mesh_history(model: BenchModel, times, delta) -> MeshHistory:
    """Evaluate the mesh law along a trajectory (``times`` (n_t,), ``delta`` (n_t, 12))."""
    law = model.law
    if not isinstance(law, HertzianMesh):
        raise ValueError("`mesh_history` needs the Hertzian contacts (build(..., contacts='hertz'))")
    times = jnp.asarray(times, jnp.float64)
    phase = jax.vmap(model.phase)(times)
    b = model.system.contact_clearance()
    d = delta - b[None, :]
    st = law.pair_state(d, phase)
    force = law.force(delta, phase, jnp.broadcast_to(b, delta.shape))
    stiff = law.stiffness(delta, phase, jnp.broadcast_to(b, delta.shape))
    return MeshHistory(
        phase,
        d,
        force,
        stiff,
        jnp.sum(st.hertz_secant, -1),
        jnp.sum(st.hertz_tangent, -1),
        jnp.sum(st.in_contact.astype(jnp.int32), -1),
    )


def accelerations(model: BenchModel, times, u, v, force) -> Array:
    """Accelerations [m/s^2] (n_t, 12) from the equation of motion at the saved states:
    ``M a = F(t) - C v - K u - G f``."""
    from .._system import at_time

    s = model.system
    F = jax.vmap(lambda t: at_time(s.load, t))(jnp.asarray(times, jnp.float64))
    C = at_time(s.damping, 0.0)
    K = at_time(s.stiffness, 0.0)
    rhs = F - v @ C.T - u @ K.T - force @ model.directions.T
    return jnp.linalg.solve(s.mass, rhs.T).T


def motor_torque(model: BenchModel, times, u, v) -> Array:
    """Torque of the motor shaft on the reaction sun [N m] (spring + relative damping), (n_t,)."""
    p = model.params
    r = radii(p)
    t = jnp.asarray(times, jnp.float64)
    j = _index("sun", "R")
    spring = p.motor_shaft_stiffness * (model.profile.angle(t) - u[:, j] / r.sun)
    damped = bool(jnp.any(model.system.damping != 0.0))
    beta = rayleigh_coefficients(p)[1] if damped else 0.0
    return spring + beta * p.motor_shaft_stiffness * (model.profile.speed(t) - v[:, j] / r.sun)
