"""Benchmark of the ch. 4 gear pair: MC 20,000 samples x 10,000 steps, SL + recursion 10,000 steps, and a
plain NumPy implementation of the same MC scheme that loops over samples and steps as the documents' MATLAB
did (timed on a few samples and extrapolated per sample-step).

Usage: python benchmarks/bench_gear_pair.py [--samples 20000] [--steps 10000] [--numpy-samples 3]
Writes benchmarks/results/gear_pair.json. Correctness is checked before anything is timed.
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np
from _common import timed, write

import pgtjax as pg
from pgtjax.models import gear_pair as gp

THESIS_MC_S = 8 * 3600.0  # ch. 4: 20,000 MC samples, MATLAB, i7-8700
THESIS_SL_S = 35.0


def numpy_monte_carlo(system_params, n_samples, n_steps, dt, rng, noise=True):
    """Per-sample, per-step loop in NumPy: the stochastic Newmark step with the implicit backlash force
    (Newton on the single contact), written as a direct transcription of the scheme, no vectorization."""
    p = system_params
    sys = gp.build(p)
    M = np.asarray(sys.mass)
    C = np.asarray(sys.damping)
    Ks = np.asarray(sys.stiffness)
    F = np.asarray(sys.load)
    g = np.asarray(sys.contact_direction(0.0))[:, 0]
    b = float(p.half_backlash)
    bs = np.asarray(sys.scaled_noise_input(0.0))[:, 0]
    k0, ks_, kc_, w = (
        float(p.mesh_stiffness),
        np.asarray(p.mesh_sin),
        np.asarray(p.mesh_cos),
        float(p.mesh_frequency),
    )
    orders = np.arange(1, ks_.size + 1)

    def kmesh(t):
        return k0 + np.sum(ks_ * np.sin(orders * w * t) + kc_ * np.cos(orders * w * t))

    def force(d, k):
        return k * (max(d - b, 0.0) - max(-b - d, 0.0))

    finals = []
    for _ in range(n_samples):
        u, v = np.zeros(3), np.zeros(3)
        f0 = 0.0
        for i in range(n_steps):
            t1 = (i + 1) * dt
            k1 = kmesh(t1)
            keff = Ks + (2 / dt) * C + (4 / dt**2) * M
            rhs = ((4 / dt**2) * M + (2 / dt) * C - Ks) @ u + (4 / dt) * M @ v + 2 * F - g * f0
            if noise:
                rhs = rhs + (2 / np.sqrt(dt)) * bs * rng.standard_normal()
            # Newton on K_eff u + g f(g.u) = rhs
            u1 = np.linalg.solve(keff, rhs)
            for _ in range(50):
                d = g @ u1
                fd = force(d, k1)
                res = keff @ u1 + g * fd - rhs
                if np.max(np.abs(res)) <= 1e-12 * np.max(np.abs(rhs)) + 1e-300:
                    break
                kt = k1 if (d > b or d < -b) else 0.0
                u1 = u1 - np.linalg.solve(keff + kt * np.outer(g, g), res)
            v = (2 / dt) * (u1 - u) - v
            u, f0 = u1, force(g @ u1, k1)
        finals.append(u.copy())
    return np.array(finals)


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--samples", type=int, default=20_000)
    ap.add_argument("--steps", type=int, default=10_000)
    ap.add_argument("--numpy-samples", type=int, default=3)
    ap.add_argument("--dt", type=float, default=1e-5)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    params = gp.default_params()
    system = gp.build(params)
    dt, n = args.dt, args.steps

    # --- correctness first
    n_check = 400
    ref = pg.simulate(system, dt=dt, n_steps=n_check, save_every=n_check)
    np_final = numpy_monte_carlo(params, 1, n_check, dt, np.random.default_rng(0), noise=False)[0]
    check_numpy = float(np.max(np.abs(np_final - np.asarray(ref.u[-1]))) / np.max(np.abs(np_final)))
    assert check_numpy < 1e-9, check_numpy
    sl_small = pg.solve_moments(system, dt=dt, n_steps=n_check, save_every=n_check)
    mc_small = pg.monte_carlo(
        system,
        n_samples=4000,
        key=jax.random.key(1),
        dt=dt,
        n_steps=n_check,
        save_every=n_check,
        progress=False,
    )
    z_mc = np.abs(np.asarray(mc_small.mean_delta[-1] - sl_small.mean_delta[-1])) / np.asarray(
        mc_small.std_delta[-1] / np.sqrt(4000)
    )
    print(
        f"correctness: NumPy vs pgtjax deterministic rel. diff {check_numpy:.1e}; "
        f"MC vs SL mean delta {float(z_mc[0]):.2f} s.e. (heavy load, near-linear)"
    )

    # --- SL + recursion
    sl_fn = lambda: pg.solve_moments(system, dt=dt, n_steps=n, save_every=100)  # noqa: E731
    sl_first, sl_med, sl_all, _ = timed(sl_fn, repeats=args.repeats)
    print(f"SL + recursion, {n} steps: first call {sl_first:.2f} s, median {sl_med:.3f} s {sl_all}")

    # --- MC
    mc_fn = lambda: (  # noqa: E731
        pg.monte_carlo(
            system,
            n_samples=args.samples,
            key=jax.random.key(0),
            dt=dt,
            n_steps=n,
            save_every=100,
            chunk_size=args.samples,
            progress=False,
        ).mean_u
    )
    mc_first, mc_med, mc_all, _ = timed(mc_fn, repeats=args.repeats)
    print(f"MC {args.samples} x {n}: first call {mc_first:.2f} s, median {mc_med:.2f} s {mc_all}")

    # --- NumPy per-sample baseline (subset, extrapolated)
    t = time.perf_counter()
    numpy_monte_carlo(params, args.numpy_samples, n, dt, np.random.default_rng(0))
    np_time = time.perf_counter() - t
    np_per_sample_step = np_time / (args.numpy_samples * n)
    np_extrapolated = np_per_sample_step * args.samples * n
    jax_per_sample_step = mc_med / (args.samples * n)
    print(
        f"NumPy baseline: {np_per_sample_step * 1e6:.2f} us per sample-step, extrapolated "
        f"{np_extrapolated / 3600:.2f} h for {args.samples} x {n}; pgtjax {jax_per_sample_step * 1e9:.1f} ns "
        f"per sample-step: {np_per_sample_step / jax_per_sample_step:.0f}x faster"
    )
    path = write(
        "gear_pair",
        dict(
            command="python benchmarks/bench_gear_pair.py "
            + " ".join(f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items()),
            dt_s=dt,
            steps=n,
            samples=args.samples,
            correctness=dict(numpy_vs_pgtjax_rel_diff=check_numpy, mc_vs_sl_mean_delta_in_se=float(z_mc[0])),
            sl=dict(
                first_call_s=sl_first,
                median_s=sl_med,
                runs_s=sl_all,
                compile_estimate_s=sl_first - sl_med,
                ratio_vs_thesis_35s=THESIS_SL_S / sl_med,
            ),
            mc=dict(
                first_call_s=mc_first,
                median_s=mc_med,
                runs_s=mc_all,
                compile_estimate_s=mc_first - mc_med,
                per_sample_step_ns=jax_per_sample_step * 1e9,
                ratio_vs_thesis_8h=THESIS_MC_S / mc_med,
            ),
            numpy_baseline=dict(
                samples_timed=args.numpy_samples,
                seconds=np_time,
                per_sample_step_us=np_per_sample_step * 1e6,
                extrapolated_s=np_extrapolated,
                speedup_per_sample_step=np_per_sample_step / jax_per_sample_step,
            ),
        ),
    )
    print("wrote", path)


if __name__ == "__main__":
    main()
