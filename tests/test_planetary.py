"""Planetary gear train with elastic ring (thesis ch. 3): derived matrices and deflections, the rigid-ring
option against Lin & Parker's published table, elastic -> rigid convergence, MC vs recursion, gradients."""

import copy
import dataclasses
import functools
import json
import logging
import math
import tomllib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import pgtjax as pg
from pgtjax import params as embedded
from pgtjax.models import planetary as pm
from pgtjax.models.ring import ring_interpolation

with open(embedded.path("planetary.toml"), "rb") as fh:
    BASE = tomllib.load(fh)


def small_params(**over):
    """The thesis set on a 6-element ring (fast)."""
    d = copy.deepcopy(BASE)
    d["ring"]["n_elements"] = over.pop("n_elements", 6)
    for section, values in over.items():
        d[section].update(values)
    return pm.load_params(d)


@pytest.mark.slow
def test_mass_spd_stiffness_symmetric_apart_from_wind_coupling():
    p = pm.default_params()
    lay = pm.layout(p)
    s = pm.build(p)
    m = np.asarray(s.mass)
    assert (
        m.shape == (70, 70) and lay.n_dof == 70
    )  # sun 3 + 3 planets 9 + carrier 3 + 18 nodes x 3 + filter 1
    np.testing.assert_array_equal(m, m.T)
    assert np.linalg.eigvalsh(m).min() > 0
    k = np.asarray(s.stiffness) + np.asarray(pm.mean_mesh_stiffness_matrix(p, lay, 1.7))
    asym = k - k.T
    asym[lay.carrier(2), lay.chi] = asym[lay.chi, lay.carrier(2)] = 0.0  # the wind coupling (Eqs. 3.30, 3.73)
    assert np.max(np.abs(asym)) < 1e-9 * np.max(np.abs(k))
    assert s.stiffness[lay.carrier(2), lay.chi] != 0.0 and s.stiffness[lay.chi, lay.carrier(2)] == 0.0
    assert s.mass.dtype == jnp.float64


@pytest.mark.slow
def test_sun_planet_deflection_is_eq_3_2():
    p = small_params()
    lay = pm.layout(p)
    q = jax.random.normal(jax.random.key(3), (lay.n_dof,))
    a = math.radians(20.0)
    g = pm.contact_directions(p, lay)(0.0)
    for n, psi in enumerate(p.planet_angles()):
        xs, ys, us = q[0], q[1], q[2]
        xi, eta, up = q[lay.planet(n, 0)], q[lay.planet(n, 1)], q[lay.planet(n, 2)]
        eq32 = -xs * np.sin(psi - a) + ys * np.cos(psi - a) + us - xi * np.sin(a) - eta * np.cos(a) + up
        np.testing.assert_allclose(float(g[:, n] @ q), float(eq32), rtol=1e-13)


def test_ring_planet_deflection_and_rigid_rotation_limit():
    """delta_rp = xi sin a - eta cos a - u_p + sin a u_r + cos a (u_tau - e u_theta) (Eq. 3.16 corrected);
    a rigid rotation phi of the elastic ring changes it by R_pitch cos(a) phi = r_b phi, exactly as the
    rigid ring's rotation coordinate u_r = r_b phi does (Lin & Parker)."""
    p = small_params()
    lay = pm.layout(p)
    t = 3.3
    g = pm.contact_directions(p, lay)(t)
    a = math.radians(20.0)
    ring = slice(lay.ring_start, lay.ring_start + lay.n_ring)
    phi = 1e-4
    rigid_rotation = np.zeros(lay.n_ring)
    rigid_rotation[1::3] = float(p.ring.radius) * phi  # u_tau = R_mean phi
    rigid_rotation[2::3] = phi  # section rotation
    for n, psi in enumerate(p.planet_angles()):
        col = np.asarray(g[:, p.n_planets + n])
        np.testing.assert_allclose(
            col[ring] @ rigid_rotation, float(p.ring_pitch_radius) * np.cos(a) * phi, rtol=1e-10
        )
        # independent evaluation of the ring part through the interpolation rows at the contact angle
        rows = np.asarray(ring_interpolation(p.ring, float(p.mesh.carrier_speed) * t + psi))
        u = np.asarray(jax.random.normal(jax.random.key(n), (lay.n_ring,)))
        ur, ut, uth = rows @ u
        e = float(p.ring.radius - p.ring_pitch_radius)
        np.testing.assert_allclose(col[ring] @ u, np.sin(a) * ur + np.cos(a) * (ut - e * uth), rtol=1e-12)
        assert col[lay.planet(n, 0)] == pytest.approx(np.sin(a)) and col[lay.planet(n, 2)] == -1.0
    # rigid translations of the elastic ring act as the rigid ring's x_r, y_r
    pr = small_params()
    pr = pm.load_params({**copy.deepcopy(BASE), "ring_model": "rigid"})
    gr = pm.contact_directions(pr, pm.layout(pr))(0.0)
    g0 = pm.contact_directions(p, lay)(0.0)
    angles = 2 * np.pi * np.arange(p.ring.n_elements) / p.ring.n_elements
    for k, (ux, uy) in enumerate([(1.0, 0.0), (0.0, 1.0)]):
        field = np.zeros(lay.n_ring)
        field[0::3] = -(ux * np.cos(angles) + uy * np.sin(angles))  # inward radial
        field[1::3] = -ux * np.sin(angles) + uy * np.cos(angles)
        for n in range(p.n_planets):
            elastic = np.asarray(g0[ring, p.n_planets + n]) @ field
            rigid = float(gr[pm.layout(pr).ring_start + k, pr.n_planets + n])
            np.testing.assert_allclose(elastic, rigid, rtol=1e-10, atol=1e-12)


# ---------------------------------------------------------------- Lin & Parker (1999) rigid-ring table
# Parameters of Lin & Parker 1999, Table 1 (masses kg, I/r^2 kg, stiffnesses N/m, pressure angle 24.6 deg,
# k_su = k_cu = 0, k_ru = 1e9 N/m) and their natural frequencies (Hz), as copied in the test file
# tests/test_lin_parker_1999.py of the public repository gfsReboucas/Drivetrain-python (we could not open the
# paper itself; a helper reproduced every value independently, 3 N = 4 entries differ by <= 0.3 Hz).
LP_ROTATIONAL = {
    3: [0, 1475.7, 1930.3, 2658.3, 7462.8, 11775.3],
    4: [0, 1536.6, 1970.6, 2625.7, 7773.6, 13071.1],
    5: [0, 1567.4, 2006.1, 2614.8, 8065.4, 14253.1],
}
LP_TRANSLATIONAL = {
    3: [743.2, 1102.4, 1896.0, 2276.4, 6986.3, 9647.9],
    4: [727.0, 1091.0, 1892.8, 2342.5, 7189.9, 10437.6],
    5: [710.0, 1072.0, 1888.1, 2425.3, 7382.4, 11172.3],
}
LP_PLANET = [1808.2, 5963.8, 6981.7]


