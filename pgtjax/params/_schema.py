"""Schemas of the parameter files: every table's keys with type, unit, accepted range and source.

A file is checked against its schema before any model is built (:func:`pgtjax.params.read_params`): an
unknown key (with the nearest known one suggested), a missing key, a value of the wrong type (``21.7`` for a
tooth count, ``"twenty"`` for an angle), a value out of range or an inconsistent combination is a
``ValueError`` naming ``table.key``. The schemas are pydantic models (strict: no silent conversions, no NaN or
infinity); :func:`reference` writes them out as the parameter reference of ``docs/parameters.md``.
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Mapping
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator


class _Table(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


def _q(unit: str, doc: str, default: Any = ..., **bounds) -> Any:
    """A field with its unit and description (and ``gt``/``ge``/``lt``/``le`` bounds)."""
    return Field(default, description=doc, json_schema_extra={"unit": unit}, **bounds)


def _number_or_list(value, unit: str):
    """A bolt stiffness: one number >= 0 for every bolt, or a list with one per bolt (length checked by the
    file's model validator)."""
    items = value if isinstance(value, list) else [value]
    if not items or not all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v >= 0 for v in items
    ):
        raise ValueError(
            f"must be a finite number >= 0 {unit} or a list of them (one per bolt), got {value!r}"
        )
    return value


# ------------------------------------------------------------------------------------ planetary (ch. 3)


class _PlanetarySun(_Table):
    teeth: int = _q("", "number of teeth Z_s (Table 3.1)", ge=3)
    mass: float = _q("kg", "mass m_s (Table 3.1)", gt=0)
    inertia: float = _q("kg m^2", "polar moment of inertia I_s (Table 3.1)", gt=0)
    pitch_diameter: float = _q("m", "pitch diameter (Table 3.1)", gt=0)
    bearing_stiffness: float = _q("N/m", "bearing stiffness k_s (Table 3.1: 100 N/m, a floating sun)", ge=0)
    torsional_stiffness: float = _q("N m/rad", "output-shaft torsional stiffness (Table 3.1)", ge=0)


class _PlanetaryPlanet(_Table):
    teeth: int = _q("", "number of teeth Z_p (Table 3.1)", ge=3)
    mass: float = _q("kg", "mass m_p (Table 3.1)", gt=0)
    inertia: float = _q("kg m^2", "polar moment of inertia I_p (Table 3.1)", gt=0)
    pitch_diameter: float = _q("m", "pitch diameter (Table 3.1)", gt=0)
    bearing_stiffness: float = _q("N/m", "planet bearing stiffness k_p (Table 3.1)", gt=0)


class _PlanetaryCarrier(_Table):
    mass: float = _q("kg", "mass m_c (Table 3.1)", gt=0)
    inertia: float = _q("kg m^2", "polar moment of inertia I_c (Table 3.1)", gt=0)
    bearing_stiffness: float = _q("N/m", "bearing stiffness k_c (Table 3.1)", ge=0)
    torsional_stiffness: float = _q(
        "N m/rad", "torsional stiffness (0: the carrier is driven by the rotor's wind torque)", 0.0, ge=0
    )


class _PlanetaryRing(_Table):
    teeth: int = _q("", "number of teeth Z_r (Table 3.1); sets the mesh frequency Z_r omega_c", ge=3)
    pitch_diameter: float = _q("m", "pitch diameter (Table 3.1)", gt=0)
    rim_thickness: float = _q("m", "rim thickness h (thesis studies 87 / 128 / 168 mm; ASSUMED 128 mm)", gt=0)
    face_width: float = _q("m", "face width (ASSUMED: Table 3.2 gives none)", gt=0)
    youngs_modulus: float = _q("Pa", "Young's modulus E (Table 3.2)", gt=0)
    density: float = _q("kg/m^3", "density (Table 3.2)", gt=0)
    n_elements: int = _q("", "curved-beam elements of the elastic ring (thesis Sec. 3.7: 18)", ge=3)
    n_supports: int = _q("", "equally spaced bolts, the first at node 0; must divide n_elements", ge=0)
    support_radial: Any = _q(
        "N/m", "radial stiffness k_r of each bolt: one number or one per bolt (Table 3.2)"
    )
    support_tangential: Any = _q(
        "N/m", "tangential stiffness k_tau of each bolt: one number or one per bolt (Table 3.2)"
    )
    support_torsional: Any = _q(
        "N m/rad", "torsional stiffness k_theta of each bolt: one number or one per bolt (Table 3.2)"
    )
    rigid_mass: float = _q("kg", "mass of the lumped ring body (ring_model = 'rigid'; ASSUMED)", gt=0)
    rigid_inertia: float = _q("kg m^2", "inertia of the lumped ring body (rigid ring; ASSUMED)", gt=0)
    rigid_bearing_stiffness: float = _q(
        "N/m", "support stiffness of the lumped ring (rigid ring; ASSUMED)", ge=0
    )
    rigid_torsional_stiffness: float = _q(
        "N m/rad", "torsional support stiffness of the lumped ring (rigid ring; ASSUMED)", ge=0
    )

    @field_validator("support_radial", "support_tangential")
    @classmethod
    def _per_bolt_force(cls, value):
        return _number_or_list(value, "N/m")

    @field_validator("support_torsional")
    @classmethod
    def _per_bolt_moment(cls, value):
        return _number_or_list(value, "N m/rad")


