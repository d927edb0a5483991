"""Moment recursion of linear systems against independent answers (Lyapunov equations, thesis matrices)."""

import jax.numpy as jnp
import numpy as np
import pytest
from _chains import grounded_spring_chain
from scipy import linalg

import pgtjax as pg

# the two built-in integrators, by the names the tests are parametrized with
INTEGRATORS = {"trapezoidal": pg.Newmark, "newmark": pg.NewmarkBridge}

M = np.diag([1.0, 2.0])
K = np.array([[300.0, -100.0], [-100.0, 200.0]])
C = np.array([[4.0, -1.0], [-1.0, 3.0]])
B = np.array([[1.0, 0.0], [0.3, 1.0]])
S0 = np.array([0.2, 0.1])
BS = B * np.sqrt(2 * np.pi * S0)[None, :]


def linear_system():
    return pg.System(
        mass=M,
        stiffness=K,
        damping=C,
        noise_input=B,
        spectral_density=S0,
        load=np.array([1.0, -2.0]),
        dof_names=["a", "b"],
    )


def thesis_step_matrices(h, scheme):
    """T1 and T3 of thesis Eqs. 3.47 and 3.49, written out in numpy (independent of pgtjax)."""
    n1 = np.block([[C + h / 2 * K, M], [M, -h / 2 * M]])
    n2 = np.block([[C - h / 2 * K, M], [M, h / 2 * M]])
    bridge = BS * h * np.sqrt(h) / np.sqrt(12.0) if scheme == "newmark" else 0.0 * BS
    z = np.zeros_like(BS)
    t1 = np.linalg.solve(n1, n2)
    t3 = np.linalg.solve(n1, np.block([[np.sqrt(h) * BS, z], [z, bridge]]))
    return t1, t3


def state_matrix():
    minv = np.linalg.inv(M)
    a = np.block([[np.zeros((2, 2)), np.eye(2)], [-minv @ K, -minv @ C]])
    q = np.zeros((4, 4))
    q[2:, 2:] = minv @ BS @ BS.T @ minv.T
    return a, q


@pytest.mark.slow
@pytest.mark.parametrize("scheme", ["trapezoidal", "newmark"])
def test_stationary_covariance_equals_discrete_lyapunov(scheme):
    h = 0.01
    t1, t3 = thesis_step_matrices(h, scheme)
    p_disc = linalg.solve_discrete_lyapunov(t1, t3 @ t3.T)
    res = pg.solve_moments(
        linear_system(), dt=h, n_steps=4000, save_every=4000, integrator=INTEGRATORS[scheme]()
    )
    std = np.concatenate([res.std_u[-1], res.std_v[-1]])
    np.testing.assert_allclose(std, np.sqrt(np.diag(p_disc)), rtol=1e-8)
    # Starting *at* the discrete solution, one step must return it exactly (full matrix, not only std).
    res1 = pg.solve_moments(
        linear_system(), dt=h, n_steps=1, integrator=INTEGRATORS[scheme](), initial_covariance=p_disc
    )
    std1 = np.concatenate([res1.std_u[-1], res1.std_v[-1]])
    np.testing.assert_allclose(std1, np.sqrt(np.diag(p_disc)), rtol=1e-12)
    # and the mean follows T1 exactly (thesis Eq. 3.52 with the load term)
    u0 = np.array([1e-3, -2e-3])
    res2 = pg.solve_moments(
        linear_system(), dt=h, n_steps=1, integrator=INTEGRATORS[scheme](), initial_displacement=u0
    )
    n1 = np.block([[C + h / 2 * K, M], [M, -h / 2 * M]])
    f = np.array([1.0, -2.0])
    mean_thesis = t1 @ np.concatenate([u0, np.zeros(2)]) + np.linalg.solve(
        n1, np.concatenate([h * f, np.zeros(2)])
    )
    np.testing.assert_allclose(np.concatenate([res2.mean_u[-1], res2.mean_v[-1]]), mean_thesis, rtol=1e-12)