def lin_parker_params(n_planets):
    d = copy.deepcopy(BASE)
    d["n_planets"] = n_planets
    d["ring_model"] = "rigid"
    # any consistent geometry (the radii are set to one below): module 20 mm, sun 20, planets 30, ring 80 teeth
    body = lambda z, m, j, k, kt: dict(  # noqa: E731
        teeth=z,
        mass=m,
        inertia=j,
        pitch_diameter=0.02 * z,
        bearing_stiffness=k,
        torsional_stiffness=kt,
    )
    d["sun"] = body(20, 0.40, 0.39, 1e8, 0.0)
    d["planet"] = body(30, 0.66, 0.61, 1e8, 0.0)
    del d["planet"]["torsional_stiffness"]  # planets have none in the model
    d["carrier"] = dict(mass=5.43, inertia=6.29, bearing_stiffness=1e8, torsional_stiffness=0.0)
    d["ring"].update(
        rigid_mass=2.35,
        rigid_inertia=3.0,
        rigid_bearing_stiffness=1e8,
        rigid_torsional_stiffness=1e9,
        teeth=80,
        pitch_diameter=1.6,
    )
    d["mesh"].update(
        sun_planet_stiffness=5e8, ring_planet_stiffness=5e8, pressure_angle_deg=24.6, stiffness_variation=0.0
    )
    d["wind"]["turbulence_intensity"] = 0.0
    p = pm.load_params(d)
    # unit radii make the inertia entries I/r^2 as tabulated; the carrier's u_c = r_c theta_c likewise
    one = jnp.asarray(1.0)
    p = jax.tree_util.tree_map(lambda x: x, p)
    import equinox as eqx

    p = eqx.tree_at(
        lambda q: (q.sun.radius, q.planet.radius, q.carrier.radius, q.rigid_ring.radius),
        p,
        (one, one, one, one),
    )
    return p


@pytest.mark.slow
@pytest.mark.parametrize("n_planets", [3, 4, 5])
def test_rigid_ring_option_reproduces_lin_parker_table(n_planets):
    p = lin_parker_params(n_planets)
    lay = pm.layout(p)
    s = pm.build(p)
    modes = pg.modal_analysis(s)
    kinds = [pm.mode_type(p, lay, s.mass, modes.shapes[:, i]) for i in range(lay.n_dof)]
    freqs = np.asarray(modes.frequencies_hz)
    found = {k: np.sort(freqs[[i for i, t in enumerate(kinds) if t == k]]) for k in set(kinds)}
    np.testing.assert_allclose(found["rotational"], LP_ROTATIONAL[n_planets], rtol=5e-4, atol=0.06)
    np.testing.assert_allclose(found["translational"], np.repeat(LP_TRANSLATIONAL[n_planets], 2), rtol=5e-4)
    if n_planets > 3:
        np.testing.assert_allclose(found["planet"], np.repeat(LP_PLANET, n_planets - 3), rtol=5e-4)
    else:
        assert "planet" not in found
    assert found["filter"].size == 1  # the decoupled wind-filter state


def rigid_equivalent(p):
    """The rigid ring that the elastic ring becomes: its mass and support stiffness projected on the ring's
    rigid-body motions (x, y, and rotation with u_r = r_b phi)."""
    from pgtjax.models.ring import ring_matrices

    m_ring, k_ring = ring_matrices(p.ring)
    ang = 2 * np.pi * np.arange(p.ring.n_elements) / p.ring.n_elements
    rb = float(p.ring_pitch_radius) * np.cos(float(p.mesh.pressure_angle))
    basis = np.zeros((3 * p.ring.n_elements, 3))
    basis[0::3, 0], basis[1::3, 0] = -np.cos(ang), -np.sin(ang)
    basis[0::3, 1], basis[1::3, 1] = -np.sin(ang), np.cos(ang)
    basis[1::3, 2], basis[2::3, 2] = float(p.ring.radius) / rb, 1.0 / rb
    mr = basis.T @ np.asarray(m_ring) @ basis
    kr = basis.T @ np.asarray(k_ring) @ basis
    assert np.allclose(mr, np.diag(np.diag(mr)), atol=1e-9 * mr.max())
    body = pm.Body(
        jnp.asarray(mr[0, 0]),
        jnp.asarray(mr[2, 2] * rb**2),
        jnp.asarray(rb),
        jnp.asarray(kr[0, 0]),
        jnp.asarray(kr[2, 2] * rb**2),
    )
    return dataclasses.replace(p, rigid_ring=body, ring_model="rigid")


@pytest.mark.slow
def test_elastic_ring_model_tends_to_the_rigid_ring_model():
    errors = []
    for scale in (1.0, 1e2, 1e4):
        p = small_params(ring={"youngs_modulus": 210e9 * scale}, n_elements=12)
        elastic = pm.build(p)
        rigid_p = rigid_equivalent(p)
        rigid = pm.build(rigid_p)
        f_rigid = np.sort(np.asarray(pg.modal_analysis(rigid).frequencies_hz))[:12]
        f_el = np.sort(np.asarray(pg.modal_analysis(elastic).frequencies_hz))[:12]
        errors.append(np.max(np.abs(f_el - f_rigid) / np.maximum(f_rigid, 1.0)))
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 1e-3, errors


