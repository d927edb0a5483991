"""Monte Carlo of the nonlinear system against the recursion (linear case) and an exact stationary
density (nonlinear backlash case)."""

import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _chains import grounded_spring_chain
from scipy import integrate

import pgtjax as pg

# the two built-in integrators, by the names the tests are parametrized with
INTEGRATORS = {"trapezoidal": pg.Newmark, "newmark": pg.NewmarkBridge}

KEY = jax.random.key(20261121)


def time_varying_system():
    """2-DOF chain whose coupling spring is a b = 0 contact with a time-varying stiffness (Eq. 4.11 form),
    a time-varying load and a time-varying noise input."""
    stiff = pg.FourierSeries(
        mean=[400.0], sin_coefficients=[[80.0]], cos_coefficients=[[30.0]], frequency=9.0
    )
    return pg.System(
        mass=np.diag([1.0, 1.5]),
        stiffness=np.diag([200.0, 100.0]),
        damping=np.array([[2.0, -0.5], [-0.5, 1.5]]),
        load=lambda t: jnp.array([5.0, 0.0]) * jnp.sin(3.0 * t),
        noise_input=lambda t: (
            jnp.array([[1.0], [0.5]]) * (1.0 + 0.5 * jnp.sin(4.0 * t))
        ),  # moving noise input
        spectral_density=0.3,
        contacts=pg.Contacts(direction=[[1.0], [-1.0]], stiffness=stiff, clearance=[0.0], names=["coupling"]),
        dof_names=["x1", "x2"],
    )


@pytest.mark.slow
@pytest.mark.parametrize("scheme", ["trapezoidal", "newmark"])
def test_linear_time_varying_mc_within_three_standard_errors(scheme):
    system = time_varying_system()
    kw = dict(dt=0.02, n_steps=150, save_every=30, integrator=INTEGRATORS[scheme]())
    ref = pg.solve_moments(system, **kw)
    mc = pg.monte_carlo(system, n_samples=4000, key=KEY, chunk_size=4000, progress=False, **kw)
    se_mean, se_std = mc.standard_error("u")
    for i in range(1, len(mc.times)):  # skip t0, where both are exactly deterministic
        assert np.all(np.abs(mc.mean_u[i] - ref.mean_u[i]) < 3 * se_mean[i]), i
        assert np.all(np.abs(mc.std_u[i] - ref.std_u[i]) < 3 * se_std[i]), i
    se_d = mc.std_delta[1:] / np.sqrt(mc.n_samples)
    assert np.all(np.abs(mc.mean_delta[1:] - ref.mean_delta[1:]) < 3 * se_d)
    assert mc.mean_u.dtype == jnp.float64


