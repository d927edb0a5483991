"""What a competent user would write instead of pgtjax for the gear pair's Monte Carlo: the same scheme (stochastic
average-acceleration Newmark with the trapezoidal noise term, the backlash force implicit at the end of each step,
solved in closed form) in NumPy vectorized over samples, and in numba looping over samples and steps, drawing its
normals from numba's ``np.random`` (one core, and every core with ``prange``) or from NumPy's ``Generator``.

Each computes what pgtjax's ``monte_carlo`` reports for the DOFs: the mean and the centred sum of squares of u and
v at every saved time, in physical coordinates. Fed the normals pgtjax draws (``pgtjax_normals``), each reproduces
pgtjax's statistics to rounding: that is checked before anything is timed (:func:`check_against_pgtjax`).
"""

from __future__ import annotations

import concurrent.futures
import contextlib
from dataclasses import dataclass

import numpy as np

try:
    import numba
except ImportError:  # pragma: no cover - the numba peers are skipped without numba
    numba = None


@dataclass(frozen=True)
class GearPairScheme:
    """The gear pair's contact-free step map and contact data for step ``h`` (s), as plain NumPy arrays:
    ``u_lin = x_u u0 + x_v v0 + load + noise z - kinv_g f0``, ``delta_lin = g . u_lin``, the backlash solved in
    closed form with ``s = g^T A^-1 g``, then ``u1 = u_lin - kinv_g f1`` and ``v1 = (2/h)(u1 - u0) - v0``."""

    h: float
    x_u: np.ndarray  # (n, n)
    x_v: np.ndarray  # (n, n)
    load: np.ndarray  # A^-1 (F0 + F1), (n,)
    noise: np.ndarray  # A^-1 B_N, (n,)
    kinv_g: np.ndarray  # A^-1 g, (n,)
    g: np.ndarray  # contact direction, (n,)
    s: float  # g^T A^-1 g (m/N)
    b: float  # half backlash (m)
    k: np.ndarray  # mesh stiffness at t = 0, h, ..., n_steps h (N/m), (n_steps + 1,)