class _PlanetaryMesh(_Table):
    sun_planet_stiffness: float = _q("N/m", "mean sun-planet mesh stiffness (Table 3.2)", gt=0)
    ring_planet_stiffness: float = _q("N/m", "mean ring-planet mesh stiffness (Table 3.2)", gt=0)
    pressure_angle_deg: float = _q("deg", "pressure angle alpha_s = alpha_r (Table 3.2)", gt=0, lt=45)
    half_backlash: float = _q("m", "half backlash b of every mesh (Table 3.2)", ge=0)
    contact_ratio_sun: float = _q("", "sun-planet contact ratio c_s (Table 3.2)", ge=1, le=2)
    contact_ratio_ring: float = _q("", "ring-planet contact ratio c_r (Table 3.2)", ge=1, le=2)
    phase_sun_ring: float = _q(
        "mesh periods", "phase Omega_sr between sun and ring meshes (Table 3.2)", ge=-1, le=1
    )
    stiffness_variation: float = _q(
        "", "(double-tooth - single-tooth stiffness) / mean stiffness (ASSUMED 0.2)", ge=0, lt=1
    )
    harmonics: int = _q("", "Fourier terms of the rectangular mesh-stiffness wave", ge=0)
    carrier_speed: float = _q("rad/s", "carrier speed omega_c (Table 3.2)", gt=0)


class _PlanetaryWind(_Table):
    air_density: float = _q("kg/m^3", "air density (ASSUMED standard air)", gt=0)
    rotor_radius: float = _q("m", "rotor radius (ASSUMED: NREL GRC 750 kW turbine)", gt=0)
    power_coefficient: float = _q("", "rotor power coefficient (ASSUMED; Betz limit 16/27)", gt=0, le=16 / 27)
    mean_wind_speed: float = _q("m/s", "mean wind speed V0 (thesis Sec. 3.7: 16 km/h)", gt=0)
    turbulence_intensity: float = _q("", "sigma_V / V0 (ASSUMED)", ge=0)
    turbulence_length: float = _q("m", "turbulence length scale l_t (ASSUMED)", gt=0)
    a1: float = _q("", "von Karman filter constant a1 (thesis Sec. 3.3)", gt=0)
    a2: float = _q("", "von Karman filter constant a2 (thesis Sec. 3.3)", gt=0)
    spectral_density: float = _q("", "spectral density S0 of the filter's white noise W(t)", gt=0)


class _PlanetaryDamping(_Table):
    model: Literal["rayleigh", "modal"] = _q(
        "", "'rayleigh': C = alpha M + beta K (Eq. 3.91); 'modal': one ratio for every mode", "rayleigh"
    )
    alpha: float = _q("1/s", "mass-proportional Rayleigh coefficient (Eq. 3.91)", 0.05, ge=0)
    beta: float = _q("s", "stiffness-proportional Rayleigh coefficient (Eq. 3.91)", 0.03, ge=0)
    modal_ratio: float = _q("", "modal damping ratio (model = 'modal')", 0.05, gt=0, lt=1)


class _PlanetarySimulation(_Table):
    dt: float = _q("s", "time step (thesis Sec. 3.7: 2.7 ms)", 0.0027, gt=0)


def _relative_mismatch(a: float, b: float) -> float:
    return abs(a - b) / max(abs(a), abs(b))