@pytest.mark.slow
def test_never_losing_contact_mc_within_three_standard_errors_of_recursion():
    """Default thesis loads from the static equilibrium: the meshes stay in contact (|mean| - b > 6 std), so
    SL is exact and MC of the nonlinear system must agree with the recursion within sampling error."""
    p = small_params()
    lay = pm.layout(p)
    s = pm.build(p)
    u_eq = pg.static_equilibrium(s)
    # equilibrium: K u + G f = F holds (independent check of the Newton solve)
    g, k = s.contact_direction(0.0), s.contact_stiffness(0.0)
    resid = s.stiffness @ u_eq + g @ pg.Backlash().force(g.T @ u_eq, k, p.mesh.half_backlash) - s.load
    assert float(jnp.max(jnp.abs(resid))) < 1e-9 * float(jnp.max(jnp.abs(s.load)))
    kw = dict(dt=0.0027, n_steps=120, save_every=40, initial_displacement=u_eq)
    sl0 = pg.solve_moments(s, **kw)
    assert float(jnp.min(jnp.abs(sl0.mean_delta) - p.mesh.half_backlash - 6 * sl0.std_delta)) > 0
    mc = pg.monte_carlo(s, n_samples=3000, key=jax.random.key(11), progress=False, **kw)
    se_mean, se_std = mc.standard_error("u")
    idx = [lay.sun(2), lay.planet(0, 1), lay.carrier(2), lay.ring_start + 1, lay.chi]
    for i in range(1, len(mc.times)):
        assert np.all(
            np.abs(mc.mean_u[i, idx] - sl0.mean_u[i, idx])
            < 3 * se_mean[i, idx] + 1e-12 * np.abs(sl0.mean_u[i, idx])
        )
        assert np.all(np.abs(mc.std_u[i, idx] - sl0.std_u[i, idx]) < 3 * se_std[i, idx])
    se_f = mc.force_std[1:] / np.sqrt(mc.n_samples)
    assert np.all(
        np.abs(mc.force_mean[1:] - sl0.force_mean[1:]) < 3 * se_f + 1e-9 * np.abs(sl0.force_mean[1:])
    )


RING_DESIGN = jnp.array([0.128, 1.362e10])  # rim thickness (m), bolt radial stiffness (N/m)
RING_NODE, RING_STEPS = 1, 30  # ring node 1 (between two bolts: they sit at the even nodes), 30 steps of SL


def _ring_base():
    return small_params(n_elements=12)


@functools.cache
def _ring_sensitivities() -> dict:
    """``studies.planetary.sensitivities`` on a 12-element ring over 30 steps: reverse-mode derivatives and the
    study's own Richardson-extrapolated central differences. Shared by the gradient tests and the summary's
    units check, which would otherwise each compile a reverse pass of their own (compilation dominates)."""
    from pgtjax.studies import planetary as study

    return study.sensitivities(_ring_base(), dt=0.0027, n_steps=RING_STEPS, node=RING_NODE)


@functools.cache
def _ring_equilibrium():
    # evaluated now even when first called inside a trace (the jitted Jacobians below): a cached tracer would
    # leak into every later use (an UnexpectedTracerError whenever a traced test ran before the eager one)
    with jax.ensure_compile_time_eval():
        return pg.static_equilibrium(pm.build(_ring_base()))


def _ring_response(x, save_every: int, checkpoint: bool):
    """The quantities of :func:`_ring_sensitivities` written out here: std of ring node 1's radial displacement
    and of the ring-planet 1 meshing force after 30 steps, as functions of ``x`` = (rim thickness, bolt radial
    stiffness), from the base design's static equilibrium; the same times whatever ``save_every``."""
    base = _ring_base()
    lay = pm.layout(base)
    p = eqx.tree_at(lambda q: (q.ring.thickness, q.ring.k_support_radial), base, (x[0], x[1]))
    r = pg.solve_moments(
        pm.build(p),  # the ring's centre radius follows the thickness
        dt=0.0027,
        n_steps=RING_STEPS,
        save_every=save_every,
        rtol=1e-13,
        checkpoint=checkpoint,
        initial_displacement=_ring_equilibrium(),
        initial_covariance=pm.wind_filter_stationary_covariance(p, lay),
    )
    node = lay.ring_start + 3 * RING_NODE  # radial DOF
    return jnp.stack([r.std_u[-1, node], r.force_std[-1, r.contact("ring_planet1")]])


@functools.partial(jax.jit, static_argnums=(1, 2))
def _reverse_jacobian(x, save_every: int, checkpoint: bool):
    """Reverse-mode Jacobian (quantity, parameter) of :func:`_ring_response`, one reverse pass per quantity in
    a loop: ``jax.jacrev`` vmaps them, a batched program that took 1.3-1.4 times as long to compile."""
    values, pullback = jax.vjp(lambda y: _ring_response(y, save_every, checkpoint), x)
    (jacobian,) = jax.lax.map(pullback, jnp.eye(values.shape[0], dtype=values.dtype))
    return jacobian


@pytest.mark.slow
def test_gradients_wrt_rim_thickness_and_support_stiffness_match_finite_differences():
    """d std(radial displacement of ring node 1, between two bolts) and d std(ring-planet 1 meshing force) /
    d(rim thickness, bolt radial stiffness) through SL + recursion (reverse mode, as the study computes them),
    against Richardson-extrapolated central differences at 1 % and 2 % relative steps."""
    sens = _ring_sensitivities()
    jac, fd = np.asarray(sens["gradient"]), np.asarray(sens["central_difference"])
    assert jac.shape == (2, 2) and np.all(jac != 0)
    np.testing.assert_allclose(jac, fd, rtol=1e-5)
    np.testing.assert_allclose(sens["value"], _ring_response(RING_DESIGN, RING_STEPS, True), rtol=1e-12)


@pytest.mark.slow
def test_gradient_independent_of_save_interval_checkpointing_and_mode():
    """The reverse pass keeps the fixed points' solutions and their tangent rule's quantities (checkpoint
    policy) instead of recomputing them: the gradient must not depend on how the run is split into saved
    blocks, on whether blocks are rematerialized at all, nor differ from forward mode. (A consistency check
    of the reverse-mode plumbing; correctness against finite differences is the test above.)"""
    x = RING_DESIGN
    want = np.asarray(_ring_sensitivities()["gradient"])  # reverse, one saved block, rematerialized
    # each variant is a program of its own (~20-30 s of compilation on 2 cores)
    split = _reverse_jacobian(x, 3, False)  # split into saved blocks of three steps, not rematerialized
    assert split.dtype == jnp.float64
    np.testing.assert_allclose(split, want, rtol=1e-9)
    forward = jax.jit(jax.jacfwd(_ring_response), static_argnums=(1, 2))(x, RING_STEPS, True)  # forward
    np.testing.assert_allclose(forward, want, rtol=1e-9)


