"""Time the core operations of the four benchmarks with the OLD and the NEW tree, alternately, in one run.

For each benchmark (gear_pair, planetary, ring, back_to_back) one subprocess per tree and round, in the order
old, new, old, new, ... for ``--rounds`` rounds. Each subprocess (this script with ``--worker``, run with
``PYTHONPATH=<tree>``) imports pgtjax from that tree, builds the system as the benchmark does, calls each
operation once (compilation + one run: ``first_call_s``; ``compile_s`` = first call - median) and then
``--repeats`` times (``jax.block_until_ready`` after each), and prints one JSON line. Per operation the report
gives the median of every timed run of each tree (all rounds pooled), the ratio new/old, whether it is within
5 %, each round's median (their spread shows the machine's noise) and whether both trees computed the same
number (a checksum of the output, relative 1e-10).

Sizes are smaller than the benchmarks' (the whole run takes minutes on 2 cores); the defaults are printed
and saved with the benchmark sizes beside them; ``--size bench.key=value`` changes one.

Usage: python3 benchmarks/compare_timing.py [--old /tmp/baseline] [--new REPO] [--rounds 3] [--repeats 5]
       [--only gear_pair,ring] [--size planetary.mc_samples=2000] [--strict]
       [--report benchmarks/results/compare_timing.json]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_REPORT = REPO / "benchmarks" / "results" / "compare_timing.json"
MARK = "@@compare_timing@@ "
TOLERANCE = 0.05

#: default sizes of this script, and the benchmark's own (bench_*.py defaults) for reference
SIZES = {
    "gear_pair": dict(sl_steps=10_000, mc_samples=2000, mc_steps=5000),
    "planetary": dict(sl_steps=2500, grad_steps=1000, grad_save_every=1, mc_samples=1000, mc_steps=500),
    "ring": dict(steps_per_mesh=16),
    "back_to_back": dict(t_end=0.3),
}
BENCH_SIZES = {
    "gear_pair": dict(sl_steps=10_000, mc_samples=20_000, mc_steps=10_000),
    "planetary": dict(
        sl_steps=10_022, grad_steps=10_022, grad_save_every="1,2", mc_samples=2000, mc_steps=2500
    ),
    "ring": dict(steps_per_mesh=32),
    "back_to_back": dict(t_end=1.0),
}


# ------------------------------------------------------------------------------------------------ workers
# Run in the subprocess, with the tree under test first on PYTHONPATH; each returns its operation records.


def _record(op: str, what: str, first: float, median: float, runs: list, out) -> dict:
    import jax
    import jax.numpy as jnp

    leaves = [x for x in jax.tree_util.tree_leaves(out) if hasattr(x, "dtype")]
    check = float(sum(jnp.sum(jnp.abs(x.astype(jnp.float64))) for x in leaves))
    return dict(
        op=op,
        what=what,
        first_call_s=first,
        compile_s=first - median,
        median_s=median,
        runs_s=runs,
        check=check,
    )


def _interleaved(fns: dict, *args, repeats: int) -> dict:
    """:func:`_common.timed_interleaved` that also keeps each function's last output."""
    import jax

    out = {}
    for name, fn in fns.items():
        t = time.perf_counter()
        value = jax.block_until_ready(fn(*args))
        out[name] = dict(first=time.perf_counter() - t, runs=[], value=value)
    for _ in range(repeats):
        for name, fn in fns.items():
            t = time.perf_counter()
            out[name]["value"] = jax.block_until_ready(fn(*args))
            out[name]["runs"].append(time.perf_counter() - t)
    return out


def work_gear_pair(sz: dict, repeats: int) -> list:
    """bench_gear_pair.py: SL + recursion, and MC (one chunk), at dt = 1e-5 s."""
    import jax
    from _common import timed

    import pgtjax as pg
    from pgtjax.models import gear_pair as gp

    system, dt = gp.gear_pair(gp.default_params()), 1e-5
    n_sl, n_mc, samples = sz["sl_steps"], sz["mc_steps"], sz["mc_samples"]

    def sl():
        return pg.solve_moments(system, dt=dt, n_steps=n_sl, save_every=100)

    def mc():
        return pg.monte_carlo(
            system,
            n_samples=samples,
            key=jax.random.key(0),
            dt=dt,
            n_steps=n_mc,
            save_every=100,
            chunk_size=samples,
            progress=False,
        ).mean_u

    first, med, runs, out = timed(sl, repeats=repeats)
    rows = [_record("gear_pair SL forward", f"solve_moments, {n_sl} steps", first, med, runs, out.std_u)]
    first, med, runs, out = timed(mc, repeats=repeats)
    rows.append(_record("gear_pair MC", f"monte_carlo {samples} x {n_mc} steps", first, med, runs, out))
    return rows


