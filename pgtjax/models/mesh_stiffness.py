"""Mesh stiffness of a spur gear pair computed from its geometry.

Source: Hammami et al., *Dynamic behavior of non-linear planetary gear model in non-stationary
conditions*, section 3 and Table 1, Eqs. 1-13, with the corrections of the printed equations stated where
they are used (docs/corrections.md C11-C13). Mesh phasing follows Parker & Lin (2004), *Mesh phasing
relationships in planetary and epicyclic gears*, J. Mech. Des. 126:365-370.

Model, per tooth pair in contact (all quantities SI: m, N, Pa, rad, unless stated):

* tooth bending + shear + compression of each tooth, a segmented cantilever (Cornell 1981; paper
  Eqs. 3-7), obtained from the strain energy of a beam loaded at the point where the line of action
  crosses the tooth centre line;
* fillet-foundation (gear body) flexibility of each tooth (Sainsot et al. 2004; paper Eqs. 8-10,
  polynomial fit of Eq. 9 as corrected (C13));
* nonlinear Hertzian line contact, the Palmgren/Harsha power law (paper Eqs. 11-13). The fit is
  stated in millimetres and newtons: ``F[N] = 56065.703 l[mm]^0.92 delta[mm]^1.08``. Because
  ``0.92 + 1.08 = 2`` the SI form is ``F = 5.6065703e10 N/m^2 * l^0.92 delta^1.08`` with l, delta in
  metres. Eq. 11 is the inverse of Eq. 12 to within the rounding of its exponents (1/0.925 = 1.081,
  0.85/0.925 = 0.919); pgtjax uses Eq. 12 as *the* force law and inverts it exactly;
* the five flexibilities in series (Eq. 1, correction C11).

Pairs in contact carry the same mesh deflection (rigid-body transmission error, no profile errors),
so the mesh stiffness is the sum over pairs and the load shares itself by stiffness.

Conventions
-----------
The *pinion* is the planet (external); the *gear* is the sun (external mesh) or the ring (internal
mesh). Positions along the line of action are the distance ``s`` [m] from the tangent point T1 of
the line of action on the pinion base circle. The *mesh phase* ``lam`` in [0, 1) is the fraction of
a mesh period elapsed since the latest tooth pair entered contact.

Assumptions (the paper is silent):

* standard full-depth teeth without profile shift, zero backlash, tooth thickness p/2 on the pitch
  circle; operating pressure angle = generating pressure angle, standard centre distance;
* below the base circle the external tooth flank is continued radially (the trochoidal fillet is
  not modelled); the beam is clamped at the root circle and runs up to the section through the
  contact point (Eq. 3 stops at the load point on the axis; nearly the same energy for external
  teeth, but ring teeth loaded near their root have their load point below the root circle). Sainsot's
  u_f is then signed (slight extrapolation of the fit);
* Eq. 13 defines K_h as the secant F_h/delta_h; the mesh stiffness uses the tangent dF_h/d delta_h
  = 1.08 F_h/delta_h (the one a Newton/linearized dynamic model needs); both are returned;
* internal (ring) teeth: the flank is the exact internal involute (the tooth is the complement of
  an external tooth space, thicker at its root, which lies at the *larger* radius); the Cornell
  beam is built the same way with the beam axis pointing inwards. Sainsot's fillet formula was fitted
  for external gear bodies with a bore; it is applied to the ring tooth with its own root
  thickness and angle and a documented rim ratio (``hub_ratio_gear``), an approximation;
* the Harsha/Palmgren contact law has no curvature or material term, so it is the same for
  external and internal meshes (only the contact length enters). For reference,
  :func:`equivalent_radius` gives the relative radius of curvature with the internal sign
  (``1/R = 1/R1 - 1/R2``), used by :func:`hertz_half_width`; the stiffness does not use it;
* tooth bending uses the plane-strain modulus ``E/(1-nu^2)`` (wide spur teeth). The paper's Eq. 4,
  ``E(1-nu)/((1+nu)(1-2nu))``, is the constrained (uniaxial-strain) modulus, which would raise the bending
  and axial stiffness terms by 22 % for nu = 0.3; it is available as ``modulus_kind="paper_eq4"``. The fillet term uses
  ``E`` as in Eq. 8.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from functools import partial
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._validate import check_range

Array = jax.Array

__all__ = [
    "SAINSOT_COEFFS",
    "HARSHA_FORCE_COEF_SI",
    "SpurMesh",
    "ContactPath",
    "PairStiffness",
    "MeshState",
    "BackToBackMeshes",
    "effective_modulus",
    "involute",
    "contact_path",
    "contact_radii",
    "tooth_half_angle",
    "load_angle",
    "cornell_beam_compliance",
    "bending_compliance",
    "bending_stiffness",
    "sainsot_coefficients",
    "fillet_compliance",
    "fillet_stiffness",
    "hertz_force",
    "hertz_stiffness",
    "hertz_secant_stiffness",
    "hertz_deflection",
    "hertz_deflection_eq11",
    "equivalent_radius",
    "hertz_half_width",
    "series_stiffness",
    "pair_linear_compliance",
    "pair_stiffness",
    "pair_force",
    "pair_positions",
    "pairs_in_contact",
    "mesh_force",
    "mesh_state",
    "mesh_stiffness",
    "mesh_cycle",
    "periodic_interp",
    "planet_mesh_phases",
    "sun_ring_phase",
    "mesh_frequency",
    "mesh_cycles",
    "mesh_phase",
    "planet_phase_history",
    "mesh_load_from_sun_torque",
    "back_to_back_meshes",
]

# --------------------------------------------------------------------------------------------
# Constants
# --------------------------------------------------------------------------------------------

#: Sainsot et al. (2004) fit, paper Eq. 9 (correction C13); rows L*, M*, P*, Q*; columns A..F of
#: ``X* = A/theta_f^2 + B h_f^2 + C h_f/theta_f + D/theta_f + E h_f + F`` (theta_f in rad).
SAINSOT_COEFFS = np.array(
    [
        [-5.574e-5, -1.9986e-3, -2.3015e-4, 4.7702e-3, 0.0271, 6.8045],
        [60.111e-5, 28.100e-3, -83.431e-4, -9.9256e-3, 0.1624, 0.9086],
        [-50.952e-5, 185.50e-3, 0.0538e-4, 53.300e-3, 0.2895, 0.9236],
        [-6.2042e-5, 9.0889e-3, -4.0964e-4, 7.8297e-3, -0.1472, 0.6904],
    ]
)

#: Eq. 12 coefficient in its native units: F [N] with l, delta in mm.
HARSHA_FORCE_COEF_MM = 56065.703
HARSHA_LENGTH_EXP = 0.92
HARSHA_DEFLECTION_EXP = 1.08
#: Eq. 12 in SI: F [N] = HARSHA_FORCE_COEF_SI * l[m]^0.92 * delta[m]^1.08; unit N/m^2
#: (the mm -> m factor is 1e3^(0.92 + 1.08) = 1e6).
HARSHA_FORCE_COEF_SI = HARSHA_FORCE_COEF_MM * 1.0e6
#: Eq. 11 as printed: delta [mm] = 4.05e-5 F[N]^0.925 / l[mm]^0.85.
HARSHA_COMPLIANCE_COEF_MM = 4.05e-5
HARSHA_FORCE_EXP_EQ11 = 0.925
HARSHA_LENGTH_EXP_EQ11 = 0.85

_N_PAIRS = 3  # static upper bound on pairs in contact (contact ratio < 3 is validated)
_NEWTON_ITERS = 20

_MODULUS_KINDS = ("plane_strain", "plane_stress", "paper_eq4")


# --------------------------------------------------------------------------------------------
# Parameter container and validation
# --------------------------------------------------------------------------------------------


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _f64(x) -> Array:
    return jnp.asarray(x, dtype=jnp.float64)


class SpurMesh(eqx.Module):
    """Geometry and material of one spur gear mesh (pinion = planet, gear = sun or ring).

    Array fields are pytree leaves (differentiable, vmappable); tooth numbers, the internal flag,
    the number of Cornell segments and the modulus choice are static.

    Attributes (SI):
        z_pinion, z_gear: tooth numbers (static ints).
        internal: True for an internal gear (ring-planet mesh), static.
        module: m [m]; pressure_angle: alpha [rad]; face_width: W [m] (also the Hertz contact
        length l_eff); youngs_modulus: E [Pa]; poisson_ratio: nu [-];
        addendum_coef, dedendum_coef: h_a, h_f as multiples of m;
        hub_ratio_pinion, hub_ratio_gear: Sainsot's ratio h_f = r_root/r_bore [-] (for the ring,
        an equivalent rim ratio, see module docstring);
        shear_factor: s_h of Eq. 3 [-] (5/6 for a rectangular section).
    """

    z_pinion: int = eqx.field(static=True)
    z_gear: int = eqx.field(static=True)
    internal: bool = eqx.field(static=True)
    module: Array
    pressure_angle: Array
    face_width: Array
    youngs_modulus: Array
    poisson_ratio: Array
    addendum_coef: Array
    dedendum_coef: Array
    hub_ratio_pinion: Array
    hub_ratio_gear: Array
    shear_factor: Array
    n_segments: int = eqx.field(static=True)
    modulus_kind: str = eqx.field(static=True)

    def __init__(
        self,
        z_pinion: int,
        z_gear: int,
        *,
        internal: bool = False,
        module=4.23e-3,
        pressure_angle=0.4621,
        face_width=0.02,
        youngs_modulus=2.1e11,
        poisson_ratio=0.3,
        addendum_coef=1.0,
        dedendum_coef=1.25,
        hub_ratio_pinion=1.6,
        hub_ratio_gear=1.6,
        shear_factor=5.0 / 6.0,
        n_segments: int = 40,
        modulus_kind: str = "plane_strain",
    ):
        for name, z in (("z_pinion", z_pinion), ("z_gear", z_gear)):
            if isinstance(z, bool) or not isinstance(z, (int, np.integer)) or not 8 <= int(z) <= 1000:
                raise ValueError(f"`{name}` must be an integer in [8, 1000] teeth; got {z!r}")
        if internal and int(z_gear) - int(z_pinion) < 10:
            raise ValueError(
                f"`z_gear` of an internal mesh must exceed `z_pinion` by at least 10 teeth "
                f"(tip interference); got z_gear={z_gear}, z_pinion={z_pinion}"
            )
        if not isinstance(n_segments, (int, np.integer)) or not 4 <= int(n_segments) <= 2000:
            raise ValueError(f"`n_segments` must be an integer in [4, 2000]; got {n_segments!r}")
        if modulus_kind not in _MODULUS_KINDS:
            raise ValueError(f"`modulus_kind` must be one of {_MODULUS_KINDS}; got {modulus_kind!r}")
        check_range(
            "module", module, lo=0.0, hi=0.1, lo_closed=False, unit="m (SI metres, e.g. 4.23e-3 for 4.23 mm)"
        )
        check_range(
            "pressure_angle", pressure_angle, lo=0.17, hi=0.61, lo_closed=False, unit="rad (10 to 35 degrees)"
        )
        check_range("face_width", face_width, lo=0.0, hi=1.0, lo_closed=False, unit="m")
        check_range("youngs_modulus", youngs_modulus, lo=1e9, hi=1e12, lo_closed=False, unit="Pa")
        check_range("poisson_ratio", poisson_ratio, lo=0.0, hi=0.5, lo_closed=False, hi_closed=False, unit="")
        check_range("addendum_coef", addendum_coef, lo=0.0, hi=2.0, lo_closed=False, unit="x module")
        check_range("dedendum_coef", dedendum_coef, lo=0.0, hi=2.5, lo_closed=False, unit="x module")
        if _is_concrete(addendum_coef) and _is_concrete(dedendum_coef):
            if not float(dedendum_coef) > float(addendum_coef):
                raise ValueError(
                    f"`dedendum_coef` must exceed `addendum_coef` (root clearance); "
                    f"got {dedendum_coef!r} <= {addendum_coef!r}"
                )
        check_range(
            "hub_ratio_pinion", hub_ratio_pinion, lo=1.0, hi=10.0, lo_closed=False, unit="(r_root / r_bore)"
        )
        check_range(
            "hub_ratio_gear",
            hub_ratio_gear,
            lo=1.0,
            hi=10.0,
            lo_closed=False,
            unit="(r_root / r_bore, rim ratio for a ring)",
        )
        check_range("shear_factor", shear_factor, lo=0.0, hi=1.0, lo_closed=False, unit="")

        self.z_pinion = int(z_pinion)
        self.z_gear = int(z_gear)
        self.internal = bool(internal)
        self.module = _f64(module)
        self.pressure_angle = _f64(pressure_angle)
        self.face_width = _f64(face_width)
        self.youngs_modulus = _f64(youngs_modulus)
        self.poisson_ratio = _f64(poisson_ratio)
        self.addendum_coef = _f64(addendum_coef)
        self.dedendum_coef = _f64(dedendum_coef)
        self.hub_ratio_pinion = _f64(hub_ratio_pinion)
        self.hub_ratio_gear = _f64(hub_ratio_gear)
        self.shear_factor = _f64(shear_factor)
        self.n_segments = int(n_segments)
        self.modulus_kind = modulus_kind

    def __check_init__(self):
        if not all(_is_concrete(x) for x in jax.tree.leaves(self)):
            return  # built inside a trace (vmap/jit over parameters): geometry checks need values
        path = contact_path(self)
        g = _gear(self, "gear")
        p = _gear(self, "pinion")
        eps = float(path.contact_ratio)
        if not 1.0 < eps < _N_PAIRS:
            raise ValueError(
                f"contact ratio must be in (1, {_N_PAIRS}); got {eps:.4f} for z_pinion={self.z_pinion}, "
                f"z_gear={self.z_gear}, addendum_coef={float(self.addendum_coef)}"
            )
        if float(path.s_start) <= 0.0 or (not self.internal and float(path.s_end) >= float(path.line_length)):
            raise ValueError(
                "the active path of contact leaves the base-circle tangent points (involute interference); "
                "reduce `addendum_coef` or raise `pressure_angle`"
            )
        if self.internal and float(g.r_tip) <= float(g.r_base):
            raise ValueError("internal gear tip circle lies inside its base circle; reduce `addendum_coef`")
        for gear, name in ((p, "pinion"), (g, "gear")):
            if float(tooth_half_angle(gear, gear.r_tip)) <= 0.0:
                raise ValueError(f"{name} teeth are pointed (zero tip thickness); reduce `addendum_coef`")
        r1, r2 = contact_radii(self, jnp.stack([path.s_start, path.s_end]))
        below_gear_root = not self.internal and float(jnp.min(r2)) < float(g.r_root)
        if float(jnp.min(r1)) < float(p.r_root) or below_gear_root:
            raise ValueError("contact reaches below the root circle; reduce `addendum_coef`")


class _Gear(NamedTuple):
    """Per-gear derived geometry (internal helper). sign = +1 external, -1 internal."""

    z: int
    sign: float
    r_pitch: Array
    r_base: Array
    r_tip: Array
    r_root: Array
    pressure_angle: Array
    hub_ratio: Array


def _gear(mesh: SpurMesh, which: str) -> _Gear:
    if which not in ("pinion", "gear"):
        raise ValueError(f"`which` must be 'pinion' or 'gear'; got {which!r}")
    m, a = mesh.module, mesh.pressure_angle
    if which == "pinion":
        z, sign, hub = mesh.z_pinion, 1.0, mesh.hub_ratio_pinion
    else:
        z, sign, hub = mesh.z_gear, (-1.0 if mesh.internal else 1.0), mesh.hub_ratio_gear
    r = 0.5 * m * z
    return _Gear(
        z=z,
        sign=sign,
        r_pitch=r,
        r_base=r * jnp.cos(a),
        r_tip=r + sign * mesh.addendum_coef * m,
        r_root=r - sign * mesh.dedendum_coef * m,
        pressure_angle=a,
        hub_ratio=hub,
    )


def effective_modulus(youngs_modulus, poisson_ratio, kind: str = "plane_strain") -> Array:
    """Modulus used in the tooth beam of Eq. 3 [Pa].

    ``plane_strain``: E/(1-nu^2) (wide tooth, default); ``plane_stress``: E; ``paper_eq4``: the paper's
    Eq. 4, E(1-nu)/((1+nu)(1-2nu)) (constrained modulus, stiffer).
    """
    E, nu = youngs_modulus, poisson_ratio
    if kind == "plane_strain":
        return E / (1.0 - nu**2)
    if kind == "plane_stress":
        return E * jnp.ones_like(nu)
    if kind == "paper_eq4":
        return E * (1.0 - nu) / ((1.0 + nu) * (1.0 - 2.0 * nu))
    raise ValueError(f"`kind` must be one of {_MODULUS_KINDS}; got {kind!r}")


# --------------------------------------------------------------------------------------------
# Involute geometry and path of contact
# --------------------------------------------------------------------------------------------


def involute(angle) -> Array:
    """Involute function inv(a) = tan(a) - a [rad]."""
    return jnp.tan(angle) - angle


def _profile_pressure_angle(r_base, r) -> Array:
    """Pressure angle of the involute at radius r [rad]; 0 at and below the base circle (grad-safe)."""
    above = r > r_base
    ratio = jnp.where(above, r_base / jnp.where(above, r, 1.0), 0.5)
    return jnp.where(above, jnp.arccos(ratio), 0.0)


def tooth_half_angle(gear: _Gear, r) -> Array:
    """Half angular thickness of a tooth at radius r [rad], standard tooth (thickness p/2 at pitch).

    External: psi = pi/(2z) + inv(alpha0) - inv(alpha_r), constant (radial flank) below the base circle.
    Internal: the tooth is the complement of an external space: psi = pi/(2z) - inv(alpha0) + inv(alpha_r).
    """
    a_r = _profile_pressure_angle(gear.r_base, r)
    return jnp.pi / (2.0 * gear.z) + gear.sign * (involute(gear.pressure_angle) - involute(a_r))


def load_angle(gear: _Gear, r) -> Array:
    """Angle beta between the load line and the normal to the tooth centre line [rad] (alpha_m of Eq. 3).

    External tooth: beta = alpha_r - psi; internal tooth: beta = alpha_r + psi. In both cases the load line
    crosses the centre line at distance r_b / cos(beta) from the gear centre, shifted from the contact
    point toward the tooth root.
    """
    return _profile_pressure_angle(gear.r_base, r) - gear.sign * tooth_half_angle(gear, r)


class ContactPath(NamedTuple):
    """Path of contact along the line of action, distances from T1 (pinion base tangent point) [m]."""

    s_start: Array  # start of active contact when the pinion drives (pinion root side)
    s_end: Array  # end of active contact (pinion tip)
    line_length: Array  # |T1 T2| = a sin(alpha) [m]
    base_pitch: Array  # p_b = pi m cos(alpha) [m]
    contact_ratio: Array  # (s_end - s_start) / p_b [-]


@jax.jit
def contact_path(mesh: SpurMesh) -> ContactPath:
    """Active path of contact and contact ratio from the tip circles (standard centre distance).

    External: s in [L - sqrt(ra2^2 - rb2^2), sqrt(ra1^2 - rb1^2)], L = (r1 + r2) sin(alpha).
    Internal: s in [sqrt(ra2^2 - rb2^2) - L, sqrt(ra1^2 - rb1^2)], L = (r2 - r1) sin(alpha).
    """
    p, g = _gear(mesh, "pinion"), _gear(mesh, "gear")
    center = g.r_pitch + g.sign * p.r_pitch
    line = center * jnp.sin(mesh.pressure_angle)
    s_end = jnp.sqrt(p.r_tip**2 - p.r_base**2)
    s_start = g.sign * (line - jnp.sqrt(g.r_tip**2 - g.r_base**2))
    pb = jnp.pi * mesh.module * jnp.cos(mesh.pressure_angle)
    return ContactPath(s_start, s_end, line, pb, (s_end - s_start) / pb)


@jax.jit
def contact_radii(mesh: SpurMesh, s) -> tuple[Array, Array]:
    """Radii [m] of the contact point on pinion and gear at LOA position s [m] (from T1)."""
    p, g = _gear(mesh, "pinion"), _gear(mesh, "gear")
    line = (g.r_pitch + g.sign * p.r_pitch) * jnp.sin(mesh.pressure_angle)
    r1 = jnp.sqrt(p.r_base**2 + s**2)
    r2 = jnp.sqrt(g.r_base**2 + (line - g.sign * s) ** 2)
    return r1, r2


# --------------------------------------------------------------------------------------------
# Tooth bending (Cornell, Eqs. 3-7) and fillet foundation (Sainsot, Eqs. 8-10)
# --------------------------------------------------------------------------------------------


@jax.jit
def cornell_beam_compliance(
    xi, half_thickness, xi_load, beta, face_width, e_beam, shear_modulus, shear_factor
):
    """Compliance [m/N] of a segmented cantilever tooth (paper Eq. 3 divided by F, i.e. 1/Eq. 7).

    Derived from the strain energy of a beam clamped at xi = 0 and loaded at xi_load on its axis by a force
    at angle beta to the axis normal: bending moment F cos(beta)(xi_load - xi), shear F cos(beta), axial
    F sin(beta). Castigliano gives per segment i of width e_i whose far end lies d_i from the load point::

        cos^2(beta) e_i [ (d_i^2 - d_i e_i + e_i^2/3)/(E' I_i) + 1/(s_h G A_i) + tan^2(beta)/(E' A_i) ]

    with the segment's 1/I and 1/A the mean of the values at its ends (Eqs. 5-6). The per-segment
    moment integral is exact for any sign of d_i, so the load point may lie outside the beam.

    Args:
        xi: (n+1,) node positions along the tooth axis from the root [m], increasing, up to the section
            through the contact point.
        half_thickness: (n+1,) half tooth thickness at the nodes [m].
        xi_load: load point on the axis [m]. beta: load angle [rad]. face_width [m].
        e_beam: beam modulus E' [Pa]. shear_modulus: G [Pa]. shear_factor: s_h [-].
    """
    h = 2.0 * half_thickness
    inv_i = 12.0 / (face_width * h**3)
    inv_a = 1.0 / (face_width * h)
    inv_i_bar = 0.5 * (inv_i[:-1] + inv_i[1:])
    inv_a_bar = 0.5 * (inv_a[:-1] + inv_a[1:])
    e = xi[1:] - xi[:-1]
    d = xi_load - xi[:-1]
    bend = (d**2 - d * e + e**2 / 3.0) * inv_i_bar / e_beam
    shear = inv_a_bar / (shear_factor * shear_modulus)
    axial = jnp.tan(beta) ** 2 * inv_a_bar / e_beam
    return jnp.cos(beta) ** 2 * jnp.sum(e * (bend + shear + axial))


def _tooth_load_geometry(gear: _Gear, r):
    """Load angle, load point and root data of a tooth contacted at radius r (internal helper)."""
    beta = load_angle(gear, r)
    d_load = gear.r_base / jnp.cos(beta)  # distance gear centre -> load line x tooth axis
    psi_root = tooth_half_angle(gear, gear.r_root)
    x_root = gear.r_root * jnp.cos(psi_root)
    xi_load = gear.sign * (d_load - x_root)  # may be < 0 for ring teeth loaded near the root
    return beta, d_load, psi_root, x_root, xi_load


def _tooth_bending_compliance(mesh: SpurMesh, gear: _Gear, r) -> Array:
    beta, _, _, x_root, xi_load = _tooth_load_geometry(gear, r)
    # The loaded part of the tooth runs from the root circle to the section through the contact point.
    # Eq. 3 stops its segments at the load point on the axis; integrating the same strain energy up to
    # the contact section differs little for external teeth, but is required for ring teeth, whose load
    # line can cross the axis below the root circle (moment arm changing sign along the tooth).
    t = jnp.linspace(0.0, 1.0, mesh.n_segments + 1)
    r_nodes = gear.r_root + (r - gear.r_root) * t
    psi = tooth_half_angle(gear, r_nodes)
    xi = gear.sign * (r_nodes * jnp.cos(psi) - x_root)
    y = r_nodes * jnp.sin(psi)
    e_beam = effective_modulus(mesh.youngs_modulus, mesh.poisson_ratio, mesh.modulus_kind)
    shear_mod = mesh.youngs_modulus / (2.0 * (1.0 + mesh.poisson_ratio))
    return cornell_beam_compliance(
        xi, y, xi_load, beta, mesh.face_width, e_beam, shear_mod, mesh.shear_factor
    )


@jax.jit
def sainsot_coefficients(hub_ratio, theta_f) -> Array:
    """(L*, M*, P*, Q*) of Sainsot et al. 2004 (paper Eq. 9, correction C13); theta_f in rad. Shape (4,)."""
    basis = jnp.stack(
        [
            1.0 / theta_f**2,
            hub_ratio**2,
            hub_ratio / theta_f,
            1.0 / theta_f,
            hub_ratio,
            jnp.ones_like(theta_f),
        ]
    )
    return jnp.asarray(SAINSOT_COEFFS) @ basis


def _tooth_fillet_compliance(mesh: SpurMesh, gear: _Gear, r) -> Array:
    beta, _, psi_root, _, u_f = _tooth_load_geometry(gear, r)
    s_f = 2.0 * gear.r_root * jnp.sin(psi_root)  # root chord thickness S_f
    lstar, mstar, pstar, qstar = sainsot_coefficients(gear.hub_ratio, psi_root)
    ratio = u_f / s_f
    bracket = lstar * ratio**2 + mstar * ratio + pstar * (1.0 + qstar * jnp.tan(beta) ** 2)
    return jnp.cos(beta) ** 2 / (mesh.face_width * mesh.youngs_modulus) * bracket


@partial(jax.jit, static_argnames=("which",))
def bending_compliance(mesh: SpurMesh, s, which: str) -> Array:
    """Bending + shear + axial compliance [m/N] of one tooth (Eqs. 3-6) at LOA position s [m].

    ``which`` is 'pinion' or 'gear'. The load is the normal force along the line of action.
    """
    r1, r2 = contact_radii(mesh, s)
    gear = _gear(mesh, which)
    r = r1 if which == "pinion" else r2
    return _tooth_bending_compliance(mesh, gear, r)


def bending_stiffness(mesh: SpurMesh, s, which: str) -> Array:
    """Tooth bending stiffness K_b = F/delta_b [N/m] (Eq. 7) at LOA position s [m]."""
    return 1.0 / bending_compliance(mesh, s, which)


@partial(jax.jit, static_argnames=("which",))
def fillet_compliance(mesh: SpurMesh, s, which: str) -> Array:
    """Fillet-foundation compliance [m/N] of one tooth (Eq. 8) at LOA position s [m].

    delta_f/F = cos^2(beta)/(W E) [L* (u_f/S_f)^2 + M* (u_f/S_f) + P*(1 + Q* tan^2 beta)], with u_f the
    distance from the root circle to the load point along the tooth axis, S_f the root chord thickness,
    theta_f the tooth half angle at the root circle [rad] and h_f the hub ratio.
    """
    r1, r2 = contact_radii(mesh, s)
    gear = _gear(mesh, which)
    r = r1 if which == "pinion" else r2
    return _tooth_fillet_compliance(mesh, gear, r)


def fillet_stiffness(mesh: SpurMesh, s, which: str) -> Array:
    """Fillet-foundation stiffness K_f = F/delta_f [N/m] (Eq. 10) at LOA position s [m]."""
    return 1.0 / fillet_compliance(mesh, s, which)


# --------------------------------------------------------------------------------------------
# Hertzian contact (Eqs. 11-13)
# --------------------------------------------------------------------------------------------


@jax.jit
def hertz_force(delta, length) -> Array:
    """Contact force F_h [N] at contact deflection delta [m] over contact length l [m] (Eq. 12, SI).

    F_h = 5.6065703e10 l^0.92 delta^1.08 for delta > 0, zero otherwise (loss of contact).
    """
    pos = delta > 0.0
    dp = jnp.where(pos, delta, 1.0)
    f = HARSHA_FORCE_COEF_SI * length**HARSHA_LENGTH_EXP * dp**HARSHA_DEFLECTION_EXP
    return jnp.where(pos, f, 0.0)


@jax.jit
def hertz_stiffness(delta, length) -> Array:
    """Tangent Hertzian stiffness dF_h/d delta [N/m] (derivative of Eq. 12): 1.08 F_h/delta."""
    pos = delta > 0.0
    dp = jnp.where(pos, delta, 1.0)
    k = (
        HARSHA_DEFLECTION_EXP
        * HARSHA_FORCE_COEF_SI
        * length**HARSHA_LENGTH_EXP
        * dp ** (HARSHA_DEFLECTION_EXP - 1.0)
    )
    return jnp.where(pos, k, 0.0)


@jax.jit
def hertz_secant_stiffness(delta, length) -> Array:
    """Secant Hertzian stiffness F_h/delta [N/m], the paper's Eq. 13 definition of K_h."""
    return hertz_stiffness(delta, length) / HARSHA_DEFLECTION_EXP