class PlanetaryFile(_Table):
    """``planetary.toml``: the wind-turbine planetary train with an elastic ring (thesis ch. 3, Tables 3.1-3.2)."""

    n_planets: int = _q("", "planets, equally spaced", 3, ge=1)
    ring_model: Literal["elastic", "rigid"] = _q(
        "", "'elastic': curved-beam ring on bolts; 'rigid': lumped ring body", "elastic"
    )
    sun: _PlanetarySun
    planet: _PlanetaryPlanet
    carrier: _PlanetaryCarrier
    ring: _PlanetaryRing
    mesh: _PlanetaryMesh
    wind: _PlanetaryWind
    damping: _PlanetaryDamping = _PlanetaryDamping()
    simulation: _PlanetarySimulation = _PlanetarySimulation()

    @model_validator(mode="after")
    def _consistent(self):
        ring, n = self.ring, self.n_planets
        if ring.n_supports and ring.n_elements % ring.n_supports:
            raise ValueError(
                f"`ring.n_supports` ({ring.n_supports}) must divide `ring.n_elements` ({ring.n_elements}): "
                "the bolts are equally spaced on nodes"
            )
        for key in ("support_radial", "support_tangential", "support_torsional"):
            value = getattr(ring, key)
            if isinstance(value, list) and len(value) != ring.n_supports:
                raise ValueError(
                    f"`ring.{key}` lists {len(value)} values but `ring.n_supports` is {ring.n_supports} "
                    "(one per bolt, or a single number for all)"
                )
        module = {
            name: body.pitch_diameter / body.teeth
            for name, body in (("sun", self.sun), ("planet", self.planet), ("ring", ring))
        }
        if max(_relative_mismatch(module["sun"], m) for m in module.values()) > 0.02:
            raise ValueError(
                "`sun.pitch_diameter / sun.teeth`, `planet.pitch_diameter / planet.teeth` and "
                "`ring.pitch_diameter / ring.teeth` (the module) must agree to 2 % for gears that mesh; got "
                + ", ".join(f"{k} {1e3 * v:.6g} mm" for k, v in module.items())
            )
        coaxial = self.sun.pitch_diameter + 2.0 * self.planet.pitch_diameter
        if _relative_mismatch(ring.pitch_diameter, coaxial) > 0.01:
            raise ValueError(
                f"`ring.pitch_diameter` ({ring.pitch_diameter} m) must equal `sun.pitch_diameter` + 2 x "
                f"`planet.pitch_diameter` ({coaxial:.6g} m) to 1 %: sun, planets and ring are coaxial"
            )
        varying = self.mesh.stiffness_variation > 0 and self.mesh.harmonics > 0
        if varying and (ring.teeth % n or self.sun.teeth % n):
            raise ValueError(
                f"`n_planets` = {n} with `sun.teeth` = {self.sun.teeth} and `ring.teeth` = {ring.teeth}: the "
                "model meshes every planet in phase (thesis Sec. 3.7), which needs both tooth counts divisible "
                "by n_planets when the mesh stiffness varies; these planets would mesh sequentially phased, "
                "which pgtjax does not model (set mesh.stiffness_variation = 0 for constant mesh stiffness)"
            )
        return self


# ------------------------------------------------------------------------------------- gear pair (ch. 4)


class _GearPairGears(_Table):
    teeth_1: int = _q("", "pinion teeth a_1 (Table 4.1)", ge=1)
    teeth_2: int = _q("", "gear teeth a_2 (Table 4.1)", ge=1)
    pitch_radius_1: float = _q("m", "pinion pitch (base) radius r_1 (Table 4.1)", gt=0)
    pitch_radius_2: float = _q("m", "gear pitch (base) radius r_2 (Table 4.1)", gt=0)
    mass_1: float = _q("kg", "pinion mass m_1 (Table 4.1)", gt=0)
    mass_2: float = _q("kg", "gear mass m_2 (Table 4.1)", gt=0)
    inertia_1: float = _q("kg m^2", "pinion inertia I_1 (Table 4.1)", gt=0)
    inertia_2: float = _q("kg m^2", "gear inertia I_2 (Table 4.1)", gt=0)
    bearing_stiffness_1: float = _q("N/m", "pinion bearing stiffness k_1 (Table 4.1)", gt=0)
    bearing_stiffness_2: float = _q("N/m", "gear bearing stiffness k_2 (Table 4.1)", gt=0)


class _GearPairMesh(_Table):
    mean_stiffness: float = _q("N/m", "mean mesh stiffness k_0 (Table 4.1)", gt=0)
    half_backlash: float = _q("m", "half backlash b of Eq. 4.9 (Sec. 4.6.1)", ge=0)
    sin_coefficients: list[float] = _q("N/m", "sine harmonics k_a^(j) of Eq. 4.11 (ASSUMED 10 % of k_0)", [])
    cos_coefficients: list[float] = _q("N/m", "cosine harmonics k_b^(j) of Eq. 4.11", [])
    pinion_speed_rpm: float = _q("rpm", "pinion speed; mesh frequency = teeth_1 x speed (ASSUMED 1500)", gt=0)

    @model_validator(mode="after")
    def _harmonics(self):
        if len(self.sin_coefficients) != len(self.cos_coefficients):
            raise ValueError(
                f"`mesh.sin_coefficients` ({len(self.sin_coefficients)} values) and `mesh.cos_coefficients` "
                f"({len(self.cos_coefficients)} values) must have the same length (one pair per harmonic)"
            )
        # harmonic j has amplitude sqrt(a_j^2 + b_j^2): their sum bounds the variation of k(t)
        amplitude = sum(math.hypot(a, b) for a, b in zip(self.sin_coefficients, self.cos_coefficients))
        if amplitude >= self.mean_stiffness:
            raise ValueError(
                f"`mesh.sin_coefficients` / `mesh.cos_coefficients`: the harmonic amplitudes sum to {amplitude} "
                f"N/m, which must stay below `mesh.mean_stiffness` ({self.mean_stiffness} N/m) so that the "
                "mesh stiffness stays positive"
            )
        return self


