"""Sharded Monte Carlo on forced CPU devices: the same run on one device and sharded over N devices of the same
process (``--xla_force_host_platform_device_count=N``), timed alternately, with the largest relative difference of
their statistics. On a CPU the N devices share the machine's cores, so this measures what sharding itself costs
(or, when one device leaves cores idle, what it gains).

Usage: python benchmarks/bench_sharding.py [--devices 2] [--repeats 5] [--gear-samples 20000] [--gear-steps 2000]
       [--planetary-samples 4000] [--planetary-steps 1000]
Writes benchmarks/results/sharding.json. Each configuration runs in a fresh process (the device count is fixed
when JAX starts); compile time is reported apart (first call).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path


def _worker(args) -> dict:
    import jax
    import numpy as np
    from _common import machine

    import pgtjax as pg
    from pgtjax.models import gear_pair as gp
    from pgtjax.models import planetary as pm

    def cases():
        yield "gear_pair", gp.build(), 1e-5, args.gear_samples, args.gear_steps
        p = pm.default_params()
        yield "planetary", pm.build(p), 0.0027, args.planetary_samples, args.planetary_steps

    devices = jax.local_devices()
    out = dict(machine=machine(), cases={})
    for name, system, dt, n_samples, n_steps in cases():
        save_every = n_steps // 10
        per_device = -(-n_samples // len(devices))

        def run(devs, chunk):
            return pg.monte_carlo(
                system,
                n_samples=n_samples,
                key=jax.random.key(1),
                dt=dt,
                n_steps=n_steps,
                save_every=save_every,
                chunk_size=chunk,
                devices=devs,
                progress=False,
            )

        # one device: all samples in one batch; N devices: n_samples / N each, so both make one compiled call
        configs = {"1 device": ([devices[0]], n_samples), f"{len(devices)} devices": (devices, per_device)}
        rows = {}
        for label, (devs, chunk) in configs.items():
            t = time.perf_counter()
            result = run(devs, chunk)
            rows[label] = dict(first_call_s=time.perf_counter() - t, runs_s=[], result=result)
        for _ in range(args.repeats):
            for label, (devs, chunk) in configs.items():
                t = time.perf_counter()
                run(devs, chunk)
                rows[label]["runs_s"].append(time.perf_counter() - t)
        ref = rows["1 device"].pop("result")
        for label, row in rows.items():
            result = row.pop("result", ref)
            row["median_s"] = statistics.median(row["runs_s"])
            row["ns_per_sample_step"] = row["median_s"] / (n_samples * n_steps) * 1e9
            row["max_rel_diff_vs_1_device"] = max(
                float(np.max(np.abs(np.asarray(getattr(result, f)) - np.asarray(getattr(ref, f)))))
                / float(np.max(np.abs(np.asarray(getattr(ref, f)))))
                for f in ("mean_u", "std_u", "force_mean", "force_std")
            )
        many = rows[f"{len(devices)} devices"]
        out["cases"][name] = dict(
            n_samples=n_samples,
            n_steps=n_steps,
            n_dof=system.n_dof,
            runs=rows,
            time_ratio_n_devices_over_1=many["median_s"] / rows["1 device"]["median_s"],
        )
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--devices", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--gear-samples", type=int, default=20_000)
    parser.add_argument("--gear-steps", type=int, default=2_000)
    parser.add_argument("--planetary-samples", type=int, default=4_000)
    parser.add_argument("--planetary-steps", type=int, default=1_000)
    parser.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker is not None:
        args.worker.write_text(json.dumps(_worker(args)))
        return
    scratch = Path(__file__).parent / "results" / ".sharding-worker.json"
    env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={args.devices}")
    subprocess.run([sys.executable, __file__, *sys.argv[1:], "--worker", str(scratch)], env=env, check=True)
    data = json.loads(scratch.read_text())
    scratch.unlink()
    from _common import write

    path = write(
        "sharding",
        dict(
            description="Monte Carlo on 1 device and sharded over N forced CPU devices of one process, "
            "timed alternately; both configurations use the same cores",
            n_devices=args.devices,
            repeats=args.repeats,
            command="python benchmarks/bench_sharding.py " + " ".join(sys.argv[1:]),
            cases=data["cases"],
        ),
        machine_info=data["machine"],
    )
    for name, case in data["cases"].items():
        for label, row in case["runs"].items():
            print(
                f"{name:10s} {label:10s} compile+run {row['first_call_s']:6.2f} s, median {row['median_s']:6.3f} s, "
                f"{row['ns_per_sample_step']:7.1f} ns/sample-step, max rel diff {row['max_rel_diff_vs_1_device']:.1e}"
            )
        print(f"{name:10s} time ratio N devices / 1 device: {case['time_ratio_n_devices_over_1']:.3f}")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