@pytest.mark.slow
def test_models_differing_only_in_their_bolts_share_one_compiled_solver():
    """The bolts enter the stiffness matrix only: the system and the contact-point observables of a support-count
    sweep hold no copy of the (static) support nodes, so every variant has the same compiled solver's key
    (static structure, leaf shapes, dtypes and weak types). Before, the sweep of `pgtjax run` compiled SL for each count."""
    from pgtjax.studies import planetary as study

    variants = study.support_variants(small_params(), (3, 6))
    keys = []
    for q in variants.values():
        held = (pm.build(q), study.contact_point_observables(q))
        leaves, structure = jax.tree.flatten(held)
        keys.append((structure, [jax.typeof(x) for x in leaves]))  # shape, dtype and weak type
    assert [len(q.ring.support_nodes) for q in variants.values()] == [3, 6]
    assert keys[0] == keys[1]


def test_build_checks_values_in_python_and_assembles_in_one_compiled_program(caplog):
    """A value set with ``eqx.tree_at`` skips the loader's checks: ``build`` still refuses it, in Python. The
    matrices are then assembled by one compiled program, reused by every value of one shape; op by op, two
    builds of a new shape compiled 147 small kernels (seconds) before."""
    p = small_params(n_elements=24)  # a ring size no other test builds: nothing compiled for it yet
    with pytest.raises(ValueError, match="mesh.half_backlash"):
        pm.build(eqx.tree_at(lambda q: q.mesh.half_backlash, p, jnp.asarray(-1e-6)))
    with jax.log_compiles(True), caplog.at_level(logging.WARNING):
        systems = [pm.build(eqx.tree_at(lambda q: q.ring.thickness, p, jnp.asarray(h))) for h in (0.1, 0.15)]
    compiled = [r.getMessage() for r in caplog.records if "Finished XLA compilation" in r.getMessage()]
    assert len(compiled) <= 5 and sum("_assemble_system" in m for m in compiled) == 1, compiled  # before: 147
    assert systems[0].mass.dtype == jnp.float64 and systems[0].n_dof == pm.layout(p).n_dof
    assert not np.allclose(systems[0].stiffness, systems[1].stiffness)  # the values did reach the program


@pytest.mark.slow
def test_checks_before_a_run_evaluate_the_time_functions_in_one_compiled_program(caplog):
    """The checks a solver makes before it runs (the system's fields, its stability, the observables at t0)
    evaluate the model's time functions in one compiled program per check, reused by every model of the same
    structure; op by op, a model of a new size compiled dozens of small kernels first (seconds). The values
    are those of the time functions evaluated directly."""
    from pgtjax._system import check_stability, fields_at, validate_system
    from pgtjax.design import ring_mesh_observables

    def check(p):
        system, observables = pm.build(p), ring_mesh_observables(p)
        with jax.log_compiles(True), caplog.at_level(logging.WARNING):
            caplog.clear()
            validate_system(system, 0.0)
            check_stability(system, 0.0, horizon=0.1)
            observables.check(system.n_dof, 0.0)
        compiled = [r.getMessage() for r in caplog.records if "Finished XLA compilation" in r.getMessage()]
        return system, observables, [m for m in compiled if "_modules_at_compiled" in m], compiled

    p = small_params(n_elements=30)  # a ring size no other test builds: nothing compiled for it yet
    system, observables, checks, compiled = check(p)
    assert len(checks) == 3 and len(compiled) <= 12, compiled
    # another design of the same structure: the three programs are reused
    _, _, checks, _ = check(eqx.tree_at(lambda q: q.ring.thickness, p, jnp.asarray(0.11, jnp.float64)))
    assert checks == []
    t = jnp.asarray(0.013)
    direction, inputs, c_matrix = fields_at(
        (system.contacts.direction, system.contacts.inputs, observables), t
    )
    for got, want in (
        (direction, system.contact_direction(t)),
        (inputs, system.contacts.inputs(t)),
        (c_matrix, observables(t)),
    ):
        assert got.dtype == jnp.float64
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15 * float(jnp.max(jnp.abs(want))))


def test_bad_parameters_raise():
    with pytest.raises(ValueError, match="ring_model"):
        small_params().__class__  # noqa: B018
        pm.load_params({**copy.deepcopy(BASE), "ring_model": "flexible"})
    d = copy.deepcopy(BASE)
    d["mesh"]["half_backlash"] = -1e-6
    with pytest.raises(ValueError, match="half_backlash"):
        pm.load_params(d)
    d = copy.deepcopy(BASE)
    d["ring"]["n_supports"] = 4
    with pytest.raises(ValueError, match="n_supports"):
        pm.load_params(d)
    with pytest.raises(ValueError, match="does not exist"):
        pm.load_params("/nonexistent/planetary.toml")


def test_derived_stiffness_matches_appendix_3a3_blocks():
    """The energy-derived K against the hand-written blocks of thesis App. 3.A.3 (Eqs. 3.75-3.80).

    Resolved: K_C prints psi_sp,n where psi_n is meant, harmless since it appears only in sin^2 + cos^2 = 1;
    the K_Qn sign pattern (flagged as suspect) is what the planet-bearing energy gives. The planet bearing's
    own diag(k_p, k_p, 0) (Eq. 3.78's companion) is not printed in K_Pn, and the ring-planet coupling K_R
    (Eq. 3.82) follows the printed Eq. 3.16, which we correct (see test_ring_planet_deflection...)."""
    d = copy.deepcopy(BASE)
    d["ring_model"] = "rigid"
    d["mesh"]["stiffness_variation"] = 0.0
    p = pm.load_params(d)
    lay = pm.layout(p)
    k = np.asarray(pm.structural_stiffness(p, lay) + pm.mean_mesh_stiffness_matrix(p, lay, 0.0))
    ksp, krp, kp = 16.9e9, 19.2e9, 6.8e9
    a = math.radians(20.0)
    sa, ca = np.sin(a), np.cos(a)
    sun = slice(0, 3)
    k_s1 = np.zeros((3, 3))
    k_c = np.zeros((3, 3))
    for n, psi in enumerate(p.planet_angles()):
        s, c = np.sin(psi - a), np.cos(psi - a)
        k_s1 += ksp * np.array([[s * s, -s * c, -s], [-s * c, c * c, c], [-s, c, 1.0]])  # Eq. 3.75
        k_s2 = ksp * np.array([[sa * s, ca * s, -s], [-sa * c, -ca * c, c], [-sa, -ca, 1.0]])  # Eq. 3.76
        pl = slice(lay.planet(n, 0), lay.planet(n, 0) + 3)
        np.testing.assert_allclose(k[sun, pl], k_s2, rtol=1e-12, atol=1e-3)
        k_pn = ksp * np.array([[sa * sa, ca * sa, -sa], [ca * sa, ca * ca, -ca], [-sa, -ca, 1.0]])  # Eq. 3.77
        k_pn += krp * np.array(
            [[sa * sa, -ca * sa, -sa], [-ca * sa, ca * ca, ca], [-sa, ca, 1.0]]
        )  # Eq. 3.78
        np.testing.assert_allclose(k[pl, pl], k_pn + kp * np.diag([1.0, 1.0, 0.0]), rtol=1e-12, atol=1e-3)
        cs, sn = np.cos(psi), np.sin(psi)
        k_qn = kp * np.array([[-cs, -sn, 0.0], [sn, -cs, -1.0], [0.0, 0.0, 0.0]])  # Eq. 3.79
        car = slice(lay.carrier(0), lay.carrier(0) + 3)
        np.testing.assert_allclose(k[pl, car], k_qn, rtol=1e-12, atol=1e-3)
        k_c += kp * np.array([[1.0, 0.0, -sn], [0.0, 1.0, cs], [-sn, cs, 1.0]])  # Eq. 3.80
    bearing = np.diag([100.0, 100.0, 45.8e6 / float(p.sun.radius) ** 2])
    np.testing.assert_allclose(k[sun, sun], k_s1 + bearing, rtol=1e-12, atol=1e-3)
    car = slice(lay.carrier(0), lay.carrier(0) + 3)
    np.testing.assert_allclose(k[car, car], k_c + np.diag([5e9, 5e9, 0.0]), rtol=1e-12, atol=1e-3)