class _GearPairDamping(_Table):
    damping_ratio: float = _q(
        "",
        "Rayleigh damping fitted to this ratio at the lowest and highest mode (ASSUMED 0.05)",
        0.05,
        gt=0,
        lt=1,
    )
    alpha: float | None = _q(
        "1/s", "mass-proportional Rayleigh coefficient (with beta; replaces damping_ratio)", None, ge=0
    )
    beta: float | None = _q("s", "stiffness-proportional Rayleigh coefficient (with alpha)", None, ge=0)

    @model_validator(mode="after")
    def _both(self):
        if (self.alpha is None) != (self.beta is None):
            raise ValueError("`damping.alpha` and `damping.beta` must be given together (or neither)")
        return self


class _GearPairExcitation(_Table):
    noise_amplitude: float = _q("N", "noise amplitude w_0 (Sec. 4.6.1)")
    spectral_density: float = _q("", "spectral density S_0 (Sec. 4.6.1)", ge=0)
    torque_in: float = _q("N m", "input torque T_in (Sec. 4.6.2: heavy load)")
    torque_out: float = _q("N m", "output torque T_out (Sec. 4.6.2)")


class _GearPairRegimes(_Table):
    torque_in: list[float] = _q("N m", "T_in of each load regime (Secs. 4.6.2-4.6.4)")
    torque_out: list[float] = _q("N m", "T_out of each load regime")
    names: list[str] = _q("", "a name for each regime (used in file names)")

    @model_validator(mode="after")
    def _aligned(self):
        lengths = {k: len(getattr(self, k)) for k in ("torque_in", "torque_out", "names")}
        if len(set(lengths.values())) != 1 or not lengths["names"]:
            raise ValueError(
                "`regimes.torque_in`, `regimes.torque_out` and `regimes.names` must list one entry per regime "
                f"(at least one), got lengths {lengths}"
            )
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"`regimes.names` must be unique, got {self.names}")
        return self


class GearPairFile(_Table):
    """``gear_pair.toml``: the spur gear pair with backlash (thesis ch. 4, Table 4.1)."""

    gears: _GearPairGears
    mesh: _GearPairMesh
    damping: _GearPairDamping = _GearPairDamping()
    excitation: _GearPairExcitation
    regimes: _GearPairRegimes | None = _q("", "load regimes of the study (optional)", None)


# ------------------------------------------------------------------------ ring under moving loads (ch. 6)


class _RingGeometry(_Table):
    outer_radius: float = _q("m", "outer radius of the rim (Sec. 6.4)", gt=0)
    root_radius: float = _q("m", "root radius of the teeth (Sec. 6.4)", gt=0)
    face_width: float = _q("m", "face width (Sec. 6.4)", gt=0)
    youngs_modulus: float = _q("Pa", "Young's modulus (Sec. 6.4)", gt=0)
    density: float = _q("kg/m^3", "density (Sec. 6.4)", gt=0)
    n_elements: int = _q("", "curved-beam elements L (Sec. 6.4: 36)", ge=3)
    rotary_inertia: bool = _q("", "keep the rotary inertia, Lambda = diag(A, A, I) (Eq. 6.22)", True)

    @model_validator(mode="after")
    def _radii(self):
        if not self.root_radius < self.outer_radius:
            raise ValueError(
                f"`ring.root_radius` ({self.root_radius} m) must be < `ring.outer_radius` ({self.outer_radius} m)"
            )
        return self


class _RingSupports(_Table):
    n_bolts: int = _q("", "equally spaced bolts, the first at node 0 (Sec. 6.4: six)", ge=0)
    k_radial: float = _q("N/m", "radial bolt stiffness k_r (Sec. 6.4)", ge=0)
    k_tangential: float = _q("N/m", "tangential bolt stiffness k_tau (Sec. 6.4)", ge=0)
    k_torsional: float = _q("N m/rad", "torsional bolt stiffness k_theta (Sec. 6.4)", ge=0)