@jax.jit
def hertz_deflection(force, length) -> Array:
    """Contact deflection [m] under force F [N] over length l [m]: exact inverse of Eq. 12."""
    pos = force > 0.0
    fp = jnp.where(pos, force, 1.0)
    d = (fp / (HARSHA_FORCE_COEF_SI * length**HARSHA_LENGTH_EXP)) ** (1.0 / HARSHA_DEFLECTION_EXP)
    return jnp.where(pos, d, 0.0)


@jax.jit
def hertz_deflection_eq11(force, length) -> Array:
    """Contact deflection [m] from Eq. 11 as printed (mm/N fit), for comparison with Eq. 12."""
    pos = force > 0.0
    fp = jnp.where(pos, force, 1.0)
    d_mm = HARSHA_COMPLIANCE_COEF_MM * fp**HARSHA_FORCE_EXP_EQ11 / (length * 1e3) ** HARSHA_LENGTH_EXP_EQ11
    return jnp.where(pos, d_mm * 1e-3, 0.0)


@jax.jit
def equivalent_radius(mesh: SpurMesh, s) -> Array:
    """Relative radius of curvature [m] of the flanks at LOA position s: 1/R = 1/rho1 + sign/rho2.

    rho are the involute radii of curvature (distances to the tangent points). For an internal gear the
    ring flank is concave, sign = -1. Not used by the Harsha stiffness law (which has no curvature term).
    """
    g = _gear(mesh, "gear")
    path = contact_path(mesh)
    rho1 = s
    rho2 = path.line_length - g.sign * s
    return 1.0 / (1.0 / rho1 + g.sign / rho2)


