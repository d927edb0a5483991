"""The GPU figures: the ch. 3 planetary model over one carrier period, Monte Carlo of 100,000 and 1,000,000
samples (targets on one H100: <= 10 s and <= 60 s); the gear pair's Monte Carlo throughput; the planetary SL +
recursion; then every solver once on the default device (a smoke test that reports where each result lives).
The targets come first because a lent GPU is short-lived: the JSON is rewritten (atomically) after each stage,
so a run stopped part-way keeps what it measured.

Monte Carlo compiles once per batch shape (samples per device): one round of each shape the runs will use is
timed apart as the compilation, then each sample count is timed once (long enough not to need repeats). On a
machine without a GPU the script stops with exit status 1 unless ``--allow-cpu`` is given (then it measures the
CPU: a check of the script, not a GPU figure; use ``--quick`` for small sizes).

Usage: python benchmarks/bench_gpu.py [--samples 100000,1000000] [--chunk-size 100000] [--periods 1.0]
       [--sl-repeats 3] [--allow-cpu] [--quick]
       python benchmarks/bench_gpu.py --samples 100000 --periods 0.5 --chunk-sweep 5000,25000,100000
Writes benchmarks/results/gpu.json (gpu_quick.json with --quick, cpu_check.json on a CPU); with --chunk-sweep,
only the Monte Carlo at each chunk size, to gpu_chunks.json.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

GPU_TARGETS_S = {100_000: 10.0, 1_000_000: 60.0}  # planetary MC over one carrier period on one H100


def _device_summary(jax) -> dict:
    devices = jax.local_devices()
    return dict(
        platform=devices[0].platform,
        device_kind=devices[0].device_kind,
        local_devices=len(devices),
    )


def _smoke(jax, pg, pm, study, dt, n_steps) -> dict:
    """Each solver once at a small size on the default device: time (compilation included) and where the
    result's arrays live."""
    p = pm.default_params()
    system = pm.build(p)
    out = {}

    def record(name, fn, array_of):
        t = time.perf_counter()
        result = fn()
        array = jax.block_until_ready(array_of(result))
        out[name] = dict(
            seconds_including_compilation=time.perf_counter() - t,
            result_on=str(next(iter(array.devices()))),
            finite=bool(jax.numpy.all(jax.numpy.isfinite(array))),
        )
        print(f"  {name:20s} {out[name]['seconds_including_compilation']:7.2f} s on {out[name]['result_on']}")
        return result

    u0 = record("static_equilibrium", lambda: pg.static_equilibrium(system), lambda r: r)
    record("modal_analysis", lambda: pg.modal_analysis(system), lambda r: r.frequencies_hz)
    record(
        "simulate",
        lambda: pg.simulate(system, dt=dt, n_steps=n_steps, initial_displacement=u0, save_every=10),
        lambda r: r.u,
    )
    record(
        "solve_moments",
        lambda: pg.solve_moments(system, dt=dt, n_steps=n_steps, initial_displacement=u0, save_every=10),
        lambda r: r.std_u,
    )
    record(
        "monte_carlo",
        lambda: pg.monte_carlo(
            system,
            n_samples=256,
            key=jax.random.key(0),
            dt=dt,
            n_steps=n_steps,
            initial_displacement=u0,
            save_every=10,
            progress=False,
        ),
        lambda r: r.std_u,
    )
    sens = record(
        "gradient (reverse)",
        lambda: study.sensitivities(p, dt=dt, n_steps=n_steps),
        lambda r: jax.numpy.asarray(r["gradient"]),
    )
    grad, fd = np.asarray(sens["gradient"]), np.asarray(sens["central_difference"])
    out["gradient (reverse)"]["max_relative_difference_to_central_differences"] = float(
        np.max(np.abs(grad - fd) / np.maximum(np.abs(fd), 1e-300))
    )
    out["gradient (reverse)"]["result_on"] = "host (the study returns lists)"
    return out


def _peak_bytes(jax) -> int | None:
    """Peak memory in use on the first local device since the process started (None where JAX does not
    report it, as on the CPU)."""
    stats = jax.local_devices()[0].memory_stats()
    return None if not stats else stats.get("peak_bytes_in_use")