def work_planetary(sz: dict, repeats: int) -> list:
    """bench_planetary.py: SL, a scalar of an SL run and its reverse-mode gradient (calls alternating), and MC
    in eigen-coordinates (one chunk), at the thesis's dt = 0.0027 s."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp
    from _common import timed

    import pgtjax as pg
    from pgtjax.models import planetary as pm

    p = pm.default_params()
    lay = pm.layout(p)
    system = pm.planetary(p)
    u_eq = pg.static_equilibrium(system)
    p0 = pm.wind_filter_stationary_covariance(p, lay)
    dt = 0.0027
    n_sl, n_grad, every = sz["sl_steps"], sz["grad_steps"], sz["grad_save_every"]
    samples, n_mc = sz["mc_samples"], sz["mc_steps"]

    def sl():
        return pg.solve_moments(
            system, dt=dt, n_steps=n_sl, save_every=2, initial_displacement=u_eq, initial_covariance=p0
        ).std_u

    first, med, runs, out = timed(sl, repeats=repeats)
    rows = [
        _record("planetary SL forward", f"solve_moments, {n_sl} steps, save_every 2", first, med, runs, out)
    ]

    node = lay.ring_start + 6
    x = jnp.array([float(p.ring.thickness), 1.362e10])

    def loss(x):
        ring = eqx.tree_at(
            lambda r: (r.thickness, r.radius, r.k_support_radial),
            p.ring,
            (x[0], p.ring_pitch_radius + x[0] / 2, x[1]),
        )
        q = eqx.tree_at(lambda z: z.ring, p, ring)
        r = pg.solve_moments(
            pm.planetary(q),
            dt=dt,
            n_steps=n_grad,
            save_every=every,
            initial_displacement=u_eq,
            initial_covariance=p0,
        )
        return jnp.max(r.std_u[:, node])

    t = _interleaved({"forward": jax.jit(loss), "gradient": jax.jit(jax.grad(loss))}, x, repeats=repeats)
    for name in ("forward", "gradient"):
        r = t[name]
        rows.append(
            _record(
                f"planetary SL {'scalar forward' if name == 'forward' else 'reverse-mode gradient'}",
                f"jit{'' if name == 'forward' else '(grad)'} of max std, {n_grad} steps, save_every {every}",
                r["first"],
                statistics.median(r["runs"]),
                r["runs"],
                r["value"],
            )
        )

    def mc():
        return pg.monte_carlo(
            system,
            n_samples=samples,
            key=jax.random.key(1),
            dt=dt,
            n_steps=n_mc,
            save_every=10,
            chunk_size=samples,
            initial_displacement=u_eq,
            initial_covariance=p0,
            progress=False,
            propagation="eigen",
        ).std_u

    first, med, runs, out = timed(mc, repeats=repeats)
    rows.append(
        _record("planetary MC (eigen)", f"monte_carlo {samples} x {n_mc} steps", first, med, runs, out)
    )
    return rows


def work_ring(sz: dict, repeats: int) -> list:
    """bench_ring.py: SL of the 108-DOF ring under 3 moving loads over one revolution and the gradient of the
    mid-node's max std w.r.t. rim thickness and bolt stiffness (calls alternating)."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    import pgtjax as pg
    from pgtjax.models import ring_moving_load as rml

    p0 = rml.default_params()
    n = int(round(float(p0.mesh_frequency_ratio))) * sz["steps_per_mesh"]
    dt = float(p0.revolution_time) / n
    mid = f"ring_node{rml.mid_node(p0.ring)}_radial"

    def build(thickness, k_radial):
        ring = eqx.tree_at(lambda r: (r.thickness, r.k_support_radial), p0.ring, (thickness, k_radial))
        q = eqx.tree_at(lambda q: q.ring, p0, ring)
        if hasattr(rml, "build"):  # outputs are Observables, no observer DOF to switch off
            return rml.build(q)
        return rml.ring_moving_load_system(q, observe_contact=False)  # the tree before that change

    system = build(p0.ring.thickness, p0.ring.k_support_radial)
    u0, v0 = rml.static_initial_state(system)
    j = system.dof_names.index(mid)

    @jax.jit
    def forward(thickness, k_radial):
        r = pg.solve_moments(
            build(thickness, k_radial),
            dt=dt,
            n_steps=n,
            save_every=n // 144,
            initial_displacement=u0,
            initial_velocity=v0,
        )
        return r.mean_u, r.std_u

    grad = jax.jit(jax.grad(lambda h, k: jnp.max(forward(h, k)[1][:, j]), argnums=(0, 1)))
    t = _interleaved(
        {"forward": forward, "gradient": grad}, p0.ring.thickness, p0.ring.k_support_radial, repeats=repeats
    )
    return [
        _record(
            f"ring SL {name}",
            f"{'jit' if name == 'forward' else 'jit(grad)'}, {n} steps, 108 DOFs",
            t[name]["first"],
            statistics.median(t[name]["runs"]),
            t[name]["runs"],
            t[name]["value"],
        )
        for name in ("forward", "gradient")
    ]