@jax.jit
def hertz_half_width(mesh: SpurMesh, s, force) -> Array:
    """Classical Hertz half contact width b [m] = sqrt(4 F R / (pi W E*)), E* = E/(2(1-nu^2))."""
    e_star = mesh.youngs_modulus / (2.0 * (1.0 - mesh.poisson_ratio**2))
    return jnp.sqrt(4.0 * force * equivalent_radius(mesh, s) / (jnp.pi * mesh.face_width * e_star))


# --------------------------------------------------------------------------------------------
# Tooth pair (Eq. 1) and mesh (sum over pairs)
# --------------------------------------------------------------------------------------------


def series_stiffness(*stiffnesses) -> Array:
    """Series combination 1/K = sum 1/K_i [N/m] (Eq. 1)."""
    return 1.0 / sum(1.0 / k for k in stiffnesses)


def _tooth_pair_compliances(mesh: SpurMesh, s) -> tuple[Array, Array]:
    """Bending and fillet compliances [m/N] of (pinion, gear) teeth at LOA position s, shapes (2,).

    The two teeth are evaluated in one vectorized pass (half the traced program of two calls).
    """
    r = jnp.stack(contact_radii(mesh, s))
    p, g = _gear(mesh, "pinion"), _gear(mesh, "gear")
    both = jax.tree.map(lambda a, b: jnp.stack([_f64(a), _f64(b)]), p, g)
    return jax.vmap(
        lambda gear, rr: (_tooth_bending_compliance(mesh, gear, rr), _tooth_fillet_compliance(mesh, gear, rr))
    )(both, r)