def test_trapezoidal_scheme_is_exact_in_the_stationary_limit_and_documents_scheme_follows_errata():
    a, q = state_matrix()
    p_c = linalg.solve_continuous_lyapunov(a, -q)
    errors = []
    steps = np.array([0.04, 0.02, 0.01, 0.005])
    for h in steps:
        t1, t3 = thesis_step_matrices(h, "trapezoidal")
        np.testing.assert_allclose(linalg.solve_discrete_lyapunov(t1, t3 @ t3.T), p_c, rtol=1e-8, atol=1e-12)
        t1, t3 = thesis_step_matrices(h, "newmark")
        p_d = linalg.solve_discrete_lyapunov(t1, t3 @ t3.T)
        # docs/corrections.md C2: exactly P_c + h^2/12 A P_c A^T
        np.testing.assert_allclose(p_d, p_c + h**2 / 12 * a @ p_c @ a.T, rtol=1e-8, atol=1e-14)
        errors.append(np.linalg.norm(p_d - p_c) / np.linalg.norm(p_c))
    order = np.polyfit(np.log(steps), np.log(errors), 1)[0]
    assert 1.95 < order < 2.05


def slow_and_fast_system(n: int, time_varying: bool = False):
    """``n`` DOFs, alternately slow (m = 1000, k = 1, overdamped: omega h ~ 3e-4 at h = 0.01) and ordinary
    (m = 1, k = 100), each slow one weakly coupled to its neighbour, every DOF driven by its own white noise.
    ``time_varying``: K given as a function of time (constant in value), which takes the solver's general path."""
    mass = np.diag([1000.0 if i % 2 == 0 else 1.0 for i in range(n)])
    stiffness = np.diag([1.0 if i % 2 == 0 else 100.0 for i in range(n)])
    for i in range(0, n - 1, 2):
        stiffness[i, i + 1] = stiffness[i + 1, i] = -0.1
        stiffness[i, i] += 0.1
        stiffness[i + 1, i + 1] += 0.1
    damping = np.diag([130.0 if i % 2 == 0 else 2.0 for i in range(n)])
    k_value = jnp.asarray(stiffness)
    return pg.System(
        mass=mass,
        stiffness=(lambda t: k_value + 0.0 * t) if time_varying else stiffness,
        damping=damping,
        noise_input=np.eye(n),
        spectral_density=np.full(n, 0.05),
        load=np.zeros(n),
    ), (mass, damping, stiffness)


@pytest.mark.slow
@pytest.mark.parametrize("n, time_varying", [(2, False), (20, False), (20, True)])
def test_slow_dofs_keep_their_stationary_covariance(n, time_varying):
    """The trapezoidal scheme keeps the continuous stationary covariance exactly, for any step. Started
    there, a system with slow DOFs (4 m / (h^2 k) = 4e7) must stay there to rounding over many steps: on each
    of the solver's paths (small dense, constant K and C, time-varying K). Forming the velocity covariance
    from the displacement rows of the step map, rather than from their increments, lost about 4e7 x eps of
    it per step, and the slow stds drifted: by up to 7e-7 here after 2,000 steps (2e-10 on the dense path);
    now they stay within 2e-13."""
    system, (mass, damping, stiffness) = slow_and_fast_system(n, time_varying)
    minv = np.linalg.inv(mass)
    a = np.block([[np.zeros((n, n)), np.eye(n)], [-minv @ stiffness, -minv @ damping]])
    q = np.zeros((2 * n, 2 * n))
    q[n:, n:] = minv @ (2 * np.pi * np.diag(np.full(n, 0.05))) @ minv.T
    p_c = linalg.solve_continuous_lyapunov(a, -q)
    res = pg.solve_moments(system, dt=0.01, n_steps=2000, save_every=500, initial_covariance=p_c)
    want = np.sqrt(np.diag(p_c))
    for i in range(1, len(res.times)):
        got = np.concatenate([res.std_u[i], res.std_v[i]])
        assert got.dtype == np.float64
        np.testing.assert_allclose(got, want, rtol=1e-11, err_msg=f"at t = {res.times[i]} s")


class StiffNewmark(pg.Newmark):
    """A user's variant of the scheme's algebra: 1.5 times the stiffness in E and K_eff."""

    name = "stiff"

    def effective_matrices(self, mass, damping, stiffness0, stiffness1, h):
        return super().effective_matrices(mass, damping, 1.5 * stiffness0, 1.5 * stiffness1, h)