class _RingSupportCase(_Table):
    k_radial: float = _q("N/m", "radial bolt stiffness", ge=0)
    k_tangential: float = _q("N/m", "tangential bolt stiffness", ge=0)
    k_torsional: float = _q("N m/rad", "torsional bolt stiffness", ge=0)


class _RingLoads(_Table):
    n_loads: int = _q("", "moving mesh loads (planets; Sec. 6.4: 3)", ge=1)
    carrier_speed: float = _q("rad/s", "carrier speed omega_c (Sec. 6.4)", gt=0)
    mean_force: float = _q("N", "mean mesh force F_0 (Sec. 6.4)")
    force_amplitude: float = _q("N", "amplitude f_a of the mesh-frequency force (Sec. 6.4)", ge=0)
    mesh_frequency_ratio: float = _q("", "mesh frequency / carrier speed (Sec. 6.4: 36)", ge=0)
    pressure_angle_deg: float = _q("deg", "pressure angle alpha (Sec. 6.4)", ge=0, lt=90)
    noise_intensity: float = _q("N sqrt(s)", "noise level b-bar of a unit white noise (Sec. 6.4)", ge=0)
    initial_angle_deg: float = _q("deg", "angle of load 1 at t = 0 (ASSUMED 0: on the first bolt)", 0.0)


class _RingDamping(_Table):
    damping_ratio: float | None = _q(
        "", "Rayleigh damping fitted to this ratio at omega_a and omega_b (ASSUMED 2 %)", None, gt=0, lt=1
    )
    omega_a: float | None = _q("rad/s", "first fitting frequency (with damping_ratio)", None, gt=0)
    omega_b: float | None = _q("rad/s", "second fitting frequency (with damping_ratio)", None, gt=0)
    rayleigh_mass: float | None = _q("1/s", "lambda_M of Eq. 6.23 (with rayleigh_stiffness)", None, ge=0)
    rayleigh_stiffness: float | None = _q("s", "lambda_K of Eq. 6.23 (with rayleigh_mass)", None, ge=0)
    modal_damping_ratio: float | None = _q(
        "", "a modal damping ratio instead of Rayleigh damping", None, ge=0
    )

    @model_validator(mode="after")
    def _one_form(self):
        fitted = [self.damping_ratio, self.omega_a, self.omega_b]
        direct = [self.rayleigh_mass, self.rayleigh_stiffness]
        if any(v is not None for v in direct) and any(v is None for v in direct):
            raise ValueError("`damping.rayleigh_mass` and `damping.rayleigh_stiffness` go together")
        if any(v is not None for v in fitted) and any(v is None for v in fitted):
            raise ValueError("`damping.damping_ratio`, `damping.omega_a` and `damping.omega_b` go together")
        if fitted[0] is not None and direct[0] is not None:
            raise ValueError(
                "give either `damping.damping_ratio` (with omega_a, omega_b) or `damping.rayleigh_mass` "
                "(with rayleigh_stiffness), not both"
            )
        if self.omega_a is not None and not self.omega_a < self.omega_b:
            raise ValueError(
                f"`damping.omega_a` ({self.omega_a}) must be < `damping.omega_b` ({self.omega_b})"
            )
        return self


class RingMovingLoadFile(_Table):
    """``ring_ch6.toml``: the wind-turbine ring gear under random moving mesh loads (thesis ch. 6, Sec. 6.4)."""

    ring: _RingGeometry
    supports: _RingSupports
    support_cases: dict[str, _RingSupportCase] = _q(
        "", "alternative bolt sets named case1, case2, ... (Sec. 6.4.3)", {}
    )
    loads: _RingLoads
    damping: _RingDamping = _RingDamping()

    @model_validator(mode="after")
    def _consistent(self):
        n, bolts = self.ring.n_elements, self.supports.n_bolts
        if bolts and n % bolts:
            raise ValueError(
                f"`supports.n_bolts` ({bolts}) must divide `ring.n_elements` ({n}): the bolts sit on nodes"
            )
        for key in self.support_cases:
            if not (key.startswith("case") and key[4:].isdigit()):
                raise ValueError(f"`support_cases.{key}`: entries must be named case1, case2, ...")
        return self


# --------------------------------------------------------------------------------- back-to-back bench


class _BenchBodies(_Table):
    ring: float = _q("", "ring", gt=0)
    planet: float = _q("", "planet", gt=0)
    sun: float = _q("", "sun", gt=0)
    carrier: float = _q("", "carrier", gt=0)