@pytest.mark.slow
def test_study_grids_outputs_and_symmetry_zero_dofs(tmp_path):
    """The study saves SL ``sl_refine`` times as often as MC: SL on MC's grid must equal an SL run saved
    there directly; the symmetric train's translations are reported as round-off, not compared; the
    written results reload with their labels and every figure is written."""
    from pgtjax.studies import planetary as study

    p = small_params()
    result = study.run_study(
        p,
        n_samples=200,
        periods=0.02,
        n_saves=4,
        sl_refine=3,
        key=jax.random.key(2),
        progress=False,
        peak_force_bins=40,
    )
    st = result.settings
    assert st["sl_save_every"] * st["sl_refine"] == st["mc_save_every"] and st["sl_refine"] == 3
    assert st["n_steps"] == 4 * st["mc_save_every"]
    sl, mc = result.sl["force"], result.mc
    assert len(sl.times) == 3 * (len(mc.times) - 1) + 1 and sl.mean_u.dtype == jnp.float64
    coarse = result.sl_on_mc_grid()
    np.testing.assert_allclose(np.asarray(coarse.times), np.asarray(mc.times), rtol=0, atol=1e-12)
    system, kw, mc_every, _ = study._setup(p, result.dt, 0.02, 4, 3)
    direct = pg.solve_moments(system, save_every=mc_every, **kw)
    for field in ("mean_u", "std_u", "force_mean", "std_obs"):
        want = np.asarray(getattr(direct, field))
        np.testing.assert_allclose(
            np.asarray(getattr(coarse, field)), want, rtol=1e-9, atol=1e-12 * np.abs(want).max()
        )

    quiet = study.roundoff_dofs(sl)
    assert {"sun_x", "sun_y", "carrier_x", "carrier_y"} <= set(quiet)
    assert not {"sun_u", "carrier_u", "planet1_eta", "ring_node1_radial"} & set(quiet)
    summary = study.error_summary(result)
    skipped = summary["roundoff_dofs_not_compared"]  # at round-off in both SL and MC
    assert {"sun_x", "sun_y", "carrier_x", "carrier_y"} <= set(skipped) <= set(quiet)
    assert summary["dofs_compared"] == system.n_dof - 1 - len(skipped) and summary["criterion"] == "force"
    # the meshes never leave contact here, so SL is exact: the meshing forces agree within sampling error
    assert set(summary["mesh_force"]["per_mesh_mean"]) == set(sl.contact_names)
    assert summary["mesh_force"]["fraction_of_mesh_time_points_within_3_se"] == 1.0

    sweeps = {
        "Rim thickness: test": study.parameter_sweep(
            p, study.rim_thickness_variants(p, (0.1, 0.15)), periods=0.02, n_saves=4, sl_refine=3
        )
    }
    written = {f.name for f in study.write_outputs(result, tmp_path, sweeps=sweeps)}
    assert {
        "planetary_dofs.png",
        "planetary_more_dofs.png",
        "planetary_ring_contact.png",
        "planetary_mesh_forces.png",
        "planetary_mesh_forces_zoom.png",
        "planetary_peak_forces.png",
        "planetary_rim_thickness.png",
        "planetary_sl_force.npz",
        "planetary_mc.npz",
        "summary.json",
    } <= written
    # every number of summary.json carries its unit (a sweep, the modes and the sensitivities included)
    from pgtjax._summary import missing_units

    sens = _ring_sensitivities()  # another model's, whose summary section carries the same units
    full = study.summary(result, sweeps=sweeps, modal=study.modal_table(p), sens=sens)
    assert missing_units(full) == [] and missing_units({**full, "bare": 1.0}) == ["bare"]
    # a unit for each setting the run has, and none for one it lacks (no peaks' start without peaks)
    assert (
        set(full["settings"]["units"]) <= set(full["settings"])
        and "peak_start_s" in full["settings"]["units"]
    )
    without_peaks = {k: v for k, v in result.settings.items() if k != "peak_start_s"} | {"peak_force_bins": 0}
    bare = study.summary(dataclasses.replace(result, settings=without_peaks))["settings"]
    assert "peak_start_s" not in bare["units"] and missing_units(bare) == []
    # the peak meshing forces: every sample counted within the bins, quantiles in order, at or above each
    # sample's magnitude at the end (the peaks' median is at least the end's smallest |mean| - 3 std)
    peaks = full["peak_meshing_forces"]
    assert set(peaks["per_mesh"]) == set(sl.contact_names) and peaks["n_samples"] == 200
    assert st["peak_start_s"] == 0.0 and "from t = 0 s" in peaks["note"]
    # SL's bound from below: the largest probability of being beyond a level at one step, under Monte Carlo's
    # peak probability (within its error)
    for q, estimate in result.sl_peaks.items():
        p_mc, se = mc.peak_exceedance(q).probability[-1], mc.peak_exceedance(q).standard_error[-1]
        assert np.all(estimate["lower_bound"][-1] <= p_mc + 3 * se + 1.0 / mc.n_samples), q
        assert 0.0 < np.max(estimate["lower_bound"][-1] * (estimate["lower_bound"][-1] < 1.0))
    reached = [e["sl_lower_bound_reach_probability"] for e in peaks["per_mesh"].values()]
    assert all(v is None or 0.0 <= v <= 1.0 for r in reached for v in r.values())
    # peaks counted from a later save (the same samples): over a shorter window, never larger
    saved = np.asarray(mc.times)
    later = study.run_study(p, n_samples=200, periods=0.02, n_saves=4, sl_refine=3, key=jax.random.key(2),
                            progress=False, peak_force_bins=40, peak_start=0.9 * saved[1])  # fmt: skip
    assert later.settings["peak_start_s"] == saved[1] and later.mc.peak_start == saved[1]
    assert np.all(np.asarray(later.mc.histogram_times) >= saved[1])
    np.testing.assert_array_equal(np.asarray(later.mc.std_u), np.asarray(mc.std_u))
    assert f"from t = {saved[1]:g} s" in study.peak_force_summary(later)["note"]
    for q in mc.peak_edges:
        shorter, whole = later.mc.peak_exceedance(q), mc.peak_exceedance(q)
        np.testing.assert_array_equal(shorter.levels, whole.levels)
        assert np.all(shorter.probability[-1] <= whole.probability[-1])
        assert np.all(later.sl_peaks[q]["probability"][-1] <= result.sl_peaks[q]["probability"][-1] + 1e-15)
    assert any(
        np.any(later.mc.peak_exceedance(q).probability[-1] < mc.peak_exceedance(q).probability[-1])
        for q in mc.peak_edges
    )  # the start-up's peaks are left out
    end = np.abs(np.asarray(mc.force_mean[-1])) - 3 * np.asarray(mc.force_std[-1])
    for k, name in enumerate(sl.contact_names):
        entry = peaks["per_mesh"][name]
        assert entry["beyond_top_edge_fraction"] == 0.0 and entry["q99_N"] is None  # 200 samples: 2 beyond
        assert end[k] <= entry["median_N"] <= entry["q90_N"] <= entry["top_edge_N"]
        # SL's estimate of reaching each stated quantile: a probability, falling with the level
        reach = entry["sl_reach_probability"]
        assert reach["q99"] is None and 0.0 <= reach["q90"] <= reach["median"] <= 1.0
    thin = full["rim_thickness"]["variants"]["t_r = 100 mm"]["ring_node2_tangential"]
    assert thin["unit"] == "m" and thin["min_mean"] <= thin["time_average_of_mean"] <= thin["max_mean"]
    derivative = full["sensitivities"]["quantities"][1]["derivatives"][1]
    assert derivative["unit"] == "N/(N/m)" and derivative["parameter"] == "bolt radial stiffness (N/m)"
    assert full["modes"]["table"][0]["type"] == "filter"  # the wind filter's state, named in the note
    assert "wind filter" in full["modes"]["note"]
    written_summary = json.loads((tmp_path / "summary.json").read_text())
    assert missing_units(written_summary) == [] and written_summary["units_convention"].startswith("Every")
    back, attrs = pg.load_results(tmp_path / "planetary_sl_force.npz")
    assert back.dof_names == sl.dof_names and back.observable_names == sl.observable_names
    assert attrs["sl_refine"] == 3 and attrs["dt_s"] == result.dt
    np.testing.assert_array_equal(np.asarray(back.std_u), np.asarray(sl.std_u))
    # merged saves keep the worst solver diagnostics of the blocks they merge
    flagged = eqx.tree_at(lambda r: r.converged, sl, sl.converged.at[2].set(False))
    merged = study.every_nth_save(flagged, 3)
    assert not bool(merged.converged[1]) and bool(jnp.all(merged.converged[2:]))
    for bad, match in [
        (dict(sl_refine=0), "sl_refine"),
        (dict(n_saves=0), "n_saves"),
        (dict(n_saves=2.5), "n_saves"),
        (dict(n_samples=1), "n_samples"),
        (dict(n_samples=-3), "0 \\(no Monte Carlo\\) or"),
        (dict(n_samples=10.0), "n_samples"),
        (dict(criteria=()), "criteria"),
        (dict(peak_force_bins=10), "peak_force_bins"),  # without samples
        (dict(peak_force_bins=-1, n_samples=4), "peak_force_bins"),
        (dict(peak_start=0.01), "`peak_start` sets where the peaks are counted from"),  # without bins
        (dict(peak_start=-0.01, peak_force_bins=10, n_samples=4), "`peak_start` must be a time >= 0"),
        (dict(peak_start=float("nan"), peak_force_bins=10, n_samples=4), "`peak_start` must be a time >= 0"),
        (dict(peak_start=100.0, peak_force_bins=10, n_samples=4), "nearest the last Monte Carlo save"),
    ]:
        with pytest.raises(ValueError, match=match):
            study.run_study(p, **{"n_samples": 0, "periods": 0.02, **bad})
    with pytest.raises(ValueError, match="was not run"):
        result.sl_on_mc_grid("energy")