@pytest.mark.slow
@pytest.mark.parametrize("n, time_varying", [(2, False), (20, False), (20, True)])
def test_a_variant_of_the_effective_matrices_keeps_its_own_stationary_covariance(n, time_varying):
    """SL with an integrator that overrides ``effective_matrices`` propagates that variant's map, not the
    built-in one's: started at the variant's discrete stationary covariance (its one-step map written out in
    NumPy, discrete Lyapunov equation), it stays there. The exact ``E - K_eff = -(K0 + K1)`` of the built-in
    scheme would be wrong for it (stds 12.7 % off); the variant gets ``E - K_eff`` by subtraction."""
    system, (mass, damping, stiffness) = slow_and_fast_system(n, time_varying)
    h = 0.01
    k = 1.5 * stiffness
    a_eff = k + (2 / h) * damping + (4 / h**2) * mass
    x = np.linalg.solve(a_eff, np.hstack([(4 / h**2) * mass + (2 / h) * damping - k, (4 / h) * mass]))
    eye_u, eye_v = np.eye(n, 2 * n), np.eye(n, 2 * n, k=n)
    phi = np.vstack([x, (2 / h) * (x - eye_u) - eye_v])
    b_n = (2 / np.sqrt(h)) * np.eye(n) * np.sqrt(2 * np.pi * 0.05)  # Newmark's noise input per draw
    g_u = np.linalg.solve(a_eff, b_n)
    gamma = np.vstack([g_u, (2 / h) * g_u])
    p_d = linalg.solve_discrete_lyapunov(phi, gamma @ gamma.T)
    p_d = 0.5 * (p_d + p_d.T)
    res = pg.solve_moments(
        system, dt=h, n_steps=50, save_every=25, initial_covariance=p_d, integrator=StiffNewmark()
    )
    want = np.sqrt(np.diag(p_d))
    for i in range(1, len(res.times)):
        np.testing.assert_allclose(np.concatenate([res.std_u[i], res.std_v[i]]), want, rtol=1e-8)


@pytest.mark.slow
@pytest.mark.parametrize("scheme", ["trapezoidal", "newmark"])
def test_recursion_converges_to_continuous_lyapunov(scheme):
    a, q = state_matrix()
    p_c = linalg.solve_continuous_lyapunov(a, -q)
    std_c = np.sqrt(np.diag(p_c))
    errs, steps = [], [0.02, 0.01, 0.005]
    for h in steps:
        n = int(round(40.0 / h))
        res = pg.solve_moments(
            linear_system(), dt=h, n_steps=n, save_every=n, integrator=INTEGRATORS[scheme]()
        )
        std = np.concatenate([res.std_u[-1], res.std_v[-1]])
        errs.append(np.max(np.abs(std - std_c) / std_c))
    if scheme == "trapezoidal":
        assert max(errs) < 1e-8
    else:
        order = np.polyfit(np.log(steps), np.log(errs), 1)[0]
        assert 1.9 < order < 2.1, errs