class _BenchGears(_Table):
    z_sun: int = _q("", "sun teeth (paper Table 1)", ge=8, le=1000)
    z_planet: int = _q("", "planet teeth (paper Table 1)", ge=8, le=1000)
    z_ring: int = _q("", "ring teeth (paper Table 1)", ge=8, le=1000)
    n_planets: int = _q("", "planets per stage (the bench model has 3)", ge=3, le=3)
    module_mm: float = _q("mm", "module (paper Table 1)", gt=0, le=100)
    pressure_angle_rad: float = _q("rad", "pressure angle (paper Table 1: 26.48 deg)", ge=0.17, le=0.61)
    mass_kg: _BenchBodies = _q("kg", "masses: ring, planet, sun, carrier (paper Table 1)")
    inertia_kgm2: _BenchBodies = _q("kg m^2", "inertias: ring, planet, sun, carrier (paper Table 1)")
    base_diameter_m: _BenchBodies = _q(
        "m", "base diameters: ring, planet, sun, carrier (paper Table 1; not used)"
    )
    tip_diameter_m: _BenchBodies = _q(
        "m", "'tip diameters': ring, planet, sun, carrier (paper Table 1; not used)"
    )

    @model_validator(mode="after")
    def _internal_mesh(self):
        if self.z_ring - self.z_planet < 10:
            raise ValueError(
                f"`gears.z_ring` ({self.z_ring}) must exceed `gears.z_planet` ({self.z_planet}) by at least 10 "
                "teeth (tip interference of the internal mesh)"
            )
        return self


class _BenchMesh(_Table):
    face_width: float = _q("m", "face width = Hertz contact length (ASSUMED)", gt=0, le=1)
    youngs_modulus: float = _q("Pa", "Young's modulus (ASSUMED steel)", gt=1e9, le=1e12)
    poisson_ratio: float = _q("", "Poisson's ratio (ASSUMED steel)", gt=0, lt=0.5)
    addendum_coef: float = _q("module", "addendum (ASSUMED standard)", gt=0, le=2)
    dedendum_coef: float = _q(
        "module", "dedendum (ASSUMED standard); must exceed addendum_coef", gt=0, le=2.5
    )
    hub_ratio_sun: float = _q("", "sun r_root / r_bore (ASSUMED)", gt=1, le=10)
    hub_ratio_planet: float = _q("", "planet r_root / r_bore (ASSUMED)", gt=1, le=10)
    rim_ratio_ring: float = _q("", "ring rim ratio in Sainsot's fit (ASSUMED)", gt=1, le=10)
    shear_factor: float = _q("", "shear correction of the tooth beam (5/6, rectangular section)", gt=0, le=1)
    n_segments: int = _q("", "Cornell beam segments of a tooth", ge=4, le=2000)
    modulus_kind: Literal["plane_strain", "paper_eq4"] = _q(
        "", "tooth-beam modulus: E/(1-nu^2) or the paper's Eq. 4", "plane_strain"
    )

    @model_validator(mode="after")
    def _clearance(self):
        if not self.dedendum_coef > self.addendum_coef:
            raise ValueError(
                f"`mesh.dedendum_coef` ({self.dedendum_coef}) must exceed `mesh.addendum_coef` "
                f"({self.addendum_coef}): root clearance"
            )
        return self


class _BenchOperating(_Table):
    sun_torque_Nm: float = _q("N m", "nominal circulating test-sun torque (ASSUMED)", ge=0, le=1e5)


class _BenchTorsional(_Table):
    carrier_radius_m: float = _q("m", "planet-centre radius (ASSUMED reading of Table 1)", gt=0)
    carrier_shaft_stiffness_Nm_per_rad: float = _q("N m/rad", "carrier shaft (paper Table 3)", gt=0, le=1e12)
    sun_shaft_stiffness_Nm_per_rad: float = _q(
        "N m/rad", "sun shaft (ASSUMED: Table 3 lost it)", gt=0, le=1e12
    )
    motor_shaft_stiffness_Nm_per_rad: float = _q("N m/rad", "motor coupling (ASSUMED)", ge=0, le=1e12)
    test_ring_support_stiffness_Nm_per_rad: float = _q(
        "N m/rad", "test-ring support (ASSUMED)", ge=0, le=1e14
    )
    half_backlash_m: float = _q("m", "half backlash of every mesh (ASSUMED)", ge=0, le=1e-3)
    reaction_phase_offset: float = _q(
        "mesh cycles", "assembly phase of the reaction set (ASSUMED 0)", gt=-1e6, le=1e6
    )
    stiffness_table_points: int = _q("", "points of the pair-compliance table", 257, ge=16, le=100_000)


