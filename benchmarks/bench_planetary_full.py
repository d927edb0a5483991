"""End-to-end benchmark of the issue's Monte Carlo target: the ch. 3 planetary study at the thesis's size
(SL + recursion and 100,000 Monte Carlo samples over one carrier period at dt = 2.7 ms, both saved about
2,000 times as the study does, the contact-point observables), i.e. the SL and MC part of ``pgtjax run --full``, timed once from a cold
start (compilation included) with the process's peak resident memory. The SL-vs-MC agreement of the run is
recorded with it.

Monte Carlo runs on JAX's one CPU device, as ``pgtjax run`` does; ``--cpu-devices N`` shards it over N (as
``pgtjax --cpu-devices N run --full``).

Usage: python benchmarks/bench_planetary_full.py [--samples 100000] [--chunk-size 5000] [--cpu-devices N]
Writes benchmarks/results/planetary_full.json. Takes minutes (about 5 on the 2-core development machine).
"""

from __future__ import annotations

import argparse
import resource
import time

import jax
from _common import write

import pgtjax as pg
from pgtjax.models import planetary as pm
from pgtjax.studies import planetary as study

THESIS_MC_S = 223 * 3600.0


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--chunk-size", type=int, default=5000)
    ap.add_argument("--cpu-devices", type=int, default=None, help="JAX CPU devices (default: JAX's one)")
    args = ap.parse_args()
    if args.cpu_devices is not None:
        pg.use_cpu_cores(args.cpu_devices)  # before any JAX computation
    devices = len(jax.local_devices())
    p = pm.default_params()
    start = time.perf_counter()
    result = study.run_study(p, n_samples=args.samples, key=jax.random.key(0), chunk_size=args.chunk_size)
    wall = time.perf_counter() - start
    rss_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
    e = study.error_summary(result)
    print(
        f"SL + MC of {args.samples} samples over one carrier period ({result.settings['n_steps']} steps): "
        f"{wall:.1f} s wall including compilation, peak RSS {rss_gb:.2f} GB; MC stepped in "
        f"{result.mc.propagation} coordinates on {devices} device(s)"
    )
    print(
        f"SL vs MC: {100 * e['fraction_of_dof_time_points_within_3_se']:.2f} % of (DOF, time) points within 3 s.e."
    )
    path = write(
        "planetary_full",
        dict(
            command=f"python benchmarks/bench_planetary_full.py --samples {args.samples} --chunk-size {args.chunk_size}"
            + (f" --cpu-devices {args.cpu_devices}" if args.cpu_devices else ""),
            samples=args.samples,
            devices=len(jax.local_devices()),
            chunk_size=args.chunk_size,
            steps=result.settings["n_steps"],
            dt_s=result.dt,
            settings=result.settings,
            wall_s_including_compilation=wall,
            peak_rss_gb=rss_gb,
            propagation=result.mc.propagation,
            ratio_vs_thesis_223_cpu_hours=THESIS_MC_S / wall,
            sl_vs_mc=e,
        ),
    )
    print("wrote", path)


if __name__ == "__main__":
    main()