def test_mean_equals_deterministic_response():
    system = linear_system()
    res = pg.solve_moments(system, dt=0.005, n_steps=200, save_every=10)
    traj = pg.simulate(system, dt=0.005, n_steps=200, save_every=10)
    np.testing.assert_allclose(res.mean_u, traj.u, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(res.mean_v, traj.v, rtol=1e-10, atol=1e-13)
    assert res.mean_u.dtype == jnp.float64 and res.std_u.dtype == jnp.float64


@pytest.mark.slow
def test_linear_contact_with_zero_clearance_is_exactly_linear():
    """A b = 0 contact linearizes exactly (k_e = k, f_0 = k mu): same moments as putting k in K."""
    g = np.array([[1.0], [-1.0]])
    k_c = 150.0
    with_contact = pg.System(
        mass=M,
        stiffness=K,
        damping=C,
        noise_input=B,
        spectral_density=S0,
        load=np.array([1.0, -2.0]),
        contacts=pg.Contacts(direction=g, stiffness=[k_c], clearance=[0.0]),
    )
    merged = pg.System(
        mass=M,
        stiffness=K + k_c * g @ g.T,
        damping=C,
        noise_input=B,
        spectral_density=S0,
        load=np.array([1.0, -2.0]),
    )
    for crit in (pg.ForceCriterion(), pg.EnergyCriterion()):
        r1 = pg.solve_moments(with_contact, dt=0.01, n_steps=300, save_every=30, criterion=crit)
        r2 = pg.solve_moments(merged, dt=0.01, n_steps=300, save_every=30)
        np.testing.assert_allclose(r1.mean_u, r2.mean_u, rtol=1e-10, atol=1e-15)
        np.testing.assert_allclose(r1.std_u, r2.std_u, rtol=1e-10, atol=1e-15)
        np.testing.assert_allclose(
            r1.mean_delta[:, 0], r2.mean_u[:, 0] - r2.mean_u[:, 1], rtol=1e-9, atol=1e-14
        )


@pytest.mark.slow
@pytest.mark.parametrize("stiffness_form", ["constant", "function"])
def test_large_system_path_equals_discrete_lyapunov_of_thesis_matrices(stiffness_form):
    """n = 18 > 16: with a constant K the step uses the once-formed contact-free map plus rank-nc contact
    corrections; with K given as a function of time, the per-step LU with the Woodbury contact solve. Both
    stationary covariances must equal the discrete Lyapunov solution of the thesis's T1, T3 (Eqs. 3.47,
    3.49), with the b = 0 contact folded into K."""
    n, h = 18, 0.01
    m, k = grounded_spring_chain(n, 300.0, 4, ground_both_ends=True)
    c = 0.02 * k + 0.5 * m
    b = np.zeros((n, 1))
    b[3, 0] = 1.0
    g = np.zeros((n, 1))
    g[5, 0], g[12, 0] = 1.0, -1.0
    kc = 150.0
    stiffness = k if stiffness_form == "constant" else pg.FourierSeries(k)
    system = pg.System(
        mass=m,
        stiffness=stiffness,
        damping=c,
        noise_input=b,
        spectral_density=0.1,
        contacts=pg.Contacts(direction=g, stiffness=[kc], clearance=[0.0]),
    )
    res = pg.solve_moments(system, dt=h, n_steps=3000, save_every=3000, integrator=pg.NewmarkBridge())
    k_all = k + kc * g @ g.T
    bs = b * np.sqrt(2 * np.pi * 0.1)
    n1 = np.block([[c + h / 2 * k_all, m], [m, -h / 2 * m]])
    n2 = np.block([[c - h / 2 * k_all, m], [m, h / 2 * m]])
    z = np.zeros_like(bs)
    t1 = np.linalg.solve(n1, n2)
    t3 = np.linalg.solve(n1, np.block([[np.sqrt(h) * bs, z], [z, bs * h * np.sqrt(h) / np.sqrt(12.0)]]))
    p_disc = linalg.solve_discrete_lyapunov(t1, t3 @ t3.T)
    np.testing.assert_allclose(
        np.concatenate([res.std_u[-1], res.std_v[-1]]), np.sqrt(np.diag(p_disc)), rtol=1e-8
    )


def backlash_chain(stiffness_form):
    """20-DOF grounded chain with three backlash contacts whose directions and stiffnesses vary in time and
    a time-varying load; K either a constant array or the same matrix as a function of time."""
    n = 20
    m, k = grounded_spring_chain(n, 400.0, 11)
    c = 0.01 * k + 0.3 * m
    b = np.zeros((n, 1))
    b[2, 0] = 1.0
    g0 = np.zeros((n, 3))
    g0[[4, 9, 15], [0, 1, 2]] = 1.0
    g0[[5, 10, 16], [0, 1, 2]] = -1.0

    def direction(t):  # contact 3 slides between two DOF pairs
        w = 0.5 * (1.0 + jnp.sin(5.0 * t))
        return jnp.asarray(g0).at[:, 2].multiply(w) + (1.0 - w) * jnp.zeros((n, 3)).at[14, 2].set(1.0).at[
            17, 2
        ].set(-1.0)

    stiff = pg.FourierSeries(
        mean=[300.0, 250.0, 350.0], sin_coefficients=[[40.0, 20.0, 30.0]], frequency=13.0
    )
    return pg.System(
        mass=m,
        stiffness=k if stiffness_form == "constant" else pg.FourierSeries(k),
        damping=c,
        load=lambda t: jnp.zeros(n).at[2].set(3.0 + jnp.sin(2.0 * t)),
        noise_input=b,
        spectral_density=0.05,
        contacts=pg.Contacts(direction=direction, stiffness=stiff, clearance=[0.004, 0.006, 0.005]),
    )


@pytest.mark.slow
@pytest.mark.parametrize(
    "scheme, criterion",
    [("trapezoidal", pg.EnergyCriterion()), ("newmark", pg.ForceCriterion())],
    ids=["trapezoidal-energy", "newmark-force"],
)
def test_constant_stiffness_path_equals_general_path_with_backlash(scheme, criterion):
    """The two covariance updates (once-formed map + rank-nc corrections; per-step LU + Woodbury) are exact
    rewritings of the same step: nonlinear contacts, moving directions, time-varying mesh stiffness. Each
    scheme and each criterion is taken once (each pair compiles two programs, ~12 s each): the criterion
    only sets the linearized coefficients and the scheme only the noise matrices, which both paths share."""
    kw = dict(dt=0.01, n_steps=300, save_every=10, criterion=criterion, integrator=INTEGRATORS[scheme]())
    a = pg.solve_moments(backlash_chain("constant"), **kw)
    b = pg.solve_moments(backlash_chain("function"), **kw)
    assert a.mean_u.dtype == jnp.float64
    assert float(jnp.max(b.std_delta)) > 1e-3  # contacts open and close: a real nonlinear test
    for x, y in [
        (a.mean_u, b.mean_u),
        (a.std_u, b.std_u),
        (a.std_v, b.std_v),
        (a.mean_delta, b.mean_delta),
        (a.std_delta, b.std_delta),
        (a.k_e, b.k_e),
    ]:
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-10 * float(jnp.max(jnp.abs(y))))


