"""Transformations (jit, vmap, grad) through the solvers, dtypes, and input validation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import pgtjax as pg


def gear_like(k_mesh, gap, load=800.0):
    """Two inertias (as translations) coupled by a backlash mesh, noise on the first."""
    return pg.System(
        mass=np.diag([2.0, 3.0]),
        stiffness=np.diag([0.0, 2.0e4]),
        damping=np.array([[30.0, -10.0], [-10.0, 40.0]]),
        load=jnp.array([load, 0.0]),
        noise_input=np.array([[1.0], [0.0]]),
        spectral_density=20.0,
        contacts=pg.Contacts(
            direction=[[1.0], [-1.0]], stiffness=jnp.atleast_1d(k_mesh), clearance=jnp.atleast_1d(gap)
        ),
    )


def final_std(params):
    k_mesh, gap = params
    res = pg.solve_moments(gear_like(k_mesh, gap), dt=2e-3, n_steps=100, save_every=50, rtol=1e-14)
    return res.std_u[-1, 1] + 10.0 * res.mean_delta[-1, 0]


@pytest.mark.slow
def test_grad_through_sl_matches_central_differences():
    p = jnp.array([5.0e4, 0.02])
    g = jax.grad(final_std)(p)
    assert g.dtype == jnp.float64
    for i, h in enumerate([5.0e4 * 1e-5, 0.02 * 1e-5]):
        e = jnp.zeros(2).at[i].set(h)
        fd = (final_std(p + e) - final_std(p - e)) / (2 * h)
        np.testing.assert_allclose(float(g[i]), float(fd), rtol=1e-5)
    # forward mode agrees with reverse mode
    jv = jax.jvp(final_std, (p,), (jnp.array([1.0, 0.0]),))[1]
    np.testing.assert_allclose(float(jv), float(g[0]), rtol=1e-9)


def _std_and_mean(params, checkpoint_blocks, n_steps, save_every):
    k_mesh, gap = params
    res = pg.solve_moments(
        gear_like(k_mesh, gap),
        dt=2e-3,
        n_steps=n_steps,
        save_every=save_every,
        rtol=1e-14,
        checkpoint_blocks=checkpoint_blocks,
    )
    return jnp.max(res.std_u[:, 1]) + 10.0 * res.mean_delta[-1, 0]


@pytest.mark.slow
def test_grouped_checkpoints_give_the_same_gradient_with_less_memory():
    """``checkpoint_blocks`` keeps the state once per group of saved blocks: the gradient equals the one with the
    state kept once per block (a consistency check of the plumbing; the gradient itself is checked against central
    differences above), also with a group left incomplete, and its compiled reverse pass needs less memory."""
    p = jnp.array([5.0e4, 0.02])
    grad = jax.jit(jax.grad(_std_and_mean), static_argnums=(1, 2, 3))
    want = grad(p, 1, 400, 1)  # 400 saved blocks
    got = grad(p, 7, 400, 1)  # 57 groups of 7 blocks, 1 block left over
    assert got.dtype == jnp.float64
    np.testing.assert_allclose(got, want, rtol=1e-12)

    def temporary_bytes(k):  # the programs called above: no compilation of their own
        return grad.lower(p, k, 400, 1).compile().memory_analysis().temp_size_in_bytes

    # kept per step whatever the grouping: the fixed point's solution and its tangent rule's quantities, here about
    # twice the 2-DOF model's state; grouped, 58 states are kept instead of 400 (measured: 0.73 of the memory)
    assert temporary_bytes(7) < 0.8 * temporary_bytes(1)


@pytest.mark.slow
def test_gradient_wrt_the_initial_covariance_is_symmetric_and_matches_central_differences():
    """The recursion takes P symmetric, so the initial covariance enters as its symmetric part: the gradient with
    respect to it is a symmetric matrix, and along a symmetric direction it matches central differences."""
    system = gear_like(5e4, 0.02)
    p0 = jnp.asarray(np.diag([1e-6, 2e-6, 1e-4, 3e-4]))
    p0 = p0.at[0, 2].set(5e-6).at[2, 0].set(5e-6)

    def final_std_from(p):
        return pg.solve_moments(system, dt=2e-3, n_steps=20, initial_covariance=p, rtol=1e-14).std_u[-1, 1]

    g = jax.grad(final_std_from)(p0)
    assert g.dtype == jnp.float64
    np.testing.assert_array_equal(g, g.T)
    direction = jnp.asarray(np.diag([1e-7, 1e-7, 1e-5, 1e-5])).at[1, 3].set(2e-6).at[3, 1].set(2e-6)
    fd = (final_std_from(p0 + direction) - final_std_from(p0 - direction)) / 2.0
    np.testing.assert_allclose(float(jnp.sum(g * direction)), float(fd), rtol=1e-5)


def test_bad_checkpoint_blocks_raise_value_error():
    for k in (0, 5, 1.5, True):
        with pytest.raises(ValueError, match=r"checkpoint_blocks.*\[1, 4\]"):
            pg.solve_moments(gear_like(5e4, 0.02), dt=0.01, n_steps=4, checkpoint_blocks=k)
    with pytest.raises(ValueError, match="checkpoint=True"):
        pg.solve_moments(gear_like(5e4, 0.02), dt=0.01, n_steps=4, checkpoint_blocks=2, checkpoint=False)


@pytest.mark.slow
def test_jit_and_vmap_over_a_parameter():
    ks = jnp.array([3.0e4, 5.0e4, 8.0e4])
    batched = jax.vmap(lambda k: final_std((k, 0.02)))(ks)
    single = jnp.array([final_std((k, 0.02)) for k in ks])
    np.testing.assert_allclose(batched, single, rtol=1e-10)
    jitted = jax.jit(lambda p: final_std(p))(jnp.array([5.0e4, 0.02]))
    np.testing.assert_allclose(jitted, single[1], rtol=1e-12)


@pytest.mark.slow
def test_results_are_float64_and_labelled(tmp_path):
    res = pg.solve_moments(gear_like(5e4, 0.02), dt=2e-3, n_steps=20, save_every=10)
    for leaf in jax.tree.leaves(res):
        if eqx_is_float(leaf):
            assert leaf.dtype == jnp.float64
    assert res.dof_names == ("q0", "q1") and res.times.shape == (3,)
    path = pg.save_results(tmp_path / "r.npz", res, note="test")
    back, attrs = pg.load_results(path)
    np.testing.assert_array_equal(back.std_u, res.std_u)
    assert back.dof_names == res.dof_names and attrs == {"note": "test"}


def eqx_is_float(x):
    return hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.floating)


def test_nonconvergence_is_reported():
    res = pg.solve_moments(gear_like(5e4, 0.02), dt=2e-3, n_steps=10, max_iter=1, rtol=1e-300, throw=False)
    assert not bool(jnp.all(res.converged))
    with pytest.raises(Exception, match="did not converge"):
        pg.solve_moments(gear_like(5e4, 0.02), dt=2e-3, n_steps=10, max_iter=1, rtol=1e-300)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: pg.System(mass=[[-1.0]], stiffness=[[1.0]]), "mass"),
        (lambda: pg.System(mass=[[0.0]], stiffness=[[1.0]]), "mass"),
        (lambda: pg.System(mass=[[1.0, 2.0], [2.0, 1.0]], stiffness=np.eye(2)), "positive definite"),
        (lambda: pg.System(mass=[[1.0, 0.5], [0.0, 1.0]], stiffness=np.eye(2)), "symmetric"),
        (lambda: pg.System(mass=np.eye(2), stiffness=np.eye(3)), "stiffness"),
        (lambda: pg.System(mass=[[1.0]], stiffness=[[np.nan]]), "finite"),
        (lambda: pg.System(mass=[[1.0]], stiffness=[[1.0]], load=[np.inf]), "finite"),
        (
            lambda: pg.System(mass=[[1.0]], stiffness=[[1.0]], contacts=pg.Contacts([[1.0]], [1.0], [-0.1])),
            "clearance",
        ),
        (
            lambda: pg.System(
                mass=[[1.0]], stiffness=[[1.0]], contacts=pg.Contacts([[1.0], [0.0]], [1.0], [0.1])
            ),
            "direction",
        ),
        (lambda: pg.System(mass=[[1.0]], stiffness=[[1.0]], noise_input=[[1.0], [1.0]]), "noise_input"),
        (
            lambda: pg.System(mass=[[1.0]], stiffness=[[1.0]], noise_input=[[1.0]], spectral_density=-1.0),
            "spectral_density",
        ),
    ],
)
def test_bad_systems_raise_value_error(make, match):
    with pytest.raises(ValueError, match=match):
        pg.solve_moments(make(), dt=0.01, n_steps=2)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(dt=0.0), "dt"),
        (dict(dt=-1.0), "dt"),
        (dict(dt=np.nan), "dt"),
        (dict(n_steps=0), "n_steps"),
        (dict(n_steps=10, save_every=3), "multiple"),
        (dict(criterion="energy"), "criterion"),
        (dict(integrator="newmark"), "integrator"),
        (dict(initial_displacement=[1.0]), "initial_displacement"),
    ],
)
def test_bad_solver_arguments_raise_value_error(kwargs, match):
    args = dict(dt=0.01, n_steps=4) | kwargs
    with pytest.raises(ValueError, match=match):
        pg.solve_moments(gear_like(5e4, 0.02), **args)
    if "criterion" not in kwargs:
        with pytest.raises(ValueError, match=match):
            pg.monte_carlo(gear_like(5e4, 0.02), n_samples=4, key=jax.random.key(0), progress=False, **args)


def test_modal_analysis_two_dof():
    m, k = 2.0, 800.0
    sys = pg.System(mass=np.diag([m, m]), stiffness=np.array([[2 * k, -k], [-k, 2 * k]]))
    modes = pg.modal_analysis(sys)
    np.testing.assert_allclose(modes.angular_frequencies, [np.sqrt(k / m), np.sqrt(3 * k / m)], rtol=1e-12)
    np.testing.assert_allclose(modes.shapes.T @ sys.mass @ modes.shapes, np.eye(2), atol=1e-12)


@pytest.mark.slow
def test_jit_of_value_and_grad_with_concrete_initial_state():
    """Regression: input checks on concrete arrays must not stage jnp ops under an outer jit."""
    u0 = np.array([1e-3, 0.0])

    def loss(k):
        res = pg.solve_moments(
            gear_like(k, 0.02),
            dt=2e-3,
            n_steps=20,
            save_every=20,
            initial_displacement=u0,
            initial_covariance=np.eye(4) * 1e-8,
        )
        return res.std_u[-1, 1]

    value, grad = jax.jit(jax.value_and_grad(loss))(5.0e4)
    np.testing.assert_allclose(value, loss(5.0e4), rtol=1e-12)
    assert np.isfinite(float(grad))


def test_numpy_integer_sizes_accepted_and_bools_refused(capsys):
    """Sizes may be NumPy integers (as from np.arange or a config array); each solver runs with them and
    gives what the same Python ints give. A bool is not a size."""
    system = pg.System(mass=[[1.0]], stiffness=[[4.0]], damping=[[0.2]], noise_input=[[1.0]], load=[0.5])
    kw = dict(dt=0.01, initial_displacement=[0.1])
    want = pg.solve_moments(system, n_steps=6, save_every=3, **kw)
    got = pg.solve_moments(system, n_steps=np.int64(6), save_every=np.int32(3), **kw)
    np.testing.assert_array_equal(got.std_u, want.std_u)
    np.testing.assert_array_equal(
        pg.simulate(system, n_steps=np.int64(6), **kw).u, pg.simulate(system, n_steps=6, **kw).u
    )
    mc = pg.monte_carlo(
        system,
        n_samples=np.int64(40),
        chunk_size=np.int64(16),
        n_steps=np.int64(6),
        key=jax.random.key(0),
        progress=False,
        **kw,
    )
    np.testing.assert_array_equal(
        mc.std_u,
        pg.monte_carlo(
            system, n_samples=40, chunk_size=16, n_steps=6, key=jax.random.key(0), progress=True, **kw
        ).std_u,
    )
    # progress on a stream that is not a terminal (here captured): a plain line per batch of 16 samples
    lines = capsys.readouterr().err.splitlines()
    assert [line.split(" samples")[0] for line in lines] == [
        f"Monte Carlo: {n} / 40" for n in (16, 32, 40)
    ], lines
    with pytest.raises(ValueError, match="`n_steps` must be an integer >= 1, got True"):
        pg.solve_moments(system, n_steps=True, **kw)