def gear_pair_scheme(system, h: float, n_steps: int) -> GearPairScheme:
    """The scheme of ``pgtjax.models.gear_pair.build()`` (constant K, C, load, direction and noise input: checked)."""
    import jax

    M, C, K = (np.asarray(a, dtype=np.float64) for a in (system.mass, system.damping, system.stiffness))
    if system.n_contacts != 1 or system.n_noise != 1 or callable(system.load):
        raise ValueError("the peers implement one contact, one noise input and a constant load")
    times = h * np.arange(n_steps + 1)
    g = np.asarray(system.contact_direction(0.0))[:, 0]
    for t in (times[n_steps // 2], times[-1]):
        if not np.array_equal(np.asarray(system.contact_direction(t))[:, 0], g):
            raise ValueError("the peers assume a constant contact direction")
    a = K + (2.0 / h) * C + (4.0 / h**2) * M
    a_inv = np.linalg.inv(a)
    b_n = (2.0 / np.sqrt(h)) * np.asarray(system.scaled_noise_input(0.0))[:, 0]
    k = np.asarray(jax.vmap(lambda t: system.contact_inputs(t)[0])(times), dtype=np.float64)
    return GearPairScheme(
        h=float(h),
        x_u=a_inv @ ((4.0 / h**2) * M + (2.0 / h) * C - K),
        x_v=a_inv @ ((4.0 / h) * M),
        load=a_inv @ (2.0 * np.asarray(system.load)),
        noise=a_inv @ b_n,
        kinv_g=a_inv @ g,
        g=g,
        s=float(g @ a_inv @ g),
        b=float(system.contacts.clearance[0]),
        k=k,
    )


def _backlash_force(delta_lin, s, k, b):
    """End-of-step force of the backlash law from the contact-free deflection (closed form, as pgtjax)."""
    sk = s * k
    delta = np.where(delta_lin > b, (delta_lin + sk * b) / (1.0 + sk), delta_lin)
    delta = np.where(delta_lin < -b, (delta_lin - sk * b) / (1.0 + sk), delta)
    return k * (np.maximum(delta - b, 0.0) - np.maximum(-b - delta, 0.0))


def numpy_monte_carlo(scheme: GearPairScheme, n_samples, n_steps, save_every, *, rng=None, normals=None):
    """NumPy, vectorized over samples: one (n_samples, n) update per step. Normals from ``rng``
    (a ``np.random.Generator``) or given as (n_steps, n_samples). Returns mean and centred sum of squares of
    (u, v), each (n_saved, 2n)."""
    n = scheme.g.size
    u, v, f = np.zeros((n_samples, n)), np.zeros((n_samples, n)), np.zeros(n_samples)
    n_saved = n_steps // save_every + 1
    mean, m2 = np.zeros((n_saved, 2 * n)), np.zeros((n_saved, 2 * n))
    x_u_t, x_v_t = scheme.x_u.T.copy(), scheme.x_v.T.copy()
    for i in range(n_steps):
        z = rng.standard_normal(n_samples) if normals is None else normals[i]
        u_lin = u @ x_u_t + v @ x_v_t + scheme.load + np.outer(z, scheme.noise) - np.outer(f, scheme.kinv_g)
        f = _backlash_force(u_lin @ scheme.g, scheme.s, scheme.k[i + 1], scheme.b)
        u1 = u_lin - np.outer(f, scheme.kinv_g)
        v = (2.0 / scheme.h) * (u1 - u) - v
        u = u1
        if (i + 1) % save_every == 0:
            q = np.concatenate([u, v], axis=1)
            j = (i + 1) // save_every
            mean[j] = q.mean(axis=0)
            m2[j] = ((q - mean[j]) ** 2).sum(axis=0)
    return mean, m2


if numba is not None:
    _LANES = 64  # samples stepped together: independent chains the CPU overlaps and vectorizes

    @numba.njit(inline="always")
    def _draw_np_random(unused, i, sample):
        return np.random.standard_normal()

    @numba.njit(inline="always")
    def _draw_generator(rng, i, sample):
        return rng.standard_normal()

    @numba.njit(inline="always")
    def _draw_given(normals, i, sample):
        return normals[i, sample]

    _DRAWS = {"np.random": _draw_np_random, "generator": _draw_generator, "given": _draw_given}

    def _kernel(source: str, nogil: bool = False):
        """A numba kernel: blocks of ``_LANES`` samples (``prange`` over blocks), each block stepped through
        time with its samples in the innermost loop, its statistics reduced per block and merged at the end.
        ``source`` says where the normals come from: ``"np.random"`` (numba's generator, one stream per
        thread), ``"generator"`` (a NumPy Generator passed in; one thread only) or ``"given"`` (an array
        (n_steps, n_samples)). ``nogil``: a serial kernel that releases the GIL, for Python threads that
        each run it on their own samples with their own Generator (:func:`numba_monte_carlo`)."""
        draw = _DRAWS[source]

        @numba.njit(inline="always")
        def block(
            first, lanes, src, n_steps, save_every, x_u, x_v, load, noise, kinv_g, g, s, b, h, k, mean, m2
        ):
            n = g.size
            u, v, lin = np.zeros((n, lanes)), np.zeros((n, lanes)), np.empty((n, lanes))
            f, z = np.zeros(lanes), np.empty(lanes)
            two_over_h = 2.0 / h
            i = 0
            for j in range(n_steps // save_every + 1):
                if j:
                    for _ in range(save_every):
                        for q in range(lanes):
                            z[q] = draw(src, i, first + q)
                        k1 = k[i + 1]
                        sk = s * k1
                        for r in range(n):  # contact-free displacement
                            for q in range(lanes):
                                lin[r, q] = load[r] + noise[r] * z[q] - kinv_g[r] * f[q]
                            for c in range(n):
                                for q in range(lanes):
                                    lin[r, q] += x_u[r, c] * u[c, q] + x_v[r, c] * v[c, q]
                        for q in range(lanes):  # backlash in closed form, as pgtjax
                            dl = 0.0
                            for r in range(n):
                                dl += g[r] * lin[r, q]
                            upper = (dl + sk * b) / (1.0 + sk)
                            lower = (dl - sk * b) / (1.0 + sk)
                            d = upper if dl > b else (lower if dl < -b else dl)
                            f[q] = k1 * (max(d - b, 0.0) - max(-b - d, 0.0))
                        for r in range(n):
                            for q in range(lanes):
                                u1 = lin[r, q] - kinv_g[r] * f[q]
                                v[r, q] = two_over_h * (u1 - u[r, q]) - v[r, q]
                                u[r, q] = u1
                        i += 1
                for c in range(2 * n):  # this block's mean and centred sum of squares
                    acc = 0.0
                    for q in range(lanes):
                        acc += u[c, q] if c < n else v[c - n, q]
                    mu = acc / lanes
                    acc = 0.0
                    for q in range(lanes):
                        d = (u[c, q] if c < n else v[c - n, q]) - mu
                        acc += d * d
                    mean[j, c] = mu
                    m2[j, c] = acc

        # prange over blocks; with one thread the same code on one core (a serial loop where ``nogil``)
        @(numba.njit(nogil=True) if nogil else numba.njit(parallel=True))
        def run(src, n_samples, n_steps, save_every, x_u, x_v, load, noise, kinv_g, g, s, b, h, k):
            n_blocks = -(-n_samples // _LANES)
            n_saved = n_steps // save_every + 1
            means = np.zeros((n_blocks, n_saved, 2 * g.size))
            m2s = np.zeros((n_blocks, n_saved, 2 * g.size))
            for blk in numba.prange(n_blocks):
                first = blk * _LANES
                lanes = min(_LANES, n_samples - first)
                block(
                    first,
                    lanes,
                    src,
                    n_steps,
                    save_every,
                    x_u,
                    x_v,
                    load,
                    noise,
                    kinv_g,
                    g,
                    s,
                    b,
                    h,
                    k,
                    means[blk],
                    m2s[blk],
                )
            mean, m2, total = means[0].copy(), m2s[0].copy(), min(_LANES, n_samples)
            for blk in range(1, n_blocks):  # Chan's parallel combination, as pgtjax merges chunks
                count = min(_LANES, n_samples - blk * _LANES)
                new = total + count
                d = means[blk] - mean
                mean += d * (count / new)
                m2 += m2s[blk] + d * d * (total * count / new)
                total = new
            return mean, m2

        return run

    _KERNELS = {}

    def numba_monte_carlo(
        scheme: GearPairScheme,
        n_samples,
        n_steps,
        save_every,
        *,
        source,
        rng=None,
        normals=None,
        seed=0,
        parallel=False,
    ):
        """The numba kernel of ``source`` ("np.random", "generator" with ``rng``, or "given" with ``normals``);
        ``parallel`` runs the blocks of samples on all of numba's threads, else on one. A NumPy Generator is
        not thread-safe, so with ``parallel`` the "generator" kernel runs in as many Python threads, each on
        a contiguous share of the samples with its own child of ``rng`` (``Generator.spawn``), and the shares'
        statistics are merged as the kernel merges its blocks. Returns (mean, m2)."""
        if parallel and source == "generator":
            return numba_in_threads(
                scheme, n_samples, n_steps, save_every, n_threads=numba.get_num_threads(), rng=rng
            )
        if source not in _KERNELS:
            _KERNELS[source] = _kernel(source)
        if source == "np.random":
            _seed(seed)
            first = np.zeros(1)
        else:
            first = rng if source == "generator" else np.ascontiguousarray(normals)
        with _threads(numba.get_num_threads() if parallel else 1):
            return _KERNELS[source](
                first, n_samples, n_steps, save_every, scheme.x_u, scheme.x_v, scheme.load,
                scheme.noise, scheme.kinv_g, scheme.g, scheme.s, scheme.b, scheme.h, scheme.k,
            )  # fmt: skip

    def _shares(n_samples, n_threads):
        """Contiguous shares of the samples, one per thread (at most one thread per sample)."""
        edges = np.linspace(0, n_samples, min(n_threads, n_samples) + 1).astype(int)
        return list(zip(edges[:-1], edges[1:]))

    def _in_threads(source, sources, shares, scheme, n_steps, save_every):
        """The serial ``nogil`` kernel of ``source`` run on each share in a Python thread of its own, with that
        share's source of normals, and the shares' statistics merged (Chan's parallel combination)."""
        name = source + "-nogil"
        if name not in _KERNELS:
            _KERNELS[name] = _kernel(source, nogil=True)
        kernel = _KERNELS[name]

        def share(i):
            lo, hi = shares[i]
            return kernel(
                sources[i], int(hi - lo), n_steps, save_every, scheme.x_u, scheme.x_v, scheme.load,
                scheme.noise, scheme.kinv_g, scheme.g, scheme.s, scheme.b, scheme.h, scheme.k,
            )  # fmt: skip

        with concurrent.futures.ThreadPoolExecutor(len(shares)) as pool:
            parts = list(pool.map(share, range(len(shares))))
        counts = [hi - lo for lo, hi in shares]
        (mean, m2), total = parts[0], counts[0]
        mean, m2 = mean.copy(), m2.copy()
        for (mean_i, m2_i), count in zip(parts[1:], counts[1:]):
            new = total + count
            d = mean_i - mean
            mean += d * (count / new)
            m2 += m2_i + d * d * (total * count / new)
            total = new
        return mean, m2

    def numba_in_threads(scheme, n_samples, n_steps, save_every, *, n_threads, rng=None, normals=None):
        """What a user with a NumPy ``Generator`` runs on every core: the "generator" kernel in ``n_threads``
        Python threads, each with a child of ``rng`` (``Generator.spawn``); with ``normals`` (n_steps,
        n_samples) instead, the "given" kernel on the same shares (a check of the shares and their merge)."""
        shares = _shares(n_samples, n_threads)
        if normals is not None:
            sources = [np.ascontiguousarray(normals[:, lo:hi]) for lo, hi in shares]
            return _in_threads("given", sources, shares, scheme, n_steps, save_every)
        return _in_threads("generator", rng.spawn(len(shares)), shares, scheme, n_steps, save_every)

    @contextlib.contextmanager
    def _threads(n):
        """numba's thread count set to ``n`` for a call (a one-thread kernel runs on one core)."""
        previous = numba.get_num_threads()
        numba.set_num_threads(n)
        try:
            yield
        finally:
            numba.set_num_threads(previous)

    @numba.njit
    def _seed(seed):
        np.random.seed(seed)


def pgtjax_normals(key, n_samples, n_steps, save_every):
    """The standard normals pgtjax's ``monte_carlo`` draws for the gear pair (one noise input), as
    (n_steps, n_samples): sample ``s``, saved block ``j``: ``normal(fold_in(fold_in(key, s), j), (save_every, 1))``."""
    import jax

    from pgtjax._random import normal

    def sample(s):
        k = jax.random.fold_in(key, s)
        blocks = jax.vmap(lambda j: normal(jax.random.fold_in(k, j), (save_every, 1)))(
            np.arange(n_steps // save_every)
        )
        return blocks.reshape(n_steps)

    return np.asarray(jax.vmap(sample)(np.arange(n_samples))).T.copy()


def check_against_pgtjax(system, h, *, n_samples=64, n_steps=400, save_every=100) -> dict:
    """Largest relative difference of each peer's mean and std of (u, v) from pgtjax's, all fed pgtjax's normals."""
    import jax

    import pgtjax as pg

    key = jax.random.key(3)
    ref = pg.monte_carlo(
        system, n_samples=n_samples, key=key, dt=h, n_steps=n_steps, save_every=save_every, progress=False
    )
    ref_mean = np.concatenate([np.asarray(ref.mean_u), np.asarray(ref.mean_v)], axis=1)
    ref_std = np.concatenate([np.asarray(ref.std_u), np.asarray(ref.std_v)], axis=1)
    scheme = gear_pair_scheme(system, h, n_steps)
    normals = pgtjax_normals(key, n_samples, n_steps, save_every)
    runs = {"numpy": numpy_monte_carlo(scheme, n_samples, n_steps, save_every, normals=normals)}
    if numba is not None:
        runs["numba"] = numba_monte_carlo(
            scheme, n_samples, n_steps, save_every, source="given", normals=normals
        )
        runs["numba_parallel"] = numba_monte_carlo(
            scheme, n_samples, n_steps, save_every, source="given", normals=normals, parallel=True
        )
        runs["numba_threads"] = numba_in_threads(
            scheme, n_samples, n_steps, save_every, n_threads=2, normals=normals
        )
    out = {}
    for name, (mean, m2) in runs.items():
        std = np.sqrt(m2 / (n_samples - 1))
        scale_m = np.max(np.abs(ref_mean), axis=0)
        scale_s = np.max(ref_std, axis=0)
        out[name] = dict(
            mean=float(np.max(np.abs(mean - ref_mean) / scale_m)),
            std=float(np.max(np.abs(std - ref_std)[1:] / scale_s)),
        )
    return out


def time_gear_pair(system, *, h, n_samples, n_steps, save_every, rounds, seed=0, diffrax_steps=None) -> dict:
    """ns per sample-step of pgtjax (all local devices, and one) and of each peer on the same problem, timed
    alternately over ``rounds`` (medians); the first call of each (compilation) is reported apart.
    ``diffrax_steps``: ``{name: (solver, substeps)}`` adds diffrax with ``substeps`` steps per Newmark step
    (the matched accuracy of :func:`matched_diffrax_step`) on a quarter of the samples; its time is still
    reported per sample and per Newmark step (what the same statistics cost)."""
    import jax

    import pgtjax as pg

    scheme = gear_pair_scheme(system, h, n_steps)
    devices = jax.local_devices()

    def pgtjax_run(devs, chunk_size=None):
        def run():
            r = pg.monte_carlo(
                system,
                n_samples=n_samples,
                key=jax.random.key(seed),
                dt=h,
                n_steps=n_steps,
                save_every=save_every,
                chunk_size=chunk_size,  # None: the default batch (5,000 samples per CPU device)
                devices=devs,
                progress=False,
            )
            jax.block_until_ready(r.std_u)

        return run

    runs = {f"pgtjax, {len(devices)} {devices[0].platform} device(s)": pgtjax_run(devices)}
    # the whole run in one batch per device: larger batches leave the caches (docs/performance.md)
    one_batch = -(-n_samples // len(devices))
    runs[f"pgtjax, {len(devices)} {devices[0].platform} device(s), one batch of {one_batch} each"] = (
        pgtjax_run(devices, one_batch)
    )
    if len(devices) > 1:
        runs[f"pgtjax, 1 {devices[0].platform} device"] = pgtjax_run(devices[:1])
    runs["NumPy vectorized over samples (Generator)"] = lambda: numpy_monte_carlo(
        scheme, n_samples, n_steps, save_every, rng=np.random.default_rng(seed)
    )
    if numba is not None:
        runs["numba, np.random, 1 thread"] = lambda: numba_monte_carlo(
            scheme, n_samples, n_steps, save_every, source="np.random", seed=seed
        )
        runs["numba, NumPy Generator, 1 thread"] = lambda: numba_monte_carlo(
            scheme, n_samples, n_steps, save_every, source="generator", rng=np.random.default_rng(seed)
        )
        runs[f"numba, np.random, prange over {numba.get_num_threads()} threads"] = lambda: numba_monte_carlo(
            scheme, n_samples, n_steps, save_every, source="np.random", seed=seed, parallel=True
        )
        runs[f"numba, NumPy Generator, {numba.get_num_threads()} Python threads"] = lambda: numba_monte_carlo(
            scheme, n_samples, n_steps, save_every, source="generator", rng=np.random.default_rng(seed),
            parallel=True,
        )  # fmt: skip
    samples = dict.fromkeys(runs, n_samples)
    for name, (solver, substeps) in (diffrax_steps or {}).items():
        label = f"diffrax {name}, {substeps} steps per Newmark step, 1 device"
        samples[label] = max(n_samples // 4, 2)
        runs[label] = lambda solver=solver, substeps=substeps, n=samples[label]: jax.block_until_ready(
            diffrax_monte_carlo(
                system,
                solver=solver,
                h=h / substeps,
                n_samples=n,
                n_steps=n_steps * substeps,
                save_every=save_every * substeps,
                key=jax.random.key(seed),
            )
        )
    from _common import timed_interleaved

    # diffrax's runs after the others': timed among them, they slowed every later pgtjax run of the process by
    # a quarter, with or without garbage collection and a pause (2026-11-26); their ratios to the rest are of
    # 30-60, which this does not blur
    late = [name for name in runs if name.startswith("diffrax")]
    rows = timed_interleaved(
        {k: f for k, f in runs.items() if k not in late}, repeats=rounds, serpentine=True
    )
    rows.update(timed_interleaved({k: runs[k] for k in late}, repeats=rounds))
    for name, row in rows.items():
        row["n_samples"] = samples[name]
        row["ns_per_sample_step"] = row["median_s"] / (samples[name] * n_steps) * 1e9
    return rows


# ----------------------------------------------------------------------------------------------- diffrax


def _diffrax_terms(system):
    """Drift and diffusion of the gear pair as a first-order SDE in x = (u, v):
    ``du = v dt``, ``dv = M^-1 (F - C v - K u - g f(g.u, k(t))) dt + M^-1 B_s dW`` (B_s = B sqrt(2 pi S0))."""
    import diffrax
    import jax.numpy as jnp

    M, C, K = (jnp.asarray(a) for a in (system.mass, system.damping, system.stiffness))
    m_inv = jnp.linalg.inv(M)
    n = M.shape[0]
    load, law, b = jnp.asarray(system.load), system.contacts.law, system.contacts.clearance
    noise = jnp.concatenate([jnp.zeros((n, 1)), m_inv @ jnp.asarray(system.scaled_noise_input(0.0))])

    def drift(t, x, args):
        u, v = x[:n], x[n:]
        g = system.contact_direction(t)
        f = law.force(g.T @ u, system.contact_inputs(t), b)
        return jnp.concatenate([v, m_inv @ (load - C @ v - K @ u - g @ f)])

    def diffusion(t, x, args):
        return noise

    return diffrax.ODETerm(drift), diffusion, n


_DIFFRAX_RUNS = {}


def diffrax_monte_carlo(system, *, solver, h, n_samples, n_steps, save_every, key, noise=True):
    """The gear pair's statistics from diffrax: ``solver`` (e.g. ``diffrax.Heun()``) at constant step ``h`` on
    every sample (``vmap``), Brownian increments from ``UnsafeBrownianPath`` (the cheapest path diffrax
    offers for fixed steps). Returns the mean and centred sum of squares of (u, v) at the saved times. The
    whole run is one ``jax.jit``, compiled once per configuration (a fresh closure per call would recompile
    every time, and the timing would include it)."""
    import jax

    config = (id(system), type(solver).__name__, float(h), n_samples, n_steps, save_every, noise)
    if config not in _DIFFRAX_RUNS:
        _DIFFRAX_RUNS[config] = jax.jit(
            _diffrax_run(system, solver, h, n_samples, n_steps, save_every, noise)
        )
    return _DIFFRAX_RUNS[config](key)


def _diffrax_run(system, solver, h, n_samples, n_steps, save_every, noise):
    import diffrax
    import jax
    import jax.numpy as jnp

    drift, diffusion, n = _diffrax_terms(system)
    t_end = n_steps * h
    ts = jnp.linspace(0.0, t_end, n_steps // save_every + 1)
    scale = 1.0 if noise else 0.0  # noise-free: the same terms with the diffusion switched off
    # ShARK-type solvers need the space-time Levy area of the path; Heun and Euler the increment alone
    levy = (
        diffrax.SpaceTimeLevyArea
        if isinstance(solver, diffrax.ShARK | diffrax.SRA1)
        else diffrax.BrownianIncrement
    )
    control = lambda t, x, a: scale * diffusion(t, x, a)  # noqa: E731

    def one(k):
        bm = diffrax.UnsafeBrownianPath(shape=(1,), key=k, levy_area=levy)
        terms = diffrax.MultiTerm(drift, diffrax.ControlTerm(control, bm))
        sol = diffrax.diffeqsolve(
            terms,
            solver,
            0.0,
            t_end,
            h,
            jnp.zeros(2 * n),
            saveat=diffrax.SaveAt(ts=ts),
            max_steps=n_steps + 16,
            adjoint=diffrax.ForwardMode(),  # UnsafeBrownianPath: no reverse mode (none is needed here)
        )
        return sol.ys

    def run(key):
        ys = jax.vmap(one)(jax.random.split(key, n_samples))  # (samples, saved, 2n)
        mean = jnp.mean(ys, axis=0)
        return mean, jnp.sum((ys - mean) ** 2, axis=0)

    return run


def matched_diffrax_step(system, *, h, n_steps, solvers) -> dict:
    """For each diffrax solver, the largest step h / 2^j whose noise-free trajectory (u at every saved time)
    is as accurate as pgtjax's Newmark at ``h``, both measured against Newmark at h / 64 (second order: its
    error is 4096 times smaller). Returns ``{name: dict(step_s, error, newmark_error)}``."""
    import jax

    import pgtjax as pg

    save_every = max(n_steps // 20, 1)
    fine = 64
    ref = pg.simulate(system, dt=h / fine, n_steps=n_steps * fine, save_every=save_every * fine)
    ref_u = np.asarray(ref.u)
    scale = np.max(np.abs(ref_u))
    newmark = np.asarray(pg.simulate(system, dt=h, n_steps=n_steps, save_every=save_every).u)
    target = float(np.max(np.abs(newmark - ref_u)) / scale)
    out = {}
    for name, solver in solvers.items():
        for j in range(7):
            step = h / 2**j
            mean, _ = diffrax_monte_carlo(
                system,
                solver=solver,
                h=step,
                n_samples=1,
                n_steps=n_steps * 2**j,
                save_every=save_every * 2**j,
                key=jax.random.key(0),
                noise=False,
            )
            error = float(np.max(np.abs(np.asarray(mean)[:, : ref_u.shape[1]] - ref_u)) / scale)
            if error <= target:
                break
        out[name] = dict(
            step_s=step,
            steps_per_newmark_step=2**j,
            error=error,
            newmark_error=target,
            matched=error <= target,
        )
    return out
