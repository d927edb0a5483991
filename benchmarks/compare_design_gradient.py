"""The design study's value and value-and-gradient with an OLD and the NEW tree, in one process, alternating.

Both trees are imported side by side: the old tree's ``pgtjax`` package is copied to a scratch folder as
``pgtjax_old`` (its absolute imports rewritten), so that both are timed on the same machine state. Per tree:
the bolt study's problem (12 log-mapped bolt stiffnesses, the time-mean std of the ring-mesh deformation
``--objective ring_mesh``, or of one ring node's radial displacement without observables ``--objective node``),
``--periods`` carrier periods; the first calls (compilation) apart, then ``--repeats`` rounds of forward,
gradient for old then new. Reports medians, the ratios and the largest relative difference of the two trees'
values and gradients.

Usage: python3 benchmarks/compare_design_gradient.py --old /tmp/baseline [--periods 1.0] [--repeats 5]
       [--objective ring_mesh|node] [--out benchmarks/results/compare_design_gradient.json]
"""

from __future__ import annotations

import argparse
import importlib
import json
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import equinox as eqx
import jax
import numpy as np
from _common import RESULTS, machine

REPO = Path(__file__).resolve().parents[1]


def old_package(tree: Path, scratch: Path) -> str:
    """Copy ``tree/pgtjax`` to ``scratch/pgtjax_old`` with its absolute imports renamed; returns the name."""
    target = scratch / "pgtjax_old"
    shutil.copytree(tree / "pgtjax", target)
    for f in target.rglob("*.py"):
        text = f.read_text()
        new = re.sub(r"\bfrom pgtjax([. ])", r"from pgtjax_old\1", text)
        new = re.sub(r"^import pgtjax$", "import pgtjax_old", new, flags=re.M)
        if new != text:
            f.write_text(new)
    sys.path.insert(0, str(scratch))
    return "pgtjax_old"


def commit(tree: Path) -> str:
    p = subprocess.run(["git", "-C", str(tree), "rev-parse", "HEAD"], capture_output=True, text=True)
    return p.stdout.strip() or "unknown"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--old", type=Path, required=True, help="a checkout of the old tree")
    ap.add_argument("--periods", type=float, default=1.0)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--objective", choices=["ring_mesh", "node"], default="ring_mesh")
    ap.add_argument("--out", type=Path, default=RESULTS / "compare_design_gradient.json")
    args = ap.parse_args()
    jax.config.update("jax_enable_x64", True)
    scratch = Path(tempfile.mkdtemp(prefix="pgtjax_old_"))
    try:
        names = {"old": old_package(args.old, scratch), "new": "pgtjax"}
        calls, first, results = {}, {}, {}
        for label, name in names.items():
            pd = importlib.import_module(name + ".design")
            pm = importlib.import_module(name + ".models.planetary")
            p = pm.default_params()
            observe = args.objective == "ring_mesh"
            response = pd.planetary_response(p, periods=args.periods, ring_mesh=observe)
            quantities = [f"ring_mesh{n}" for n in (1, 2, 3)] if observe else ["ring_node2_radial"]
            problem = pd.DesignProblem(
                pd.DesignSpace(p, pd.bolt_variables(p)),
                response,
                pd.Std(quantities),
                [pd.SupportStiffness(weight=0.2)],
            )
            z0 = problem.space.initial()
            fwd = eqx.filter_jit(lambda z, problem=problem: problem.value(z))
            vg = eqx.filter_jit(jax.value_and_grad(lambda z, problem=problem: problem.value(z)))
            t = time.perf_counter()
            value = float(fwd(z0))
            first[(label, "forward")] = time.perf_counter() - t
            t = time.perf_counter()
            _, grad = vg(z0)
            grad = np.asarray(grad)
            first[(label, "gradient")] = time.perf_counter() - t
            calls[label] = (fwd, vg, z0)
            results[label] = (value, grad)
        runs = {(label, kind): [] for label in names for kind in ("forward", "gradient")}
        for _ in range(args.repeats):
            for label, (fwd, vg, z0) in calls.items():
                for kind, fn in (("forward", fwd), ("gradient", vg)):
                    t = time.perf_counter()
                    jax.block_until_ready(fn(z0))
                    runs[(label, kind)].append(time.perf_counter() - t)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    trees = {}
    for label in names:
        f, g = (float(np.median(runs[(label, k)])) for k in ("forward", "gradient"))
        trees[label] = dict(
            forward_median_s=f,
            gradient_median_s=g,
            ratio=g / f,
            forward_runs_s=runs[(label, "forward")],
            gradient_runs_s=runs[(label, "gradient")],
            forward_first_call_s=first[(label, "forward")],
            gradient_first_call_s=first[(label, "gradient")],
        )
        print(f"{label}: forward {f:.3f} s, value-and-gradient {g:.3f} s, ratio {g / f:.3f}")
    (v_old, g_old), (v_new, g_new) = results["old"], results["new"]
    payload = dict(
        machine=machine(),
        date=time.strftime("%Y-%m-%d %H:%M:%S"),
        command="python3 benchmarks/compare_design_gradient.py " + shlex.join(sys.argv[1:]),
        old_commit=commit(args.old),
        new_commit=commit(REPO),
        arguments={k: str(v) for k, v in vars(args).items()},
        trees=trees,
        gradient_time_new_over_old=trees["new"]["gradient_median_s"] / trees["old"]["gradient_median_s"],
        value_rel_diff=abs(v_new - v_old) / abs(v_old),
        gradient_max_rel_diff=float(np.max(np.abs(g_new - g_old)) / np.max(np.abs(g_old))),
    )
    print(
        f"gradient new/old {payload['gradient_time_new_over_old']:.3f}; value rel diff {payload['value_rel_diff']:.1e}, "
        f"gradient max rel diff {payload['gradient_max_rel_diff']:.1e}"
    )
    tmp = args.out.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(payload, indent=1) + "\n")
    tmp.replace(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