class _BenchDamping(_Table):
    damping_ratio: float = _q("", "Rayleigh damping ratio at the two frequencies (ASSUMED)", ge=0, le=1)
    rayleigh_f1_hz: float = _q("Hz", "first fitting frequency (ASSUMED)", gt=0, le=1e6)
    rayleigh_f2_hz: float = _q(
        "Hz", "second fitting frequency (ASSUMED); must exceed the first", gt=0, le=1e6
    )

    @model_validator(mode="after")
    def _ordered(self):
        if not self.rayleigh_f2_hz > self.rayleigh_f1_hz:
            raise ValueError(
                f"`damping.rayleigh_f2_hz` ({self.rayleigh_f2_hz}) must exceed `damping.rayleigh_f1_hz` "
                f"({self.rayleigh_f1_hz})"
            )
        return self


class _BenchRunUp(_Table):
    speed_start_rpm: float = _q(
        "rpm", "motor speed of regime A and at the ramp's start (ASSUMED)", ge=0, le=19_000
    )
    speed_end_rpm: float = _q("rpm", "motor speed at the ramp's end (ASSUMED)", ge=0, le=19_000)
    ramp_start_s: float = _q("s", "start of the run-up ramp (ASSUMED)", ge=0, le=1e4)
    ramp_duration_s: float = _q("s", "duration of the run-up ramp (ASSUMED)", gt=0, le=1e4)
    torque_end_Nm: float = _q("N m", "circulating torque at the ramp's end (ASSUMED)", ge=0, le=1e5)
    t_end_s: float = _q("s", "default simulated length of the run-up study", gt=0)


class BackToBackFile(_Table):
    """``back_to_back.toml``: the back-to-back planetary test bench (bench paper, Tables 1 and 3)."""

    gears: _BenchGears
    mesh: _BenchMesh
    operating: _BenchOperating
    bench: _BenchTorsional
    damping: _BenchDamping
    run_up: _BenchRunUp


SCHEMAS: dict[str, type[_Table]] = {
    "planetary": PlanetaryFile,
    "gear_pair": GearPairFile,
    "ring_ch6": RingMovingLoadFile,
    "back_to_back": BackToBackFile,
}


# ------------------------------------------------------------------------------------------- checking


def _table_fields(schema: type[BaseModel], loc: tuple) -> dict | None:
    """The fields of the table at ``loc`` (keys only) in ``schema``, or None if it is not a table."""
    model: Any = schema
    named_entry = False  # the next part names an entry of a {name: table} field (support_cases.case1)
    for part in loc:
        if named_entry:
            named_entry = False
            continue
        if not (isinstance(model, type) and issubclass(model, BaseModel)) or part not in model.model_fields:
            return None
        annotation = model.model_fields[part].annotation
        named_entry = getattr(annotation, "__origin__", None) is dict
        model = _table_type(annotation)
    return model.model_fields if isinstance(model, type) and issubclass(model, BaseModel) else None


def _table_type(annotation):
    for arg in (annotation, *getattr(annotation, "__args__", ())):
        if isinstance(arg, type) and issubclass(arg, BaseModel):
            return arg
    return None


def _field_info(schema, loc: tuple):
    fields = _table_fields(schema, loc[:-1])
    return None if fields is None else fields.get(loc[-1])


def _describe(schema, error: dict) -> str:
    loc = tuple(p for p in error["loc"] if isinstance(p, str | int))
    keys = tuple(p for p in loc if isinstance(p, str))
    name = ".".join(str(p) for p in loc)
    kind = error["type"]
    if kind == "extra_forbidden":
        known = _table_fields(schema, keys[:-1]) or {}
        close = difflib.get_close_matches(keys[-1], list(known), n=1, cutoff=0.6)
        hint = f"; did you mean `{'.'.join((*keys[:-1], close[0]))}`?" if close else ""
        where = f"[{'.'.join(keys[:-1])}]" if len(keys) > 1 else "the top level"
        return f"`{name}` is not a known key of {where}{hint} (known: {', '.join(known)})"
    info = _field_info(schema, keys) if keys else None
    unit = (info.json_schema_extra or {}).get("unit", "") if info is not None else ""
    doc = f" ({info.description})" if info is not None and info.description else ""
    if kind == "missing":
        return f"`{name}` is missing{doc}"
    message = error["msg"].removeprefix("Value error, ")
    if kind == "value_error":  # our own checks name their keys; a field check names its value only
        return message if message.startswith("`") or not name else f"`{name}` {message}"
    if kind in ("model_type", "dict_type", "model_attributes_type"):
        return f"`{name}` must be a table, got {error.get('input')!r}"
    message = message[0].lower() + message[1:]
    if unit and unit != "mesh periods" and ("than" in message or "number" in message):
        message += f" ({unit})" if "number" in message else f" {unit}"
    return f"`{name}` = {error.get('input')!r}: {message}{doc}"