def _contact_space_data(nc, seed):
    """A contact-space step: S = G^T A^-1 G symmetric positive definite, Y a covariance."""
    from pgtjax._linearization import _StepData

    rng = np.random.default_rng(seed)
    a = rng.standard_normal((nc, nc))
    y = rng.standard_normal((nc, nc))
    coupling = jnp.asarray(a @ a.T * 1e-10 + np.eye(nc) * 1e-9)
    return _StepData(
        coupling,
        jnp.asarray(rng.standard_normal(nc) * 2e-5),
        jnp.asarray(y @ y.T * 1e-10),
        jnp.full(nc, 1e9),
        jnp.full(nc, 1e-5),
    )


@pytest.mark.slow
@pytest.mark.parametrize("criterion", [pg.ForceCriterion(), pg.EnergyCriterion()], ids=["force", "energy"])
def test_closed_form_fixed_point_jacobian_equals_forward_mode_autodiff(criterion):
    """The Newton Jacobian of the contact-space fixed point is assembled in closed form from the law's own
    derivatives (pgtjax._linearization._evaluate); it must equal jax.jacfwd of the residual, including a
    contact with sigma = 0 (where the sigma rows vanish) and contacts in and out of the dead zone."""
    import jax

    from pgtjax._linearization import _evaluate

    nc = 4
    data = _contact_space_data(nc, 3)
    law = pg.Backlash()
    z = jnp.array([2e-5, -1e-5, 0.3e-5, 1.5e-5, 1e-5, 0.5e-5, 2e-5, 0.0])
    residual, terms, jacobian = _evaluate(law, nc, criterion, z, data, with_jacobian=True)
    jac = jacobian
    jac_ad = jax.jacfwd(lambda zz: _evaluate(law, nc, criterion, zz, data)[0])(z)
    assert jac.dtype == jnp.float64
    np.testing.assert_allclose(jac, jac_ad, rtol=1e-10, atol=1e-12 * float(jnp.max(jnp.abs(jac_ad))))
    # the end terms are the law's linearization at z and (I + S K_e)^-1
    lin = law.linearize(z[:nc], z[nc:], data.inputs, data.clearance, criterion)
    np.testing.assert_allclose(terms.lin.k_e, lin.k_e, rtol=1e-15)
    np.testing.assert_allclose(
        terms.r_inv @ (jnp.eye(nc) + data.coupling * lin.k_e[None, :]), jnp.eye(nc), atol=1e-12
    )