@jax.jit
def pair_linear_compliance(mesh: SpurMesh, s) -> Array:
    """Load-independent part of a pair's compliance [m/N]: 1/K_b + 1/K_f of pinion and gear (Eq. 1)."""
    cb, cf = _tooth_pair_compliances(mesh, s)
    return jnp.sum(cb) + jnp.sum(cf)


class PairStiffness(NamedTuple):
    """Stiffness components of one tooth pair under a load [N/m] (Eq. 1 with tangent Hertz)."""

    bending_pinion: Array
    fillet_pinion: Array
    bending_gear: Array
    fillet_gear: Array
    hertz: Array  # tangent dF_h/d delta_h
    hertz_secant: Array  # F_h/delta_h, paper Eq. 13
    total: Array  # series of the five (tangent Hertz): dF/d delta of the pair
    hertz_deflection: Array  # [m]


@jax.jit
def pair_stiffness(mesh: SpurMesh, s, load) -> PairStiffness:
    """All stiffness components of one pair at LOA position s [m] carrying normal load F [N] (Eqs. 1-13)."""
    cb, cf = _tooth_pair_compliances(mesh, s)
    kb1, kb2 = 1.0 / cb[0], 1.0 / cb[1]
    kf1, kf2 = 1.0 / cf[0], 1.0 / cf[1]
    dh = hertz_deflection(load, mesh.face_width)
    kh = hertz_stiffness(dh, mesh.face_width)
    return PairStiffness(
        kb1,
        kf1,
        kb2,
        kf2,
        kh,
        hertz_secant_stiffness(dh, mesh.face_width),
        series_stiffness(kb1, kf1, kb2, kf2, kh),
        dh,
    )


