"""pgtjax.design: gradients of every built-in objective and cost through the variable maps against central
differences, a 2-DOF problem with a hand-derived optimum, bounds, resume, batch evaluation, Monte Carlo
verification and the errors of bad design specifications."""

import copy
import json
import tomllib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import pgtjax as pg
from pgtjax import design as pd
from pgtjax import params as embedded
from pgtjax.models import planetary as pm

# ------------------------------------------------------------------ a 2-DOF chain with an analytic optimum
#
# ground -k1- m1 -k2- m2, damping C = alpha M, white-noise forces with intensity 2 pi S0 M (B = sqrt(M)).
# Lyapunov: with C = alpha M and noise intensity Q = 2 pi S0 M, the stationary covariance is
# Sigma_uu = c K^-1, Sigma_vv = c M^-1, Sigma_uv = 0 with c = pi S0 / alpha (substitute into
# d/dt Sigma = 0). K^-1 = [[1/k1, 1/k1], [1/k1, 1/k1 + 1/k2]], so the mean of the two variances is
# c (2/k1 + 1/k2) / 2 and with the cost lam (k1 + k2) the optimum is k1 = sqrt(c/lam), k2 = sqrt(c/(2 lam)).
# Newmark's default noise treatment keeps the stationary covariance exactly, so starting from it the
# time-mean variance is the stationary one at any step.

MASSES = jnp.array([2.0, 1.0])
ALPHA, S0 = 0.5, 0.01
C = np.pi * S0 / ALPHA


class Chain(eqx.Module):
    k1: jax.Array
    k2: jax.Array


def chain_system(p):
    k = jnp.array([[p.k1 + p.k2, -p.k2], [-p.k2, p.k2]])
    m = jnp.diag(MASSES)
    return pg.System(m, k, damping=ALPHA * m, noise_input=jnp.diag(jnp.sqrt(MASSES)), spectral_density=S0)


def stationary(params, system):
    return jax.scipy.linalg.block_diag(C * jnp.linalg.inv(system.stiffness), C * jnp.diag(1.0 / MASSES))


def chain_problem(
    lam, lower=0.01, upper=100.0, transform="log", k0=(1.0, 3.0), n_steps=20, checkpoint_blocks=1
):
    space = pd.DesignSpace(
        Chain(jnp.asarray(k0[0]), jnp.asarray(k0[1])),
        [pd.Variable("k1", lower, upper, transform), pd.Variable("k2", lower, upper, transform)],
    )
    response = pd.Response(
        build=chain_system,
        dt=0.05,
        n_steps=n_steps,
        initial_covariance=stationary,
        checkpoint_blocks=checkpoint_blocks,
    )
    cost = pd.ParameterCost(fn=lambda p: p.k1 + p.k2, weight=lam, label="k1 + k2", unit="N/m")
    return pd.DesignProblem(space, response, pd.Variance(["q0", "q1"]), [cost], normalize=False)


@pytest.mark.slow
def test_two_dof_optimum_matches_the_hand_derived_one():
    lam = 0.01
    result = pd.optimize(chain_problem(lam), rtol=0.0, gtol=1e-10, max_iter=60, progress=False)
    k = result.history[-1]["variables"]
    assert result.converged, result.reason
    np.testing.assert_allclose([k["k1"], k["k2"]], [np.sqrt(C / lam), np.sqrt(C / (2 * lam))], rtol=1e-6)
    # the value there is the analytic minimum too (the SL of a linear system is exact)
    k1, k2 = np.sqrt(C / lam), np.sqrt(C / (2 * lam))
    np.testing.assert_allclose(result.value, C * (2 / k1 + 1 / k2) / 2 + lam * (k1 + k2), rtol=1e-10)
    assert result.z.dtype == np.float64