def _tangent_case(criterion, data):
    """A contact state ``z`` (one contact with sigma = 0, contacts in and out of the dead zone), its end terms
    and a data tangent, for the tangent-rule tests."""
    import jax

    from pgtjax._linearization import _end_terms

    nc = data.mean.shape[0]
    d_data = jax.tree.map(
        lambda x: x * jnp.linspace(0.5, 1.5, x.size).reshape(x.shape) * 1e-2, _contact_space_data(nc, 6)
    )
    law = pg.Backlash()
    z = jnp.array([2e-5, -1e-5, 0.3e-5, 1.5e-5, 1e-5, 0.5e-5, 2e-5, 0.0])
    return law, z, _end_terms(law, nc, criterion, z, data), d_data


@pytest.mark.slow
@pytest.mark.parametrize("criterion", [pg.ForceCriterion(), pg.EnergyCriterion()], ids=["force", "energy"])
def test_implicit_tangent_of_end_terms_equals_autodiff(criterion):
    """The tangent rule of the converged fixed point builds the end terms' derivative through z in closed form
    (law derivatives and dR^-1 = -R^-1 S dK_e R^-1); it must equal forward-mode autodiff of the end terms
    along the same (dz, d data)."""
    import jax

    from pgtjax._linearization import _end_terms, _implicit_solution

    nc = 4
    data = _contact_space_data(nc, 5)
    law, z, terms, d_data = _tangent_case(criterion, data)
    _, (d_z, d_terms) = jax.jvp(
        lambda d: _implicit_solution(z, terms, d, law, nc, criterion), (data,), (d_data,)
    )
    _, d_terms_ad = jax.jvp(lambda zz, dd: _end_terms(law, nc, criterion, zz, dd), (z, data), (d_z, d_data))
    for got, want in zip(jax.tree.leaves(d_terms), jax.tree.leaves(d_terms_ad)):
        assert got.dtype == jnp.float64
        np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12 * float(jnp.max(jnp.abs(want))))


@pytest.mark.slow
@pytest.mark.parametrize("case", ["general", "zero_std", "asymmetric_y"])
@pytest.mark.parametrize("criterion", [pg.ForceCriterion(), pg.EnergyCriterion()], ids=["force", "energy"])
def test_implicit_tangent_of_fixed_point_equals_autodiff_formula(criterion, case):
    """The closed-form tangent of the converged point, ``dz = -J^-1 (dR/ddata) ddata``, against the same
    formula built from plain autodiff: J by jacfwd of the residual in z, dR/ddata by a jvp of the residual
    in the data. Also where a contact's implied std is zero (uncoupled contacts, Y with a zero row and
    column: the std derivative is zero there, as safe_sqrt's) and where rounding left Y asymmetric."""
    import jax

    from pgtjax._linearization import _evaluate, _implicit_solution

    nc = 4
    data = _contact_space_data(nc, 5)
    if case == "zero_std":
        keep = jnp.ones(nc).at[1].set(0.0)
        data = data._replace(
            coupling=jnp.diag(jnp.diagonal(data.coupling)),
            covariance=data.covariance * keep[:, None] * keep[None, :],
        )
    elif case == "asymmetric_y":
        data = data._replace(covariance=data.covariance * (1.0 + 1e-3 * jnp.triu(jnp.ones((nc, nc)), 1)))
    law, z, terms, d_data = _tangent_case(criterion, data)
    _, (d_z, _) = jax.jvp(lambda d: _implicit_solution(z, terms, d, law, nc, criterion), (data,), (d_data,))
    residual = lambda zz, dd: _evaluate(law, nc, criterion, zz, dd)[0]  # noqa: E731
    jac = jax.jacfwd(residual)(z, data)
    _, d_res = jax.jvp(lambda dd: residual(z, dd), (data,), (d_data,))
    if case == "zero_std":
        assert float(d_res[nc + 1]) == 0.0  # the zero-std contact's std row
    want = -np.linalg.solve(np.asarray(jac), np.asarray(d_res))
    assert d_z.dtype == jnp.float64
    np.testing.assert_allclose(d_z, want, rtol=1e-9, atol=1e-12 * float(np.max(np.abs(want))))


