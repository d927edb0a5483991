"""Cost against size: Monte Carlo time and peak memory against the sample count (gear pair and planetary), and SL +
recursion and Monte Carlo time of the planetary model against the number of ring elements and of planets, with
the exponents of least-squares fits in log-log; and the gear pair's Monte Carlo against what a competent user would
write instead (benchmarks/_peers.py: NumPy vectorized over samples, numba with np.random on one thread and on every
core, numba with NumPy's Generator, diffrax's Heun and ShARK at the step that matches Newmark's noise-free
accuracy), timed alternately in the same run after each NumPy and numba peer's statistics were checked equal to
pgtjax's when fed pgtjax's normals. Writes benchmarks/results/scaling.json and scaling.png.

Monte Carlo runs on one JAX device per core (``pgtjax.use_cpu_cores()``, ``pgtjax --cpu-devices``), except the
model sizes: they run in a process of their own on one device, since this script's planetary Monte Carlo hung
three times there on two devices (docs/performance.md). Every point: compile time apart (first call), then the
median of ``--repeats`` calls. Peak memory: each sample count runs in a fresh
process, which reports its peak resident set size (``ru_maxrss``), so that one size's allocations cannot hide
another's.

Usage: python benchmarks/bench_scaling.py [--quick] [--repeats 3] [--no-peers | --peers-only | --models-only]
(``--peers-only`` and ``--models-only`` measure one section again and replace it in scaling.json, with the
machine and date of that section's run.)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

GEAR_STEPS, PLANETARY_STEPS = 1000, 500
SL_STEPS, MC_SAMPLES, MC_STEPS = 1000, 2000, 500
PEER_SAMPLES, PEER_STEPS, PEER_SAVE_EVERY = 20_000, 2_000, 100  # the issue's side-by-side size


def _median_time(fn, repeats):
    t = time.perf_counter()
    fn()
    first = time.perf_counter() - t
    runs = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - t)
    return first, statistics.median(runs)


def _samples_point(model: str, n_samples: int, repeats: int) -> dict:
    """One (model, sample count) point, run in its own process (see :func:`main`)."""
    import jax

    import pgtjax as pg

    pg.use_cpu_cores()
    from pgtjax.models import gear_pair as gp
    from pgtjax.models import planetary as pm

    if model == "gear_pair":
        system, dt, n_steps = gp.build(), 1e-5, GEAR_STEPS
    else:
        system, dt, n_steps = pm.build(pm.default_params()), 0.0027, PLANETARY_STEPS

    def run():
        r = pg.monte_carlo(
            system,
            n_samples=n_samples,
            key=jax.random.key(0),
            dt=dt,
            n_steps=n_steps,
            save_every=n_steps // 10,
            progress=False,
        )
        return jax.block_until_ready(r.std_u)

    first, median = _median_time(run, repeats)
    return dict(
        n_samples=n_samples,
        n_steps=n_steps,
        first_call_s=first,
        median_s=median,
        ns_per_sample_step=median / (n_samples * n_steps) * 1e9,
        peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    )


def _model_sizes(repeats: int, elements, planets) -> dict:
    import jax

    import pgtjax as pg
    from pgtjax.models import planetary as pm
    from pgtjax.studies import planetary as study

    def point(p):
        system = pm.build(p)
        sl = lambda: jax.block_until_ready(  # noqa: E731
            pg.solve_moments(system, dt=0.0027, n_steps=SL_STEPS, save_every=10).std_u
        )
        mc = lambda: jax.block_until_ready(  # noqa: E731
            pg.monte_carlo(
                system,
                n_samples=MC_SAMPLES,
                key=jax.random.key(0),
                dt=0.0027,
                n_steps=MC_STEPS,
                save_every=MC_STEPS // 10,
                progress=False,
            ).std_u
        )
        sl_first, sl_median = _median_time(sl, repeats)
        mc_first, mc_median = _median_time(mc, repeats)
        return dict(
            n_dof=system.n_dof,
            sl_first_call_s=sl_first,
            sl_median_s=sl_median,
            sl_ms_per_step=sl_median / SL_STEPS * 1e3,
            mc_first_call_s=mc_first,
            mc_median_s=mc_median,
            mc_ns_per_sample_step=mc_median / (MC_SAMPLES * MC_STEPS) * 1e9,
        )

    out = dict(ring_elements=[], planets=[])
    for n in elements:
        out["ring_elements"].append(dict(n_elements=n, **point(study.load_params(n_elements=n))))
    base = pm.default_params()
    for n in planets:
        out["planets"].append(dict(n_planets=n, **point(dataclasses.replace(base, n_planets=n))))
    return out


def _peers(repeats: int, quick: bool) -> dict:
    """The gear pair's Monte Carlo in pgtjax and its peers: correctness first, then timed alternately."""
    import _peers

    from pgtjax.models import gear_pair as gp

    system = gp.build()
    check = _peers.check_against_pgtjax(system, 1e-5)
    for name, diff in check.items():
        print(
            f"peer {name}: statistics fed pgtjax's normals differ from pgtjax's by {max(diff.values()):.1e}"
        )
        assert max(diff.values()) < 1e-9, (name, diff)
    n_samples, n_steps = (2000, 500) if quick else (PEER_SAMPLES, PEER_STEPS)
    matched, diffrax_steps = {}, {}
    try:
        import diffrax
    except ImportError:
        print("diffrax is not installed: its peers are skipped (pip install -e '.[bench]')")
    else:
        solvers = {"Heun": diffrax.Heun(), "ShARK": diffrax.ShARK()}
        matched = _peers.matched_diffrax_step(system, h=1e-5, n_steps=n_steps, solvers=solvers)
        for name, m in matched.items():
            print(
                f"diffrax {name}: {m['steps_per_newmark_step']} steps per Newmark step for the noise-free "
                f"accuracy of Newmark ({m['error']:.2e} against {m['newmark_error']:.2e}, relative)"
            )
            diffrax_steps[name] = (solvers[name], m["steps_per_newmark_step"])
    rows = _peers.time_gear_pair(
        system,
        h=1e-5,
        n_samples=n_samples,
        n_steps=n_steps,
        save_every=PEER_SAVE_EVERY,
        rounds=repeats,
        diffrax_steps=diffrax_steps,
    )
    for name, row in rows.items():
        print(f"gear pair MC, {name:45s} {row['ns_per_sample_step']:6.1f} ns/sample-step", flush=True)
    return dict(
        n_samples=n_samples,
        n_steps=n_steps,
        save_every=PEER_SAVE_EVERY,
        numba_version=_peers.numba.__version__ if _peers.numba is not None else None,
        check_max_relative_difference=check,
        diffrax_matched_accuracy=matched,
        runs=rows,
    )


