"""Design batches on each device: ``pgtjax.design.evaluate`` of the README's design problem (the bolts' 12
log-mapped stiffnesses; the ring's deformation at the three meshes plus 0.2 x the support stiffness) over
random designs, one after the other (``batch_size=None``: one compiled loop) and ``vmap``-ed
(``batch_size=k``), on the default device (a GPU where there is one) and on the CPU, in one process.

Each design runs SL over ``--periods`` carrier periods from its own static equilibrium. On a GPU a step of
one design is a few hundred small kernels whose launches cost more than their arithmetic, so ``vmap``-ing
designs should cost little more per call than one design: the seconds per design are the figure. Every
configuration is called once to compile (reported apart), then ``--repeats`` times, the configurations
alternating. The first ``--sequential`` vmapped designs' values are checked against their one-by-one values.

Usage: python benchmarks/bench_design_batch.py [--periods 0.1] [--sequential 8] [--batches 32,128]
       [--cpu-batches 32] [--repeats 2] [--quick]
Writes benchmarks/results/design_batch_<platform>.json (``_quick`` with --quick), rewritten after each
configuration's first call (so that a run stopped part-way keeps its compilation times) and at the end.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--periods", type=float, default=0.1, help="carrier periods each design is simulated")
    ap.add_argument("--sequential", type=int, default=8, help="designs evaluated one after the other")
    ap.add_argument("--batches", default="32,128", help="vmap sizes on the default device, comma-separated")
    ap.add_argument("--cpu-batches", default="32", help="vmap sizes on the CPU ('' for none)")
    ap.add_argument("--repeats", type=int, default=2, help="timed calls of each configuration")
    ap.add_argument("--quick", action="store_true", help="small sizes (a check of the script)")
    args = ap.parse_args()
    if args.quick:
        args.periods, args.sequential, args.batches, args.cpu_batches, args.repeats = 0.002, 2, "4", "4", 1

    import jax
    from _common import write

    import pgtjax as pg  # noqa: F401 (float64)
    from pgtjax import design as pd
    from pgtjax._parallel import _available_cores, lapack_batches_wait_on_pool
    from pgtjax.models import planetary as pm

    default, cpu = jax.devices()[0], jax.devices("cpu")[0]
    p = pm.default_params()
    problem = pd.DesignProblem(
        pd.DesignSpace(p, pd.bolt_variables(p)),
        pd.planetary_response(p, periods=args.periods),
        pd.Std(["ring_mesh1", "ring_mesh2", "ring_mesh3"]),
        [pd.SupportStiffness(weight=0.2)],
    )
    batches = [int(b) for b in args.batches.split(",") if b]
    cpu_batches = [int(b) for b in args.cpu_batches.split(",") if b]
    n_all = max([args.sequential, *batches, *cpu_batches])
    zs = np.random.default_rng(0).normal(0.0, 0.3, (n_all, problem.space.n))  # around the symmetric design

    skipped = None
    cpu_vmap_can_hang = lapack_batches_wait_on_pool() and _available_cores() > 1  # docs/performance.md
    if cpu_vmap_can_hang:
        skipped = f"vmap on the CPU skipped: jaxlib {jax.__version__}'s batched LAPACK calls can hang"
    configurations = [(default, None, args.sequential)]
    if not (default.platform == "cpu" and cpu_vmap_can_hang):
        configurations += [(default, b, b) for b in batches]
    if cpu.platform != default.platform:
        configurations += [(cpu, None, args.sequential)]
        if not cpu_vmap_can_hang:
            configurations += [(cpu, b, b) for b in cpu_batches]

    def run(device, batch_size, n):
        return pd.evaluate(problem, zs[:n], devices=[device], batch_size=batch_size).value

    rows, values = [], {}
    name = f"design_batch_{default.platform}" + ("_quick" if args.quick else "")
    n_steps = int(problem.response.n_steps)

    def save():
        payload = dict(
            command="python benchmarks/bench_design_batch.py " + " ".join(sys.argv[1:]),
            periods=args.periods,
            n_steps=n_steps,
            n_variables=problem.space.n,
            default_device=default.device_kind,
            skipped=skipped,
            rows=rows,
        )
        return write(name, payload)

    # compile each configuration (first call), then the timed calls alternate between configurations
    for device, batch_size, n in configurations:
        t = time.perf_counter()
        values[(str(device), batch_size)] = np.asarray(jax.block_until_ready(run(device, batch_size, n)))
        rows.append(
            dict(
                device=str(device),
                batch_size=batch_size,
                n_designs=n,
                first_call_s=time.perf_counter() - t,
                runs_s=[],
            )  # fmt: skip
        )
        print(
            f"{rows[-1]['device']:8s} batch {str(batch_size):>5s}: first call {rows[-1]['first_call_s']:.1f} s"
        )
        save()
    for _ in range(args.repeats):
        for row, (device, batch_size, n) in zip(rows, configurations):
            t = time.perf_counter()
            jax.block_until_ready(run(device, batch_size, n))
            row["runs_s"].append(time.perf_counter() - t)
    for row, (device, batch_size, n) in zip(rows, configurations):
        row["median_s"] = float(np.median(row["runs_s"]))
        row["s_per_design"] = row["median_s"] / n
        one_by_one = values[(str(device), None)]
        common = min(len(one_by_one), n)  # the designs evaluated both ways
        mine = values[(str(device), batch_size)][:common]
        row["largest_relative_difference_to_one_by_one"] = float(
            np.max(np.abs(mine / one_by_one[:common] - 1.0))
        )
        row["finite"] = bool(np.all(np.isfinite(values[(str(device), batch_size)])))
        print(
            f"{row['device']:8s} batch {str(batch_size):>5s}: {row['median_s']:7.2f} s for {n} designs, "
            f"{row['s_per_design'] * 1e3:8.1f} ms per design; values vs one by one "
            f"{row['largest_relative_difference_to_one_by_one']:.1e}"
        )
    if skipped:
        print(skipped)
    print("wrote", save())
    return 0


if __name__ == "__main__":
    sys.exit(main())