@pytest.mark.slow
def test_same_key_same_statistics_whatever_the_chunk_size():
    system = time_varying_system()
    kw = dict(
        dt=0.02,
        n_steps=40,
        save_every=10,
        key=KEY,
        n_samples=301,
        progress=False,
        histograms={"u:x1": np.linspace(-0.2, 0.2, 21)},
        histogram_times=[0.8],
        peaks={"u:x1": np.linspace(0.0, 0.4, 21)},
    )
    a = pg.monte_carlo(system, chunk_size=301, **kw)
    b = pg.monte_carlo(system, chunk_size=64, **kw)
    np.testing.assert_allclose(a.mean_u, b.mean_u, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(a.std_u, b.std_u, rtol=1e-10)
    np.testing.assert_array_equal(a.histograms["u:x1"], b.histograms["u:x1"])
    np.testing.assert_array_equal(a.peak_histograms["u:x1"], b.peak_histograms["u:x1"])
    assert b.n_samples == 301
    # histogram counts are the samples inside the edges at the requested time
    assert 0 < float(a.histograms["u:x1"].sum()) <= 301


@pytest.mark.slow
def test_padding_samples_cannot_spoil_the_statistics_of_finite_samples():
    """A batch is padded to whole rows with weight-0 samples. If those drew noise of their own, a sample outside
    the run could be NaN (here: a law defined only near the mean deflection) while every real one is finite,
    and 0 x NaN would make the statistics NaN for one chunk size and not another."""
    import equinox as eqx

    from pgtjax._contact import Backlash
    from pgtjax._montecarlo import _INITIAL_STATE_TAG
    from pgtjax._random import normal
    from pgtjax._system import initial_state
    from pgtjax.models import gear_pair as gp

    system = gp.build()
    p0 = np.diag([0.0, 0.0, 1e-10, 0.0, 0.0, 0.0])  # a random initial third coordinate, std 1e-5
    g = np.asarray(system.contact_direction(0.0))[:, 0]

    def offsets(key):  # each sample's initial deflection from the mean, as monte_carlo draws it
        z = [
            normal(jax.random.fold_in(jax.random.fold_in(key, s), _INITIAL_STATE_TAG), (6,))[2]
            for s in range(12)
        ]
        return np.abs(g[2] * 1e-5 * np.asarray(z))

    n = 9
    # a key for which a would-be padding sample (ids 9-11) lies beyond every real one
    key = next(k for k in map(jax.random.key, range(100)) if offsets(k)[n:].max() > offsets(k)[:n].max())
    limit = 0.5 * (offsets(key)[n:].max() + offsets(key)[:n].max())
    centre = float(g @ np.asarray(initial_state(system, None, None)[0]))  # the mean initial deflection

    class Limited(Backlash):  # NaN beyond `limit` from the mean, like the square root of a negative number
        def force(self, delta, k, b):
            return super().force(delta, k, b) + jnp.where(jnp.abs(delta - centre) < limit, 0.0, jnp.nan)

    limited = eqx.tree_at(lambda s: s.contacts.law, system, Limited())
    kw = dict(n_samples=n, key=key, dt=1e-5, n_steps=1, save_every=1, progress=False, initial_covariance=p0)
    whole = pg.monte_carlo(limited, chunk_size=n, **kw)  # one batch of 9: no padding
    padded = pg.monte_carlo(limited, chunk_size=4, **kw)  # batches of 4: three padding samples
    assert np.all(np.isfinite(whole.std_u)) and whole.std_u.dtype == jnp.float64
    np.testing.assert_allclose(padded.mean_u, whole.mean_u, rtol=1e-12, atol=1e-20)
    np.testing.assert_allclose(padded.std_u, whole.std_u, rtol=1e-10)
    assert padded.n_samples == n and float(padded.unconverged) == 0.0


# ----------------------------------------------------------------------------- exact nonlinear answer
# SDOF  m x'' + c x' + f(x) = F0 + w(t),  E[w w] = 2 pi S0 delta,  f = backlash (b, k).
# Stationary Fokker-Planck solution: p(x, v) ~ exp(-(c / (pi S0)) (m v^2 / 2 + P(x) - F0 x)), so
#   x has density ~ exp(-(c/(pi S0)) (P(x) - F0 x))  and  Var[v] = pi S0 / (c m) for any f.
MASS, DAMP, KC, GAP, F0, S0 = 1.0, 1.0, 100.0, 0.01, 0.6, 3.2e-3


def backlash_oscillator():
    return pg.System(
        mass=[[MASS]],
        stiffness=[[0.0]],
        damping=[[DAMP]],
        load=[F0],
        noise_input=[[1.0]],
        spectral_density=S0,
        contacts=pg.Contacts(direction=[[1.0]], stiffness=[KC], clearance=[GAP]),
        dof_names=["x"],
    )


def exact_stationary_moments():
    beta = DAMP / (np.pi * S0)
    pot = lambda x: 0.5 * KC * (max(x - GAP, 0) ** 2 + max(-GAP - x, 0) ** 2) - F0 * x  # noqa: E731
    x_min = GAP + F0 / KC
    w = lambda x: np.exp(-beta * (pot(x) - pot(x_min)))  # noqa: E731
    lo, hi, pts = -0.2, 0.2, [-GAP, GAP]
    z = integrate.quad(w, lo, hi, points=pts, epsabs=0, epsrel=1e-12, limit=400)[0]
    m1 = integrate.quad(lambda x: x * w(x), lo, hi, points=pts, epsabs=0, epsrel=1e-12, limit=400)[0] / z
    m2 = (
        integrate.quad(lambda x: (x - m1) ** 2 * w(x), lo, hi, points=pts, epsabs=0, epsrel=1e-12, limit=400)[
            0
        ]
        / z
    )
    p_gap = integrate.quad(w, -GAP, GAP, epsabs=0, epsrel=1e-12)[0] / z
    return m1, np.sqrt(m2), p_gap


@pytest.mark.slow
def test_backlash_oscillator_mc_matches_exact_stationary_density(capsys):
    mean_x, std_x, p_gap = exact_stationary_moments()
    std_v = np.sqrt(np.pi * S0 / (DAMP * MASS))
    # starting at the static equilibrium; 16 s = 8 relaxation times of the velocity (c/m = 1/s)
    kw = dict(dt=0.004, n_steps=4000, save_every=500, initial_displacement=[GAP + F0 / KC])
    mc = pg.monte_carlo(backlash_oscillator(), n_samples=6000, key=KEY, progress=False, **kw)
    # the last three saved times are 2 s apart (about 2 relaxation times): use the last one
    se_mean, se_std = mc.standard_error("u")
    assert abs(float(mc.mean_u[-1, 0]) - mean_x) < 3 * float(se_mean[-1, 0])
    assert abs(float(mc.std_u[-1, 0]) - std_x) < 3 * float(se_std[-1, 0])
    se_v = float(mc.std_v[-1, 0]) / np.sqrt(2 * (mc.n_samples - 1))
    assert abs(float(mc.std_v[-1, 0]) - std_v) < 3 * se_v
    p_loss = float(mc.contact_loss_probability[-1, 0])
    assert abs(p_loss - p_gap) < 3 * np.sqrt(p_gap * (1 - p_gap) / mc.n_samples)
    assert float(mc.unconverged) == 0.0
    # how far SL is from the exact answer (reported, and bounded loosely)
    with capsys.disabled():
        print(
            f"\nexact: mean {mean_x:.6e} std {std_x:.6e} P(gap) {p_gap:.4f}; "
            f"MC: mean {float(mc.mean_u[-1, 0]):.6e} std {float(mc.std_u[-1, 0]):.6e} P(gap) {p_loss:.4f}"
        )
        for crit in (pg.ForceCriterion(), pg.EnergyCriterion()):
            sl = pg.solve_moments(backlash_oscillator(), criterion=crit, **kw)
            em = (float(sl.mean_u[-1, 0]) - mean_x) / std_x
            es = float(sl.std_u[-1, 0]) / std_x - 1
            print(f"SL {crit.name:6s}: mean error {em:+.3f} std_x, std error {100 * es:+.2f} %")
            assert abs(em) < 0.5 and abs(es) < 0.3


@pytest.mark.slow
def test_initial_covariance_and_observables_agree_with_the_recursion():
    """MC from a Gaussian initial state, with a time-dependent observable y = C(t) u, against the recursion."""
    system = time_varying_system()
    obs = pg.Observables(lambda t: jnp.array([[jnp.cos(t), -jnp.sin(t)], [1.0, 1.0]]), names=["rot", "sum"])
    p0 = np.diag([0.01, 0.02, 0.3, 0.1]) ** 2
    p0[0, 1] = p0[1, 0] = 0.5 * 0.01 * 0.02
    kw = dict(
        dt=0.02,
        n_steps=60,
        save_every=20,
        initial_covariance=p0,
        initial_displacement=[0.01, -0.02],
        observables=obs,
    )
    ref = pg.solve_moments(system, **kw)
    mc = pg.monte_carlo(system, n_samples=4000, key=KEY, progress=False, **kw)
    assert mc.observable_names == ("rot", "sum") and ref.mean_obs.shape == (4, 2)
    se_m = mc.std_obs / np.sqrt(mc.n_samples)
    se_s = mc.std_obs / np.sqrt(2 * (mc.n_samples - 1))
    assert np.all(np.abs(mc.mean_obs - ref.mean_obs) < 3 * se_m)
    assert np.all(np.abs(mc.std_obs - ref.std_obs) < 3 * se_s)
    # the observable's moments are those of C(t) u computed from the DOF moments at t0
    np.testing.assert_allclose(ref.mean_obs[0], [0.01, -0.01], rtol=1e-12)
    np.testing.assert_allclose(ref.std_obs[0, 1], np.sqrt(0.01**2 + 0.02**2 + 0.01 * 0.02), rtol=1e-12)


@pytest.mark.slow
def test_pattern_table_contact_solve_equals_per_sample_newton():
    """Batched backlash solve (Jacobian inverses of all 2^nc contact patterns) vs per-sample Newton."""
    from pgtjax._newmark import solve_contacts, solve_contacts_batch

    rng = np.random.default_rng(3)
    nc = 4
    a = rng.normal(size=(nc, nc))
    coupling = jnp.asarray(a @ a.T * 1e-3 + 1e-3 * np.eye(nc))  # G^T K_eff^-1 G: symmetric positive definite
    k = jnp.asarray(rng.uniform(500.0, 1500.0, nc))
    b = jnp.asarray(rng.uniform(0.5e-3, 2e-3, nc))
    delta_lin = jnp.asarray(rng.normal(scale=3e-3, size=(400, nc)))  # many samples in the gap, some not
    law = pg.Backlash()
    d_table, ok_table = solve_contacts_batch(delta_lin, coupling, k, b, law)
    d_ref, ok_ref = jax.vmap(lambda dl: solve_contacts(dl, coupling, k, b, law))(delta_lin)
    assert bool(jnp.all(ok_table)) and bool(jnp.all(ok_ref))
    open_any = jnp.any(jnp.abs(d_ref) < b[None, :], axis=1)
    assert 0.1 < float(jnp.mean(open_any)) < 0.9
    np.testing.assert_allclose(d_table, d_ref, rtol=0, atol=1e-14)
    residual = d_table + law.force(d_table, k[None, :], b[None, :]) @ coupling.T - delta_lin
    assert float(jnp.max(jnp.abs(residual))) < 1e-15


def _solved_alone(delta_lin, coupling, k, b, law, rows):
    """Rows ``rows`` of ``delta_lin`` each solved as a batch of one, in a loop. A ``vmap`` would turn the
    solve's branches into selects that run every route's LAPACK calls at once, and those can wait forever on
    jaxlib 0.10.0-0.11.0 (docs/performance.md)."""
    from pgtjax._newmark import solve_contacts_batch

    one = jax.jit(lambda dl: solve_contacts_batch(dl, coupling, k, b, law)[0][0])
    return np.stack([np.asarray(one(delta_lin[i : i + 1])) for i in rows])


def _closed_or_gap_batch(rng, nc, batch, closed_patterns, b):
    """Contact-free deflections (batch, nc) whose contacts are closed (beyond the clearance) or in the gap
    by row of ``closed_patterns`` (batch, nc) bool, with margins wide enough that the solve keeps them."""
    closed = -rng.uniform(3.0, 6.0, (batch, nc)) * b
    gap = rng.uniform(-0.5, 0.5, (batch, nc)) * b
    return jnp.asarray(np.where(closed_patterns, closed, gap))


@pytest.mark.slow
@pytest.mark.parametrize(
    "route, batch",
    [
        ("one pattern", 300),
        ("a few other patterns", 300),
        ("many patterns, table", 300),
        ("many, per sample", 200),
    ],
)
def test_majority_pattern_contact_solve_on_every_route(route, batch):
    """More contacts than the pattern table takes: the batch's majority pattern is inverted once, up to 16
    other patterns are found and inverted, more fall back to the table of all 2^nc patterns (2^nc <= batch)
    or to one inverse per sample. Every route agrees with a per-sample Newton solve, and a sample's result is
    the one it gets alone (checked for some samples) (a batch of one, its own pattern the majority) up to rounding: 1e-17 here, on
    deflections of 1e-4 to 6e-3."""
    from pgtjax._newmark import _MAX_ODD_PATTERNS, _TABLE_MAX_CONTACTS, solve_contacts, solve_contacts_batch

    rng = np.random.default_rng(7)
    nc = 8
    assert nc > _TABLE_MAX_CONTACTS and 2**nc > 200 and 2**nc <= 300
    a = rng.normal(size=(nc, nc))
    coupling = jnp.asarray(a @ a.T * 1e-5 + 1e-4 * np.eye(nc))  # weak coupling: the margins below hold
    k = jnp.asarray(rng.uniform(500.0, 1500.0, nc))
    b = np.full(nc, 1e-3)
    closed = np.ones((batch, nc), dtype=bool)
    if route == "a few other patterns":
        odd = rng.choice(batch, 40, replace=False)
        closed[odd] = rng.uniform(size=(5, nc))[rng.integers(0, 5, 40)] < 0.5  # 5 distinct patterns at most
    elif route.startswith("many"):
        closed = rng.uniform(size=(batch, nc)) < 0.85
    distinct_odd = {tuple(row) for row in closed if not row.all()}
    if route == "one pattern":
        assert not distinct_odd
    elif route == "a few other patterns":
        assert 1 <= len(distinct_odd) <= _MAX_ODD_PATTERNS
    else:
        assert len(distinct_odd) > _MAX_ODD_PATTERNS and np.mean(closed.all(axis=1)) < 0.5
    delta_lin = _closed_or_gap_batch(rng, nc, batch, closed, b)
    law, b = pg.Backlash(), jnp.asarray(b)
    d_batch, ok_batch = solve_contacts_batch(delta_lin, coupling, k, b, law)
    d_ref, ok_ref = jax.vmap(lambda dl: solve_contacts(dl, coupling, k, b, law))(delta_lin)
    assert d_batch.dtype == jnp.float64 and bool(jnp.all(ok_batch)) and bool(jnp.all(ok_ref))
    np.testing.assert_array_equal(np.abs(np.asarray(d_batch)) > np.asarray(b)[None, :], closed)
    np.testing.assert_allclose(d_batch, d_ref, rtol=0, atol=1e-16)
    rows = np.r_[np.nonzero(~closed.all(axis=1))[0][:12], 0, batch - 1]  # odd samples and two others
    alone = _solved_alone(delta_lin, coupling, k, b, law, rows)
    np.testing.assert_allclose(np.asarray(d_batch)[rows], alone, rtol=0, atol=1e-17)


@pytest.mark.slow
def test_majority_route_with_open_contacts_and_iterations_agrees_with_the_table(monkeypatch):
    """A majority pattern with open contacts, a few other patterns, and coupling strong enough that contacts
    change piece, so that the residual iteration runs (and samples stop as they converge): the majority route
    agrees with the pattern table forced on the same batch, with a per-sample Newton solve, and with each
    sample solved alone, to rounding (1e-17 on deflections of order 1e-3)."""
    import pgtjax._newmark as newmark

    rng = np.random.default_rng(9)
    nc, batch = 8, 400
    a = rng.normal(size=(nc, nc))
    coupling = jnp.asarray(a @ a.T * 3e-4 + 1e-3 * np.eye(nc))  # S k of order 1: contacts change piece
    k = jnp.asarray(rng.uniform(500.0, 1500.0, nc))
    b = np.full(nc, 1e-3)
    closed = np.ones((batch, nc), dtype=bool)
    closed[:, -2:] = False  # the majority leaves the last two contacts open
    odd = rng.choice(batch, 60, replace=False)
    closed[odd] = rng.uniform(size=(4, nc))[rng.integers(0, 4, 60)] < 0.5
    majority = 2 * closed.sum(axis=0) > batch
    assert not majority.all() and 1 <= len({tuple(r) for r in closed if (r != majority).any()}) <= 16
    magnitude = np.where(closed, rng.uniform(1.05, 2.0, (batch, nc)), rng.uniform(-0.9, 0.9, (batch, nc)))
    delta_lin = jnp.asarray(magnitude * b * np.sign(rng.normal(size=(batch, nc))))
    law, b = pg.Backlash(), jnp.asarray(b)
    d_majority, ok_majority = newmark.solve_contacts_batch(delta_lin, coupling, k, b, law)
    changed = np.any(
        _pieces(np.asarray(d_majority), np.asarray(b)) != _pieces(np.asarray(delta_lin), np.asarray(b)),
        axis=1,
    )
    assert 0.05 < changed.mean() < 0.9  # the iteration ran, for some samples only
    d_ref, ok_ref = jax.vmap(lambda dl: newmark.solve_contacts(dl, coupling, k, b, law))(delta_lin)
    rows = np.r_[np.nonzero(changed)[0][:8], odd[:4], 0]  # samples that iterated, odd ones, one other
    alone = _solved_alone(delta_lin, coupling, k, b, law, rows)
    monkeypatch.setattr(newmark, "_TABLE_MAX_CONTACTS", nc)
    d_table, ok_table = newmark.solve_contacts_batch(delta_lin, coupling, k, b, law)
    assert bool(jnp.all(ok_majority)) and bool(jnp.all(ok_table)) and bool(jnp.all(ok_ref))
    np.testing.assert_allclose(d_majority, d_ref, rtol=0, atol=1e-16)
    np.testing.assert_allclose(d_majority, d_table, rtol=0, atol=1e-17)
    np.testing.assert_allclose(np.asarray(d_majority)[rows], alone, rtol=0, atol=1e-17)


@pytest.mark.slow
@pytest.mark.parametrize("symmetric", [True, False])
@pytest.mark.parametrize("nc", [1, 6, 12])
def test_pattern_inverses_without_pivoting_match_lapack_inverses(nc, symmetric):
    """The contact-pattern Jacobian inverses (Gauss-Jordan without pivoting; unrolled up to 8 contacts, a
    loop beyond) against NumPy's LU inverses of every pattern (up to 256 drawn ones for 12 contacts), for a
    symmetric positive definite coupling and a non-symmetric one with a positive definite symmetric part,
    from soft to very stiff contacts (S k up to 1e6, cond(J) up to 3e7): relative error per inverse
    (Frobenius) within 1e-14 here, where both are near-exact. A rank-one update per closed contact
    (Sherman-Morrison), tried first, was off by 1e-10 at S k = 1e6 and fails this. An all-open pattern gives
    exactly the identity."""
    from pgtjax._newmark import _all_patterns, _pattern_inverses

    rng = np.random.default_rng(nc + (0 if symmetric else 100))
    a = rng.normal(size=(nc, nc))
    coupling = a @ a.T / nc + 0.1 * np.eye(nc)
    if not symmetric:
        skew = rng.normal(size=(nc, nc))
        coupling = coupling + 0.5 * (skew - skew.T)  # the symmetric part stays positive definite
    patterns = np.asarray(_all_patterns(nc, jnp.float64)[0])
    if len(patterns) > 256:
        patterns = np.r_[patterns[:1], rng.permutation(patterns[1:])[:255]]
    for stiffness in (1e-2, 1.0, 1e3, 1e6):
        k_on = stiffness * rng.uniform(0.5, 1.5, nc)
        inverses = _pattern_inverses(jnp.asarray(coupling), jnp.asarray(k_on), jnp.asarray(patterns))
        assert inverses.dtype == jnp.float64 and inverses.shape == (len(patterns), nc, nc)
        jacobians = np.eye(nc)[None] + coupling[None] * (patterns * k_on)[:, None, :]
        reference = np.linalg.inv(jacobians)
        difference = np.linalg.norm(np.asarray(inverses) - reference, axis=(1, 2))
        error = difference / np.linalg.norm(reference, axis=(1, 2))
        assert np.all(error <= 1e-14), (stiffness, error.max(), np.linalg.cond(jacobians).max())
        np.testing.assert_array_equal(inverses[0], np.eye(nc))


@pytest.mark.slow
@pytest.mark.skipif(jax.default_backend() != "cpu", reason="looks for LAPACK custom calls of the CPU backend")
def test_contact_solve_of_an_on_off_law_makes_no_lapack_call():
    """The backlash contact solve is elementwise work and products only: a compiled solve holds no LAPACK
    custom call, on the pattern table (6 contacts), the majority route with its fallback to all 2^nc
    patterns (7 contacts, 128 samples) and to one inverse per sample (8 contacts, 64 samples), and the
    looped elimination (10 contacts). jaxlib 0.10.0-0.11.0 can hang when several batched LAPACK calls wait
    on XLA's thread pool at once (docs/performance.md), so a Monte Carlo step of a backlash system must not
    make one. The same search finds the LAPACK calls of ``jnp.linalg.inv`` (the control)."""
    from pgtjax._newmark import solve_contacts_batch

    def lapack_calls(compiled):
        targets = set(re.findall(r'custom_call_target="([^"]*)"', compiled.as_text()))
        return {t for t in targets if "lapack" in t}

    assert lapack_calls(jax.jit(jnp.linalg.inv).lower(jnp.eye(6)[None]).compile())  # the control
    rng = np.random.default_rng(5)
    law = pg.Backlash()
    for nc, batch in ((6, 64), (7, 128), (8, 64), (10, 64)):
        a = rng.normal(size=(nc, nc))
        coupling = jnp.asarray(a @ a.T * 1e-5 + 1e-4 * np.eye(nc))
        k, b = jnp.asarray(rng.uniform(500.0, 1500.0, nc)), jnp.full(nc, 1e-3)
        delta_lin = jnp.asarray(rng.normal(size=(batch, nc)) * 3e-3)
        compiled = (
            jax.jit(lambda d, s: solve_contacts_batch(d, s, k, b, law)).lower(delta_lin, coupling).compile()
        )
        assert not lapack_calls(compiled), nc


@pytest.mark.slow
def test_constant_stiffness_mc_equals_time_function_mc():
    """Monte Carlo with the once-formed contact-free map (constant K) and with the per-step solve (K as a
    function of time) draw the same noise and must give the same statistics up to rounding."""
    n = 18
    m, k = grounded_spring_chain(n, 400.0, 8)
    g = np.zeros((n, 2))
    g[[4, 11], [0, 1]], g[[5, 12], [0, 1]] = 1.0, -1.0
    noise = np.zeros((n, 1))
    noise[2, 0] = 1.0
    common = dict(
        mass=m,
        damping=0.01 * k + 0.3 * m,
        load=np.eye(n)[2] * 2.0,
        noise_input=noise,
        spectral_density=0.05,
        contacts=pg.Contacts(direction=g, stiffness=[300.0, 300.0], clearance=[0.004, 0.005]),
    )
    kw = dict(n_samples=200, key=KEY, dt=0.01, n_steps=100, save_every=10, progress=False)
    a = pg.monte_carlo(pg.System(stiffness=k, **common), **kw)
    b = pg.monte_carlo(pg.System(stiffness=pg.FourierSeries(k), **common), **kw)
    assert (a.propagation, b.propagation) == ("eigen", "physical")  # the default picks each system's path
    assert float(jnp.max(b.std_delta)) > 1e-3
    for x, y in [(a.mean_u, b.mean_u), (a.std_u, b.std_u), (a.std_delta, b.std_delta)]:
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-9 * float(jnp.max(jnp.abs(y))))