def _planetary_mc(jax, pg, system, kw, mc_every, n_samples, chunk):
    """The planetary Monte Carlo of the benchmark (key 0, no progress bar), waited for; returns std_u."""
    r = pg.monte_carlo(
        system,
        n_samples=n_samples,
        key=jax.random.key(0),
        chunk_size=chunk,
        save_every=mc_every,
        progress=False,
        **kw,
    )
    return jax.block_until_ready(r.std_u)


def _chunk_sweep(jax, pg, system, kw, mc_every, n_samples, args, where, on_gpu) -> int:
    """Monte Carlo of ``n_samples`` at each chunk size of ``--chunk-sweep``: the first call (compilation
    included) and the median of two more."""
    from _common import timed, write

    rows = []
    for chunk in [int(c) for c in args.chunk_sweep.split(",")]:
        first, seconds, runs, _ = timed(
            _planetary_mc, jax, pg, system, kw, mc_every, n_samples, chunk, repeats=2
        )
        rows.append(
            dict(
                chunk_size=chunk,
                first_call_s=first,
                runs_s=runs,
                median_s=seconds,
                ns_per_sample_step=seconds / (n_samples * kw["n_steps"]) * 1e9,
                peak_device_bytes_so_far=_peak_bytes(jax),
            )
        )
        print(
            f"chunk {chunk:>9,}: {seconds:7.2f} s ({rows[-1]['ns_per_sample_step']:.2f} ns per sample-step), "
            f"first call {first:.1f} s"
        )
    name = "gpu_chunks" if on_gpu else "cpu_check_chunks"
    path = write(
        name,
        dict(
            command="python benchmarks/bench_gpu.py " + " ".join(sys.argv[1:]),
            devices=where,
            planetary=dict(n_samples=n_samples, n_steps=kw["n_steps"], mc_save_every=mc_every, chunks=rows),
        ),
    )
    print("wrote", path)
    return 0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", default="100000,1000000", help="Monte Carlo sample counts, comma-separated")
    ap.add_argument("--chunk-size", type=int, default=100_000, help="samples per device per compiled batch")
    ap.add_argument("--periods", type=float, default=1.0, help="carrier periods simulated")
    ap.add_argument("--sl-repeats", type=int, default=3, help="timed SL runs after the first call")
    ap.add_argument(
        "--chunk-sweep",
        default=None,
        help="comma-separated chunk sizes: only time the first --samples count at each (first call, then two "
        "timed calls) and write gpu_chunks.json",
    )
    ap.add_argument("--allow-cpu", action="store_true", help="run on a CPU too (a check of the script)")
    ap.add_argument("--quick", action="store_true", help="small sizes (a check of the script)")
    args = ap.parse_args()

    import jax

    import pgtjax as pg

    if args.allow_cpu:  # a check on a CPU: one device per core (a GPU process keeps its GPUs as devices)
        pg.use_cpu_cores()
    from _common import timed, write

    from pgtjax.models import gear_pair as gp
    from pgtjax.models import planetary as pm
    from pgtjax.studies import planetary as study

    where = _device_summary(jax)
    on_gpu = where["platform"] == "gpu"
    if not on_gpu and not args.allow_cpu:
        print(
            f"bench_gpu: no GPU here (JAX's devices: {jax.local_devices()}); install jax[cuda12] on a GPU "
            "machine, or pass --allow-cpu to check the script on the CPU",
            file=sys.stderr,
        )
        return 1
    samples = [int(s) for s in args.samples.split(",")]
    periods, chunk = args.periods, args.chunk_size
    if args.quick:
        samples, periods, chunk = [2_000, 4_000], 0.02, 1_000
    print(f"devices: {where}")
    dt = 0.0027
    p = pm.default_params()
    n_steps = int(round(periods * study.carrier_period(p) / dt))
    save_every = 5  # as the study: about 20 saves per mesh period
    system, kw, mc_every, _ = study._setup(p, dt, periods, n_saves=max(n_steps // save_every, 1))

    if args.chunk_sweep:
        return _chunk_sweep(jax, pg, system, kw, mc_every, samples[0], args, where, on_gpu)
    name = ("gpu" if on_gpu else "cpu_check") + ("_quick" if args.quick and on_gpu else "")
    report = dict(
        command="python benchmarks/bench_gpu.py " + " ".join(sys.argv[1:]),
        devices=where,
        complete=False,  # set when every stage has run: a stopped run's file says it is partial
        planetary=dict(
            periods=periods,
            n_steps=kw["n_steps"],
            dt_s=dt,
            mc_save_every=mc_every,
            chunk_size_per_device=chunk,
            mc=[],
        ),
    )
    save = lambda: write(name, report)  # noqa: E731

    def mc(n):
        return _planetary_mc(jax, pg, system, kw, mc_every, n, chunk)

    # one round per batch shape the runs will use (monte_carlo's per-device size), timed apart: compilation
    n_dev = where["local_devices"]
    shapes = sorted({min(chunk, -(-n // n_dev)) for n in samples})
    compile_rounds = report["planetary"]["mc_compile_round_s_per_device_batch"] = {}
    for per_device in shapes:
        t = time.perf_counter()
        mc(max(per_device * n_dev, 2))
        compile_rounds[str(per_device)] = time.perf_counter() - t
        print(
            f"planetary MC compilation round, {per_device:,} samples per device: {compile_rounds[str(per_device)]:.1f} s"
        )
        save()
    for n in samples:
        t = time.perf_counter()
        std_u = mc(n)
        seconds = time.perf_counter() - t
        row = dict(
            n_samples=n,
            seconds=seconds,
            ns_per_sample_step=seconds / (n * kw["n_steps"]) * 1e9,
            target_s=GPU_TARGETS_S.get(n) if on_gpu and periods == 1.0 else None,
            finite=bool(np.all(np.isfinite(np.asarray(std_u)))),
            peak_device_bytes_so_far=_peak_bytes(jax),
        )
        report["planetary"]["mc"].append(row)
        target = f" (target {row['target_s']:.0f} s)" if row["target_s"] else ""
        print(
            f"planetary MC {n:>9,} samples x {kw['n_steps']} steps: {seconds:8.2f} s{target}, "
            f"{row['ns_per_sample_step']:.2f} ns per sample-step"
        )
        save()

    gear = gp.build()
    gear_samples, gear_steps = (4_000, 500) if args.quick else (1_000_000, 2_000)

    def gear_mc():
        r = pg.monte_carlo(
            gear,
            n_samples=gear_samples,
            key=jax.random.key(0),
            dt=1e-5,
            n_steps=gear_steps,
            save_every=100,
            chunk_size=gear_samples,
            progress=False,
        )
        return jax.block_until_ready(r.std_u)

    gear_first, gear_s, gear_runs, _ = timed(gear_mc, repeats=3)
    report["gear_pair"] = dict(
        n_samples=gear_samples,
        n_steps=gear_steps,
        first_call_s=gear_first,
        runs_s=gear_runs,
        median_s=gear_s,
        ns_per_sample_step=gear_s / (gear_samples * gear_steps) * 1e9,
    )
    print(
        f"gear pair MC {gear_samples:,} x {gear_steps:,}: {report['gear_pair']['ns_per_sample_step']:.2f} ns per "
        f"sample-step (median of 3; first call {gear_first:.1f} s)"
    )
    save()

    sl = lambda: jax.block_until_ready(pg.solve_moments(system, save_every=mc_every, **kw).std_u)  # noqa: E731
    t = time.perf_counter()
    sl()
    sl_first = time.perf_counter() - t
    sl_runs = []
    for _ in range(args.sl_repeats):
        t = time.perf_counter()
        sl()
        sl_runs.append(time.perf_counter() - t)
    sl_median = float(np.median(sl_runs)) if sl_runs else None
    report["planetary"].update(sl_first_call_s=sl_first, sl_runs_s=sl_runs, sl_median_s=sl_median)
    shown = f"{sl_median:.2f} s (median of {len(sl_runs)})" if sl_runs else "not repeated"
    print(f"planetary SL + recursion, {kw['n_steps']} steps: {shown}, first call {sl_first:.1f} s")
    save()

    print("every solver once (compilation included):")
    report["smoke"] = _smoke(jax, pg, pm, study, dt, 200)
    report["peak_device_bytes"] = _peak_bytes(jax)
    report["complete"] = True
    print("wrote", save())
    return 0


if __name__ == "__main__":
    sys.exit(main())