@pytest.mark.slow
def test_sl_peak_probability_as_a_design_objective_has_the_gradient_of_a_central_difference():
    """``Response(covariance_dofs=...)`` keeps the joint covariance SL's peak estimate reads, so a ``Custom``
    objective on ``result.peak_exceedance`` (the probability that q1's peak from 2 s on has reached 0.5 m by
    10 s) runs in the compiled design problem, with the gradient of a central difference in the variables."""
    space = pd.DesignSpace(
        Chain(jnp.asarray(1.0), jnp.asarray(3.0)),
        [pd.Variable("k1", 0.01, 100.0), pd.Variable("k2", 0.01, 100.0)],
    )
    response = pd.Response(
        build=chain_system, dt=0.05, n_steps=200, initial_covariance=stationary, covariance_dofs=["q1"]
    )
    peak = pd.Custom(
        fn=lambda result, system: result.peak_exceedance("u:q1", [0.5], start=2.0).probability[-1, 0],
        label="P(peak |q1| >= 0.5 m)",
        unit="1",
    )
    problem = pd.DesignProblem(space, response, peak, [], normalize=False)
    assert_probability_gradient_matches_central_difference(problem, jnp.array([0.3, -0.2]))


def assert_probability_gradient_matches_central_difference(problem, z, h=1e-5):
    """The jitted value and gradient of a probability objective: a probability neither 0 nor 1, and each
    component of the gradient non-zero and equal to a central difference of the (unjitted) value."""
    value, grad = jax.jit(jax.value_and_grad(problem.value))(z)
    assert 0.05 < float(value) < 0.95 and grad.dtype == jnp.float64
    for i in range(z.shape[0]):
        e = jnp.zeros(z.shape[0]).at[i].set(h)
        fd = (problem.value(z + e) - problem.value(z - e)) / (2 * h)
        np.testing.assert_allclose(float(grad[i]), float(fd), rtol=1e-6)
        assert float(grad[i]) != 0.0


class MeshDesign(eqx.Module):
    stiffness: jax.Array  # N/m, the mean mesh stiffness
    damping: jax.Array  # N s/m


def mesh_system(p):
    """A 1 kg oscillator held by a contact (no clearance) whose stiffness k0 (1 - cos 2 pi 7 t) is 0 at the
    start, where a force level's barrier b + F / k is at infinity."""
    k = pg.FourierSeries(p.stiffness, cos_coefficients=[-p.stiffness], frequency=2 * np.pi * 7.0)
    return pg.System([[1.0]], [[0.0]], damping=[[p.damping]], noise_input=[[1.0]], spectral_density=1.0,
                     contacts=pg.Contacts([[1.0]], k, [0.0], names=["mesh"]))  # fmt: skip


@pytest.mark.slow
def test_sl_force_peak_probability_as_a_design_objective_has_the_gradient_of_a_central_difference():
    """``Response(deflection_lag=True)`` keeps what SL's peak estimate of a contact force reads, so a
    ``Custom`` objective on ``result.peak_exceedance("force:mesh", ..., system=system)`` (the probability that
    the mesh force's peak from 0.3 s on has reached 130 N, about 2.7 std, by 0.6 s) runs in the compiled design
    problem, with the gradient of a central difference in the variables (the mesh stiffness and the damping),
    finite although the barrier starts at infinity."""
    space = pd.DesignSpace(
        MeshDesign(jnp.asarray(4000.0), jnp.asarray(30.0)),
        [pd.Variable("stiffness", 1000.0, 1e4), pd.Variable("damping", 5.0, 100.0)],
    )
    response = pd.Response(build=mesh_system, dt=1e-3, n_steps=600, static_start=False, deflection_lag=True)
    peak = pd.Custom(
        fn=lambda result, system: result.peak_exceedance(
            "force:mesh", [130.0], start=0.3, system=system
        ).probability[-1, 0],
        label="P(peak |f| >= 130 N)",
        unit="1",
    )
    problem = pd.DesignProblem(space, response, peak, [], normalize=False)
    assert_probability_gradient_matches_central_difference(problem, jnp.array([0.1, -0.1]))
    with pytest.raises(ValueError, match="Response `deflection_lag` must be True or False"):
        pd.Response(build=mesh_system, dt=1e-3, n_steps=600, deflection_lag="yes")
    with pytest.raises(ValueError, match="Response `deflection_lag` needs save_every = 1, got 2"):
        pd.Response(build=mesh_system, dt=1e-3, n_steps=600, save_every=2, deflection_lag=True)


