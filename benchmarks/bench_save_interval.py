"""Monte Carlo time and peak memory against the save interval (gear pair and planetary), with a saved block's
random draws and step inputs formed a part at a time (``pgtjax._parallel.CPU_DRAW_BYTES``, the default) and,
for comparison, for the whole block at once (what Monte Carlo did before 2026-11-28). Writes
benchmarks/results/save_interval.json and save_interval.png.

Each point (model, save interval, way of drawing) runs in a fresh process on one JAX device per core, which
reports its first call (compilation included) apart, the median of ``--repeats`` further calls and its peak
resident set size (``ru_maxrss``). The two ways of drawing run one after the other for each save interval,
in alternating order from one interval to the next.

Usage: python benchmarks/bench_save_interval.py [--quick] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
from pathlib import Path

SIZES = {  # model: (samples, steps, save intervals)
    "gear_pair": (20_000, 2_000, [10, 100, 500, 2_000]),
    "planetary": (20_000, 1_000, [5, 50, 250, 1_000]),
}
QUICK_SIZES = {"gear_pair": (2_000, 200, [10, 200]), "planetary": (1_000, 100, [10, 100])}
WHOLE_BLOCKS = 2**62  # a budget no block exceeds: every block drawn at once


def _point(model: str, n_samples: int, n_steps: int, save_every: int, whole: bool, repeats: int) -> dict:
    """One point, in its own process (module docstring)."""
    import pgtjax as pg

    pg.use_cpu_cores()
    import jax

    from pgtjax import _parallel
    from pgtjax.models import gear_pair as gp
    from pgtjax.models import planetary as pm

    if whole:
        _parallel.CPU_DRAW_BYTES = WHOLE_BLOCKS
    system, dt = (gp.build(), 1e-5) if model == "gear_pair" else (pm.build(pm.default_params()), 0.0027)

    def run():
        r = pg.monte_carlo(
            system,
            n_samples=n_samples,
            key=jax.random.key(0),
            dt=dt,
            n_steps=n_steps,
            save_every=save_every,
            progress=False,
        )
        return jax.block_until_ready(r.std_u)

    from _common import timed

    first, median, runs, _ = timed(run, repeats=repeats)
    return dict(
        save_every=save_every,
        drawn="whole block" if whole else "in parts",
        first_call_s=first,
        runs_s=runs,
        median_s=median,
        ns_per_sample_step=median / (n_samples * n_steps) * 1e9,
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    )


def _figure(data: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), constrained_layout=True)
    for model, color in (("gear_pair", "C0"), ("planetary", "C1")):
        entry = data["models"][model]
        for drawn, style in (("in parts", "o-"), ("whole block", "s--")):
            rows = [r for r in entry["points"] if r["drawn"] == drawn]
            x = [r["save_every"] for r in rows]
            label = f"{model}, {drawn}"
            axes[0].loglog(x, [r["ns_per_sample_step"] for r in rows], style, color=color, label=label)
            axes[1].semilogx(x, [r["peak_rss_mb"] for r in rows], style, color=color, label=label)
    axes[0].set(
        xlabel="save interval (steps)", ylabel="ns per sample-step (median)", title="Monte Carlo time"
    )
    axes[1].set(
        xlabel="save interval (steps)", ylabel="peak resident memory (MB)", title="Monte Carlo memory"
    )
    axes[1].set_ylim(0, None)
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    sizes = ", ".join(f"{m} {e['n_samples']:,} x {e['n_steps']:,}" for m, e in data["models"].items())
    fig.suptitle(
        f"Monte Carlo against the save interval ({sizes}; {data['cpu_devices']} CPU devices)", fontsize=9
    )
    fig.savefig(path, dpi=200)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="small sizes (a check of the script)")
    parser.add_argument("--figure-only", action="store_true", help="redraw the figure from the JSON")
    parser.add_argument("--point", nargs=6, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.point:
        model, n, s, every, whole, out = args.point
        row = _point(model, int(n), int(s), int(every), whole == "whole", args.repeats)
        Path(out).write_text(json.dumps(row))
        return
    from _common import RESULTS, machine, write

    name = "save_interval_quick" if args.quick else "save_interval"
    if args.figure_only:
        _figure(json.loads((RESULTS / f"{name}.json").read_text()), RESULTS / f"{name}.png")
        return
    import pgtjax as pg

    n_devices = pg.use_cpu_cores()
    scratch = RESULTS / ".save-interval-point.json"
    models = {}
    for model, (n_samples, n_steps, intervals) in (QUICK_SIZES if args.quick else SIZES).items():
        points = []
        for i, every in enumerate(intervals):
            for whole in (False, True) if i % 2 == 0 else (True, False):
                cmd = [sys.executable, __file__, "--repeats", str(args.repeats), "--point", model]
                cmd += [str(n_samples), str(n_steps), str(every), "whole" if whole else "parts", str(scratch)]
                subprocess.run(cmd, check=True)
                points.append(json.loads(scratch.read_text()))
                scratch.unlink()
                row = points[-1]
                print(
                    f"{model:10s} saved every {every:5d}, {row['drawn']:11s}: {row['ns_per_sample_step']:7.2f} "
                    f"ns/sample-step (first call {row['first_call_s']:.1f} s), peak {row['peak_rss_mb']:.0f} MB",
                    flush=True,
                )
        points.sort(key=lambda r: (r["drawn"], r["save_every"]))
        models[model] = dict(n_samples=n_samples, n_steps=n_steps, points=points)
    data = dict(
        description=(
            "Monte Carlo time and peak memory against the save interval; a block's draws and step inputs formed "
            "in parts of at most CPU_DRAW_BYTES (the default) or for the whole block at once"
        ),
        command="python benchmarks/bench_save_interval.py " + " ".join(sys.argv[1:]),
        repeats=args.repeats,
        cpu_devices=n_devices,
        draw_bytes_per_device=_draw_bytes(),
        models=models,
    )
    path = write(name, data, machine_info=machine())
    _figure(data, RESULTS / f"{name}.png")
    print(f"wrote {path} and {RESULTS / f'{name}.png'}")


def _draw_bytes() -> int:
    from pgtjax import _parallel

    return _parallel.CPU_DRAW_BYTES


if __name__ == "__main__":
    main()
