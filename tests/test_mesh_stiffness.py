"""Tests of pgtjax.models.mesh_stiffness against independent computations."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import integrate

from pgtjax.models import mesh_stiffness as ms
from pgtjax.params import path as params_path
from pgtjax.params import read_toml

# Numbers reported by the paper (Hammami et al., section 5): mean Hertzian stiffness during the run-up.
PAPER_HS_SUN = (1.13e9, 1.234e9)
PAPER_HS_RING = (2.102e9, 2.243e9)


@pytest.fixture(scope="module")
def bench():
    return ms.back_to_back_meshes(read_toml(params_path("back_to_back.toml")))


@pytest.fixture(scope="module")
def cycles(bench):
    """One mesh cycle of each mesh under the nominal load (sun drives the planet, planet drives the ring)."""
    sun = ms.mesh_cycle(bench.sun_planet, bench.mesh_load, 64, pinion_drives=False)
    ring = ms.mesh_cycle(bench.ring_planet, bench.mesh_load, 64, pinion_drives=True)
    return sun, ring


# ------------------------------------------------------------------ independent geometry (numpy only)


def _path_by_circle_intersection(z1, z2, m, alpha, ha, internal):
    """Active path length of contact from 2D circle/line intersections (no closed form used)."""
    r1, r2 = 0.5 * m * z1, 0.5 * m * z2
    o1 = np.array([0.0, 0.0])
    if internal:  # ring centre on the same side as the pitch point, farther away
        o2 = np.array([r1 - r2, 0.0])
        ra2 = r2 - ha * m
    else:
        o2 = np.array([r1 + r2, 0.0])
        ra2 = r2 + ha * m
    ra1 = r1 + ha * m
    pitch = np.array([r1, 0.0])
    u = np.array([math.sin(alpha), math.cos(alpha)])  # line of action through the pitch point

    def hits(center, radius):
        # |pitch + t u - center| = radius, both roots
        w = pitch - center
        b = 2 * w @ u
        c = w @ w - radius**2
        disc = math.sqrt(b * b - 4 * c)
        return np.array([(-b - disc) / 2, (-b + disc) / 2])

    t1 = hits(o1, ra1)
    t2 = hits(o2, ra2)
    # the pinion tip circle and the gear tip circle cut the line on opposite sides of the pitch point;
    # keep the crossing nearest to the pitch point on each side
    t_pin = t1[np.argmin(np.abs(t1))]
    t_gear = t2[np.argmin(np.abs(t2))]
    assert t_pin * t_gear < 0
    return abs(t_pin), abs(t_gear), math.pi * m * math.cos(alpha)


# ------------------------------------------------------------------ Hertz (Eqs. 11-13)


def test_hertz_stiffness_is_autodiff_derivative_of_force_law():
    length = jnp.array([0.01, 0.02, 0.04])
    delta = jnp.array([1e-7, 2e-6, 1.5e-5])
    closed = ms.hertz_stiffness(delta, length)
    auto = jax.vmap(jax.grad(ms.hertz_force))(delta, length)
    np.testing.assert_allclose(auto, closed, rtol=1e-12)
    # and a finite difference of the force law, independent of autodiff
    h = 1e-6 * delta
    fd = (ms.hertz_force(delta + h, length) - ms.hertz_force(delta - h, length)) / (2 * h)
    np.testing.assert_allclose(fd, closed, rtol=1e-7)
    # secant (Eq. 13) = F/delta; no force and no stiffness out of contact
    secant = ms.hertz_secant_stiffness(delta, length)
    np.testing.assert_allclose(secant, ms.hertz_force(delta, length) / delta)
    assert float(ms.hertz_force(-1e-6, 0.02)) == 0.0 and float(ms.hertz_stiffness(-1e-6, 0.02)) == 0.0


def test_hertz_units_eq11_and_eq12_are_mutual_inverses_in_mm_and_newton():
    # Eq. 12 in its native units, evaluated by hand: l = 20 mm, delta = 5 um = 0.005 mm
    f_native = 56065.703 * 20.0**0.92 * 0.005**1.08
    assert float(ms.hertz_force(5e-6, 0.02)) == pytest.approx(f_native, rel=1e-12)
    forces = jnp.array([50.0, 500.0, 2000.0, 10000.0])
    for length in (0.01, 0.02, 0.05):
        d12 = ms.hertz_deflection(forces, length)
        np.testing.assert_allclose(ms.hertz_force(d12, length), forces, rtol=1e-12)
        d11 = ms.hertz_deflection_eq11(forces, length)
        # the printed exponents are rounded: the two fits agree to a few percent, not exactly
        np.testing.assert_allclose(d11, d12, rtol=0.06)


# ------------------------------------------------------------------ bending (Eqs. 3-7), series (Eq. 1)


def test_cornell_uniform_beam_matches_cantilever_closed_form():
    length, half, width, beta = 0.008, 0.003, 0.02, 0.4
    e_beam, g_mod, ks = 2.3e11, 8.1e10, 5 / 6
    xi = jnp.linspace(0.0, length, 11)
    c = ms.cornell_beam_compliance(xi, jnp.full(11, half), length, beta, width, e_beam, g_mod, ks)
    inertia, area = width * (2 * half) ** 3 / 12, width * 2 * half
    exact = math.cos(beta) ** 2 * (
        length**3 / (3 * e_beam * inertia)
        + length / (ks * g_mod * area)
        + math.tan(beta) ** 2 * length / (e_beam * area)
    )
    assert float(c) == pytest.approx(exact, rel=1e-12)


def test_cornell_tapered_beam_converges_to_energy_integral():
    # linearly tapered tooth loaded beyond its end (ring-like): compare with quadrature of the energy
    length, xi_load, width, beta = 0.008, 0.0065, 0.02, 0.5
    e_beam, g_mod, ks = 2.3e11, 8.1e10, 5 / 6

    def y(x):
        return 0.004 - 0.002 * x / length

    def integrand(x):
        h = 2 * y(x)
        return math.cos(beta) ** 2 * (
            12 * (xi_load - x) ** 2 / (e_beam * width * h**3)
            + 1 / (ks * g_mod * width * h)
            + math.tan(beta) ** 2 / (e_beam * width * h)
        )

    exact = integrate.quad(integrand, 0.0, length, epsabs=0, epsrel=1e-12)[0]
    xi = np.linspace(0.0, length, 201)
    c = ms.cornell_beam_compliance(
        jnp.asarray(xi), jnp.asarray(y(xi)), xi_load, beta, width, e_beam, g_mod, ks
    )
    assert float(c) == pytest.approx(exact, rel=2e-4)


def test_series_stiffness_is_below_every_component(bench):
    for mesh in (bench.sun_planet, bench.ring_planet):
        path = ms.contact_path(mesh)
        s = jnp.linspace(path.s_start, path.s_end, 7)
        for load in (200.0, 2000.0):
            pk = jax.vmap(lambda x, ld=load: ms.pair_stiffness(mesh, x, ld))(s)
            comps = np.stack([pk.bending_pinion, pk.fillet_pinion, pk.bending_gear, pk.fillet_gear, pk.hertz])
            assert np.all(comps > 0)
            assert np.all(np.asarray(pk.total)[None, :] < comps)
            np.testing.assert_allclose(pk.total, 1.0 / np.sum(1.0 / comps, axis=0), rtol=1e-12)


def test_load_sharing_is_consistent_with_the_force_law(bench):
    mesh = bench.ring_planet
    load = 1500.0
    for lam in (0.1, 0.8):  # double- and single-tooth zones
        st = ms.mesh_state(mesh, lam, load)
        assert float(jnp.sum(st.pair_loads)) == pytest.approx(load, rel=1e-10)
        # total force at the solved deflection, and its derivative (central difference) = mesh stiffness
        d0 = float(st.deflection)
        f = ms.mesh_force(mesh, lam, d0)
        h = 1e-5 * d0
        k = (ms.mesh_force(mesh, lam, d0 + h) - ms.mesh_force(mesh, lam, d0 - h)) / (2 * h)
        assert float(f) == pytest.approx(load, rel=1e-10)
        assert float(k) == pytest.approx(float(st.stiffness), rel=1e-7)
        # each pair: delta = (bending + fillet compliance) F + Hertz deflection(F)
        pk = jax.vmap(lambda x: ms.pair_stiffness(mesh, x, 200.0))(st.positions)
        c_lin = 1 / pk.bending_pinion + 1 / pk.fillet_pinion + 1 / pk.bending_gear + 1 / pk.fillet_gear
        direct = [ms.pair_linear_compliance(mesh, x) for x in st.positions]
        np.testing.assert_allclose(c_lin, direct, rtol=1e-12)
        rebuilt = c_lin * st.pair_loads + ms.hertz_deflection(st.pair_loads, mesh.face_width)
        on = np.asarray(st.in_contact)
        np.testing.assert_allclose(np.asarray(rebuilt)[on], float(st.deflection), rtol=1e-10)


# ------------------------------------------------------------------ contact ratio and zones


@pytest.mark.parametrize("which", ["sun_planet", "ring_planet"])
def test_single_double_zones_switch_where_the_contact_ratio_says(bench, which):
    mesh = getattr(bench, which)
    t_pin, t_gear, pb = _path_by_circle_intersection(
        mesh.z_pinion,
        mesh.z_gear,
        float(mesh.module),
        float(mesh.pressure_angle),
        float(mesh.addendum_coef),
        mesh.internal,
    )
    eps = (t_pin + t_gear) / pb
    assert 1.0 < eps < 2.0
    assert float(ms.contact_path(mesh).contact_ratio) == pytest.approx(eps, rel=1e-12)
    switch = eps - 1.0  # two pairs during the first (eps - 1) of each mesh period, then one
    for drives in (True, False):
        probes = jnp.array(
            [0.0, 0.5 * switch, switch - 1e-9, switch + 1e-9, 0.5 * (switch + 1.0), 1.0 - 1e-9]
        )
        n = jax.vmap(lambda lam, d=drives: ms.pairs_in_contact(mesh, lam, d))(probes)
        np.testing.assert_array_equal(n, [2, 2, 2, 1, 1, 1])
    drives = mesh.internal  # as in the bench: sun drives the planet, the planet drives the ring
    k_double = ms.mesh_state(mesh, switch - 1e-6, 1000.0, drives).stiffness
    k_single = ms.mesh_state(mesh, switch + 1e-6, 1000.0, drives).stiffness
    assert float(k_double) > 1.3 * float(k_single)  # the stiffness drops when a pair leaves


def test_mean_hertz_stiffness_order_of_magnitude(bench, cycles):
    (_, sun), (_, ring) = cycles
    hs_sun = float(jnp.mean(sun.hertz_secant_stiffness))
    hs_ring = float(jnp.mean(ring.hertz_secant_stiffness))
    print(
        f"\nmean Hertzian stiffness (Eq. 13, secant), load {float(bench.mesh_load):.0f} N, "
        f"W = {float(bench.sun_planet.face_width) * 1e3:.0f} mm: sun-planet {hs_sun:.3e} N/m "
        f"(paper {PAPER_HS_SUN[0]:.3e}-{PAPER_HS_SUN[1]:.3e}), ring-planet {hs_ring:.3e} N/m "
        f"(paper {PAPER_HS_RING[0]:.3e}-{PAPER_HS_RING[1]:.3e}); mean mesh stiffness "
        f"{float(jnp.mean(sun.stiffness)):.3e} / {float(jnp.mean(ring.stiffness)):.3e} N/m"
    )
    for hs in (hs_sun, hs_ring):
        assert 3e8 < hs < 3e9  # the paper's 1e9 N/m range (mm -> m mistakes would be off by 1e3)
    assert hs_ring > hs_sun  # longer path of contact -> more time with two pairs
    # every component of the mesh is stiffer than the mesh: mean mesh stiffness below the Hertz term
    assert float(jnp.mean(sun.stiffness)) < hs_sun and float(jnp.mean(ring.stiffness)) < hs_ring
    # the Hertzian stiffness rises with load (the paper's trend during the run-up)
    hi = ms.mesh_state(bench.sun_planet, 0.9, 3.0 * bench.mesh_load, False).hertz_secant_stiffness
    lo = ms.mesh_state(bench.sun_planet, 0.9, bench.mesh_load, False).hertz_secant_stiffness
    assert float(hi) > float(lo)


# ------------------------------------------------------------------ phasing and non-stationary meshing


def test_mesh_frequency_of_fixed_ring_planetary():
    zs, zr = 16, 65
    fc = jnp.array([0.5, 3.0])
    np.testing.assert_allclose(ms.mesh_frequency(zs, zr, carrier_freq=fc), zr * fc, rtol=1e-15)
    fs = 10.0
    fm = ms.mesh_frequency(zs, zr, sun_freq=fs)
    # Willis: (f_s - f_c)/(f_r - f_c) = -Z_r/Z_s, f_r = 0 -> f_c = Z_s f_s/(Z_s + Z_r); f_m = Z_s (f_s - f_c)
    fc_willis = zs * fs / (zs + zr)
    assert float(fm) == pytest.approx(zr * fc_willis, rel=1e-14)
    assert float(fm) == pytest.approx(zs * (fs - fc_willis), rel=1e-14)
    # a rotating ring: relative speeds count
    assert float(ms.mesh_frequency(zs, zr, carrier_freq=2.0, ring_freq=0.5)) == pytest.approx(zr * 1.5)


def test_mesh_phase_of_a_speed_ramp_equals_the_analytic_integral():
    zr, f0, a = 65, 0.2, 0.8  # carrier 0.2 Hz ramping at 0.8 Hz/s
    t = np.concatenate([[0.0], np.sort(np.random.default_rng(0).uniform(0.0, 2.0, 400))])  # uneven grid
    fm = ms.mesh_frequency(16, zr, carrier_freq=f0 + a * t)
    exact = zr * (f0 * t + 0.5 * a * t**2)
    np.testing.assert_allclose(ms.mesh_cycles(t, fm), exact, rtol=0, atol=1e-10)  # trapezoid exact for ramps
    np.testing.assert_allclose(ms.mesh_phase(t, fm, 0.25), np.mod(exact + 0.25, 1.0), atol=1e-10)
    # nonlinear speed history: second-order convergence
    errs = []
    for n in (101, 201):
        tt = np.linspace(0.0, 2.0, n)
        c = ms.mesh_cycles(tt, zr * (f0 + tt**2))
        errs.append(abs(float(c[-1]) - zr * (f0 * 2.0 + 8.0 / 3.0)))
    assert 3.5 < errs[0] / errs[1] < 4.5
    # the mesh period shortens as the speed rises
    tt = np.linspace(0.0, 2.0, 20001)
    wraps = np.flatnonzero(np.diff(np.asarray(ms.mesh_phase(tt, zr * (f0 + a * tt)))) < 0)
    periods = np.diff(np.asarray(tt)[wraps])
    assert np.all(np.diff(periods) < 1.5e-4) and periods[-1] < 0.5 * periods[0]


def test_planet_phasing_parker_lin(bench):
    gs, gr = ms.planet_mesh_phases(16, 65, bench.planet_angles)
    np.testing.assert_allclose(gs, [0.0, 1 / 3, 2 / 3], atol=1e-12)  # 16/3 -> sequential phasing
    # equally spaced planets with (Z_s + Z_r)/N integer: ring and sun phase sets coincide
    np.testing.assert_allclose(np.mod(gr - gs + 0.5, 1.0) - 0.5, 0.0, atol=1e-12)
    gs_in, _ = ms.planet_mesh_phases(18, 66, jnp.array([0.0, 2 * math.pi / 3, 4 * math.pi / 3]))
    np.testing.assert_allclose(np.mod(gs_in + 0.5, 1.0) - 0.5, 0.0, atol=1e-12)  # Z_s/N integer: in phase
    # sun-ring phase: the pitch-point form, from independent circle intersections
    sp, rp = bench.sun_planet, bench.ring_planet
    m, al = float(sp.module), float(sp.pressure_angle)
    ps_as, _, pb = _path_by_circle_intersection(24, 16, m, al, 1.0, False)  # |P_s A_s|: planet tip side
    _, ar_pr, _ = _path_by_circle_intersection(24, 65, m, al, 1.0, True)  # |A_r P_r|: ring tip side
    expected = np.mod((ar_pr - ps_as) / pb + (1 - 24) / 2, 1.0)
    assert float(ms.sun_ring_phase(sp, rp)) == pytest.approx(expected, abs=1e-10)
    # phase histories of the three planets under a constant carrier speed: one mesh cycle per 1/(Z_r f_c)
    t = np.linspace(0.0, 0.1, 11)
    lam_s, lam_r = ms.planet_phase_history(t, np.full(11, 2.0), sp, rp, bench.planet_angles)
    assert lam_s.shape == lam_r.shape == (11, 3)
    lag = np.mod(np.asarray(lam_s[:, 1]) - 65 * 2.0 * t + 1 / 3 + 0.5, 1.0) - 0.5
    np.testing.assert_allclose(lag, 0.0, atol=1e-9)
    offset = (expected + np.asarray(gs) - np.asarray(gr))[None, :]
    wrap = np.mod(np.asarray(lam_r - lam_s) - offset + 0.5, 1.0)
    np.testing.assert_allclose(wrap - 0.5, 0.0, atol=1e-9)


# ------------------------------------------------------------------ validation, dtypes, transforms


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(module=4.23), "module"),
        (dict(module=-1e-3), "module"),
        (dict(pressure_angle=25.0), "pressure_angle"),
        (dict(face_width=0.0), "face_width"),
        (dict(poisson_ratio=0.5), "poisson_ratio"),
        (dict(youngs_modulus=210.0), "youngs_modulus"),
        (dict(addendum_coef=1.3, dedendum_coef=1.25), "dedendum_coef"),
        (dict(hub_ratio_gear=0.5), "hub_ratio_gear"),
        (dict(modulus_kind="plane"), "modulus_kind"),
        (dict(addendum_coef=0.3), "contact ratio"),
    ],
)
def test_bad_input_raises_value_error(kwargs, name):
    with pytest.raises(ValueError, match=name):
        ms.SpurMesh(24, 16, **kwargs)


def test_bad_tooth_numbers_raise():
    with pytest.raises(ValueError, match="z_pinion"):
        ms.SpurMesh(5, 16)
    with pytest.raises(ValueError, match="z_gear"):
        ms.SpurMesh(24, 16.0)
    with pytest.raises(ValueError, match="z_gear"):
        ms.SpurMesh(24, 30, internal=True)


def test_float64_and_differentiable(bench, cycles):
    (_, sun), _ = cycles
    assert sun.stiffness.dtype == jnp.float64 and sun.pair_loads.dtype == jnp.float64
    mesh = bench.sun_planet
    for x in (
        ms.contact_path(mesh).contact_ratio,
        ms.bending_stiffness(mesh, 0.02, "gear"),
        ms.fillet_stiffness(mesh, 0.02, "pinion"),
        ms.hertz_force(1e-6, 0.02),
    ):
        assert x.dtype == jnp.float64

    # gradient of the mesh stiffness w.r.t. the face width (a pytree leaf) vs a central difference
    mesh = bench.ring_planet

    def k_of_width(w):
        return ms.mesh_stiffness(ms_replace(mesh, face_width=w), 0.7, 1500.0)

    w0 = float(mesh.face_width)
    g = jax.grad(k_of_width)(w0)
    h = 1e-6 * w0
    fd = (k_of_width(w0 + h) - k_of_width(w0 - h)) / (2 * h)
    assert float(g) == pytest.approx(float(fd), rel=1e-5)
    assert float(g) > 0


def ms_replace(mesh, **fields):
    names = list(fields)
    values = [jnp.asarray(fields[n]) for n in names]
    return eqx.tree_at(lambda m: [getattr(m, n) for n in names], mesh, values)