@pytest.mark.slow
def test_grouped_checkpoints_leave_the_objective_and_its_gradient_unchanged():
    """``Response(checkpoint_blocks=k)`` reaches ``solve_moments``: the same value and gradient (the state kept
    once per 3 saved blocks, 20 blocks: a group left incomplete), and a bad k is refused when the problem is built."""
    grouped = chain_problem(0.01, checkpoint_blocks=3)
    z = jnp.array([0.3, -0.2])
    want, got = (jax.jit(jax.value_and_grad(q.value))(z) for q in (chain_problem(0.01), grouped))
    assert got[1].dtype == jnp.float64
    np.testing.assert_allclose(got[0], want[0], rtol=1e-13)
    np.testing.assert_allclose(got[1], want[1], rtol=1e-12)
    for k in (0, 21):
        with pytest.raises(ValueError, match=r"Response.checkpoint_blocks.*\[1, 20\]"):
            pd.Response(build=chain_system, dt=0.05, n_steps=20, checkpoint_blocks=k)


@pytest.mark.slow
@pytest.mark.parametrize("transform", ["log", "linear", "box"])
def test_bounds_are_never_violated(transform):
    # a tiny cost pushes both stiffnesses up; the upper bound stops them
    lower, upper = 0.5, 5.0
    problem = chain_problem(1e-5, lower, upper, transform)
    evaluate = eqx.filter_jit(jax.value_and_grad(lambda z: problem.value(z)))
    for optimizer in (None, optax.adam(0.3)):
        result = pd.optimize(
            problem,
            optimizer=optimizer,
            max_iter=15,
            rtol=0.0,
            gtol=0.0,
            progress=False,
        )
        values = np.array([[e["variables"]["k1"], e["variables"]["k2"]] for e in result.history])
        assert np.all(values >= lower) and np.all(values <= upper)
        # the coordinates themselves stay in their bounds (the physical values are clipped by the maps
        # anyway, so the check above alone could not fail)
        lo, hi = problem.space.bounds()
        zs = np.array([e["z"] for e in result.history])
        # every iterate's recorded value and gradient are those of its projected point, not the line search's
        for e in (result.history[1], result.history[-1]):
            z = jnp.asarray(e["z"])
            value, grad = evaluate(z)
            projected = np.linalg.norm(z - problem.space.project(z - grad))
            np.testing.assert_allclose([e["objective"], e["gradient_norm"]], [value, projected], rtol=1e-9)
        assert np.all(zs >= lo) and np.all(zs <= hi)
        params = result.params
        assert lower <= float(params.k1) <= upper and lower <= float(params.k2) <= upper
        if transform != "box":  # the box map approaches its bound only asymptotically
            np.testing.assert_allclose(values[-1], [upper, upper], rtol=1e-6)


def test_gradient_at_a_bound_points_inside():
    # at the upper bound, a cost that favours smaller k must show a positive gradient (the map's clip against
    # rounding must not zero it, or a variable that reached its bound could never leave it)
    problem = chain_problem(10.0, 0.5, 5.0, "log")
    z_top = jnp.asarray(problem.space.bounds()[1])
    grad = eqx.filter_jit(jax.grad(lambda z: problem.value(z)))(z_top)
    k = 5.0
    expected = (
        -C / k**2 * np.array([1.0, 0.5]) + 10.0
    ) * k  # d/dlog k of c (1/k1 + 1/(2 k2)) + lam (k1 + k2)
    np.testing.assert_allclose(grad, expected, rtol=1e-8)