_EVERY_STATISTIC = (
    "mean_u",
    "std_u",
    "mean_v",
    "std_v",
    "mean_delta",
    "std_delta",
    "force_mean",
    "force_std",
    "contact_loss_probability",
)


def _chain_with_contacts(n=14, seed=5, damping_scale=1.0):
    """Lightly damped grounded chain with one heavy dashpot (complex eigenvalue pairs and real eigenvalues);
    two backlash contacts that open and close, one of them moving (its direction turns with time, as the
    planetary ring-planet meshes do); a time-varying load and noise input; a time-dependent observable.
    ``damping_scale`` multiplies the proportional damping (60 leaves 3 complex pairs, 1 leaves 13) and the
    noise's spectral density by ``max(1, damping_scale / 2)``, so that the contacts still open and close."""
    m, k = grounded_spring_chain(n, 400.0, seed)
    c = damping_scale * (0.002 * k + 0.05 * m)
    c[5, 5] += 80.0  # overdamps a few modes: real eigenvalues
    g = np.zeros((n, 2))
    g[[3, 9], [0, 1]], g[[4, 10], [0, 1]] = 1.0, -1.0
    g_moving = np.zeros((n, 2))
    g_moving[[8, 11], 1] = 0.5, -0.5

    def direction(t):
        return jnp.asarray(g) + jnp.sin(7.0 * t) * jnp.asarray(g_moving)

    noise = np.zeros((n, 2))
    noise[1, 0] = noise[n - 1, 1] = 1.0
    contacts = pg.Contacts(
        direction=direction, stiffness=[900.0, 600.0], clearance=[0.003, 0.004], names=["a", "b"]
    )
    system = pg.System(
        mass=m,
        stiffness=k,
        damping=c,
        load=lambda t: jnp.eye(n)[1] * (1.5 + jnp.cos(5.0 * t)),
        noise_input=lambda t: jnp.asarray(noise) * (1.0 + 0.4 * jnp.sin(3.0 * t)),
        spectral_density=[0.04 * max(1.0, damping_scale / 2), 0.02 * max(1.0, damping_scale / 2)],
        contacts=contacts,
    )
    obs = pg.Observables(
        lambda t: jnp.stack([jnp.eye(n)[2] * jnp.cos(t), jnp.eye(n)[7]]),
        names=["c", "d"],
        offset=lambda t: jnp.array([1e-3 * jnp.sin(2.0 * t), -5e-4]),
    )
    return system, obs