def _newton_root(fun, slope, x0) -> Array:
    """Scalar root of an increasing convex ``fun`` by Newton from x0 > root (monotone convergence).

    ``slope`` is the derivative of ``fun`` (closed form, so the iteration itself is not differentiated).
    Differentiated implicitly (``lax.custom_root``): gradients do not unroll the iterations.
    """

    def solve(f, x_init):
        return jax.lax.fori_loop(0, _NEWTON_ITERS, lambda _, x: x - f(x) / slope(x), x_init)

    def tangent_solve(g, y):
        return y / g(jnp.ones_like(y))

    return jax.lax.custom_root(fun, x0, solve, tangent_solve)


def _pair_hertz_deflection(compliance, coef, delta) -> Array:
    """Solve delta_h + c F_h(delta_h) = delta for delta_h >= 0 (convex, increasing; Newton from delta)."""
    pos = delta > 0.0
    dp = jnp.where(pos, delta, 1.0)
    p = HARSHA_DEFLECTION_EXP
    x = _newton_root(
        lambda x: x + compliance * coef * x**p - dp,
        lambda x: 1.0 + compliance * coef * p * x ** (p - 1.0),
        dp,
    )
    return jnp.where(pos, x, 0.0)


@jax.jit
def pair_force(mesh: SpurMesh, s, delta) -> Array:
    """Normal force [N] of one pair at LOA position s [m] for mesh deflection delta [m] (0 if delta <= 0)."""
    coef = HARSHA_FORCE_COEF_SI * mesh.face_width**HARSHA_LENGTH_EXP
    dh = _pair_hertz_deflection(pair_linear_compliance(mesh, s), coef, delta)
    return hertz_force(dh, mesh.face_width)