def work_back_to_back(sz: dict, repeats: int) -> list:
    """bench_back_to_back.py: deterministic Newmark-Newton simulate of the bench's run-up at dt = 1e-4 s
    (the benchmark's parameters, its first ``t_end`` seconds)."""
    from _common import timed

    import pgtjax as pg
    from pgtjax.models import back_to_back as bb

    dt = 1e-4
    build_model = getattr(bb, "build_model", bb.build)  # the old tree named it build
    model = build_model(bb.default_params(ramp_start=0.0, ramp_duration=1.0))
    u0, v0 = bb.initial_state(model, 0.5 * dt)
    n = int(round(sz["t_end"] / dt))

    def run():
        return pg.simulate(
            model.system, t0=0.5 * dt, dt=dt, n_steps=n, initial_displacement=u0, initial_velocity=v0
        )

    first, med, runs, out = timed(run, repeats=repeats)
    return [
        _record(
            "back_to_back simulate",
            f"simulate, {n} steps, 12 DOF, 12 Hertzian contacts",
            first,
            med,
            runs,
            (out.u, out.v),
        )
    ]


WORKERS = {
    "gear_pair": work_gear_pair,
    "planetary": work_planetary,
    "ring": work_ring,
    "back_to_back": work_back_to_back,
}


def worker(name: str, sizes: dict, repeats: int) -> int:
    import pgtjax

    start = time.perf_counter()
    rows = WORKERS[name](sizes, repeats)
    print(
        MARK + json.dumps(dict(pgtjax=pgtjax.__file__, rows=rows, wall_s=time.perf_counter() - start)),
        flush=True,
    )
    return 0


# -------------------------------------------------------------------------------------------- orchestration


def run_worker(
    label: str, tree: Path, name: str, sizes: dict, repeats: int, python: str, timeout: float
) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(PYTHONPATH=str(tree), MPLBACKEND="Agg", PYTHONDONTWRITEBYTECODE="1")
    cmd = [
        python,
        str(Path(__file__).resolve()),
        "--worker",
        name,
        "--repeats",
        str(repeats),
        "--sizes",
        json.dumps(sizes),
    ]
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="compare_timing_") as cwd:
        p = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - start
    lines = [x for x in p.stdout.splitlines() if x.startswith(MARK)]
    if p.returncode != 0 or not lines:
        raise RuntimeError(f"{name} with the {label} tree failed (rc {p.returncode}):\n{p.stderr[-3000:]}")
    out = json.loads(lines[-1][len(MARK) :])
    if not out["pgtjax"].startswith(str(tree) + os.sep):
        raise RuntimeError(f"{label}: pgtjax imported from {out['pgtjax']}, not from {tree}")
    return dict(out, argv=cmd, pythonpath=str(tree), process_wall_s=wall)


def source_digest(tree: Path) -> str:
    """Hash of the package's sources (.py, .toml): shows whether a tree changed during the run."""
    h = hashlib.sha256()
    for p in sorted((tree / "pgtjax").rglob("*")):
        if p.is_file() and p.suffix in (".py", ".toml"):
            h.update(p.relative_to(tree).as_posix().encode() + b"\0" + p.read_bytes())
    return h.hexdigest()[:16]