@pytest.mark.parametrize("n_saves, sl_refine", [(200, 10), (200, 30), (7, 3), (3000, 10), (200, 1)])
def test_study_grid_saves_sl_exactly_sl_refine_times_as_often(n_saves, sl_refine):
    from pgtjax.studies import planetary as study

    p = pm.default_params()
    target = round(study.carrier_period(p) / 0.0027)
    n_steps, mc_every, sl_every = study._grid(p, 0.0027, 1.0, n_saves, sl_refine)
    assert mc_every == sl_refine * sl_every and n_steps % mc_every == 0
    assert target - mc_every < n_steps <= target  # the whole steps of MC's grid that fit in the period
    assert n_steps // mc_every >= min(
        n_saves, target // sl_refine
    )  # at least the saves asked for, if possible


def test_study_grid_refuses_a_step_that_aliases_the_mesh_stiffness_or_spans_the_run():
    """The time step must sample the mesh stiffness's highest harmonic at least twice a period (pi / (H w_m),
    H harmonics), and the run must span at least one step; NaN and infinite values are refused too."""
    from pgtjax.studies import planetary as study

    p = pm.default_params()
    limit = np.pi / (p.mesh.harmonics * float(p.mesh.mesh_frequency))
    assert p.mesh.harmonics == 5 and 0.0027 < limit < 0.1  # the thesis's step passes, 0.1 s would alias
    study._grid(p, 0.999 * limit, 1.0, 10, 1)
    for dt in (limit, 0.1, 0.0, -1.0, np.nan):
        with pytest.raises(ValueError, match=r"`dt` must be > 0 and below half the period .*\(harmonic 5"):
            study._grid(p, dt, 1.0, 10, 1)
    one_step = 0.0027 / study.carrier_period(p)
    assert study._grid(p, 0.0027, one_step, 10, 1)[0] == 1
    for periods in (0.99 * one_step, np.inf, np.nan):
        with pytest.raises(ValueError, match=r"`periods` .* must span at least one time step"):
            study._grid(p, 0.0027, periods, 10, 1)