@pytest.mark.slow
@pytest.mark.parametrize(
    "scheme, damping_scale", [("trapezoidal", 1.0), ("newmark", 1.0), ("trapezoidal", 60.0)]
)
def test_eigen_coordinates_reproduce_the_physical_coordinate_scheme(scheme, damping_scale):
    """Stepping the samples in the eigenbasis of the contact-free map is the same discretization: on the same
    draws every statistic agrees with the physical-coordinate step to rounding. A part of the state (Re and Im
    parts of the complex pairs, real eigenvalues' columns) with many columns enters the contact deflections as
    a matrix product, one with a few as a sum of outer products: both cases are covered for the pairs'
    parts and for the real part. The recorded quantities (u, v, deflections, forces, observables with their
    offset) are formed straight from the eigen-coordinates, with the same two routes."""
    from pgtjax._eigenbasis import _FUSED_DEFLECTION_MAX_COLUMNS, eigen_propagator

    system, obs = _chain_with_contacts(damping_scale=damping_scale)
    n = system.n_dof
    prop, reason = eigen_propagator(system, 0.01)
    assert reason == "" and prop.condition < 1e4
    assert 0 < 2 * prop.n_pairs < 2 * n  # complex pairs and real eigenvalues
    few_pairs = prop.n_pairs <= _FUSED_DEFLECTION_MAX_COLUMNS
    few_real = 0 < 2 * (n - prop.n_pairs) <= _FUSED_DEFLECTION_MAX_COLUMNS
    assert few_pairs == (damping_scale > 1.0) and few_real == (damping_scale == 1.0)
    p0 = np.diag(np.r_[np.full(n, 1e-3), np.full(n, 1e-2)]) ** 2
    kw = dict(
        n_samples=300,
        key=KEY,
        dt=0.01,
        n_steps=120,
        save_every=8,
        progress=False,
        integrator=INTEGRATORS[scheme](),
        initial_displacement=np.full(n, 2e-3),
        initial_covariance=p0,
        observables=obs,
        histograms={"force:a": np.linspace(-3.0, 3.0, 13)},
        histogram_times=[0.4, 1.2],
    )
    eig = pg.monte_carlo(system, propagation="eigen", **kw)
    phys = pg.monte_carlo(system, propagation="physical", **kw)
    assert (eig.propagation, phys.propagation) == ("eigen", "physical")
    assert 0.05 < float(jnp.mean(phys.contact_loss_probability[1:])) < 0.95  # the contacts open and close
    for name in _EVERY_STATISTIC + ("mean_obs", "std_obs"):
        a, b = np.asarray(getattr(eig, name)), np.asarray(getattr(phys, name))
        assert a.dtype == np.float64
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * np.max(np.abs(b)), err_msg=name)
    # a sample may cross a bin edge by rounding: at most one count per bin
    assert np.max(np.abs(np.asarray(eig.histograms["force:a"] - phys.histograms["force:a"]))) <= 1.0
    assert float(eig.unconverged) == float(phys.unconverged) == 0.0