def pair_positions(mesh: SpurMesh, phase, pinion_drives: bool = True) -> tuple[Array, Array]:
    """LOA positions s_k [m] of up to 3 consecutive pairs at mesh phase lam, and contact mask.

    Pinion driving: contact enters at s_start and moves toward s_end, s_k = s_start + (lam + k) p_b.
    Gear driving: contact enters at s_end and moves back; the set of positions equals the former at
    lam' = frac(eps - lam). Pairs outside [s_start, s_end] are clipped and flagged False.
    """
    path = contact_path(mesh)
    lam = jnp.mod(phase, 1.0)
    if not pinion_drives:
        lam = jnp.mod(path.contact_ratio - lam, 1.0)
    k = jnp.arange(_N_PAIRS, dtype=jnp.float64)
    s = path.s_start + (lam + k) * path.base_pitch
    in_contact = s <= path.s_end
    return jnp.minimum(s, path.s_end), in_contact


@partial(jax.jit, static_argnames=("pinion_drives",))
def pairs_in_contact(mesh: SpurMesh, phase, pinion_drives: bool = True) -> Array:
    """Number of tooth pairs in contact at mesh phase lam (int)."""
    return jnp.sum(pair_positions(mesh, phase, pinion_drives)[1].astype(jnp.int32))


@partial(jax.jit, static_argnames=("pinion_drives",))
def mesh_force(mesh: SpurMesh, phase, delta, pinion_drives: bool = True) -> Array:
    """Total mesh force [N] at mesh phase lam and mesh deflection delta [m] along the line of action."""
    s, on = pair_positions(mesh, phase, pinion_drives)
    f = jax.vmap(lambda sk: pair_force(mesh, sk, delta))(s)
    return jnp.sum(jnp.where(on, f, 0.0))


class MeshState(NamedTuple):
    """Quasi-static state of a mesh under a total normal load (arrays over the 3 candidate pairs)."""

    stiffness: Array  # total tangent mesh stiffness dF/d delta [N/m]
    deflection: Array  # mesh deflection delta [m]
    hertz_stiffness: Array  # sum over pairs in contact of tangent K_h [N/m]
    hertz_secant_stiffness: Array  # sum over pairs in contact of F_h/delta_h (Eq. 13) [N/m]
    n_contact: Array  # pairs in contact
    positions: Array  # (3,) LOA positions [m]
    in_contact: Array  # (3,) bool
    pair_loads: Array  # (3,) [N]
    pair_stiffness: Array  # (3,) tangent series stiffness per pair [N/m]
    pair_hertz_stiffness: Array  # (3,) tangent K_h per pair [N/m]