def test_bad_fixed_point_settings_raise():
    m, k = grounded_spring_chain(4, 100.0, 1)
    system = pg.System(
        mass=m, stiffness=k, damping=0.01 * k, noise_input=np.eye(4)[:, :1], spectral_density=1.0
    )
    with pytest.raises(ValueError, match="rtol"):
        pg.solve_moments(system, dt=0.01, n_steps=4, rtol=0.0)
    with pytest.raises(ValueError, match="max_iter"):
        pg.solve_moments(system, dt=0.01, n_steps=4, max_iter=0)


@pytest.mark.slow
def test_derivative_rules_of_the_covariance_products_equal_autodiff_of_the_plain_products():
    """The covariance update's two hand-written derivative rules (``_quadratic_forms``: dX P dX^T and dX P;
    ``_congruence``: x P x^T) against forward- and reverse-mode autodiff of the plain matrix products, for a
    symmetric P, with and without a tangent of each argument, and under jit."""
    import jax

    from pgtjax._linearization import _congruence, _quadratic_forms

    rng = np.random.default_rng(11)
    n, m = 6, 3
    x = jnp.asarray(rng.standard_normal((n, 2 * n)))
    p = rng.standard_normal((2 * n, 2 * n))
    p = jnp.asarray(p @ p.T)
    rows = jnp.asarray(rng.standard_normal((m, 2 * n)))

    def plain_forms(x, p):
        a = x @ p
        return a @ x.T, a

    def plain_congruence(y, p):
        return (y @ p) @ y.T

    sym = rng.standard_normal((2 * n, 2 * n))
    tangents = (jnp.asarray(rng.standard_normal((n, 2 * n))), jnp.asarray(sym + sym.T))

    def close(got, want):
        for g, w in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
            assert g.dtype == jnp.float64
            np.testing.assert_allclose(g, w, rtol=0, atol=1e-13 * float(jnp.max(jnp.abs(w))))

    close(jax.jvp(_quadratic_forms, (x, p), tangents), jax.jvp(plain_forms, (x, p), tangents))
    # P is symmetric, so only the symmetric part of its cotangent is defined (the rule's differs from the plain
    # products' by an antisymmetric part, with an asymmetric cotangent of dX P dX^T as here)
    sym_part = lambda a: 0.5 * (a + a.T)  # noqa: E731
    cotangents = (jnp.asarray(rng.standard_normal((n, n))), jnp.asarray(rng.standard_normal((n, 2 * n))))
    (x_bar, p_bar), (x_want, p_want) = (
        jax.vjp(f, x, p)[1](cotangents) for f in (_quadratic_forms, plain_forms)
    )
    close((x_bar, sym_part(p_bar)), (x_want, sym_part(p_want)))
    # one argument differentiated (the other's tangent a symbolic zero), under jit
    loss = lambda f: lambda x, p: jnp.sum(jnp.sin(f(x, p)[0])) + jnp.sum(f(x, p)[1] ** 2)  # noqa: E731
    for arg in (0, 1):
        got = jax.jit(jax.grad(loss(_quadratic_forms), arg))(x, p)
        want = jax.grad(loss(plain_forms), arg)(x, p)
        close(got if arg == 0 else sym_part(got), want if arg == 0 else sym_part(want))

    row_tangents = (tangents[0][:m], tangents[1])
    close(jax.jvp(_congruence, (rows, p), row_tangents), jax.jvp(plain_congruence, (rows, p), row_tangents))
    bar = jnp.asarray(rng.standard_normal((m, m)))
    close(jax.vjp(_congruence, rows, p)[1](bar), jax.vjp(plain_congruence, rows, p)[1](bar))