@pytest.mark.slow
def test_gear_pair_eigen_step_with_every_part_fused_reproduces_the_physical_step():
    """The gear pair's map has 2 complex pairs and 2 real eigenvalues at dt = 10 us: every part of the state
    enters the contact deflections as outer products. On the same draws the statistics agree with the
    physical-coordinate step to rounding (cond(W) is about 140), with the mesh opening in some samples."""
    from pgtjax._eigenbasis import _FUSED_DEFLECTION_MAX_COLUMNS, eigen_propagator
    from pgtjax.models import gear_pair as gp

    system = gp.build(gp.default_params())
    prop, reason = eigen_propagator(system, 1e-5)
    assert reason == ""
    assert 0 < prop.n_pairs <= _FUSED_DEFLECTION_MAX_COLUMNS
    assert 0 < 2 * (system.n_dof - prop.n_pairs) <= _FUSED_DEFLECTION_MAX_COLUMNS
    kw = dict(n_samples=200, key=jax.random.key(3), dt=1e-5, n_steps=300, save_every=30, progress=False)
    eig = pg.monte_carlo(system, propagation="eigen", **kw)
    phys = pg.monte_carlo(system, propagation="physical", **kw)
    assert (eig.propagation, phys.propagation) == ("eigen", "physical")
    assert 0.02 < float(jnp.mean(phys.contact_loss_probability[1:])) < 0.98
    for name in ("mean_u", "std_u", "mean_v", "std_v", "mean_delta", "std_delta", "force_mean", "force_std"):
        a, b = np.asarray(getattr(eig, name)), np.asarray(getattr(phys, name))
        assert a.dtype == np.float64
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-10 * np.max(np.abs(b)), err_msg=name)


@pytest.mark.slow
def test_eigen_coordinates_without_contacts_or_complex_pairs_reproduce_the_physical_scheme():
    """A heavily damped chain without contacts: every eigenvalue of its map is real (no Re or Im parts, no
    forces), so the recorded quantities come from one matrix product alone; observables without an offset.
    On the same draws the statistics agree with the physical-coordinate step to rounding."""
    from pgtjax._eigenbasis import _FUSED_DEFLECTION_MAX_COLUMNS, eigen_propagator

    n = 8
    m, k = grounded_spring_chain(n, 400.0, 5)
    noise = np.zeros((n, 1))
    noise[n - 1, 0] = 1.0
    system = pg.System(
        mass=m,
        stiffness=k,
        damping=150.0 * (0.002 * k + 0.5 * m),
        load=lambda t: jnp.eye(n)[2] * jnp.sin(4.0 * t),
        noise_input=noise,
        spectral_density=[0.5],
    )
    prop, reason = eigen_propagator(system, 0.01)
    assert reason == "" and prop.n_pairs == 0 and 2 * n > _FUSED_DEFLECTION_MAX_COLUMNS
    obs = pg.Observables(lambda t: jnp.stack([jnp.eye(n)[3] - jnp.eye(n)[4] * jnp.cos(t)]), names=["e"])
    kw = dict(
        n_samples=200,
        key=KEY,
        dt=0.01,
        n_steps=60,
        save_every=6,
        progress=False,
        observables=obs,
        initial_covariance=np.diag(np.r_[np.full(n, 1e-3), np.full(n, 1e-2)]) ** 2,
    )
    eig = pg.monte_carlo(system, propagation="eigen", **kw)
    phys = pg.monte_carlo(system, propagation="physical", **kw)
    assert (eig.propagation, phys.propagation) == ("eigen", "physical")
    for name in ("mean_u", "std_u", "mean_v", "std_v", "mean_obs", "std_obs"):
        a, b = np.asarray(getattr(eig, name)), np.asarray(getattr(phys, name))
        assert a.dtype == np.float64 and a.shape == b.shape
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-10 * np.max(np.abs(b)), err_msg=name)


@pytest.mark.parametrize("widths", [(1, 1, 6), (1, 2, 20)])  # fused sum of outer products; matrix product
def test_outer_products_of_the_eigen_step_equal_the_matrix_product(widths):
    from pgtjax._eigenbasis import _outer_products

    rng = np.random.default_rng(5)
    columns = [jnp.asarray(rng.standard_normal((37, w))) for w in widths]
    rows = [jnp.asarray(rng.standard_normal((w, 12))) for w in widths]
    got = jax.jit(_outer_products)(columns, rows)
    expected = np.concatenate([np.asarray(c) for c in columns], 1) @ np.concatenate(
        [np.asarray(r) for r in rows]
    )
    assert got.shape == (37, 12) and got.dtype == jnp.float64
    np.testing.assert_allclose(np.asarray(got), expected, rtol=0, atol=1e-13 * np.max(np.abs(expected)))


def test_initial_draws_move_only_at_rounding_level_with_the_initial_covariance():
    """A covariance with repeated eigenvalues, changed at rounding level (as another thread count or BLAS
    changes a computed one), draws the same initial states to rounding: the factor is the symmetric square
    root, not LAPACK's eigenvectors, whose basis of a repeated eigenvalue such a change rotates freely."""
    from pgtjax.models import gear_pair

    system = gear_pair.build()
    p0 = np.diag(np.r_[np.full(3, 1e-10), np.full(3, 1e-4)])  # two triple eigenvalues
    rng = np.random.default_rng(11)
    noise = rng.standard_normal((6, 6))
    nudged = p0 + 1e-16 * np.abs(p0).max() * (noise + noise.T)
    kw = dict(n_samples=64, key=KEY, dt=1e-5, n_steps=2, save_every=1, progress=False)
    a = pg.monte_carlo(system, initial_covariance=p0, **kw)
    b = pg.monte_carlo(system, initial_covariance=nudged, **kw)
    for name in ("mean_u", "std_u", "mean_v", "std_v"):
        x, y = (
            np.asarray(getattr(a, name))[0],
            np.asarray(getattr(b, name))[0],
        )  # the initial draws' statistics
        assert x.dtype == np.float64
        np.testing.assert_allclose(y, x, rtol=1e-9, atol=1e-9 * np.max(np.abs(x)), err_msg=name)
    # and the draws have the asked covariance: std of the sample within 4 standard errors of sqrt(diag p0)
    expected = np.sqrt(np.diag(p0))
    got = np.r_[np.asarray(a.std_u)[0], np.asarray(a.std_v)[0]]
    assert np.all(np.abs(got / expected - 1.0) < 4.0 / np.sqrt(2 * 63))


@pytest.mark.slow
def test_eigen_coordinates_refused_where_they_cannot_be_used(monkeypatch):
    import pgtjax._eigenbasis as eigenbasis

    kw = dict(n_samples=10, key=KEY, dt=0.02, n_steps=4, progress=False)
    varying = time_varying_system()  # constant K and C: accepted
    assert pg.monte_carlo(varying, **kw).propagation == "eigen"
    varying_k = pg.System(
        mass=np.eye(2),
        stiffness=pg.FourierSeries(np.diag([200.0, 100.0])),
        damping=np.eye(2),
        noise_input=np.ones((2, 1)),
    )
    assert pg.monte_carlo(varying_k, **kw).propagation == "physical"
    with pytest.raises(ValueError, match="propagation='eigen'.*K or C depends on time"):
        pg.monte_carlo(varying_k, propagation="eigen", **kw)
    with pytest.raises(ValueError, match="`propagation` must be one of"):
        pg.monte_carlo(varying, propagation="modal", **kw)
    # an undamped free mass: the step map is a Jordan block, whose computed basis is singular
    free = pg.System(mass=[[1.0]], stiffness=[[0.0]], damping=[[0.0]], noise_input=[[1.0]])
    prop, reason = eigenbasis.eigen_propagator(free, 0.02)
    assert prop is None and "cond(W)" in reason
    assert pg.monte_carlo(free, **kw).propagation == "physical"
    # each acceptance test refuses on its own
    monkeypatch.setattr(eigenbasis, "MAX_CONDITION", 1.0)
    assert "cond(W)" in eigenbasis.eigen_propagator(varying, 0.02)[1]
    monkeypatch.setattr(eigenbasis, "MAX_CONDITION", 1e8)
    monkeypatch.setattr(eigenbasis, "MAX_MAP_ERROR", 0.0)
    assert "one step off" in eigenbasis.eigen_propagator(varying, 0.02)[1]


def _pieces(d, b):
    return np.where(d > b, 1, np.where(d < -b, 2, 0))