@partial(jax.jit, static_argnames=("pinion_drives",))
def mesh_state(mesh: SpurMesh, phase, load, pinion_drives: bool = True) -> MeshState:
    """Load sharing and mesh stiffness at mesh phase lam under total normal load F [N] (must be > 0).

    All pairs in contact share one deflection delta; delta solves sum_k F_k(delta) = F (Newton from
    the right on a convex increasing function, started from pair 0 carrying the whole load, so the
    iteration is monotone). Each F_k(delta) solves delta = c_k F + delta_h(F) (Eq. 1 in series form).
    """
    s, on = pair_positions(mesh, phase, pinion_drives)
    comp = jax.vmap(lambda sk: pair_linear_compliance(mesh, sk))(s)
    coef = HARSHA_FORCE_COEF_SI * mesh.face_width**HARSHA_LENGTH_EXP
    p = HARSHA_DEFLECTION_EXP
    load = jnp.asarray(load, dtype=jnp.float64)

    def pair_response(delta):
        dh = jax.vmap(lambda c: _pair_hertz_deflection(c, coef, delta))(comp)
        f = jnp.where(on, coef * dh**p, 0.0)
        kh = coef * p * jnp.where(dh > 0.0, dh, 1.0) ** (p - 1.0)
        k = jnp.where(on & (dh > 0.0), 1.0 / (comp + 1.0 / kh), 0.0)
        return dh, f, k, kh

    delta0 = comp[0] * load + hertz_deflection(load, mesh.face_width)
    delta = _newton_root(
        lambda d: jnp.sum(pair_response(d)[1]) - load,
        lambda d: jnp.sum(jax.lax.stop_gradient(pair_response(d)[2])),
        delta0,
    )
    dh, f, k, kh = pair_response(delta)
    kh_on = jnp.where(on, kh, 0.0)
    return MeshState(
        stiffness=jnp.sum(k),
        deflection=delta,
        hertz_stiffness=jnp.sum(kh_on),
        hertz_secant_stiffness=jnp.sum(kh_on) / p,
        n_contact=jnp.sum(on.astype(jnp.int32)),
        positions=s,
        in_contact=on,
        pair_loads=f,
        pair_stiffness=k,
        pair_hertz_stiffness=kh_on,
    )


def mesh_stiffness(mesh: SpurMesh, phase, load, pinion_drives: bool = True) -> Array:
    """Total tangent mesh stiffness [N/m] at mesh phase lam under total normal load F [N]."""
    return mesh_state(mesh, phase, load, pinion_drives).stiffness


@partial(jax.jit, static_argnames=("n_points", "pinion_drives"))
def mesh_cycle(mesh: SpurMesh, load, n_points: int = 256, pinion_drives: bool = True):
    """(phases, MeshState) over one mesh period, phases = arange(n)/n (periodic grid)."""
    phases = jnp.arange(n_points, dtype=jnp.float64) / n_points
    return phases, jax.vmap(lambda lam: mesh_state(mesh, lam, load, pinion_drives))(phases)


def periodic_interp(table, phase) -> Array:
    """Linear interpolation at ``phase`` (any shape) of a 1-periodic table sampled on arange(n)/n."""
    table = jnp.asarray(table)
    n = table.shape[0]
    x = jnp.mod(phase, 1.0) * n
    i0 = jnp.floor(x).astype(jnp.int32) % n
    w = x - jnp.floor(x)
    return (1.0 - w) * table[i0] + w * table[(i0 + 1) % n]


# --------------------------------------------------------------------------------------------
# Planetary mesh phasing (Parker & Lin 2004) and non-stationary mesh phase
# --------------------------------------------------------------------------------------------


@partial(jax.jit, static_argnames=("z_sun", "z_ring"))
def planet_mesh_phases(z_sun: int, z_ring: int, planet_angles) -> tuple[Array, Array]:
    """Mesh phases of planet n relative to planet 1 (Parker & Lin 2004), fractions in [0, 1).

    gamma_sn = frac(Z_s psi_n / 2 pi), gamma_rn = frac(-Z_r psi_n / 2 pi), with psi_n the planet angle
    [rad] measured in the direction of the sun's rotation relative to the carrier, psi_1 = 0. Meaning:
    k_sn(t) = k_s1(t - gamma_sn T_m), k_rn(t) = k_r1(t - gamma_rn T_m), i.e. mesh phase lam_n = lam_1 - gamma.
    """
    psi = jnp.asarray(planet_angles, dtype=jnp.float64)
    return jnp.mod(z_sun * psi / (2.0 * jnp.pi), 1.0), jnp.mod(-z_ring * psi / (2.0 * jnp.pi), 1.0)


@jax.jit
def sun_ring_phase(sun_mesh: SpurMesh, ring_mesh: SpurMesh) -> Array:
    """Phase gamma_rs of a planet's ring mesh relative to its sun mesh, fraction in [0, 1).

    lam_ring(t) = lam_sun(t) + gamma_rs, for torque flowing sun -> planet -> ring (sun mesh: planet driven,
    contact enters at the planet tip; ring mesh: planet driving, contact enters near the planet root).
    Derived from the involute flanks of the planet (the two meshes load opposite flanks; sun and ring pitch
    points are diametrically opposite on the planet); it reproduces Parker & Lin (2004)::

        gamma_rs = [r_bp (alpha_s + alpha_r) + t_b - s_A,r - s_A,s] / p_b - Z_p/2   (mod 1)

    with t_b the planet base-circle tooth thickness, s_A,s = |T_s A_s| (planet tip) and s_A,r = |T_r A_r|,
    both measured from the planet's base tangent points. With equal pressure angles and standard teeth it
    reduces to (|A_r P_r| - |P_s A_s|)/p_b + (1 - Z_p)/2 (mod 1): the Z_p parity enters.
    """
    if sun_mesh.internal or not ring_mesh.internal:
        raise ValueError("`sun_mesh` must be external and `ring_mesh` internal")
    if sun_mesh.z_pinion != ring_mesh.z_pinion:
        raise ValueError("`sun_mesh` and `ring_mesh` must share the planet (`z_pinion`)")
    p = _gear(sun_mesh, "pinion")
    ps, pr = contact_path(sun_mesh), contact_path(ring_mesh)
    psi_b = jnp.pi / (2.0 * p.z) + involute(p.pressure_angle)
    angles = sun_mesh.pressure_angle + ring_mesh.pressure_angle + 2.0 * psi_b
    num = p.r_base * angles - pr.s_start - ps.s_end
    return jnp.mod(num / ps.base_pitch - 0.5 * p.z, 1.0)


