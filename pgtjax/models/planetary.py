"""Hybrid finite-element / lumped planetary gear train with an elastic ring gear (thesis ch. 3).

Coordinates (thesis Eq. 3.44): sun ``(x_s, y_s, u_s)``; planets ``(xi_n, eta_n, u_n)`` (radial/tangential in
the carrier frame); carrier ``(x_c, y_c, u_c)``; ring: ``L`` curved-beam nodes ``(u_r, u_tau, u_theta)``
(:mod:`pgtjax.models.ring`; radial positive inward) or, with ``ring_model = "rigid"``, a lumped ring body
``(x_r, y_r, u_r)``; and the von Karman filter state ``chi``. Rotations are written as ``u = r theta`` with
the base radius (sun, planets, rigid ring) or the carrier radius; all rotations are counter-clockwise.
The lumped bodies live in the frame turning with the carrier (gyroscopic terms neglected, omega_c = 0.23
rad/s); the elastic ring is fixed in the ground frame, so the planets' meshes move around it.

Derive, don't transcribe (docs/corrections.md C4, on Eqs. 3.9-3.11, 3.16, 3.25-3.26, App. 3.A.3): every spring's deflection
is written once as ``delta = g^T q`` from vector geometry, and ``K = sum k g g^T`` (symmetric by
construction). In the local basis of planet n (``e_r`` outward through its centre at angle ``psi_n``,
``e_t`` counter-clockwise):

- sun-planet line of action ``m = sin(a_s) e_r + cos(a_s) e_t``; both base-circle contact points move along
  ``m`` by ``+u`` for counter-clockwise rotations, so
  ``delta_sp = (d_s - d_p) . m + u_s + u_p``  (= Eq. 3.2, with ``psi_sp = psi - a_s``);
- ring-planet line of action ``n = sin(a_r) e_r - cos(a_r) e_t``;
  ``delta_rp = (d_p - d_R) . n - u_p + (ring rotation)``, where ``d_R`` is the ring displacement at the
  contact point on the pitch circle. For the elastic ring at contact angle ``theta = omega_c t + psi_n``,
  with the inward radial ``u_r``, tangential ``u_tau`` and section rotation ``u_theta`` interpolated by the
  shape functions and the pitch circle at ``e = R_mean - R_pitch`` inside the rim centre line:
  ``-d_R . n = sin(a_r) u_r + cos(a_r) (u_tau - e u_theta)``.
  (Eq. 3.16 as printed projects with ``cos``/``sin`` exchanged: a rigid rotation ``u_tau = R phi`` must
  change ``delta_rp`` by the base-radius arc ``R_pitch cos(a_r) phi``, exactly as the rigid ring's
  ``u_r = r_b phi`` does; this form does, the printed one gives ``-R sin(a_r) phi``.)
- planet bearing: ``d_p - d_pin`` with ``d_pin = d_c + u_c e_t`` (both components, stiffness ``k_p``);
  Eqs. 3.9-3.10 follow from this energy except for a sign of the ``(eta - u_c) cos`` term in Eq. 3.10.

Mesh stiffness (Eq. 3.1, App. 3.A.1): a rectangular wave between single- and double-tooth stiffness, the
double-tooth share of each mesh period being ``c - 1`` (contact ratio c); its Fourier series
``k(t) = k_mean + dk sum_j (2/(j pi)) sin(j pi (c-1)) cos(j (omega t - 2 pi Omega) - j pi (c-1))`` is our
own derivation (App. 3.A.1's coefficients leave ``phi`` undefined); ``dk = stiffness_variation * k_mean``.
Phases: ``Omega_sp,n = Omega_rp,n = 0`` (teeth multiples of N, thesis 3.7), ring meshes shifted by ``Omega_sr``.

Wind (Eqs. 3.28-3.31): ``T_in = T_d + T_r`` with ``T_d = rho A R (C_p/lambda_0) V0^2 / 2`` and
``T_r = rho A R (C_p/lambda_0) V0 V_t`` (the derivative of T_d in V0; the printed Eq. 3.28 carries an extra
V0), ``lambda_0 = omega_c R / V0`` (Eq. 3.29), ``V_t = sigma_V k_v (chi + a1 T_v chi')`` (Eq. 3.30) with
``sigma_V = I V0``, and the filter ``a2 T_v^2 chi'' + (a2 T_v + T_v) chi' + chi = W`` (Eq. 3.31).
``k_v`` normalizes the filter output to unit variance for the given S0 (Bianchi et al. normalize the
von Karman filter so): ``k_v^2 = (a2 + 1) T_v / (pi S0 (1 + a1^2 / a2))``. T_r couples the carrier to chi
through K and C (non-symmetric, App. 3.A.3 K_e2, C_2).

Damping: ``C = alpha M + beta K_mean`` on the mechanical DOFs (Eq. 3.91, alpha = 0.05, beta = 0.03 s; the mesh
springs at their mean stiffness), or modal damping ratios (``model = "modal"``).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import Backlash, Contacts, System, symmetric_eigen
from .. import params as _params
from .._system import check_count
from .._validate import check_range
from .ring import (
    RingParams,
    ring_dof_names,
    ring_interpolation,
    ring_matrices,
    ring_nodal_inverse,
    without_supports,
)
from .ring import validate as validate_ring


class Body(eqx.Module):
    """A lumped body: mass (kg), inertia (kg m^2), radius r of ``u = r theta`` (m), translational bearing
    stiffness (N/m) and torsional stiffness (N m/rad)."""

    mass: jax.Array
    inertia: jax.Array
    radius: jax.Array
    bearing: jax.Array
    torsional: jax.Array


class MeshParams(eqx.Module):
    sun_planet: jax.Array  # mean stiffness, N/m
    ring_planet: jax.Array
    pressure_angle: jax.Array  # rad, sun-planet and ring-planet
    half_backlash: jax.Array  # m
    contact_ratio_sun: jax.Array
    contact_ratio_ring: jax.Array
    phase_sun_ring: jax.Array  # fraction of a mesh period
    stiffness_variation: jax.Array  # (k_double - k_single) / k_mean
    carrier_speed: jax.Array  # rad/s
    ring_teeth: int = eqx.field(static=True)
    harmonics: int = eqx.field(static=True)

    @property
    def mesh_frequency(self):
        """omega = Z_r omega_c (rad/s), Table 3.2: 99 x 0.2322 = 22.99."""
        return self.ring_teeth * self.carrier_speed


class WindParams(eqx.Module):
    air_density: jax.Array
    rotor_radius: jax.Array
    power_coefficient: jax.Array
    mean_wind_speed: jax.Array
    turbulence_intensity: jax.Array
    turbulence_length: jax.Array
    a1: jax.Array
    a2: jax.Array
    spectral_density: jax.Array

    def time_constant(self):
        """T_v = l_t / V0 (s)."""
        return self.turbulence_length / self.mean_wind_speed

    def filter_gain(self):
        """k_v making Var[chi + a1 T_v chi'] * k_v^2 = 1 in stationarity (see module docstring)."""
        tv = self.time_constant()
        return jnp.sqrt(
            (self.a2 + 1.0) * tv / (jnp.pi * self.spectral_density * (1.0 + self.a1**2 / self.a2))
        )

    def torque_sensitivity(self, carrier_speed):
        """dT/dV = rho A R (C_p / lambda_0) V0 (N m s/m), lambda_0 = omega_c R / V0 (Eq. 3.29)."""
        area = jnp.pi * self.rotor_radius**2
        tip_speed_ratio = carrier_speed * self.rotor_radius / self.mean_wind_speed
        return (
            self.air_density
            * area
            * self.rotor_radius
            * self.power_coefficient
            / tip_speed_ratio
            * self.mean_wind_speed
        )

    def mean_torque(self, carrier_speed):
        """T_d (N m), Eq. 3.28."""
        return 0.5 * self.torque_sensitivity(carrier_speed) * self.mean_wind_speed


class DampingParams(eqx.Module):
    alpha: jax.Array
    beta: jax.Array
    modal_ratio: jax.Array
    model: str = eqx.field(static=True)


class PlanetaryParams(eqx.Module):
    """All parameters of the planetary model (see ``pgtjax/params/planetary.toml``)."""

    sun: Body
    planet: Body
    carrier: Body
    ring: RingParams
    rigid_ring: Body
    ring_pitch_radius: jax.Array
    mesh: MeshParams
    wind: WindParams
    damping: DampingParams
    n_planets: int = eqx.field(static=True)
    ring_model: str = eqx.field(static=True)

    def __check_init__(self):
        validate(self)

    @property
    def elastic_ring(self) -> RingParams:
        """The ring structure the model uses: ``ring`` with its centre radius derived, here and only here,
        as ``R = R_pitch + h / 2`` (the pitch circle on the rim's inner face, Model I), so that changing
        ``ring.thickness`` (a sweep, a design variable) moves the centre line with it. :func:`build` (and
        every model function taking the parameters) applies it through :func:`resolved`."""
        return eqx.tree_at(lambda r: r.radius, self.ring, self.ring_pitch_radius + self.ring.thickness / 2)

    @property
    def pitch_offset(self):
        """e = R_mean - R_pitch (m): the pitch circle lies on the inner face of the rim (Model I)."""
        return self.ring.radius - self.ring_pitch_radius

    def planet_angles(self):
        return 2.0 * np.pi * np.arange(self.n_planets) / self.n_planets


def _f(x):
    return jnp.asarray(x, dtype=jnp.float64)


def _per_support(name: str, value, n_supports: int):
    """A bolt stiffness of the parameter file: one number for every bolt, or a list with one per bolt."""
    if isinstance(value, list):
        if len(value) != n_supports or not all(isinstance(v, (int, float)) for v in value):
            raise ValueError(
                f"[ring] `{name}` must be a number or a list of {n_supports} numbers (one per bolt), got {value!r}"
            )
        return np.asarray(value, dtype=np.float64)
    return float(value)


# Where each differentiable parameter that a design may change lives in the parameter file: the path of
# the PlanetaryParams leaf -> (TOML table, key). Used to write an optimized design back to a file.
PARAMETER_FILE_KEYS = {
    "ring.k_support_radial": ("ring", "support_radial"),
    "ring.k_support_tangential": ("ring", "support_tangential"),
    "ring.k_support_torsional": ("ring", "support_torsional"),
    "ring.thickness": ("ring", "rim_thickness"),
    "ring.face_width": ("ring", "face_width"),
    "mesh.sun_planet": ("mesh", "sun_planet_stiffness"),
    "mesh.ring_planet": ("mesh", "ring_planet_stiffness"),
    "mesh.half_backlash": ("mesh", "half_backlash"),
    "sun.bearing": ("sun", "bearing_stiffness"),
    "planet.bearing": ("planet", "bearing_stiffness"),
    "carrier.bearing": ("carrier", "bearing_stiffness"),
    "damping.alpha": ("damping", "alpha"),
    "damping.beta": ("damping", "beta"),
}


def resolved(p: PlanetaryParams) -> PlanetaryParams:
    """``p`` with its derived quantities set from the independent ones (the ring's centre radius,
    :attr:`PlanetaryParams.elastic_ring`). Done once, where the system is built, so that the time functions
    evaluated inside the solvers' loops read the result instead of re-deriving it at every step."""
    return eqx.tree_at(lambda q: q.ring, p, p.elastic_ring)


def default_params(**ring_overrides) -> PlanetaryParams:
    """Thesis Tables 3.1-3.2 with the documented assumptions of ``planetary.toml``."""
    return load_params(_params.path("planetary.toml"), **ring_overrides)


def load_params(source, **overrides) -> PlanetaryParams:
    """Read a planetary parameter file (TOML, layout of the embedded ``planetary.toml``) or a dict.

    ``overrides`` replace top-level choices: ``ring_model``, ``n_elements``, ``rim_thickness``.
    """
    unknown = set(overrides) - {"ring_model", "n_elements", "rim_thickness"}
    if unknown:
        raise ValueError(
            f"unknown override(s) {sorted(unknown)} of load_params; known: ring_model, n_elements, rim_thickness"
        )
    data = _params.read_params(source, "planetary")  # ValueError naming table.key for a bad entry
    try:
        s, p, c, r, m, w, d = (
            data[k] for k in ("sun", "planet", "carrier", "ring", "mesh", "wind", "damping")
        )
        n_planets = int(data.get("n_planets", 3))
        ring_model = overrides.get("ring_model", data.get("ring_model", "elastic"))
        alpha = math.radians(float(m["pressure_angle_deg"]))
        rs, rp = float(s["pitch_diameter"]) / 2, float(p["pitch_diameter"]) / 2
        r_pitch = float(r["pitch_diameter"]) / 2
        thickness = float(overrides.get("rim_thickness", r["rim_thickness"]))
        n_el = check_count("n_elements", overrides.get("n_elements", r["n_elements"]), minimum=3)
        n_sup = int(r["n_supports"])
        if n_sup < 0 or (n_sup and n_el % n_sup):
            raise ValueError(
                f"`n_supports` ({n_sup}) must divide `n_elements` ({n_el}) (equally spaced bolts)"
            )
        supports = tuple(range(0, n_el, n_el // n_sup)) if n_sup else ()
        ring = RingParams(
            radius=r_pitch + thickness / 2,
            thickness=thickness,
            face_width=float(r["face_width"]),
            youngs_modulus=float(r["youngs_modulus"]),
            density=float(r["density"]),
            n_elements=n_el,
            support_nodes=supports,
            k_support_radial=_per_support("support_radial", r["support_radial"], n_sup),
            k_support_tangential=_per_support("support_tangential", r["support_tangential"], n_sup),
            k_support_torsional=_per_support("support_torsional", r["support_torsional"], n_sup),
        )
        base = lambda radius: _f(radius * math.cos(alpha))  # noqa: E731
        params = PlanetaryParams(
            sun=Body(
                _f(s["mass"]),
                _f(s["inertia"]),
                base(rs),
                _f(s["bearing_stiffness"]),
                _f(s["torsional_stiffness"]),
            ),
            planet=Body(_f(p["mass"]), _f(p["inertia"]), base(rp), _f(p["bearing_stiffness"]), _f(0.0)),
            carrier=Body(
                _f(c["mass"]),
                _f(c["inertia"]),
                _f(rs + rp),
                _f(c["bearing_stiffness"]),
                _f(c.get("torsional_stiffness", 0.0)),
            ),
            ring=ring,
            rigid_ring=Body(
                _f(r["rigid_mass"]),
                _f(r["rigid_inertia"]),
                base(r_pitch),
                _f(r["rigid_bearing_stiffness"]),
                _f(r["rigid_torsional_stiffness"]),
            ),
            ring_pitch_radius=_f(r_pitch),
            mesh=MeshParams(
                _f(m["sun_planet_stiffness"]),
                _f(m["ring_planet_stiffness"]),
                _f(alpha),
                _f(m["half_backlash"]),
                _f(m["contact_ratio_sun"]),
                _f(m["contact_ratio_ring"]),
                _f(m["phase_sun_ring"]),
                _f(m["stiffness_variation"]),
                _f(m["carrier_speed"]),
                ring_teeth=int(r["teeth"]),
                harmonics=int(m["harmonics"]),
            ),
            wind=WindParams(
                *(
                    _f(w[k])
                    for k in (
                        "air_density",
                        "rotor_radius",
                        "power_coefficient",
                        "mean_wind_speed",
                        "turbulence_intensity",
                        "turbulence_length",
                        "a1",
                        "a2",
                        "spectral_density",
                    )
                )
            ),
            damping=DampingParams(
                _f(d.get("alpha", 0.05)),
                _f(d.get("beta", 0.03)),
                _f(d.get("modal_ratio", 0.05)),
                model=str(d.get("model", "rayleigh")),
            ),
            n_planets=n_planets,
            ring_model=ring_model,
        )
    except KeyError as err:
        raise ValueError(f"planetary parameter file is missing the entry {err}") from None
    return params


def validate(p: PlanetaryParams) -> None:
    """``ValueError`` naming the parameter for values outside their range (concrete values only)."""
    if p.ring_model not in ("elastic", "rigid"):
        raise ValueError(f"`ring_model` must be 'elastic' or 'rigid', got {p.ring_model!r}")
    if p.damping.model not in ("rayleigh", "modal"):
        raise ValueError(f"damping `model` must be 'rayleigh' or 'modal', got {p.damping.model!r}")
    if p.n_planets < 1:
        raise ValueError(f"`n_planets` must be >= 1, got {p.n_planets}")
    positive = dict(lo=0.0, lo_closed=False)
    for name, value, bounds in [
        ("sun.mass", p.sun.mass, positive),
        ("planet.mass", p.planet.mass, positive),
        ("carrier.mass", p.carrier.mass, positive),
        ("sun.inertia", p.sun.inertia, positive),
        ("planet.inertia", p.planet.inertia, positive),
        ("carrier.inertia", p.carrier.inertia, positive),
        ("sun.bearing_stiffness", p.sun.bearing, dict(lo=0.0)),
        ("planet.bearing_stiffness", p.planet.bearing, positive),
        ("carrier.bearing_stiffness", p.carrier.bearing, dict(lo=0.0)),
        ("sun.torsional_stiffness", p.sun.torsional, dict(lo=0.0)),
        ("mesh.sun_planet_stiffness", p.mesh.sun_planet, positive),
        ("mesh.ring_planet_stiffness", p.mesh.ring_planet, positive),
        (
            "mesh.pressure_angle_deg",
            jnp.rad2deg(p.mesh.pressure_angle),
            dict(lo=0.0, hi=45.0, lo_closed=False, hi_closed=False, unit="degrees"),
        ),
        ("mesh.half_backlash", p.mesh.half_backlash, dict(lo=0.0, unit="m")),
        ("mesh.contact_ratio_sun", p.mesh.contact_ratio_sun, dict(lo=1.0, hi=2.0)),
        ("mesh.contact_ratio_ring", p.mesh.contact_ratio_ring, dict(lo=1.0, hi=2.0)),
        ("mesh.stiffness_variation", p.mesh.stiffness_variation, dict(lo=0.0, hi=1.0, hi_closed=False)),
        ("mesh.carrier_speed", p.mesh.carrier_speed, dict(positive, unit="rad/s")),
        ("wind.mean_wind_speed", p.wind.mean_wind_speed, dict(positive, unit="m/s")),
        ("wind.turbulence_intensity", p.wind.turbulence_intensity, dict(lo=0.0)),
        ("wind.turbulence_length", p.wind.turbulence_length, dict(positive, unit="m")),
        ("wind.spectral_density", p.wind.spectral_density, positive),
        ("wind.a2", p.wind.a2, positive),
        ("damping.alpha", p.damping.alpha, dict(lo=0.0)),
        ("damping.beta", p.damping.beta, dict(lo=0.0)),
        (
            "damping.modal_ratio",
            p.damping.modal_ratio,
            dict(lo=0.0, hi=1.0, lo_closed=False, hi_closed=False),
        ),
    ]:
        check_range(name, value, **bounds)
    if p.mesh.harmonics < 0:
        raise ValueError(f"`mesh.harmonics` must be >= 0, got {p.mesh.harmonics}")
    check_range("ring_pitch_radius", p.ring_pitch_radius, lo=0.0, lo_closed=False, unit="m")
    # the ring's own checks again: a design variable or a sweep sets ring values with eqx.tree_at, which
    # bypasses RingParams.__check_init__; names are the attribute paths such code uses (ring.thickness)
    validate_ring(p.ring, prefix="ring.")


# --------------------------------------------------------------------------------------------- layout


class Layout(eqx.Module):
    """DOF indices of the assembled model."""

    n_dof: int = eqx.field(static=True)
    n_planets: int = eqx.field(static=True)
    ring_start: int = eqx.field(static=True)
    n_ring: int = eqx.field(static=True)
    names: tuple = eqx.field(static=True)

    def sun(self, k):  # k = 0 x, 1 y, 2 u
        return k

    def planet(self, n, k):  # k = 0 xi, 1 eta, 2 u
        return 3 + 3 * n + k

    def carrier(self, k):
        return 3 + 3 * self.n_planets + k

    @property
    def chi(self):
        return self.n_dof - 1


def layout(p: PlanetaryParams) -> Layout:
    names = ["sun_x", "sun_y", "sun_u"]
    for n in range(p.n_planets):
        names += [f"planet{n + 1}_xi", f"planet{n + 1}_eta", f"planet{n + 1}_u"]
    names += ["carrier_x", "carrier_y", "carrier_u"]
    ring_start = len(names)
    if p.ring_model == "elastic":
        names += ring_dof_names(p.ring)
    else:
        names += ["ring_x", "ring_y", "ring_u"]
    n_ring = len(names) - ring_start
    names += ["wind_filter_chi"]
    return Layout(len(names), p.n_planets, ring_start, n_ring, tuple(names))


def dof_units(lay: Layout) -> tuple[str, ...]:
    return tuple(
        "rad" if name.endswith("_rotation") else ("-" if name == "wind_filter_chi" else "m")
        for name in lay.names
    )


# ------------------------------------------------------------------------------------ spring directions


def _unit(n_dof, entries):
    """A dense g vector from {index: coefficient}."""
    g = jnp.zeros(n_dof)
    for i, c in entries.items():
        g = g.at[i].add(c)
    return g


def sun_planet_direction(p: PlanetaryParams, lay: Layout, n: int):
    """g of delta_sp,n (Eq. 3.2 derived in the module docstring)."""
    a = p.mesh.pressure_angle
    psi = p.planet_angles()[n]
    return _unit(
        lay.n_dof,
        {
            lay.sun(0): -jnp.sin(psi - a),
            lay.sun(1): jnp.cos(psi - a),
            lay.sun(2): 1.0,
            lay.planet(n, 0): -jnp.sin(a),
            lay.planet(n, 1): -jnp.cos(a),
            lay.planet(n, 2): 1.0,
        },
    )


def ring_planet_lumped_part(p: PlanetaryParams, lay: Layout, n: int):
    """Planet part of g of delta_rp,n: ``d_p . n - u_p`` (the ring part is added by :func:`ring_part`)."""
    a = p.mesh.pressure_angle
    return _unit(
        lay.n_dof, {lay.planet(n, 0): jnp.sin(a), lay.planet(n, 1): -jnp.cos(a), lay.planet(n, 2): -1.0}
    )


def elastic_ring_part(p: PlanetaryParams, theta, nodal_inverse=None):
    """Ring part of g (over the ring DOFs) at contact angle ``theta``:
    ``sin a u_r + cos a (u_tau - e u_theta)``. ``p``: :func:`resolved` parameters (this runs at every
    step); ``nodal_inverse``: the ring's :func:`~pgtjax.models.ring.ring_nodal_inverse` if already formed."""
    a = p.mesh.pressure_angle
    rows = ring_interpolation(p.ring, theta, nodal_inverse)
    return jnp.sin(a) * rows[0] + jnp.cos(a) * (rows[1] - p.pitch_offset * rows[2])


def rigid_ring_part(p: PlanetaryParams, psi):
    """Ring part of g for the rigid ring (x_r, y_r, u_r): ``-d_R . n + u_r``."""
    a = p.mesh.pressure_angle
    return jnp.stack([-jnp.sin(psi + a), jnp.cos(psi + a), jnp.ones(())])


class ContactDirections(eqx.Module):
    """``t -> G(t)`` (n_dof, 2N): columns sun-planet 1..N, then ring-planet 1..N; the ring-planet columns move
    with the planets around the elastic ring (contact angle ``omega_c t + psi_n``, Eq. 3.14)."""

    constant: jax.Array  # (n_dof, 2N) lumped parts
    # its ring without the bolts (models.ring.without_supports), which G does not read
    params: PlanetaryParams
    lay: Layout
    # the ring elements' shape-function inverse (6, 6), independent of t: formed with the system so that a
    # time loop (and its reverse pass) does not refactorize it at every step. Like ``constant`` it is derived
    # from ``params`` when built: rebuild with :func:`contact_directions` after changing the ring.
    ring_nodal_inverse: jax.Array | None = None

    def __call__(self, t):
        p, lay = self.params, self.lay
        if p.ring_model == "rigid":
            return self.constant
        psi = jnp.asarray(p.planet_angles())
        thetas = p.mesh.carrier_speed * t + psi
        part = lambda th: elastic_ring_part(p, th, self.ring_nodal_inverse)  # noqa: E731
        ring_cols = jax.vmap(part)(thetas)  # (N, n_ring)
        return self.constant.at[lay.ring_start : lay.ring_start + lay.n_ring, p.n_planets :].add(ring_cols.T)


def contact_directions(p: PlanetaryParams, lay: Layout) -> ContactDirections:
    p = resolved(p)
    n = p.n_planets
    cols = [sun_planet_direction(p, lay, k) for k in range(n)]
    for k in range(n):
        g = ring_planet_lumped_part(p, lay, k)
        if p.ring_model == "rigid":
            g = g.at[lay.ring_start : lay.ring_start + 3].add(rigid_ring_part(p, p.planet_angles()[k]))
        cols.append(g)
    nodal_inverse = ring_nodal_inverse(p.ring) if p.ring_model == "elastic" else None
    # the bolts enter K only: without them, designs that differ in their bolts share one compiled solver
    p = eqx.tree_at(lambda q: q.ring, p, without_supports(p.ring))
    return ContactDirections(jnp.stack(cols, axis=1), p, lay, nodal_inverse)


class MeshStiffness(eqx.Module):
    """``t -> (2N,)`` mesh stiffnesses: rectangular waves as Fourier series (module docstring)."""

    mean: jax.Array  # (2N,)
    amplitude: jax.Array  # (2N,) dk
    duty: jax.Array  # (2N,) c - 1
    phase: jax.Array  # (2N,) Omega (fraction of a mesh period)
    frequency: jax.Array
    harmonics: int = eqx.field(static=True)

    def __call__(self, t):
        if self.harmonics == 0:
            return self.mean
        j = jnp.arange(1, self.harmonics + 1, dtype=jnp.float64)[:, None]
        coef = 2.0 / (j * jnp.pi) * jnp.sin(j * jnp.pi * self.duty[None, :])
        angle = (
            j * (self.frequency * t - 2.0 * jnp.pi * self.phase[None, :]) - j * jnp.pi * self.duty[None, :]
        )
        return self.mean + self.amplitude * jnp.sum(coef * jnp.cos(angle), axis=0)


def mesh_stiffness(p: PlanetaryParams) -> MeshStiffness:
    n = p.n_planets
    m = p.mesh
    ones = jnp.ones(n)
    mean = jnp.concatenate([m.sun_planet * ones, m.ring_planet * ones])
    return MeshStiffness(
        mean=mean,
        amplitude=m.stiffness_variation * mean,
        duty=jnp.concatenate([(m.contact_ratio_sun - 1.0) * ones, (m.contact_ratio_ring - 1.0) * ones]),
        phase=jnp.concatenate([0.0 * ones, m.phase_sun_ring * ones]),
        frequency=m.mesh_frequency,
        harmonics=m.harmonics,
    )


# ------------------------------------------------------------------------------------------ assembly


def ring_block(p: PlanetaryParams):
    """(M, K) of the ring DOFs: the assembled curved-beam ring with its bolts, or the rigid ring body."""
    if p.ring_model == "elastic":
        return ring_matrices(p.elastic_ring)
    rr = p.rigid_ring
    m = jnp.diag(jnp.stack([rr.mass, rr.mass, rr.inertia / rr.radius**2]))
    k = jnp.diag(jnp.stack([rr.bearing, rr.bearing, rr.torsional / rr.radius**2]))
    return m, k


def mass_matrix(p: PlanetaryParams, lay: Layout, ring=None):
    """Eqs. 3.68-3.70: diag(m, m, I/r^2) per lumped body, the ring's mass, a2 T_v^2 for the filter."""
    diag = jnp.zeros(lay.n_dof)
    for idx, body in (
        [((0, 1, 2), p.sun)]
        + [((lay.planet(k, 0), lay.planet(k, 1), lay.planet(k, 2)), p.planet) for k in range(p.n_planets)]
        + [((lay.carrier(0), lay.carrier(1), lay.carrier(2)), p.carrier)]
    ):
        diag = diag.at[jnp.array(idx)].set(jnp.stack([body.mass, body.mass, body.inertia / body.radius**2]))
    tv = p.wind.time_constant()
    diag = diag.at[lay.chi].set(p.wind.a2 * tv**2)
    mass = jnp.diag(diag)
    rs = slice(lay.ring_start, lay.ring_start + lay.n_ring)
    m_ring, _ = ring_block(p) if ring is None else ring
    return mass.at[rs, rs].set(m_ring)


def structural_stiffness(p: PlanetaryParams, lay: Layout, ring=None):
    """Bearings, shafts, planet bearings and the ring (with its bolts); no meshes, no wind coupling."""
    k = jnp.zeros((lay.n_dof, lay.n_dof))
    springs = []
    for i in (0, 1):
        springs.append((_unit(lay.n_dof, {lay.sun(i): 1.0}), p.sun.bearing))
        springs.append((_unit(lay.n_dof, {lay.carrier(i): 1.0}), p.carrier.bearing))
    springs.append((_unit(lay.n_dof, {lay.sun(2): 1.0}), p.sun.torsional / p.sun.radius**2))
    springs.append((_unit(lay.n_dof, {lay.carrier(2): 1.0}), p.carrier.torsional / p.carrier.radius**2))
    for n, psi in enumerate(p.planet_angles()):
        c, s = math.cos(psi), math.sin(psi)
        radial = {lay.planet(n, 0): 1.0, lay.carrier(0): -c, lay.carrier(1): -s}
        tangential = {lay.planet(n, 1): 1.0, lay.carrier(0): s, lay.carrier(1): -c, lay.carrier(2): -1.0}
        springs += [
            (_unit(lay.n_dof, radial), p.planet.bearing),
            (_unit(lay.n_dof, tangential), p.planet.bearing),
        ]
    for g, stiffness in springs:
        k = k + stiffness * jnp.outer(g, g)
    rs = slice(lay.ring_start, lay.ring_start + lay.n_ring)
    _, k_ring = ring_block(p) if ring is None else ring
    k = k.at[rs, rs].add(k_ring)
    return k.at[lay.chi, lay.chi].add(1.0)  # filter: chi + ... = W (Eq. 3.31)


def mean_mesh_stiffness_matrix(p: PlanetaryParams, lay: Layout, t=0.0):
    """``G diag(k_mean) G^T`` at time t: the meshes closed at their mean stiffness."""
    g = contact_directions(p, lay)(t)
    return (g * mesh_stiffness(p).mean[None, :]) @ g.T


def _wind_coupling(p: PlanetaryParams, lay: Layout):
    """T_r / R_c moved to the left-hand side: (K, C) entries in the carrier row, chi column."""
    gain = (
        p.wind.torque_sensitivity(p.mesh.carrier_speed) * p.wind.turbulence_intensity * p.wind.mean_wind_speed
    )
    gain = gain * p.wind.filter_gain() / p.carrier.radius
    tv = p.wind.time_constant()
    return -gain, -gain * p.wind.a1 * tv


def _damping(p: PlanetaryParams, lay: Layout, mass, k_mean):
    """Eq. 3.91 (Rayleigh) or modal damping ratios, on the mechanical DOFs; the filter's own term."""
    mech = lay.n_dof - 1
    m1, k1 = mass[:mech, :mech], k_mean[:mech, :mech]
    if p.damping.model == "rayleigh":
        c1 = p.damping.alpha * m1 + p.damping.beta * k1
    else:
        eig = symmetric_eigen(m1, k1)
        omega = jnp.sqrt(jnp.maximum(eig.values, 0.0))
        # C = M Phi diag(2 zeta omega) Phi^T M with Phi = L^-T y (mass-normalised)
        left = eig.factor @ eig.rotated
        c1 = (left * (2.0 * p.damping.modal_ratio * omega)[None, :]) @ left.T
    c = jnp.zeros((lay.n_dof, lay.n_dof)).at[:mech, :mech].set(c1)
    tv = p.wind.time_constant()
    return c.at[lay.chi, lay.chi].set(p.wind.a2 * tv + tv)


def build(p: PlanetaryParams | None = None) -> System:
    """Build the :class:`System` of thesis Eq. 3.43 / 3.54 (see the module docstring); ``None``: the
    embedded defaults. Parameters are validated here too, since ``eqx.tree_at`` bypasses ``__check_init__``."""
    if p is not None and not isinstance(p, PlanetaryParams):
        raise ValueError(f"`p` must be PlanetaryParams (planetary.load_params / default_params), got {p!r}")
    p = resolved(default_params() if p is None else p)
    validate(p)
    return _assemble_system(p)


@eqx.filter_jit  # one compiled program: run op by op, a first build compiled about 150 small kernels (seconds)
def _assemble_system(p: PlanetaryParams) -> System:
    lay = layout(p)
    ring = ring_block(p)  # assembled once for both matrices
    mass = mass_matrix(p, lay, ring)
    k_struct = structural_stiffness(p, lay, ring)
    k_mean = k_struct + mean_mesh_stiffness_matrix(p, lay)
    damping = _damping(p, lay, mass, k_mean)
    k_wind, c_wind = _wind_coupling(p, lay)
    stiffness = k_struct.at[lay.carrier(2), lay.chi].add(k_wind)
    damping = damping.at[lay.carrier(2), lay.chi].add(c_wind)
    load = (
        jnp.zeros(lay.n_dof)
        .at[lay.carrier(2)]
        .set(p.wind.mean_torque(p.mesh.carrier_speed) / p.carrier.radius)
    )
    noise = jnp.zeros((lay.n_dof, 1)).at[lay.chi, 0].set(1.0)
    names = [f"sun_planet{k + 1}" for k in range(p.n_planets)] + [
        f"ring_planet{k + 1}" for k in range(p.n_planets)
    ]
    b = p.mesh.half_backlash * jnp.ones(2 * p.n_planets)
    return System(
        mass=mass,
        stiffness=stiffness,
        damping=damping,
        load=load,
        noise_input=noise,
        spectral_density=p.wind.spectral_density,
        contacts=Contacts(contact_directions(p, lay), mesh_stiffness(p), b, names=names, law=Backlash()),
        dof_names=lay.names,
        dof_units=dof_units(lay),
    )


planetary = build  # the builder's former name, kept for existing scripts


def wind_filter_stationary_covariance(p: PlanetaryParams, lay: Layout):
    """(2n, 2n) covariance with the filter state (chi, chi') at its stationary values and zeros elsewhere:
    Var chi = pi S0 / c, Var chi' = pi S0 / (c m), uncorrelated (m = a2 T_v^2, c = (a2 + 1) T_v)."""
    tv = p.wind.time_constant()
    m, c = p.wind.a2 * tv**2, (p.wind.a2 + 1.0) * tv
    s0 = p.wind.spectral_density
    cov = jnp.zeros((2 * lay.n_dof, 2 * lay.n_dof))
    cov = cov.at[lay.chi, lay.chi].set(jnp.pi * s0 / c)
    return cov.at[lay.n_dof + lay.chi, lay.n_dof + lay.chi].set(jnp.pi * s0 / (c * m))


def mode_type(p: PlanetaryParams, lay: Layout, mass, shape) -> str:
    """Classify a mode (Lin & Parker's families, plus ring modes) by where its kinetic energy lies:
    'ring' (most in the elastic ring), 'filter', 'planet' (central members at rest), 'rotational' or
    'translational' (central members mostly rotating or translating)."""
    shape = np.asarray(shape)
    ke = shape * (np.asarray(mass) @ shape)
    total = ke.sum()
    ring = ke[lay.ring_start : lay.ring_start + lay.n_ring].sum()
    if ke[lay.chi] > 0.5 * total:
        return "filter"
    if p.ring_model == "elastic" and ring > 0.5 * total:
        return "ring"
    central_t = [lay.sun(0), lay.sun(1), lay.carrier(0), lay.carrier(1)]
    central_r = [lay.sun(2), lay.carrier(2)]
    if p.ring_model == "rigid":
        central_t += [lay.ring_start, lay.ring_start + 1]
        central_r += [lay.ring_start + 2]
    t, r = ke[central_t].sum(), ke[central_r].sum()
    if t + r < 1e-6 * total:
        return "planet"
    return "rotational" if r > t else "translational"