def _same(a: float, b: float) -> bool:
    return abs(a - b) <= 1e-10 * max(abs(a), abs(b))


def summarize(name: str, rounds: list) -> list:
    """Per operation: pooled medians, ratio, per-round medians and compile times of each tree."""
    rows = []
    for k, first in enumerate(rounds[0]["old"]["rows"]):
        row = dict(benchmark=name, op=first["op"], what=first["what"])
        for label in ("old", "new"):
            recs = [r[label]["rows"][k] for r in rounds]
            runs = [x for rec in recs for x in rec["runs_s"]]
            row[label] = dict(
                median_s=statistics.median(runs),
                min_s=min(runs),
                round_medians_s=[rec["median_s"] for rec in recs],
                compile_s=[rec["compile_s"] for rec in recs],
                first_call_s=[rec["first_call_s"] for rec in recs],
                runs_s=runs,
                check=recs[0]["check"],
                same_check_every_round=all(_same(rec["check"], recs[0]["check"]) for rec in recs),
            )
        row["ratio_new_old"] = row["new"]["median_s"] / row["old"]["median_s"]
        row["within_5pct"] = abs(row["ratio_new_old"] - 1.0) <= TOLERANCE
        row["ratio_of_minima"] = row["new"]["min_s"] / row["old"]["min_s"]
        # the noise: largest (max/min - 1) of either tree's round medians; above 5 % the verdict is unsure
        medians = (row[x]["round_medians_s"] for x in ("old", "new"))
        row["round_spread"] = max(max(m) / min(m) - 1.0 for m in medians)
        row["noisy"] = row["round_spread"] > TOLERANCE
        row["same_result"] = _same(row["old"]["check"], row["new"]["check"])
        rows.append(row)
    return rows