@pytest.mark.slow
def test_resume_continues_the_same_history(tmp_path, capsys):
    straight = pd.optimize(
        chain_problem(0.01), max_iter=6, rtol=0.0, gtol=0.0, progress=False, history=tmp_path / "a.json"
    )
    path = tmp_path / "b.json"
    pd.optimize(chain_problem(0.01), max_iter=3, rtol=0.0, gtol=0.0, progress=False, history=path)
    assert len(json.loads(path.read_text())["iterations"]) == 4
    capsys.readouterr()
    resumed = pd.optimize(
        chain_problem(0.01), max_iter=6, rtol=0.0, gtol=0.0, progress=True, history=path, resume=True
    )
    assert [e["iteration"] for e in resumed.history] == list(range(7))
    # progress on a stream that is not a terminal: a plain line per iteration here (each passes a tenth of
    # 6), counted from the resumed iteration 3, with the objective reached
    lines = capsys.readouterr().err.splitlines()
    assert [line.split(" iterations")[0] for line in lines] == [f"optimize: {k} / 6" for k in (4, 5, 6)], (
        lines
    )
    for line, entry in zip(lines, resumed.history[4:]):  # each with its own iteration's objective
        assert f"J={entry['objective']:.6g}, grad={entry['gradient_norm']:.2e}" in line, (line, entry)
    np.testing.assert_allclose(
        [e["z"] for e in resumed.history], [e["z"] for e in straight.history], rtol=1e-12, atol=1e-14
    )
    np.testing.assert_allclose(
        [e["objective"] for e in resumed.history], [e["objective"] for e in straight.history], rtol=1e-12
    )
    with pytest.raises(ValueError, match=r"another problem \(costs: history .*'weight': 0.01.*this run"):
        pd.optimize(chain_problem(0.02), max_iter=6, history=path, resume=True, progress=False)


@pytest.mark.slow
def test_batch_evaluation_equals_one_by_one():
    problem = chain_problem(0.01)
    zs = jnp.array([[0.0, 0.0], [0.5, -0.3], [-1.0, 1.2]])
    batch = pd.evaluate(problem, zs)
    for z, value in zip(zs, batch.value):
        np.testing.assert_allclose(value, problem.value(z), rtol=1e-13)
    k1, k2 = np.sqrt(0.01 * 100.0) * np.exp(np.asarray(zs)).T  # Log map around sqrt(lower * upper) = 1
    np.testing.assert_allclose(batch.response, C * (2 / k1 + 1 / k2) / 2, rtol=1e-10)
    assert batch.value.dtype == jnp.float64


def test_vmapped_batches_equal_one_by_one_and_warn_on_an_affected_jaxlib():
    """``batch_size`` vmaps the designs (the same values as the one-at-a-time loop); on a jaxlib whose batched
    LAPACK calls wait on XLA's thread pool, on several cores, the user is warned (docs/performance.md)."""
    import warnings

    from pgtjax._parallel import _available_cores, lapack_batches_wait_on_pool

    problem = chain_problem(0.01)
    zs = jnp.array([[0.0, 0.0], [0.5, -0.3], [-1.0, 1.2]])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        batched = pd.evaluate(problem, zs, batch_size=2)
    hang_warnings = [w for w in caught if "can hang" in str(w.message)]
    assert len(hang_warnings) == int(lapack_batches_wait_on_pool() and _available_cores() > 1)
    assert all(w.filename == __file__ for w in hang_warnings)  # points at the caller's line
    np.testing.assert_allclose(batched.value, pd.evaluate(problem, zs).value, rtol=1e-13)


@pytest.mark.slow
def test_monte_carlo_check_agrees_with_the_exact_variance():
    problem = chain_problem(0.01, n_steps=40)
    z_opt = jnp.log(jnp.array([np.sqrt(C / 0.01), np.sqrt(C / 0.02)]))  # Log map reference 1
    check = pd.monte_carlo_check(
        problem,
        {"start": problem.space.initial(), "optimum": z_opt},
        n_samples=2000,
        batches=10,
        key=jax.random.key(1),
        save_every=10,
    )
    for entry in check["designs"].values():
        assert abs(entry["mc"] - entry["sl"]) < 4.0 * entry["mc_se"]
    opt = check["designs"]["optimum"]
    # start k = (1, 3): response c (2 + 1/3) / 2; optimum k = (2.51, 1.77): c (0.80 + 0.56) / 2, 42 % less.
    # The improvement is stated in standard errors of the paired (common random numbers) batch differences.
    exact = 1.0 - (2 / np.sqrt(C / 0.01) + 1 / np.sqrt(C / 0.02)) / (2 + 1 / 3)
    assert opt["improvement_in_se"] > 3
    assert abs(opt["improvement"] - exact * check["designs"]["start"]["sl"]) < 4 * opt["improvement_se"]


