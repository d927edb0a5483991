"""Transverse-torsional spur gear pair with backlash, thesis ch. 4 (Eqs. 4.1-4.18).

Coordinates ``q = (y1, y2, z)`` (m): bearing translations of the two gears along the line of action and the
relative torsional displacement ``z = theta1 r1 - theta2 r2`` (Eq. 4.5-4.7). Mesh deflection
``delta = y1 - y2 + z`` (Eq. 4.10), so the contact direction is ``g = (1, -1, 1)``: the mesh force acts with
signs ``{+f, -f, +f}`` on the three equations (docs/corrections.md C3: the printed ``F_int = {f f f}`` of Eq. 4.16 drops the
sign that Eqs. 4.5-4.7 and 4.28 carry). ``M = diag(m1, m2, m_c)`` with the equivalent mass
``m_c = I1 I2 / (I2 r1^2 + I1 r2^2)`` (Eq. 4.8; the printed ``diag(m m m_c)`` of Eq. 4.13 means this).

The torsional load: eliminating theta1 and theta2 from Eqs. 4.2 and 4.4 gives
``m_c z'' + f = m_c (T_in r1 / I1 + T_out r2 / I2)``; with balanced torques (``T_out = T_in r2 / r1``) this is
the ``T_in / r1`` of Eq. 4.7. We keep the general form so that the thesis's ``T_out`` values (which are within
0.4 % of balanced) are used as given. Random excitation ``B w`` enters the z equation only (Eq. 4.18).

Mesh stiffness: Fourier series of Eq. 4.11 at the mesh frequency ``omega = a1 * pinion speed``.
Damping: ``C = alpha M + beta K`` (thesis section 4.2: "proportional damping", no values given), with
``K = K_s + k0 g g^T``; by default alpha, beta give the damping ratio ``damping_ratio`` at the lowest and the
highest natural frequency of (M, K) (Rayleigh fit). Both may be given directly instead.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import Backlash, Contacts, FourierSeries, System
from .. import params as _params
from .._validate import check_range

DOF_NAMES = ("y1", "y2", "z")
CONTACT_NAMES = ("mesh",)


class GearPairParams(eqx.Module):
    """Parameters of the gear pair (SI units; see ``pgtjax/params/gear_pair.toml`` for the defaults)."""

    mass_1: jax.Array  # kg
    mass_2: jax.Array  # kg
    inertia_1: jax.Array  # kg m^2
    inertia_2: jax.Array  # kg m^2
    pitch_radius_1: jax.Array  # m
    pitch_radius_2: jax.Array  # m
    bearing_stiffness_1: jax.Array  # N/m
    bearing_stiffness_2: jax.Array  # N/m
    mesh_stiffness: jax.Array  # mean k_0, N/m
    mesh_sin: jax.Array  # k_a^(j), N/m
    mesh_cos: jax.Array  # k_b^(j), N/m
    pinion_speed_rpm: jax.Array  # rpm
    half_backlash: jax.Array  # b, m
    damping_ratio: jax.Array  # Rayleigh fit target (-)
    noise_amplitude: jax.Array  # w_0, N
    spectral_density: jax.Array  # S_0
    torque_in: jax.Array  # N m
    torque_out: jax.Array  # N m
    teeth_1: int = eqx.field(static=True)
    teeth_2: int = eqx.field(static=True)
    rayleigh: tuple | None = eqx.field(static=True, default=None)  # (alpha 1/s, beta s) overrides the fit

    def __check_init__(self):
        validate(self)

    @property
    def mesh_frequency(self):
        """Mesh frequency (rad/s): teeth of gear 1 times its speed."""
        return self.teeth_1 * self.pinion_speed_rpm * 2.0 * jnp.pi / 60.0

    @property
    def equivalent_mass(self):
        """m_c of Eq. 4.8 (kg)."""
        r1, r2 = self.pitch_radius_1, self.pitch_radius_2
        return self.inertia_1 * self.inertia_2 / (self.inertia_2 * r1**2 + self.inertia_1 * r2**2)

    def replace(self, **changes) -> GearPairParams:
        """A copy with some fields changed (floats are converted to float64 arrays)."""
        fields = {f.name for f in dataclasses.fields(self)}
        for name, value in changes.items():
            if name not in fields:
                raise ValueError(f"unknown gear-pair parameter {name!r}; known: {', '.join(sorted(fields))}")
            if name not in ("teeth_1", "teeth_2", "rayleigh"):
                changes[name] = jnp.asarray(value, dtype=jnp.float64)
        return dataclasses.replace(self, **changes)  # __init__ and __check_init__ run: validated


_POSITIVE = (
    "mass_1",
    "mass_2",
    "inertia_1",
    "inertia_2",
    "pitch_radius_1",
    "pitch_radius_2",
    "bearing_stiffness_1",
    "bearing_stiffness_2",
    "mesh_stiffness",
    "pinion_speed_rpm",
)


def validate(p: GearPairParams) -> None:
    """``ValueError`` naming the parameter for values outside their physical range."""
    for name in _POSITIVE:
        check_range(name, getattr(p, name), lo=0.0, lo_closed=False)
    check_range("half_backlash", p.half_backlash, lo=0.0, unit="m")
    check_range("damping_ratio", p.damping_ratio, lo=0.0, hi=1.0, lo_closed=False, hi_closed=False)
    check_range("spectral_density", p.spectral_density, lo=0.0)
    for name in ("noise_amplitude", "torque_in", "torque_out", "mesh_sin", "mesh_cos"):
        check_range(name, getattr(p, name))
    if np.shape(p.mesh_sin) != np.shape(p.mesh_cos):
        raise ValueError("`sin_coefficients` and `cos_coefficients` must have the same length")
    if all(_concrete(x) for x in (p.mesh_stiffness, p.mesh_sin, p.mesh_cos)):
        # harmonic j has amplitude sqrt(a_j^2 + b_j^2): their sum bounds the variation of k_h(t)
        amplitude = float(np.sum(np.hypot(np.asarray(p.mesh_sin), np.asarray(p.mesh_cos))))
        if amplitude >= float(p.mesh_stiffness):
            raise ValueError(
                "`mesh_sin`/`mesh_cos`: the harmonic amplitudes must sum to less than "
                f"`mesh_stiffness` so that k_h(t) > 0; got {amplitude} >= {float(p.mesh_stiffness)}"
            )
    for name in ("teeth_1", "teeth_2"):
        teeth = getattr(p, name)
        if isinstance(teeth, bool) or not isinstance(teeth, int | np.integer) or teeth < 1:
            raise ValueError(f"`{name}` must be an integer >= 1, got {teeth!r}")


def _concrete(x) -> bool:
    return eqx.is_array(x) and not isinstance(x, jax.core.Tracer)


def default_params() -> GearPairParams:
    """Thesis Table 4.1 with the documented assumptions of ``gear_pair.toml`` (heavy-load regime)."""
    return load_params(_params.path("gear_pair.toml"))


def load_params(source=None) -> GearPairParams:
    """Read a gear-pair parameter file (TOML, same layout as the embedded ``gear_pair.toml``) or a dict;
    ``None``: the embedded file. Values are checked on construction (``ValueError`` naming the entry)."""
    data = _params.read_params(source, "gear_pair")  # ValueError naming table.key for a bad entry
    try:
        g, m, d, e = data["gears"], data["mesh"], data["damping"], data["excitation"]
        f = lambda x: jnp.asarray(x, dtype=jnp.float64)  # noqa: E731
        rayleigh = (float(d["alpha"]), float(d["beta"])) if "alpha" in d else None
        p = GearPairParams(
            mass_1=f(g["mass_1"]),
            mass_2=f(g["mass_2"]),
            inertia_1=f(g["inertia_1"]),
            inertia_2=f(g["inertia_2"]),
            pitch_radius_1=f(g["pitch_radius_1"]),
            pitch_radius_2=f(g["pitch_radius_2"]),
            bearing_stiffness_1=f(g["bearing_stiffness_1"]),
            bearing_stiffness_2=f(g["bearing_stiffness_2"]),
            mesh_stiffness=f(m["mean_stiffness"]),
            mesh_sin=f(m.get("sin_coefficients", [])),
            mesh_cos=f(m.get("cos_coefficients", [])),
            pinion_speed_rpm=f(m["pinion_speed_rpm"]),
            half_backlash=f(m["half_backlash"]),
            damping_ratio=f(d.get("damping_ratio", 0.05)),
            noise_amplitude=f(e["noise_amplitude"]),
            spectral_density=f(e["spectral_density"]),
            torque_in=f(e["torque_in"]),
            torque_out=f(e["torque_out"]),
            teeth_1=int(g["teeth_1"]),
            teeth_2=int(g["teeth_2"]),
            rayleigh=rayleigh,
        )
    except KeyError as err:
        raise ValueError(f"gear-pair parameter file is missing the entry {err}") from None
    return p


def load_regimes(source=None) -> list[tuple[str, float, float]]:
    """The ``[regimes]`` table of a parameter file: ``[(name, T_in, T_out), ...]`` (N m)."""
    r = _params.read_params(source, "gear_pair").get("regimes")
    if r is None:
        where = f"parameter file `{source}`" if isinstance(source, str | Path) else "the parameters"
        raise ValueError(
            f"{where} have no [regimes] table (load regimes: regimes.torque_in, torque_out, names)"
        )
    return [(str(n), float(a), float(b)) for n, a, b in zip(r["names"], r["torque_in"], r["torque_out"])]


CONTACT_DIRECTION = np.array([[1.0], [-1.0], [1.0]])


def mass_matrix(p: GearPairParams):
    return jnp.diag(jnp.stack([p.mass_1, p.mass_2, p.equivalent_mass]))


def bearing_stiffness(p: GearPairParams):
    """K_s of Eq. 4.15."""
    return jnp.diag(jnp.stack([p.bearing_stiffness_1, p.bearing_stiffness_2, jnp.zeros(())]))


def rayleigh_coefficients(p: GearPairParams):
    """(alpha, beta) of ``C = alpha M + beta K`` with ``K = K_s + k0 g g^T``."""
    if p.rayleigh is not None:
        return jnp.asarray(p.rayleigh[0]), jnp.asarray(p.rayleigh[1])
    mass = mass_matrix(p)
    g = jnp.asarray(CONTACT_DIRECTION)
    k = bearing_stiffness(p) + p.mesh_stiffness * (g @ g.T)
    lam = jnp.linalg.eigvalsh(k / jnp.sqrt(jnp.outer(jnp.diag(mass), jnp.diag(mass))))
    w1, w2 = jnp.sqrt(lam[0]), jnp.sqrt(lam[-1])
    zeta = p.damping_ratio
    # zeta = alpha/(2w) + beta w/2 at w1 and w2
    alpha = 2.0 * zeta * w1 * w2 / (w1 + w2)
    beta = 2.0 * zeta / (w1 + w2)
    return alpha, beta


def mesh_stiffness_function(p: GearPairParams) -> FourierSeries:
    """k_h(t) of Eq. 4.11 (N/m)."""
    return FourierSeries(
        mean=p.mesh_stiffness[None],
        sin_coefficients=p.mesh_sin[:, None],
        cos_coefficients=p.mesh_cos[:, None],
        frequency=p.mesh_frequency,
    )


def build(p: GearPairParams | None = None) -> System:
    """Build the :class:`System` of Eq. 4.12 from parameters (default: :func:`default_params`); validated
    here too, since ``eqx.tree_at`` bypasses ``__check_init__``."""
    p = default_params() if p is None else p
    if not isinstance(p, GearPairParams):
        raise ValueError(f"`p` must be GearPairParams (gear_pair.load_params / default_params), got {p!r}")
    validate(p)
    mass = mass_matrix(p)
    g = jnp.asarray(CONTACT_DIRECTION)
    alpha, beta = rayleigh_coefficients(p)
    k_s = bearing_stiffness(p)
    damping = alpha * mass + beta * (k_s + p.mesh_stiffness * (g @ g.T))
    r1, r2 = p.pitch_radius_1, p.pitch_radius_2
    torsional_load = p.equivalent_mass * (p.torque_in * r1 / p.inertia_1 + p.torque_out * r2 / p.inertia_2)
    zero = jnp.zeros(())
    return System(
        mass=mass,
        stiffness=k_s,
        damping=damping,
        load=jnp.stack([zero, zero, torsional_load]),
        noise_input=jnp.stack([zero, zero, p.noise_amplitude])[:, None],
        spectral_density=p.spectral_density,
        contacts=Contacts(
            g, mesh_stiffness_function(p), p.half_backlash[None], names=CONTACT_NAMES, law=Backlash()
        ),
        dof_names=DOF_NAMES,
        dof_units=("m", "m", "m"),
    )


gear_pair = build  # the builder's former name, kept for existing scripts


def static_deflection(p: GearPairParams):
    """Mean mesh deflection in permanent contact under the mean stiffness: ``b + F_z / k_eq`` (m), where the
    bearings and the mesh act in series along g."""
    r1, r2 = p.pitch_radius_1, p.pitch_radius_2
    f_z = p.equivalent_mass * (p.torque_in * r1 / p.inertia_1 + p.torque_out * r2 / p.inertia_2)
    return p.half_backlash + f_z / p.mesh_stiffness