def validate(kind: str, data, where: str = "parameters") -> dict:
    """``data`` (the dict of a parameter file) checked against the schema ``kind`` (a key of
    :data:`SCHEMAS`); returns it with the optional entries' defaults filled in (absent optional keys stay
    absent). ``ValueError`` starting with ``where`` and naming every offending ``table.key``."""
    schema = SCHEMAS[kind]
    if not isinstance(data, Mapping):
        raise ValueError(f"{where}: must be a table of parameter tables, got {type(data).__name__}")
    data = dict(data)
    try:
        model = schema.model_validate(data)
    except ValidationError as err:
        problems = [_describe(schema, e) for e in err.errors(include_url=False)]
        raise ValueError(f"{where}: " + "; ".join(dict.fromkeys(problems))) from None
    return model.model_dump(exclude_none=True)


def reference(kind: str, embedded: dict | None = None) -> str:
    """Markdown reference of the schema ``kind``: one table per parameter table (key, type, unit, the value
    in the embedded file ``embedded`` (its dict), default of an optional key, accepted range, meaning and
    source)."""
    schema = SCHEMAS[kind]
    embedded = embedded or {}
    lines = [f"### `{kind}.toml`", "", (schema.__doc__ or "").strip().split(": ", 1)[-1], ""]
    top = [(k, f) for k, f in schema.model_fields.items() if _table_type(f.annotation) is None]
    tables = [(k, f) for k, f in schema.model_fields.items() if _table_type(f.annotation) is not None]
    sections = ([("top level", top, embedded)] if top else []) + [
        (
            f"[{k}.*]" if getattr(f.annotation, "__origin__", None) is dict else f"[{k}]",
            list(_table_type(f.annotation).model_fields.items()),
            embedded.get(k, {}),
        )
        for k, f in tables
    ]
    for title, fields, values in sections:
        lines += [
            f"**{title}**",
            "",
            "| key | type | unit | embedded value | default | range | meaning (source) |",
            "|---|---|---|---|---|---|---|",
        ]
        for key, info in fields:
            value = values.get(key) if isinstance(values, dict) else None
            lines.append(
                f"| `{key}` | {_type_name(info.annotation)} | {(info.json_schema_extra or {}).get('unit', '')} | "
                f"{'' if value is None else _value_text(value)} | "
                f"{'required' if info.is_required() else _value_text(info.default)} | {_range_text(info)} | "
                f"{info.description or ''} |"
            )
        lines.append("")
    return "\n".join(lines)


def _type_name(annotation) -> str:
    if annotation is Any:
        return "float or list[float]"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "table"
    text = annotation.__name__ if isinstance(annotation, type) else str(annotation)
    return text.replace("typing.", "").replace(" | None", "").replace("Literal", "one of ")


def _value_text(value) -> str:
    if isinstance(value, BaseModel) or value is None or value == {}:
        return ""
    if isinstance(value, dict):
        return "table"
    return f"`{_number_text(value)}`"


def _number_text(value) -> str:
    if isinstance(value, list):
        return "[" + ", ".join(_number_text(v) for v in value) + "]"
    if isinstance(value, float):
        return format(value, ".10g")
    return f'"{value}"' if isinstance(value, str) else repr(value)


def reference_document() -> str:
    """The text of ``docs/parameters.md``: every schema's reference with the embedded files' values."""
    from . import EMBEDDED, path, read_toml

    head = [
        "# Parameter reference",
        "",
        "Generated from the schemas in `pgtjax/params/_schema.py` (`python3 -m pgtjax.params > docs/parameters.md`;",
        "a test checks that this file is current). Every parameter file is checked against its schema before a",
        "model is built: an unknown key, a missing one, a value of the wrong type (`21.7` teeth), out of range or",
        "inconsistent with another is a `ValueError` naming `table.key`. Copy an embedded file",
        "(`pgtjax/params/*.toml`) and change what you need; the CLI's `--params FILE` reads it, and",
        '`--set TABLE.KEY=VALUE` changes one entry (in Python: `pgtjax.params.read_params(None, "planetary",',
        '{"ring.rim_thickness": 0.1})`, then the model\'s `load_params` of that dict). Every study writes the',
        "parameters it ran with to `parameters.toml` in its output folder. 'Table 3.2' and 'Sec. 6.4' refer to",
        "the thesis, 'paper' to the bench paper; ASSUMED marks our documented choices.",
        "",
    ]
    body = [reference(kind, read_toml(path(name))) for kind, name in EMBEDDED.items()]
    return "\n".join(head) + "\n" + "\n".join(body)


def _range_text(info) -> str:
    parts = []
    for meta in info.metadata:
        for attr, sign in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
            value = getattr(meta, attr, None)
            if value is not None:
                parts.append(f"{sign} {value:g}")
    return ", ".join(parts)