@pytest.mark.slow
@pytest.mark.parametrize("case", ["all_keep_their_piece", "many_change_piece"])
def test_affine_piece_shortcut_equals_the_residual_iteration(case):
    """The backlash solve accepts the first Newton step where no contact leaves its affine piece (the
    shortcut); a law without ``affine_piece`` always iterates on the residual. Both agree, whether every
    sample keeps its piece (weakly coupled contacts far from the flanks: only the shortcut runs) or many do
    not (strong coupling: the residual iteration runs)."""
    from pgtjax._newmark import solve_contacts_batch

    class ResidualOnly(pg.Backlash):
        def affine_piece(self, delta, k, b):
            return None

    rng = np.random.default_rng(4)
    nc = 3
    b = jnp.asarray(rng.uniform(0.5e-3, 2e-3, nc))
    k = jnp.asarray(rng.uniform(500.0, 1500.0, nc))
    if case == "all_keep_their_piece":
        coupling = jnp.asarray(np.diag(rng.uniform(1e-4, 3e-4, nc)) + 1e-6)  # S k ~ 0.1-0.5, weak coupling
        far = rng.uniform(1.5, 4.0, (500, nc)) * np.sign(rng.normal(size=(500, nc)))
        inside = rng.uniform(-0.5, 0.5, (500, nc))
        delta_lin = jnp.asarray(
            np.where(rng.uniform(size=(500, nc)) < 0.3, inside, far * 3.0) * np.asarray(b)
        )
    else:
        a = rng.normal(size=(nc, nc))
        coupling = jnp.asarray(a @ a.T * 1e-3 + 1e-3 * np.eye(nc))
        delta_lin = jnp.asarray(rng.normal(scale=3e-3, size=(500, nc)))
    d_fast, ok_fast = solve_contacts_batch(delta_lin, coupling, k, b, pg.Backlash())
    d_ref, ok_ref = solve_contacts_batch(delta_lin, coupling, k, b, ResidualOnly())
    assert bool(jnp.all(ok_fast)) and bool(jnp.all(ok_ref))
    kept = np.all(
        _pieces(np.asarray(d_ref), np.asarray(b)) == _pieces(np.asarray(delta_lin), np.asarray(b)), axis=1
    )
    if case == "all_keep_their_piece":
        assert kept.all()
    else:
        assert 0.1 < 1.0 - kept.mean() < 0.9
    np.testing.assert_allclose(d_fast, d_ref, rtol=0, atol=1e-16)
    residual = d_fast + pg.Backlash().force(d_fast, k[None, :], b[None, :]) @ coupling.T - delta_lin
    assert float(jnp.max(jnp.abs(residual))) < 1e-16
    # a NaN deflection is not taken for an exact step
    d_nan, ok_nan = solve_contacts_batch(delta_lin.at[0].set(jnp.nan), coupling, k, b, pg.Backlash())
    assert not bool(ok_nan[0]) and bool(jnp.all(ok_nan[1:]))


def test_designs_differing_only_in_values_share_one_compiled_sampler(caplog):
    """Two stiffnesses of one model run on one compiled Monte Carlo chunk: nothing value-dependent in the
    eigen-coordinate propagator (the condition number of its basis, say) is a static part of the run, which
    would compile the sampler anew for every design of a sweep or an optimization."""
    import logging

    from pgtjax._eigenbasis import eigen_propagator

    def system(scale):
        k = scale * np.array([[300.0, -100.0], [-100.0, 100.0]])
        return pg.System(
            mass=np.diag([1.0, 2.0]),
            stiffness=k,
            damping=0.02 * k,
            load=[0.5, 0.0],
            noise_input=[[1.0], [0.0]],
            spectral_density=1e-3,
            contacts=pg.Contacts(
                direction=[[1.0], [0.0]], stiffness=[400.0], clearance=[0.002], names=["stop"]
            ),
        )

    props = [eigen_propagator(system(s), 0.01)[0] for s in (1.0, 1.3)]
    assert all(p is not None for p in props) and props[0].n_pairs == props[1].n_pairs  # equal shapes
    assert float(props[0].condition) != float(props[1].condition)
    with jax.log_compiles(True), caplog.at_level(logging.WARNING):
        for s in (1.0, 1.3):
            pg.monte_carlo(
                system(s), n_samples=64, key=KEY, dt=0.01, n_steps=20, save_every=5, progress=False
            )
    compiled = [r for r in caplog.records if "compilation of jit(_chunk)" in r.getMessage()]
    assert len(compiled) == 1, f"{len(compiled)} compilations for two designs of equal shape"


@pytest.mark.slow
@pytest.mark.parametrize("model", ["gear_pair", "chain"])
def test_wide_vectors_change_no_statistic(monkeypatch, model):
    """Monte Carlo compiled for 512-bit vectors (``pgtjax._parallel.wide_vectors``: CPUs with AVX-512) gives
    the default program's statistics: double for double on the gear pair, whose loops are elementwise; to
    rounding on a chain with moving contacts, wide parts of the state (matrix products), observables,
    histograms and covariances, some of whose reductions XLA vectorizes differently (1.6e-15 of an array's
    largest value measured on an AMD EPYC). On a CPU without AVX-512 both programs use the same vectors."""
    from pgtjax import _montecarlo
    from pgtjax.models import gear_pair as gp

    if model == "gear_pair":
        system = gp.build()
        kw = dict(dt=1e-5, n_steps=200, save_every=50)
        names = _EVERY_STATISTIC
    else:
        system, obs = _chain_with_contacts()
        kw = dict(
            dt=0.01,
            n_steps=64,
            save_every=8,
            observables=obs,
            histograms={"force:a": np.linspace(-3.0, 3.0, 13)},
            histogram_times=[0.4],
            covariance_dofs="all",
        )
        names = _EVERY_STATISTIC + ("mean_obs", "std_obs")
    runs = {}
    for wide in (False, True):
        monkeypatch.setattr(_montecarlo, "wide_vectors", lambda devices, wide=wide: wide)
        runs[wide] = pg.monte_carlo(system, n_samples=300, key=jax.random.key(5), progress=False, **kw)
    assert float(np.max(runs[False].std_u)) > 0.0

    def assert_same(a, b, name):
        assert a.dtype == np.float64
        if model == "gear_pair":
            np.testing.assert_array_equal(a, b, err_msg=name)
        else:
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-13 * np.max(np.abs(a)), err_msg=name)

    for name in names:
        assert_same(np.asarray(getattr(runs[False], name)), np.asarray(getattr(runs[True], name)), name)
    if model == "chain":
        assert float(np.sum(runs[False].histograms["force:a"])) > 0.0
        # a sample may cross a bin edge by rounding: at most one count per bin
        diff = np.asarray(runs[False].histograms["force:a"] - runs[True].histograms["force:a"])
        assert np.max(np.abs(diff)) <= 1.0
        cov = [np.asarray(r.covariance) for r in (runs[False], runs[True])]
        assert cov[0].shape[-1] == 2 * system.n_dof
        assert_same(cov[0], cov[1], "covariance")


@pytest.mark.parametrize("save_every, rows", [(36, 4), (13, 5), (13, 8), (6, 6), (1, 1)])
def test_saved_scan_gives_each_step_its_own_input_when_a_block_is_formed_in_parts(save_every, rows):
    """``saved_scan(..., rows_per_input=rows)``: every step receives the input of its own step number and the
    parts of a block follow one another (exact integers: a part missing, repeated or shifted would show)."""
    from pgtjax._loop import saved_scan

    asked = []

    def block_inputs(block_index, first_row, n_rows):
        asked.append(n_rows)
        return block_index * save_every + first_row + jnp.arange(n_rows) + 1

    def step(carry, step_number, x):
        return carry + 1, (step_number, x, carry)

    n_blocks = 3
    carry, saved = saved_scan(
        step,
        lambda carry, infos, b: infos,
        jnp.asarray(0),
        (jnp.zeros(save_every, int),) * 3,
        n_blocks=n_blocks,
        save_every=save_every,
        block_inputs=block_inputs,
        rows_per_input=rows,
    )
    numbers, inputs, counts = (np.asarray(a)[1:].ravel() for a in saved)
    expected = np.arange(1, n_blocks * save_every + 1)
    assert int(carry) == n_blocks * save_every
    np.testing.assert_array_equal(numbers, expected)
    np.testing.assert_array_equal(inputs, expected)
    np.testing.assert_array_equal(counts, expected - 1)
    rest = save_every % rows  # traced once each: the parts' inner scan, then the block's shorter rest
    assert sorted(asked) == sorted([rows] + [rest] * (rest > 0))
    with pytest.raises(ValueError, match="rows_per_input"):
        saved_scan(step, lambda c, i, b: i, 0, None, n_blocks=1, save_every=4, rows_per_input=5)