def test_monte_carlo_check_takes_sl_from_the_response_run_at_its_own_save_interval(monkeypatch):
    """The check's SL is the response's own run (saved every step: the program the problem's normalization
    compiled) at every 10th save, not a run compiled for the check's save interval; it equals a run saved there
    directly. From rest, so that the moments change along the horizon and a wrong grid shows."""
    from pgtjax.design._problem import _moments_saved_every

    base = chain_problem(0.01, n_steps=40)
    response = pd.Response(build=chain_system, dt=0.05, n_steps=40)  # zero initial covariance
    problem = pd.DesignProblem(base.space, response, base.objective, base.costs, normalize=False)
    assert problem.response.save_every == 1
    params = problem.space.params(problem.space.initial())
    system, merged = _moments_saved_every(problem.response, params, 10)
    _, direct = problem.response.moments(params, save_every=10)
    assert merged.times.shape == (5,) and merged.std_u.dtype == jnp.float64
    assert float(merged.std_u[-1, 0]) > 2 * float(merged.std_u[1, 0]) > 0  # the moments still grow
    for got, want in zip(jax.tree.leaves(merged), jax.tree.leaves(direct), strict=True):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-12, atol=0)
    # and monte_carlo_check runs SL at the response's own interval
    intervals, moments = [], pd.Response.moments

    def recorded(self, params, *, save_every=None, throw=True):
        intervals.append(save_every)
        return moments(self, params, save_every=save_every, throw=throw)

    monkeypatch.setattr(pd.Response, "moments", recorded)
    check = pd.monte_carlo_check(
        problem,
        {"start": problem.space.initial()},
        n_samples=20,
        batches=2,
        key=jax.random.key(0),
        save_every=10,
    )
    assert intervals == [None]
    assert check["designs"]["start"]["sl"] == float(problem.objective(merged, system, problem.names))


# ------------------------------------------------------------------ gradients on a small planetary train


def small_planetary():
    with open(embedded.path("planetary.toml"), "rb") as fh:
        d = tomllib.load(fh)
    d = copy.deepcopy(d)
    d["ring"]["n_elements"] = 6
    d["wind"]["turbulence_intensity"] = 2.0  # meshes near contact loss: every objective has a gradient
    return pm.load_params(d)


def small_problem(objective, costs=()):
    p = small_planetary()
    variables = [
        pd.Variable("ring.k_support_tangential", 1e9, 1e11, "log", size=6),
        pd.Variable("ring.thickness", 0.08, 0.2, "box"),
        pd.Variable("mesh.ring_planet", 5e9, 5e10, "log"),
        # any parameter can be a variable; these two make the force statistics depend on the design at
        # first order, so that central differences resolve their derivatives to 1e-6
        pd.Variable("wind.turbulence_intensity", 0.5, 8.0, "log"),
        pd.Variable("mesh.half_backlash", 1e-5, 1e-3, "log"),
    ]
    response = pd.planetary_response(p, periods=0.002, rtol=1e-13)
    return pd.DesignProblem(pd.DesignSpace(p, variables), response, objective, costs)


OBJECTIVES = [
    pd.Std(["ring_mesh1", "ring_mesh2"]),
    pd.Variance(["sun_u", "ring_planet1"], over=pd.SmoothMax()),
    pd.DynamicFactor(["ring_planet1", "sun_planet2"]),
    pd.ContactLoss(["ring_planet1", "ring_planet2", "ring_planet3"]),
]
COSTS = [pd.SupportStiffness(), pd.RimMass()]


