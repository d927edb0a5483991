"""Compare the ring moving-load study's outputs of two trees where the contact-point / mid-node outputs moved
from observer DOFs (old) to Observables (new): the outputs, the ring's own DOFs and every summary number.

Usage (the command of ``compare_outputs.py``'s ring-moving-load study, once per tree):
    (cd OLD_RUN && PYTHONPATH=/tmp/baseline python3 -m pgtjax.cli ring-moving-load --revolutions 0.02 \
        --samples 20 --speeds 50 --sweep-speeds 2 --sweep-steps 32 --supports 2 --quiet --out out)
    (cd NEW_RUN && PYTHONPATH=. python3 -m pgtjax.cli ring-moving-load ...same options...)
    python3 benchmarks/compare_ring_outputs.py OLD_RUN/out NEW_RUN/out [--report FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

import pgtjax as pg

OUTPUTS = ("contact1_radial", "mid_node_radial")


def _series(result, name):
    if name in result.dof_names:  # the old observer DOF
        j = result.dof_names.index(name)
        return np.asarray(result.mean_u[:, j]), np.asarray(result.std_u[:, j])
    j = result.observable_names.index(name)
    return np.asarray(result.mean_obs[:, j]), np.asarray(result.std_obs[:, j])


def _rel(a, b):
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(a))), 1e-300))


def _numbers(a, b, path=""):
    if isinstance(a, dict):
        for k in a:
            yield from _numbers(a[k], b.get(k), f"{path}.{k}")
    elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            yield from _numbers(x, y, f"{path}[{i}]")
    elif isinstance(a, int | float) and not isinstance(a, bool) and isinstance(b, int | float):
        yield path, a, b


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", type=Path)
    ap.add_argument("new", type=Path)
    ap.add_argument("--report", type=Path, default=None)
    args = ap.parse_args(argv)
    report = {"old": str(args.old), "new": str(args.new), "files": {}}
    for path in sorted(args.old.glob("*.npz")):
        old, _ = pg.load_results(path)
        new, _ = pg.load_results(args.new / path.name)
        entry = {}
        for name in OUTPUTS:
            try:
                (mo, so), (mn, sn) = _series(old, name), _series(new, name)
            except ValueError:
                continue
            entry[name] = {"mean_rel_diff": _rel(mo, mn), "std_rel_diff": _rel(so, sn)}
        idx = [old.dof_names.index(n) for n in new.dof_names]
        entry["system_dofs"] = {
            "mean_rel_diff": _rel(np.asarray(old.mean_u)[:, idx], np.asarray(new.mean_u)),
            "std_rel_diff": _rel(np.asarray(old.std_u)[:, idx], np.asarray(new.std_u)),
        }
        report["files"][path.name] = entry
    so = json.loads((args.old / "summary.json").read_text())
    sn = json.loads((args.new / "summary.json").read_text())
    diffs = [(abs(a - b) / max(abs(a), abs(b), 1e-300), p) for p, a, b in _numbers(so, sn) if a != b]
    report["summary_numbers_differing"] = len(diffs)
    report["summary_worst"] = [{"path": p, "rel_diff": r} for r, p in sorted(diffs, reverse=True)[:10]]
    text = json.dumps(report, indent=2)
    print(text)
    if args.report:
        args.report.write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