def write_json_atomic(path: Path, payload: dict):
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    with os.fdopen(fd, "w") as fh:
        json.dump(payload, fh, indent=2)
    os.replace(tmp, path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument(
        "--old", type=Path, default=Path("/tmp/baseline"), help="pre-refactor tree (default %(default)s)"
    )
    ap.add_argument("--new", type=Path, default=REPO, help="refactored tree (default: this repository)")
    ap.add_argument(
        "--rounds", type=int, default=3, help="old/new subprocess pairs per benchmark (default 3)"
    )
    ap.add_argument(
        "--repeats", type=int, default=5, help="timed calls per operation and subprocess (default 5)"
    )
    ap.add_argument("--only", default=None, help=f"comma-separated benchmarks among {', '.join(WORKERS)}")
    ap.add_argument(
        "--size",
        action="append",
        default=[],
        metavar="BENCH.KEY=VALUE",
        help="override a size, e.g. planetary.mc_samples=2000 (repeatable)",
    )
    ap.add_argument(
        "--timeout", type=float, default=900.0, help="seconds per subprocess (default %(default)s)"
    )
    ap.add_argument("--python", default=sys.executable, help="interpreter of the subprocesses")
    ap.add_argument("--report", type=Path, default=DEFAULT_REPORT, help="JSON report (default %(default)s)")
    ap.add_argument("--strict", action="store_true", help="exit status 1 when an operation is outside 5 %%")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--sizes", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        return worker(args.worker, json.loads(args.sizes), args.repeats)

    names = list(WORKERS) if args.only is None else [n.strip() for n in args.only.split(",") if n.strip()]
    if not names or any(n not in WORKERS for n in names):
        ap.error(f"--only: choose among {', '.join(WORKERS)}")
    sizes = {n: dict(SIZES[n]) for n in WORKERS}
    for item in args.size:
        key, _, value = item.partition("=")
        bench, _, field = key.partition(".")
        if bench not in sizes or field not in sizes[bench] or not value:
            ap.error(f"--size {item!r}: expected BENCH.KEY=VALUE with keys {json.dumps(SIZES)}")
        sizes[bench][field] = type(SIZES[bench][field])(value)
    if args.rounds < 1 or args.repeats < 1:
        ap.error("--rounds and --repeats must be >= 1")
    trees = {"old": args.old.resolve(), "new": args.new.resolve()}
    for label, tree in trees.items():
        if not (tree / "pgtjax" / "__init__.py").is_file():
            ap.error(f"--{label} {tree}: no pgtjax package there")

    print("sizes (reduced from the benchmarks' defaults, given in brackets):")
    for n in names:
        print(f"  {n}: " + ", ".join(f"{k} {v} [{BENCH_SIZES[n][k]}]" for k, v in sizes[n].items()))
    print(
        f"{args.rounds} rounds x (old, new), {args.repeats} timed calls per operation and subprocess",
        flush=True,
    )
    digests = {label: source_digest(tree) for label, tree in trees.items()}
    start = time.perf_counter()
    results, rows = {}, []
    errors = {}
    for n in names:
        rounds = []
        try:
            for r in range(args.rounds):
                rounds.append({})
                for label in ("old", "new"):
                    out = run_worker(
                        label, trees[label], n, sizes[n], args.repeats, args.python, args.timeout
                    )
                    rounds[-1][label] = out
                    ops = ", ".join(f"{x['op']} {x['median_s']:.3f} s" for x in out["rows"])
                    print(f"  {n} round {r + 1} {label}: {out['process_wall_s']:.1f} s ({ops})", flush=True)
        except (RuntimeError, subprocess.TimeoutExpired) as err:
            errors[n] = str(err)
            print(f"error: {err}", file=sys.stderr)
            continue
        results[n] = rounds
        rows += summarize(n, rounds)
    total = time.perf_counter() - start
    changed = [label for label, tree in trees.items() if source_digest(tree) != digests[label]]
    for label in changed:
        print(f"warning: the {label} tree's sources changed during the run", file=sys.stderr)

    head = (
        f"{'operation':36s} {'old s':>7s} {'new s':>7s} {'new/old':>7s} {'5 %':>4s} {'spread':>7s} "
        f"{'min ratio':>9s} {'compile old':>11s} {'compile new':>11s} {'same':>4s}"
    )
    print("\n" + head + "\n" + "-" * len(head))
    for row in rows:
        c_old, c_new = (statistics.median(row[x]["compile_s"]) for x in ("old", "new"))
        print(
            f"{row['op']:36s} {row['old']['median_s']:7.4f} {row['new']['median_s']:7.4f} "
            f"{row['ratio_new_old']:7.3f} {('yes' if row['within_5pct'] else 'NO') + '*' * row['noisy']:>4s} "
            f"{100 * row['round_spread']:6.1f}% {row['ratio_of_minima']:9.3f} {c_old:11.2f} {c_new:11.2f} "
            f"{'yes' if row['same_result'] else 'NO':>4s}"
        )
    print(
        f"\nmedians of all timed calls ({args.rounds} rounds x {args.repeats}); spread = largest max/min - 1 "
        "of one tree's round medians (machine noise; * = above 5 %, the verdict is unsure);\nmin ratio = "
        "fastest new / fastest old call; compile = first call - median (median over rounds); same = output "
        f"checksums equal to 1e-10; total {total:.0f} s"
    )

    from _common import machine  # imports jax: only now, in the orchestrator

    payload = dict(
        date=time.strftime("%Y-%m-%d %H:%M:%S"),
        machine=machine(),
        command=[sys.executable, *sys.argv],
        trees={
            k: dict(path=str(v), source_digest=digests[k], changed_during_run=k in changed)
            for k, v in trees.items()
        },
        rounds=args.rounds,
        repeats=args.repeats,
        tolerance=TOLERANCE,
        sizes={n: sizes[n] for n in names},
        reduced_sizes_note="sizes reduced from the benchmarks' defaults (benchmark_sizes): a short run",
        benchmark_sizes={n: BENCH_SIZES[n] for n in names},
        total_wall_s=total,
        operations=rows,
        subprocesses={
            n: [
                {label: {k: v for k, v in rd[label].items() if k != "rows"} for label in rd}
                for rd in results[n]
            ]
            for n in results
        },
        errors=errors,
    )
    write_json_atomic(args.report, payload)
    print(f"report: {args.report.resolve()}")
    slow = [row["op"] for row in rows if not row["within_5pct"]]
    return 1 if errors or (args.strict and slow) else 0


if __name__ == "__main__":
    sys.exit(main())