def _exponent(x, y) -> float:
    """Slope of the least-squares line through (log x, log y)."""
    return float(np.polyfit(np.log(np.asarray(x, float)), np.log(np.asarray(y, float)), 1)[0])


def _figure(data: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fits = data["exponents"]
    peers = data.get("peers")
    n_panels = 5 if peers else 4
    fig, axes = plt.subplots(1, n_panels, figsize=(4 * n_panels, 4.2), constrained_layout=True)
    for model, marker in (("gear_pair", "o"), ("planetary", "s")):
        rows = data["samples"][model]
        n = [r["n_samples"] for r in rows]
        slope = fits[f"{model}_mc_time_vs_samples"]
        axes[0].loglog(n, [r["median_s"] for r in rows], marker + "-", label=f"{model} (slope {slope:.2f})")
        slope = fits[f"{model}_peak_memory_vs_samples"]
        axes[1].semilogx(
            n, [r["peak_rss_mb"] for r in rows], marker + "-", label=f"{model} (log-log slope {slope:.2f})"
        )
    axes[0].set(xlabel="Monte Carlo samples", ylabel="time (s)", title="Monte Carlo time")
    axes[1].set(xlabel="Monte Carlo samples", ylabel="peak resident memory (MB)", title="Monte Carlo memory")
    axes[1].set_ylim(0, None)
    for ax, key, label in ((axes[2], "ring_elements", "ring elements"), (axes[3], "planets", "planets")):
        rows = data["models"][key]
        x = [r["n_elements" if key == "ring_elements" else "n_planets"] for r in rows]
        sl, mc = fits[f"sl_time_per_step_vs_{key}"], fits[f"mc_time_per_sample_step_vs_{key}"]
        ax.loglog(
            x, [r["sl_ms_per_step"] for r in rows], "o-", label=f"SL + recursion, ms/step (slope {sl:.2f})"
        )
        ax.loglog(
            x,
            [r["mc_ns_per_sample_step"] / 1e3 for r in rows],
            "s-",
            label=f"MC, µs/sample-step (slope {mc:.2f})",
        )
        ax.set_xticks(x, [str(v) for v in x])
        ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        ax.set(xlabel=label, ylabel="time per step", title=f"planetary model against {label}")
    for ax in axes[:4]:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    if peers:
        ax = axes[4]
        names = list(peers["runs"])
        values = [peers["runs"][k]["ns_per_sample_step"] for k in names]
        colors = ["C0" if k.startswith("pgtjax") else "C7" for k in names]
        ax.barh(range(len(names)), values, color=colors)
        ax.set_yticks(range(len(names)), [k.replace(", ", ",\n", 1) for k in names], fontsize=7)
        ax.invert_yaxis()
        for y, v in enumerate(values):
            ax.text(v, y, f" {v:.1f}", va="center", fontsize=7)
        ax.set_xscale("log")  # diffrax is 30-100 times slower than the rest: linear bars would hide them
        ax.set_xlim(0.5 * min(values), 3.0 * max(values))
        ax.set(
            xlabel="ns per sample-step (median, log scale)",
            title=f"gear pair MC, {peers['n_samples']:,} x {peers['n_steps']:,}",
        )
        ax.title.set_fontsize(9)
        ax.grid(True, axis="x", alpha=0.3)
    fig.savefig(path, dpi=200)
    plt.close(fig)


def _models_in_subprocess(repeats: int, quick: bool, scratch: Path) -> dict:
    """The model sizes, measured in a process of their own on one CPU device (module docstring)."""
    cmd = [sys.executable, __file__, "--repeats", str(repeats), "--models", str(scratch)]
    subprocess.run(cmd + (["--quick"] if quick else []), check=True)
    models = json.loads(scratch.read_text())
    scratch.unlink()
    for key, label in (("ring_elements", "n_elements"), ("planets", "n_planets")):
        for r in models[key]:
            print(
                f"{label} {r[label]:3d} ({r['n_dof']:4d} DOFs): SL {r['sl_ms_per_step']:.3f} ms/step, "
                f"MC {r['mc_ns_per_sample_step']:.0f} ns/sample-step",
                flush=True,
            )
    return models


def _fits(samples: dict, models: dict) -> dict:
    """Log-log slopes of time and memory against the sample count, and of time against model size."""
    fits = {}
    for model, rows in samples.items():
        n = [r["n_samples"] for r in rows]
        fits[f"{model}_mc_time_vs_samples"] = _exponent(n, [r["median_s"] for r in rows])
        fits[f"{model}_peak_memory_vs_samples"] = _exponent(n, [r["peak_rss_mb"] for r in rows])
    for key, label in (("ring_elements", "n_elements"), ("planets", "n_planets")):
        rows = models[key]
        x = [r[label] for r in rows]
        fits[f"sl_time_per_step_vs_{key}"] = _exponent(x, [r["sl_ms_per_step"] for r in rows])
        fits[f"mc_time_per_sample_step_vs_{key}"] = _exponent(x, [r["mc_ns_per_sample_step"] for r in rows])
        fits[f"sl_time_per_step_vs_dofs_over_{key}"] = _exponent(
            [r["n_dof"] for r in rows], [r["sl_ms_per_step"] for r in rows]
        )
        fits[f"mc_time_per_sample_step_vs_dofs_over_{key}"] = _exponent(
            [r["n_dof"] for r in rows], [r["mc_ns_per_sample_step"] for r in rows]
        )
    for name, value in fits.items():
        print(f"exponent {name}: {value:.2f}")
    return fits


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--quick", action="store_true", help="small sizes (a check of the script)")
    parser.add_argument("--figure-only", action="store_true", help="redraw scaling.png from scaling.json")
    parser.add_argument("--no-peers", action="store_true", help="skip the NumPy, numba and diffrax peers")
    parser.add_argument(
        "--peers-only", action="store_true", help="run the peers alone and replace them in scaling.json"
    )
    parser.add_argument(
        "--models-only",
        action="store_true",
        help="run the model sizes alone and replace them (and the exponents) in scaling.json",
    )
    parser.add_argument("--point", nargs=3, metavar=("MODEL", "SAMPLES", "OUT"), help=argparse.SUPPRESS)
    parser.add_argument("--models", metavar="OUT", help=argparse.SUPPRESS)
    args = parser.parse_args()
    import pgtjax as pg

    if args.models:  # the model sizes in a process of their own, on one CPU device (module docstring)
        pg.use_cpu_cores(1)
        sizes = ([18, 36], [3, 4]) if args.quick else ([18, 36, 72], [3, 4, 5, 6])
        Path(args.models).write_text(json.dumps(_model_sizes(args.repeats, *sizes)))
        return
    if args.figure_only:
        from _common import RESULTS

        _figure(json.loads((RESULTS / "scaling.json").read_text()), RESULTS / "scaling.png")
        return
    if (args.peers_only or args.models_only) and args.quick:
        parser.error(
            "--quick would replace full-size results in scaling.json: run the whole script with --quick"
        )
    if not args.models_only:  # (the model sizes run in a one-device subprocess of their own)
        pg.use_cpu_cores()  # before any JAX computation: one device per core (pgtjax --cpu-devices)
    if args.point:
        model, n, out = args.point
        Path(out).write_text(json.dumps(_samples_point(model, int(n), args.repeats)))
        return
    if args.peers_only or args.models_only:  # one section measured again, the others kept as measured
        from _common import RESULTS, machine, write

        data = json.loads((RESULTS / "scaling.json").read_text())
        section = "peers" if args.peers_only else "models"
        if args.peers_only:
            data["peers"] = _peers(args.repeats, args.quick)
        else:
            data["models"] = _models_in_subprocess(args.repeats, False, RESULTS / ".scaling-models.json")
            data["exponents"] = _fits(data["samples"], data["models"])
        data[f"{section}_command"] = "python benchmarks/bench_scaling.py " + " ".join(sys.argv[1:])
        data[f"{section}_machine"] = machine()
        data[f"{section}_date"] = time.strftime("%Y-%m-%d %H:%M:%S")
        path = write("scaling", data, keep_machine=True)
        _figure(data, RESULTS / "scaling.png")
        print(f"wrote {path} and {RESULTS / 'scaling.png'}")
        return
    if args.quick:
        counts = {"gear_pair": [1000, 4000], "planetary": [500, 1000]}
    else:
        counts = {"gear_pair": [10**3, 10**4, 10**5, 10**6], "planetary": [10**3, 10**4, 10**5]}
    from _common import RESULTS, write

    scratch = RESULTS / ".scaling-point.json"
    samples = {}
    for model, ns in counts.items():
        samples[model] = []
        for n in ns:
            cmd = [
                sys.executable,
                __file__,
                "--repeats",
                str(args.repeats),
                "--point",
                model,
                str(n),
                str(scratch),
            ]
            subprocess.run(cmd, check=True)
            samples[model].append(json.loads(scratch.read_text()))
            scratch.unlink()
            row = samples[model][-1]
            print(
                f"{model:10s} {n:8d} samples: {row['median_s']:8.3f} s ({row['ns_per_sample_step']:6.1f} "
                f"ns/sample-step), peak {row['peak_rss_mb']:7.0f} MB",
                flush=True,
            )
    peers = None if args.no_peers else _peers(args.repeats, args.quick)
    models = _models_in_subprocess(args.repeats, args.quick, scratch)
    fits = _fits(samples, models)
    data = dict(
        description="cost against size; exponents are least-squares slopes in log-log",
        command="python benchmarks/bench_scaling.py " + " ".join(sys.argv[1:]),
        repeats=args.repeats,
        sizes=dict(
            gear_pair_steps=GEAR_STEPS,
            planetary_steps=PLANETARY_STEPS,
            sl_steps=SL_STEPS,
            mc_samples=MC_SAMPLES,
            mc_steps=MC_STEPS,
            chunk_size=5000,
        ),
        cpu_devices=dict(samples_and_peers=pg.use_cpu_cores(), models=1),
        samples=samples,
        models=models,
        exponents=fits,
        peers=peers,
    )
    path = write("scaling", data)
    _figure(data, RESULTS / "scaling.png")
    print(f"wrote {path} and {RESULTS / 'scaling.png'}")


if __name__ == "__main__":
    main()