@pytest.mark.slow
@pytest.mark.parametrize("model", ["gear_pair", "chain"])
def test_long_blocks_drawn_in_parts_give_the_whole_blocks_statistics(monkeypatch, model):
    """A saved block drawn a part at a time (its draws and step inputs formed for 5 + 5 + 3 of its 13 steps:
    whole parts and a part left over; two blocks) gives the whole blocks' statistics: double for double in
    physical coordinates and on the gear pair (the same normals, elementwise steps); to rounding in a chain's
    eigen-coordinates, whose step inputs XLA forms in batches of another length."""
    from pgtjax import _montecarlo
    from pgtjax.models import gear_pair as gp

    if model == "gear_pair":
        system, obs, dt = gp.build(), None, 1e-5
    else:
        (system, obs), dt = _chain_with_contacts(), 0.01
    n_steps, save_every, rows = 26, 13, 5
    for propagation in ("eigen", "physical"):
        runs = {}
        for parts in (False, True):
            monkeypatch.setattr(
                _montecarlo, "_block_rows", lambda *a, rows=rows, parts=parts: rows if parts else a[5]
            )
            runs[parts] = pg.monte_carlo(
                system, n_samples=64, key=jax.random.key(1), dt=dt, n_steps=n_steps, save_every=save_every,
                observables=obs, propagation=propagation, progress=False,
            )  # fmt: skip
        assert float(np.max(runs[False].std_u)) > 0.0
        for name in _EVERY_STATISTIC:
            a, b = np.asarray(getattr(runs[False], name)), np.asarray(getattr(runs[True], name))
            assert b.dtype == np.float64
            if model == "gear_pair" or propagation == "physical":
                np.testing.assert_array_equal(a, b, err_msg=f"{name} {propagation} {save_every}")
            else:
                np.testing.assert_allclose(
                    a, b, rtol=0, atol=1e-13 * np.max(np.abs(a)), err_msg=f"{name} {save_every}"
                )


@pytest.mark.slow
def test_rows_drawn_at_once_fit_the_budget_and_prefer_a_divisor(monkeypatch):
    from pgtjax import _montecarlo, _parallel

    rows = _montecarlo._rows_per_input
    assert rows(100, 8, 800, True) == 100  # the whole block fits
    assert rows(100, 8, 799, True) == 50  # 99 rows fit; 50 divides 100
    assert rows(36, 8, 5 * 8 + 4, True) == 4  # 5 fit; 4 divides 36
    assert rows(13, 8, 5 * 8, True) == 5  # 13 is prime: 5 + 5 + 3
    assert rows(97 * 89, 8, 96 * 8, True) == 89  # a divisor above the square root
    assert rows(10, 10**9, 8, True) == 1  # one step's draws over the budget: one step at a time
    assert rows(100, 8, 80, False) == 100  # keys whose blocks cannot be drawn in parts

    # a run's rows: its batch's draws (physical coordinates: no step inputs), within the CPU's budget
    from pgtjax.models import gear_pair as gp

    seen = []
    monkeypatch.setattr(_montecarlo, "_rows_per_input", lambda *a: seen.append(a) or rows(*a))
    monkeypatch.setattr(_parallel, "CPU_DRAW_BYTES", 12345)
    pg.monte_carlo(gp.build(), n_samples=40, key=jax.random.key(0), dt=1e-5, n_steps=20, save_every=20,
                   propagation="physical", chunk_size=25, devices=jax.local_devices()[:1], progress=False)  # fmt: skip
    assert seen == [(20, 8 * 2 * 25 * 1, 12345, True)]  # a step's uniforms and normals, 25 samples x 1 input

    # eigen-coordinates: the count of a step's inputs (from a traced snapshot) is that of the inputs the run's
    # loop is given, read here from the shape of one step's inputs as the loop forms them
    formed = []

    def recording_scan(*args, block_inputs, **kwargs):
        formed.append(jax.eval_shape(lambda: block_inputs(jnp.int32(0), jnp.int32(0), 1)))
        return saved_scan(*args, block_inputs=block_inputs, **kwargs)

    from pgtjax._loop import saved_scan

    monkeypatch.setattr(_montecarlo, "saved_scan", recording_scan)
    jax.clear_caches()  # the patched loop is seen only while a program is traced, not by a cached one
    # with peaks of quantities other than contact forces, a step's inputs also hold their rows
    peaks = dict(peaks={q: [0.0, 1.0] for q in ("u:z", "delta:mesh", "force:mesh")}, histogram_times=[2e-4])
    sizes = []
    for system, n_noise, options in [
        (gp.build(), 1, {}),
        (gp.build(), 1, peaks),
        (_chain_with_contacts()[0], 2, {}),
    ]:
        seen.clear()
        formed.clear()
        pg.monte_carlo(system, n_samples=40, key=jax.random.key(0), dt=1e-5, n_steps=20, save_every=20,
                       propagation="eigen", chunk_size=25, devices=jax.local_devices()[:1], progress=False,
                       **options)  # fmt: skip
        assert formed, "the Monte Carlo program was not traced again (a cached compile?)"
        draws, inputs = formed[0]
        assert draws.shape[:2] == (1, 25) and inputs.shape[0] == 1 and inputs.shape[1] > 0
        nd = draws.shape[2]
        assert nd == n_noise
        assert seen == [(20, 8 * ((2 if nd == 1 else 3) * 25 * nd + inputs.shape[1]), 12345, True)]
        sizes.append(inputs.shape[1])
    # two peaks' rows: (2n + nc) each for the eigen-coordinates and the force, and an offset (n = 3, nc = 1)
    assert sizes[1] - sizes[0] == 2 * (2 * 3 + 1 + 1)


def test_wide_vectors_only_on_cpus_with_avx512_unless_xla_flags_choose_a_width(monkeypatch):
    from pgtjax import _parallel

    class Accelerator:
        platform = "gpu"

    cpu = jax.devices("cpu")
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.setattr(_parallel, "cpu_has_avx512", lambda: True)
    assert _parallel.wide_vectors(cpu)
    assert not _parallel.wide_vectors([Accelerator()])
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=256")
    assert not _parallel.wide_vectors(cpu)
    monkeypatch.delenv("XLA_FLAGS")
    monkeypatch.setattr(_parallel, "cpu_has_avx512", lambda: False)
    assert not _parallel.wide_vectors(cpu)


def _cumulative(counts):
    return np.cumsum(np.asarray(counts), axis=-1)