@pytest.mark.slow
def test_every_objective_and_cost_gradient_matches_central_differences():
    # one simulation, every built-in objective and cost of it, and one compiled program for the values and
    # their reverse-mode Jacobian (the differences below call the same program: compilation dominates this test).
    # The problem's value, a fixed combination of these, would be a second simulation in the same program;
    # its gradient is checked against the exact one on the two-DOF chain (test_gradient_at_a_bound_...).
    problem = small_problem(OBJECTIVES[0], COSTS)

    def outputs(z):
        params = problem.space.params(z)
        system, result = problem.response.moments(params, throw=False)
        parts = [o(result, system, problem.names) for o in OBJECTIVES] + [c(params) for c in COSTS]
        return jnp.stack(parts)

    @eqx.filter_jit
    def values_and_jacobian(z):
        values, pullback = jax.vjp(outputs, z)
        # one reverse pass per output in a loop: vmapped over the outputs, the batched reverse pass took
        # 1.4 times as long to compile
        (jacobian,) = jax.lax.map(pullback, jnp.eye(values.shape[0], dtype=values.dtype))
        return values, jacobian

    z0 = problem.space.initial() + 0.1 * jax.random.normal(jax.random.key(2), (problem.space.n,))
    direction = jax.random.normal(jax.random.key(3), z0.shape)
    direction = direction / jnp.linalg.norm(direction)
    values0, jacobian = values_and_jacobian(z0)
    assert jacobian.dtype == jnp.float64 and bool(jnp.all(jnp.isfinite(jacobian)))

    def central(h):
        plus, minus = values_and_jacobian(z0 + h * direction)[0], values_and_jacobian(z0 - h * direction)[0]
        return (plus - minus) / (2 * h)

    # Richardson-extrapolated central differences: truncation O(h^4), round-off ~1e-13 relative / h
    reference = (4 * central(1e-2) - central(2e-2)) / 3
    derivative = jacobian @ direction
    names = [type(o).__name__ for o in OBJECTIVES + COSTS]
    for name, got, want, value in zip(names, derivative, reference, values0):
        np.testing.assert_allclose(got, want, rtol=1e-6, err_msg=name)
        assert abs(float(want)) > 1e-3 * abs(float(value)), name  # not a trivial 0


# ------------------------------------------------------------------------------------ bad specifications


def test_bad_specs_raise_value_errors_naming_the_entry():
    p = small_planetary()
    with pytest.raises(ValueError, match="ring.no_such_field"):
        pd.DesignSpace(p, [pd.Variable("ring.no_such_field", 1.0, 2.0)])
    with pytest.raises(ValueError, match="k_tan.*lower.*below"):
        pd.Variable("ring.k_support_tangential", 2e10, 1e10, name="k_tan")
    with pytest.raises(ValueError, match="ring.k_support_radial.*lower. > 0"):
        pd.Variable("ring.k_support_radial", 0.0, 1e11, "log")
    with pytest.raises(ValueError, match="transform"):
        pd.Variable("ring.thickness", 0.1, 0.2, "sqrt")
    with pytest.raises(ValueError, match="ring.thickness.*outside"):
        pd.DesignSpace(p, [pd.Variable("ring.thickness", 0.2, 0.3, "linear")])
    with pytest.raises(ValueError, match="strictly inside"):
        pd.DesignSpace(p, [pd.Variable("ring.thickness", 0.128, 0.3, "box")])
    with pytest.raises(ValueError, match="static choice"):
        pd.DesignSpace(p, [pd.Variable("n_planets", 1.0, 5.0, "linear")])
    with pytest.raises(ValueError, match="cannot be spread"):
        three = eqx.tree_at(lambda q: q.ring.k_support_radial, p, jnp.ones(3) * 1e10)
        pd.DesignSpace(three, [pd.Variable("ring.k_support_radial", 1e9, 1e11, size=6)])
    with pytest.raises(ValueError, match="unknown quantity 'ring_mesh9'"):
        small_problem(pd.Std(["ring_mesh9"]))
    with pytest.raises(ValueError, match="unknown mesh 'sun_planet7'"):
        small_problem(pd.DynamicFactor(["sun_planet7"]))
    with pytest.raises(ValueError, match="weight"):
        pd.SupportStiffness(weight=-1.0)