@pytest.mark.slow
def test_rigid_ring_study_with_another_criterion_writes_its_outputs(tmp_path):
    """The rigid-ring model has no ring nodes or contact-point observables; the energy criterion alone."""
    from pgtjax.studies import planetary as study

    p = pm.load_params({**copy.deepcopy(BASE), "ring_model": "rigid"})
    result = study.run_study(
        p,
        n_samples=100,
        periods=0.01,
        n_saves=3,
        sl_refine=2,
        criteria=(pg.EnergyCriterion(),),
        key=jax.random.key(1),
        progress=False,
    )
    written = {f.name for f in study.write_outputs(result, tmp_path)}
    assert {
        "planetary_dofs.png",
        "planetary_more_dofs.png",
        "planetary_mesh_forces.png",
        "planetary_mesh_forces_zoom.png",
        "planetary_sl_energy.npz",
        "summary.json",
    } <= written
    assert "planetary_ring_contact.png" not in written
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert list(summary["sl_vs_mc"]) == ["energy"] and summary["sl_vs_mc"]["energy"]["criterion"] == "energy"
    assert "ring_u" in summary["sl_vs_mc"]["energy"]["per_dof_std"]


def test_per_cycle_envelope_and_si_prefixes():
    """The per-cycle drawing of long runs: a sine of period T on a slow ramp, sampled 20 times a cycle, gives
    per cycle the ramp's average and the sine's extremes; the axis prefixes follow magnitudes."""
    from pgtjax import plots

    period, t = 0.25, np.arange(0, 5.0, 0.25 / 20)
    y = 3.0 * t + 2.0 * np.sin(2 * np.pi * t / period)
    tc, lo, hi, avg = plots.cycle_envelope(t, y, period)
    assert len(tc) == 20
    np.testing.assert_allclose(avg, 3.0 * tc, atol=1e-9)  # the sine averages out over whole cycles
    # the extremes are the samples at a quarter and three quarters of each cycle: +-2 and the ramp between them
    np.testing.assert_allclose(hi - lo, 4.0 - 3.0 * period / 2, rtol=1e-12)
    assert plots.scaled("m", 1.9e-4) == (1e6, "µm") and plots.scaled("m", 0.017) == (1e3, "mm")
    assert plots.scaled("rad", 3e-5) == (1e6, "µrad") and plots.scaled("N", 1.1e5) == (1e-3, "kN")
    assert plots.scaled("Hz", 10.0) == (1.0, "Hz")
    # a curve saved less than 4 times a cycle has no range within a cycle: everything is drawn point by point
    dense, sparse = np.linspace(0, 1, 2001), np.linspace(0, 1, 40)
    curves = {
        "SL": {"x": (np.sin(dense), np.ones_like(dense))},
        "MC": {"x": (np.sin(sparse), np.ones_like(sparse), 0.1 + 0 * sparse, 0.1 + 0 * sparse)},
    }
    times = {"SL": dense, "MC": sparse}
    fig = plots.mean_std_figure(
        times, curves, [("x", "m")], cycle=0.02, styles={"MC": {"ls": "none", "marker": "o"}}
    )
    assert len(fig.axes[0].get_lines()[0].get_xdata()) == 2001  # SL point by point, not 50 cycle averages
    # drawn per cycle, two panels wide: the legend (with the band's two-line note) is no wider than the figure
    # would be without it, so the panels are not squeezed into the middle of a wider image
    sl_only = {"SL": {n: curves["SL"]["x"] for n in ("x", "y")}}
    fig = plots.mean_std_figure(dense, sl_only, [("x", "m"), ("y", "m")], cycle=0.02, title="two panels")
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    legend, renderer = fig.legends[0], FigureCanvasAgg(fig).get_renderer()
    assert any("\n" in text.get_text() for text in legend.get_texts())  # the band's note on two lines
    assert legend.get_window_extent(renderer).width <= fig.bbox.width
    # with Monte Carlo's markers too: three entries, still in two columns (one row would be wider)
    both = {**sl_only, "MC": {n: curves["MC"]["x"] for n in ("x", "y")}}
    times_both = {"SL": dense, "MC": np.linspace(0, 1, 401)}
    both["MC"] = {
        n: tuple(np.interp(times_both["MC"], sparse, a) for a in curves["MC"]["x"]) for n in ("x", "y")
    }
    fig = plots.mean_std_figure(
        times_both, both, [("x", "m"), ("y", "m")], cycle=0.02, styles={"MC": {"ls": "none", "marker": "o"}}
    )
    canvas = FigureCanvasAgg(fig)
    canvas.draw()  # lays out the legend's entries
    legend, renderer = fig.legends[0], canvas.get_renderer()
    sl_text, mc_text, _ = (t.get_window_extent(renderer) for t in legend.get_texts())
    assert mc_text.y1 < sl_text.y0  # MC's entry under SL's: not all three in one row
    assert legend.get_window_extent(renderer).width <= fig.bbox.width
    # numbers of every numeric type need a unit in summary.json
    from pgtjax._summary import missing_units

    assert missing_units({"a": np.int64(3), "b": np.float32(1), "c": jnp.float64(1.0), "d": True}) == [
        "a",
        "b",
        "c",
    ]