@pytest.mark.slow
@pytest.mark.parametrize("propagation", ["eigen", "physical"])
def test_peaks_of_a_noise_free_run_count_the_largest_values_that_simulate_gives(propagation):
    """Without noise every sample follows the deterministic response, which :func:`pgtjax.simulate` computes
    with its own time loop: at each saved time all samples lie in the bin of that response's largest
    magnitude over every step so far, for a meshing force, a displacement, a velocity, the mesh deflection
    and an observable with an offset (every quantity's peak follows every step, not only the saves)."""
    import equinox as eqx

    from pgtjax.models import gear_pair as gp

    system = gp.build()
    quiet = eqx.tree_at(lambda s: s.spectral_density, system, jnp.zeros_like(system.spectral_density))
    # an observable: z - y1 / 2 plus 3e-6 m, so that its magnitude is not a DOF's
    obs = pg.Observables(np.array([[-0.5, 0.0, 1.0]]), names=["zy"], offset=np.array([3e-6]))
    every_step = pg.simulate(quiet, dt=1e-5, n_steps=400)
    u, v = np.asarray(every_step.u), np.asarray(every_step.v)  # (401, 3): t0 and every step
    values = {
        "force:mesh": np.asarray(every_step.force[:, 0]),
        "u:z": u[:, 2],
        "v:y1": v[:, 0],
        "delta:mesh": np.asarray(every_step.delta[:, 0]),
        "obs:zy": u[:, 2] - 0.5 * u[:, 0] + 3e-6,
    }
    saved_times = np.arange(41) * 1e-4
    edges, cases = {}, []
    for name, value in values.items():
        magnitude = np.abs(value)
        top = magnitude.max()
        edges[name] = np.linspace(-0.013 * top, 1.05 * top, 61)  # 0 (contact lost, the start) inside a bin
        step_peak = np.maximum.accumulate(magnitude)[::10]
        saves_only = np.maximum.accumulate(magnitude[::10])
        # meaningful: the peak between saves exceeds the peak over the saves in several bins
        moved = np.searchsorted(edges[name], step_peak) != np.searchsorted(edges[name], saves_only)
        assert np.sum(moved) > 2, name
        cases.append((name, step_peak))
    peak_values = dict(cases)
    mc = pg.monte_carlo(quiet, n_samples=7, key=KEY, progress=False, dt=1e-5, n_steps=400, save_every=10,
                        histograms={"force:mesh": edges["force:mesh"]}, peaks=edges, observables=obs,
                        histogram_times=saved_times, propagation=propagation)  # fmt: skip
    np.testing.assert_allclose(np.asarray(mc.histogram_times), saved_times, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(mc.peak_edges["u:z"]), edges["u:z"])
    cases = [(f"values of {n}", mc.histograms[n], values[n][::10]) for n in ["force:mesh"]] + [
        (f"peaks of {n}", mc.peak_histograms[n], step_peak) for n, step_peak in cases
    ]
    for label, counts, expected_values in cases:
        e = edges[label.split()[-1]]
        # the test's bins are decisive: no value within 1e-9 of an edge
        assert np.min(np.abs(expected_values[:, None] - e[None, :])) > 1e-9 * np.max(np.abs(e)), label
        got = np.asarray(counts)
        assert got.dtype == np.float64 and got.shape == (41, 60)
        expected = np.zeros_like(got)
        expected[np.arange(41), np.searchsorted(e, expected_values, side="right") - 1] = 7.0
        np.testing.assert_array_equal(got, expected, err_msg=label)
    # peaks taken from a later time (after the start-up, say; the nearest saved time, 1 ms): the largest
    # magnitude from that step on
    later = pg.monte_carlo(quiet, n_samples=3, key=KEY, progress=False, dt=1e-5, n_steps=400, save_every=10,
                           peaks={q: edges[q] for q in ("force:mesh", "u:z")}, peak_start=1.03e-3,
                           histogram_times=saved_times[10:], propagation=propagation)  # fmt: skip
    assert later.peak_start == pytest.approx(1e-3, abs=1e-15)
    for name in ("force:mesh", "u:z"):
        magnitude = np.abs(values[name])
        late_peak = np.maximum.accumulate(magnitude[100:])[::10]  # steps 100, 110, ... 400
        # decisive: a start one save earlier (step 90) or one step later (101) would give other bins
        bins = lambda x: np.searchsorted(edges[name], x, side="right")  # noqa: E731
        assert np.any(bins(np.maximum.accumulate(magnitude[90:])[10::10]) != bins(late_peak)), name
        assert np.any(bins(np.maximum.accumulate(magnitude[101:])[9::10]) != bins(late_peak[1:])), name
        expected = np.zeros((31, 60))
        expected[np.arange(31), np.searchsorted(edges[name], late_peak, side="right") - 1] = 3.0
        np.testing.assert_array_equal(np.asarray(later.peak_histograms[name]), expected, err_msg=name)
        assert later.peak_exceedance(name).start == later.peak_start
    # the probability that the peak has reached each level: 1 up to the deterministic peak, 0 beyond
    for name, step_peak in peak_values.items():
        exceedance = mc.peak_exceedance(name)
        assert exceedance.probability.dtype == np.float64 and exceedance.probability.shape == (41, 60)
        np.testing.assert_array_equal(exceedance.levels, edges[name][1:])
        np.testing.assert_array_equal(exceedance.times, np.asarray(mc.histogram_times))
        reached = (step_peak[:, None] >= exceedance.levels[None, :]).astype(float)
        np.testing.assert_array_equal(exceedance.probability, reached, err_msg=name)
        np.testing.assert_array_equal(exceedance.standard_error, np.zeros_like(reached))


@pytest.mark.slow
@pytest.mark.parametrize("propagation", ["eigen", "physical"])
def test_asking_for_peaks_leaves_every_other_statistic_the_same(propagation):
    """The peaks are computed beside the step, not within it: a run with peaks of a force, a displacement and
    a deflection gives the same doubles for every other statistic as one without."""
    from pgtjax.models import gear_pair as gp

    system = gp.build()
    common = dict(n_samples=64, key=KEY, dt=1e-5, n_steps=120, save_every=20, progress=False,
                  propagation=propagation, histograms={"delta:mesh": np.linspace(-1e-4, 1e-4, 9)},
                  histogram_times=[6e-4, 1.2e-3])  # fmt: skip
    plain = pg.monte_carlo(system, **common)
    edges = np.linspace(0.0, 1e-4, 9)
    peaks = pg.monte_carlo(
        system, **common, peaks={"force:mesh": edges * 1e10, "u:z": edges, "delta:mesh": edges}
    )
    for field in _EVERY_STATISTIC:
        np.testing.assert_array_equal(
            np.asarray(getattr(peaks, field)), np.asarray(getattr(plain, field)), field
        )
    np.testing.assert_array_equal(
        np.asarray(peaks.histograms["delta:mesh"]), np.asarray(plain.histograms["delta:mesh"])
    )
    assert float(np.max(np.asarray(plain.std_u))) > 0 and set(peaks.peak_histograms) == {
        "force:mesh",
        "u:z",
        "delta:mesh",
    }


@pytest.mark.slow
def test_peaks_lie_above_every_earlier_magnitude_and_grow_with_time():
    """With noise: each sample's peak is at least its magnitude at every saved time so far, so the peaks'
    cumulative counts lie below the magnitudes' at every earlier time and fall with time; at t0 they are the
    magnitudes' own. The magnitudes' histogram is that of the values over edges symmetric about 0, folded."""
    from pgtjax.models import gear_pair as gp

    system = gp.build()
    n, peak_edges = 300, np.linspace(0.0, 2e6, 201)
    value_edges = np.concatenate([-peak_edges[:0:-1], peak_edges])  # -2e6 ... 2e6, 0 an edge
    mc = pg.monte_carlo(system, n_samples=n, key=KEY, dt=1e-5, n_steps=300, save_every=10, progress=False,
                        histograms={"force:mesh": value_edges[::2]}, peaks={"force:mesh": peak_edges},
                        histogram_times=np.arange(31) * 1e-4)  # fmt: skip
    signed = np.asarray(mc.histograms["force:mesh"])  # bins of width 2e4 over [-2e6, 2e6]
    half = signed.shape[1] // 2
    magnitudes = signed[:, half:] + signed[:, :half][:, ::-1]  # |value| in bins of 2e4 over [0, 2e6]
    peaks = np.asarray(mc.peak_histograms["force:mesh"]).reshape(31, 100, 2).sum(axis=2)  # the same bins
    values, peaks = _cumulative(magnitudes), _cumulative(peaks)
    assert np.all(values[:, -1] == n) and np.all(peaks[:, -1] == n)  # the edges hold every sample
    np.testing.assert_array_equal(peaks[0], values[0])
    assert np.all(np.diff(peaks, axis=0) <= 0)
    assert np.all(peaks <= np.minimum.accumulate(values, axis=0))
    assert np.any(
        peaks < np.minimum.accumulate(values, axis=0)
    )  # the peaks are not the magnitudes themselves
    # P(peak >= level) from the counts, with its binomial standard error
    exceedance = mc.peak_exceedance("force:mesh")
    counts = np.asarray(mc.peak_histograms["force:mesh"])
    for row in (0, 15, 30):
        beyond = np.array([n - counts[row, : j + 1].sum() for j in range(counts.shape[1])])
        np.testing.assert_array_equal(exceedance.probability[row], beyond / n)
    p = exceedance.probability
    np.testing.assert_allclose(exceedance.standard_error, np.sqrt(p * (1 - p) / n), rtol=1e-15)
    assert np.any((p[-1] > 0) & (p[-1] < 1))  # levels some samples' peaks reached, not all
    with pytest.raises(ValueError, match="no peaks of 'u:z' were counted; counted: force:mesh"):
        mc.peak_exceedance("u:z")
    above = pg.monte_carlo(system, n_samples=4, key=KEY, dt=1e-5, n_steps=10, save_every=10, progress=False,
                           peaks={"force:mesh": peak_edges + 1e5}, histogram_times=[1e-4])  # fmt: skip
    with pytest.raises(ValueError, match="start at 100000 > 0"):
        above.peak_exceedance("force:mesh")