def mesh_frequency(z_sun: int, z_ring: int, *, carrier_freq=None, sun_freq=None, ring_freq=0.0) -> Array:
    """Mesh frequency [Hz] of a planetary stage (Eq. 2, correction C12).

    f_m = Z_r (f_c - f_r) = Z_s (f_s - f_c). With a fixed ring, f_m = Z_r f_c = Z_r Z_s/(Z_r + Z_s) f_s.
    Give ``carrier_freq`` or ``sun_freq`` [Hz] (arrays allowed); ``ring_freq`` defaults to 0 (fixed ring).
    """
    if carrier_freq is None and sun_freq is None:
        raise ValueError("give `carrier_freq` or `sun_freq`")
    if carrier_freq is None:
        carrier_freq = (z_sun * jnp.asarray(sun_freq) + z_ring * jnp.asarray(ring_freq)) / (z_sun + z_ring)
    return z_ring * (jnp.asarray(carrier_freq, dtype=jnp.float64) - ring_freq)


@jax.jit
def mesh_cycles(times, mesh_freq, cycles0=0.0) -> Array:
    """Mesh cycles elapsed [-], the integral of the instantaneous mesh frequency (cumulative trapezoid).

    times: (n,) increasing [s]; mesh_freq: (n,) [Hz]. Non-stationary regimes: the mesh period shortens
    as speed rises because the phase advances faster, not because a period is rescaled.
    """
    t = jnp.asarray(times, dtype=jnp.float64)
    f = jnp.asarray(mesh_freq, dtype=jnp.float64)
    inc = 0.5 * (f[1:] + f[:-1]) * (t[1:] - t[:-1])
    return cycles0 + jnp.concatenate([jnp.zeros((1,), jnp.float64), jnp.cumsum(inc)])


@jax.jit
def mesh_phase(times, mesh_freq, phase0=0.0) -> Array:
    """Mesh phase lam(t) in [0, 1): frac(phase0 + integral of f_m dt)."""
    return jnp.mod(mesh_cycles(times, mesh_freq, phase0), 1.0)


def planet_phase_history(
    times, carrier_freq, sun_mesh: SpurMesh, ring_mesh: SpurMesh, planet_angles, ring_freq=0.0, phase0=0.0
) -> tuple[Array, Array]:
    """Mesh phases of every planet's sun and ring meshes over a speed history, each (n_t, N).

    lam_sn(t) = frac(c(t) - gamma_sn), lam_rn(t) = frac(c(t) - gamma_rn + gamma_rs), where c(t) is the
    integral of the mesh frequency (cumulative trapezoid over ``times`` [s] of ``carrier_freq`` [Hz]),
    gamma_sn, gamma_rn from :func:`planet_mesh_phases` and gamma_rs from :func:`sun_ring_phase`. Evaluate
    the stiffness with ``periodic_interp(table, lam)`` of a :func:`mesh_cycle` table. Assumes the sun turns
    in the positive direction relative to the carrier (positive mesh frequency).
    """
    fm = mesh_frequency(sun_mesh.z_gear, ring_mesh.z_gear, carrier_freq=carrier_freq, ring_freq=ring_freq)
    cyc = mesh_cycles(times, fm, phase0)
    gs, gr = planet_mesh_phases(sun_mesh.z_gear, ring_mesh.z_gear, planet_angles)
    grs = sun_ring_phase(sun_mesh, ring_mesh)
    lam_s = jnp.mod(cyc[:, None] - gs[None, :], 1.0)
    lam_r = jnp.mod(cyc[:, None] - gr[None, :] + grs, 1.0)
    return lam_s, lam_r


def mesh_load_from_sun_torque(sun_mesh: SpurMesh, sun_torque, n_planets: int) -> Array:
    """Normal load per sun-planet mesh [N] = T_s / (N r_b,sun), equal load sharing between planets.

    By the planet's moment balance the ring-planet mesh carries the same normal load.
    """
    return sun_torque / (n_planets * _gear(sun_mesh, "gear").r_base)


# --------------------------------------------------------------------------------------------
# Default parameter set (paper Table 1)
# --------------------------------------------------------------------------------------------


class BackToBackMeshes(NamedTuple):
    """Meshes and operating data of one stage of the back-to-back bench (paper Table 1)."""

    sun_planet: SpurMesh
    ring_planet: SpurMesh
    n_planets: int
    planet_angles: Array  # [rad]
    sun_torque: Array  # nominal sun torque [N m] (assumed)
    mesh_load: Array  # nominal normal load per mesh [N]


def back_to_back_meshes(data: Mapping, **overrides) -> BackToBackMeshes:
    """Sun-planet and ring-planet meshes of the bench from its parameter tables (the dict
    :func:`pgtjax.params.read_toml` returns for a file laid out as ``back_to_back.toml``; the bench model's
    ``load_params`` is the one place that reads that file).

    ``overrides`` replace entries of the [mesh] table (e.g. ``face_width=0.025``).
    """
    if not isinstance(data, Mapping):
        raise ValueError(
            f"`data` must be the parameter tables as a dict (pgtjax.params.read_toml(path)), got {data!r}"
        )
    g = data["gears"]
    mesh_kw = dict(data["mesh"])
    mesh_kw.update(overrides)
    hub_sun = mesh_kw.pop("hub_ratio_sun")
    hub_planet = mesh_kw.pop("hub_ratio_planet")
    hub_ring = mesh_kw.pop("rim_ratio_ring")
    common = dict(module=g["module_mm"] * 1e-3, pressure_angle=g["pressure_angle_rad"], **mesh_kw)
    sp = SpurMesh(
        g["z_planet"],
        g["z_sun"],
        internal=False,
        hub_ratio_pinion=hub_planet,
        hub_ratio_gear=hub_sun,
        **common,
    )
    rp = SpurMesh(
        g["z_planet"],
        g["z_ring"],
        internal=True,
        hub_ratio_pinion=hub_planet,
        hub_ratio_gear=hub_ring,
        **common,
    )
    op = data["operating"]
    n = int(g["n_planets"])
    angles = jnp.asarray([2.0 * math.pi * i / n for i in range(n)], dtype=jnp.float64)
    torque = _f64(op["sun_torque_Nm"])
    return BackToBackMeshes(sp, rp, n, angles, torque, mesh_load_from_sun_torque(sp, torque, n))