@pytest.mark.slow
def test_sweep_figure_names_curves_that_coincide(caplog):
    """sun_u does not depend on the rim thickness (the sun's mean torque balance); the figure says so. The
    variants, each with its own contact-point observables, share one compiled SL solver."""
    from pgtjax.studies import planetary as study

    p = small_params()
    variants = study.rim_thickness_variants(p, (0.1, 0.12, 0.15))
    with jax.log_compiles(True), caplog.at_level(logging.WARNING):
        sweep = study.parameter_sweep(p, variants, periods=0.02, n_saves=4)
    compiled = [r for r in caplog.records if "compilation of jit(_solve_moments_jit)" in r.getMessage()]
    assert len(compiled) <= 1, f"{len(compiled)} compilations for 3 variants of equal shape"
    same = study.coinciding(sweep, study.FIGURE_DOFS)
    assert "sun_u" in same and "ring_node2_tangential" not in same
    fig = study.sweep_figure(sweep, "test")
    assert "sun_u: the 3 curves coincide" in fig._suptitle.get_text()


def test_nearly_constant_curve_is_drawn_flat():
    import matplotlib.pyplot as plt

    from pgtjax import plots

    fig, ax = plt.subplots()
    ax.plot(np.arange(50), 73.576 + 1e-6 * np.sin(np.arange(50)))
    plots.readable_ylim(ax)
    lo, hi = ax.get_ylim()
    assert hi - lo >= 0.99e-2 * 73.576 and lo < 73.576 < hi
    assert not ax.yaxis.get_major_formatter().get_useOffset()
    ax.plot(np.arange(50), np.linspace(0.0, 5.0, 50))  # a real variation keeps matplotlib's own limits
    ax.relim(), ax.autoscale()
    before = ax.get_ylim()
    plots.readable_ylim(ax)
    assert ax.get_ylim() == before
    plt.close(fig)


def test_y_labels_clear_the_panel_to_their_left(tmp_path):
    """A four-column figure shaped like the rim-thickness sweep's (slow humps, a band per mesh cycle, tick
    labels such as 197.5 in the third column): in the figure as saved, every column's y-label starts right of
    the panel to its left. At matplotlib's default 3 pt padding the third column's label overlapped the second
    panel by 7 px at 200 dpi."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from pgtjax import plots

    cycle, t = 0.2707, np.linspace(0.0, 27.07, 2005)
    shape = 0.9 * np.sin(np.pi * t / 9.0) ** 2 + 0.05 + 0.05 * np.sin(2 * np.pi * t / cycle)

    def curve(lo, hi, std_lo, std_hi):  # µm
        return 1e-6 * (lo + (hi - lo) * shape), 1e-6 * (std_lo + (std_hi - std_lo) * shape)

    ranges = {  # (mean from, to, std from, to) of the sweep's three variants
        "a": [(1.49, 13.57, 0.30, 2.69), (1.74, 9.88, 0.35, 1.97), (1.69, 8.08, 0.34, 1.61)],
        "c": [(185.81, 198.19, 15.86, 18.30), (185.42, 192.83, 15.78, 17.25), (185.14, 190.35, 15.72, 16.76)],
        "d": [(155.56, 167.93, 9.82, 12.26), (155.17, 162.58, 9.73, 11.20), (154.89, 160.10, 9.68, 10.71)],
    }
    flat = (73.577e-6 + 0 * t, 14.6961e-6 + 1.1e-9 * shape)
    curves = {f"h{k}": {"b": flat, **{n: curve(*r[k]) for n, r in ranges.items()}} for k in range(3)}
    fig = plots.mean_std_figure(
        t, curves, [(n, "m") for n in "abcd"], title="sweep", subtitle="b", cycle=cycle
    )
    gaps = []

    def measure(event):  # on the draw that is saved
        gaps.clear()
        for row in (0, 1):
            axes = [a for a in fig.axes if a.get_subplotspec().rowspan.start == row]
            for left, right in zip(axes, axes[1:]):
                label = right.yaxis.label.get_window_extent(event.renderer)
                gaps.append(label.x0 - left.get_window_extent(event.renderer).x1)

    FigureCanvasAgg(fig).mpl_connect("draw_event", measure)
    plots.save(fig, tmp_path / "sweep.png")
    assert len(gaps) == 6 and min(gaps) > 0.0, gaps


def test_share_within_three_standard_errors_is_not_rounded_up_to_all():
    from pgtjax.studies.planetary import _percent

    assert _percent(1.0) == "100.00 %" and _percent(0.9965) == "99.65 %"
    assert _percent(0.99996) == "> 99.99 %"  # 4 points in 100,000 outside: not "100.00 %"


def test_peak_quantiles_and_exceedance_from_hand_made_counts():
    """The peak summary's rule on counts made by hand: 100 samples over bins of 1 N from 0 to 10 N, 50 in
    [3, 4), 40 in [5, 6), 9 in [8, 9) and 1 beyond the top edge. A quantile is the upper edge of the bin where
    the cumulative count reaches it, stated only with at least 10 samples beyond it (the 90 % with exactly
    10); the exceedance at each upper edge counts the sample beyond the top edge too."""
    from types import SimpleNamespace

    from pgtjax.studies import planetary as study

    row = np.zeros(10)
    row[[3, 5, 8]] = 50.0, 40.0, 9.0
    counts = np.stack([np.zeros(10), row])  # two histogram times; the last one is summarized
    mc = SimpleNamespace(
        peak_histograms={"force:m": counts},
        peak_edges={"force:m": np.arange(11.0)},
        histogram_times=np.array([0.5, 1.0]),
        n_samples=100,
    )
    mc.peak_start, mc.times = 0.25, np.array([0.0, 1.0])
    summary = study.peak_force_summary(SimpleNamespace(mc=mc, sl_peaks=None))
    entry = summary["per_mesh"]["m"]
    assert entry["median_N"] == 4.0 and entry["q90_N"] == 6.0
    assert entry["q99_N"] is None and entry["q999_N"] is None
    assert entry["beyond_top_edge_fraction"] == 0.01 and entry["bin_width_N"] == 1.0
    assert summary["time_s"] == 1.0 and summary["n_samples"] == 100
    assert "over every step from t = 0.25 s to the end" in summary["note"]
    # the result's exceedance rule on the same counts (the figure's): P(peak >= 1, 2, ..., 10 N)
    mc.peak_start, mc.times = None, np.array([0.0, 1.0])
    exceedance = pg.MonteCarloResult.peak_exceedance(mc, "force:m")
    np.testing.assert_array_equal(exceedance.levels, np.arange(1.0, 11.0))
    p = exceedance.probability[1]
    np.testing.assert_allclose(p, [1, 1, 1, 0.5, 0.5, 0.1, 0.1, 0.1, 0.01, 0.01], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(exceedance.probability[0], np.ones(10))  # no count yet: all beyond
    assert exceedance.start == 0.0
