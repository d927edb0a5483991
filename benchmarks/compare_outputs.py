"""A refactor must change no number: run the CLI's seed studies with the OLD and the NEW tree at small sizes
and compare every output.

Each study runs ``python3 -m pgtjax.cli ...`` once per tree, as a subprocess with ``PYTHONPATH=<tree>`` and
its own scratch working directory (outputs go to relative ``--out`` folders inside it), same argv and seed for
both trees. Compared, per study:

* every file in the working directory: each array of each ``.npz`` (shape, dtype, values; string arrays that
  hold JSON, such as ``__meta__``, compared as JSON), every number of each ``.json`` (recursively; strings,
  booleans, keys and lengths exactly), other text files like stdout; ``.png`` only for presence in both;
* each command's exit status (must be 0 in both) and stdout: numbers parsed out of each line and compared
  numerically, the remaining text exactly, after stripping timings ("done in 12.3 s", "[  12.3 s]") and
  the scratch paths; a stdout that is one JSON document is compared as JSON.

Tolerance for floating-point values: ``|a - b| <= rtol * max(|a|, |b|) + floor * scale``, rtol = floor =
1e-10, ``scale`` the largest magnitude of the array (both trees) the value belongs to: a ``.npz`` array; in
JSON the values sharing a path once list indices are wildcarded (a list, a matrix, a field across records);
in stdout the values at one position of the lines with the same count of numbers (a table column).
A value alone in its group gets no floor. Integers, booleans and strings must be equal; NaN matches NaN.
JSON keys named like timings (``wall_s``) are skipped. The report gives, per study, the largest relative
difference among values that differ by more than the floor, and how many values passed only by the floor.

Usage: python3 benchmarks/compare_outputs.py [--old /tmp/baseline] [--new REPO] [--only planetary,gear-pair]
       [--seed 7] [--jobs 2] [--keep] [--report benchmarks/results/compare_outputs.json] [--list]
Exit status 0 when every study passes, 1 otherwise.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import difflib
import hashlib
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DEFAULT_REPORT = REPO / "benchmarks" / "results" / "compare_outputs.json"
RTOL = 1e-10
FLOOR = 1e-10
TIMING_KEYS = re.compile(r"^(wall_s|.*_wall_s|elapsed(_s)?|runtime(_s)?|seconds)$")
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
TIMINGS = [  # (pattern, replacement) applied to stdout before comparing
    (re.compile(r"done in \d+(?:\.\d+)? s"), "done in <T> s"),
    (re.compile(r"^\[\s*\d+(?:\.\d+)? s\]", re.M), "[<T> s]"),
    (re.compile(r"^(\s+)\d+(?:\.\d+)? s$", re.M), r"\1<T> s"),
]
MAX_LISTED = 20  # failures listed per study in the report


def studies(seed: int) -> dict[str, dict]:
    """The seed studies: commands (argv after ``python3 -m pgtjax.cli``) and what they exercise."""
    small = "--periods 0.02 --saves 10 --sl-refine 2"
    table = {
        "planetary": dict(
            what="ch. 3 elastic ring: SL force + energy, MC (2 chunks), rim-thickness and support sweeps, "
            "modal table, autodiff sensitivities vs central differences",
            commands=[
                f"run --samples 20 --chunk-size 12 {small} --criteria force,energy --seed {seed} --quiet "
                "--out out"
            ],
        ),
        "planetary-rigid": dict(
            what="ch. 3 rigid-ring model: SL force + MC",
            commands=[f"run --ring-model rigid --samples 20 {small} --seed {seed} --quiet --out out"],
        ),
        "planetary-modal": dict(
            what="modal tables of the elastic and rigid planetary models",
            commands=[
                "planetary-modal",
                "planetary-modal --json",
                "planetary-modal --ring-model rigid --json",
            ],
        ),
        "gear-pair": dict(
            what="ch. 4: three regimes, SL force + energy, MC (2 chunks, the last padded), histograms at two "
            "times, error table, KS distances",
            commands=[
                "gear-pair --samples 200 --chunk-size 120 --t-end 0.005 --saves 10 --pdf-times 0.003,0.005 "
                f"--criteria force,energy --seed {seed} --quiet --out out"
            ],
        ),
        "gear-pair-step": dict(
            what="SL time-step convergence (table and JSON)",
            commands=[
                "gear-pair-step --dts 4e-5,2e-5,1e-5 --t-end 0.005",
                "gear-pair-step --dts 2e-5,1e-5 --t-end 0.004 --json",
            ],
        ),
        "gear-pair-modal": dict(
            what="gear-pair modes (table and JSON)", commands=["gear-pair-modal", "gear-pair-modal --json"]
        ),
        "ring-modal": dict(
            what="supported ring modes: default file, all modes, pins on 24 elements",
            commands=[
                "ring-modal --modes 12",
                "ring-modal --modes 0 --json",
                "ring-modal --support 2 --n-elements 24 --json",
            ],
        ),
        "ring-free-vibration": dict(
            what="ch. 5 free ring, Models I and II (table, JSON, files)",
            commands=["ring-free-vibration --n-elements 32 --out out", "ring-free-vibration --json"],
        ),
        "ring-moving-load": dict(
            what="ch. 6: base SL + MC, one more speed, 2-speed sweep (vmap), support case 2 (modal model, 36 "
            "modes), critical-speed table",
            commands=[
                "ring-moving-load --revolutions 0.02 --samples 20 --speeds 50 --sweep-speeds 2 "
                "--sweep-steps 32 --supports 2 --quiet --out out"
            ],
        ),
        "back-to-back": dict(
            what="bench: stationary regime + run-up (Newmark-Newton, Hertzian meshes), mesh histories, Hertz "
            "comparison, STFT ridges, modes",
            commands=[
                "back-to-back --stationary-t-end 0.05 --ramp-start 0.02 --ramp-duration 0.06 --t-end 0.08 "
                "--stft-window 0.02 --quiet --out out"
            ],
        ),
        "back-to-back-modal": dict(
            what="bench modes: free, with motor, other torque and face width",
            commands=[
                "back-to-back-modal",
                "back-to-back-modal --json",
                "back-to-back-modal --motor --json",
                "back-to-back-modal --torque 200 --face-width 0.025",
            ],
        ),
    }
    return {name: dict(s, commands=[c.split() for c in s["commands"]]) for name, s in table.items()}


# ------------------------------------------------------------------------------------------------ comparison


class Tally:
    """Counts and worst differences of one study's comparisons."""

    def __init__(self):
        self.files = self.arrays = self.values = self.floored = 0
        self.max_rel, self.where = 0.0, None  # among values differing by more than the floor
        self.max_rel_raw, self.where_raw = 0.0, None  # every value, floor ignored
        self.failures: list[str] = []
        self.notes: list[str] = []

    def fail(self, msg: str):
        self.failures.append(msg)

    @property
    def ok(self) -> bool:
        return not self.failures


def _loc(where: str, shape, flat: int) -> str:
    return where if not shape else f"{where}[{','.join(map(str, np.unravel_index(flat, shape)))}]"


def compare_arrays(a, b, where: str, t: Tally, floor: float = FLOOR, labels=None):
    """Compare two arrays entry by entry (module docstring); ``labels[i]`` names flat entry i if given."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        return t.fail(f"{where}: shape {a.shape} (old) vs {b.shape} (new)")
    if a.dtype != b.dtype:
        return t.fail(f"{where}: dtype {a.dtype} (old) vs {b.dtype} (new)")
    t.values += a.size
    shape = a.shape
    name = (lambda i: labels[i]) if labels is not None else (lambda i: _loc(where, shape, i))
    if a.dtype.kind in "US":
        bad = np.flatnonzero(a != b)
        if bad.size:
            t.fail(f"{name(bad[0])}: {a.flat[bad[0]]!r} (old) vs {b.flat[bad[0]]!r} (new); {bad.size} differ")
        return
    if a.dtype.kind not in "fc":  # bool, integers: exact
        bad = np.flatnonzero(a != b)
        if bad.size:
            t.fail(
                f"{name(bad[0])}: {a.flat[bad[0]]} (old) vs {b.flat[bad[0]]} (new); "
                f"{bad.size} of {a.size} differ"
            )
        return
    a, b = a.ravel(), b.ravel()
    finite = np.isfinite(a) & np.isfinite(b)
    same_special = (a == b) | (np.isnan(a) & np.isnan(b))
    mag = np.where(finite, np.maximum(np.abs(a), np.abs(b)), 0.0)
    diff = np.where(finite, np.abs(a - b), 0.0)
    scale = float(mag.max()) if mag.size else 0.0
    absolute = floor * scale if a.size > 1 else 0.0
    bad = (finite & (diff > RTOL * mag + absolute)) | (~finite & ~same_special)
    t.floored += int(np.count_nonzero(finite & (diff > RTOL * mag) & ~bad))
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(diff > 0, diff / np.where(mag > 0, mag, 1.0), 0.0)
    rel = np.where(~finite & ~same_special, np.inf, rel)
    if rel.size:
        i = int(np.argmax(rel))
        if rel[i] > t.max_rel_raw:
            t.max_rel_raw, t.where_raw = float(rel[i]), name(i)
        beyond = np.where((diff > absolute) | ~finite, rel, 0.0)
        i = int(np.argmax(beyond))
        if beyond[i] > t.max_rel:
            t.max_rel, t.where = float(beyond[i]), name(i)
    for i in np.flatnonzero(bad)[:3]:
        x, y = a[i].item(), b[i].item()
        t.fail(f"{name(i)}: {x!r} (old) vs {y!r} (new), rel {rel[i]:.3g}, floor {absolute:.3g}")
    if np.count_nonzero(bad) > 3:
        t.fail(f"{where}: {np.count_nonzero(bad)} values out of tolerance in all")


def _walk_json(a, b, path: str, pattern: str, groups: dict, t: Tally):
    """Exact checks of structure, strings, booleans; numbers gathered into groups (wildcarded paths)."""
    num = (int, float)
    if isinstance(a, bool) or isinstance(b, bool) or a is None or b is None or isinstance(a, str):
        if type(a) is not type(b) or a != b:
            t.fail(f"{path}: {a!r} (old) vs {b!r} (new)")
        else:
            t.values += 1
    elif isinstance(a, num) and isinstance(b, num):
        groups.setdefault(pattern, []).append((path, float(a), float(b)))
    elif isinstance(a, dict) and isinstance(b, dict):
        only = sorted(set(a) ^ set(b))
        if only:
            which = ", ".join(f"{k} ({'old' if k in a else 'new'})" for k in only)
            t.fail(f"{path}: keys only in one tree: {which}")
        for k in sorted(set(a) & set(b)):
            if TIMING_KEYS.match(str(k)):
                t.notes.append(f"{path}.{k}: timing, not compared")
                continue
            _walk_json(a[k], b[k], f"{path}.{k}", f"{pattern}.{k}", groups, t)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return t.fail(f"{path}: length {len(a)} (old) vs {len(b)} (new)")
        for i, (x, y) in enumerate(zip(a, b)):
            _walk_json(x, y, f"{path}[{i}]", f"{pattern}[*]", groups, t)
    else:
        t.fail(f"{path}: {type(a).__name__} (old) vs {type(b).__name__} (new)")


def compare_json(a, b, where: str, t: Tally):
    groups: dict = {}
    _walk_json(a, b, where, where, groups, t)
    for pattern, rows in groups.items():
        paths, x, y = zip(*rows)
        compare_arrays(np.array(x), np.array(y), pattern, t, labels=paths)


def normalize(text: str, paths: dict[str, str]) -> str:
    """Strip timings and replace the scratch/tree paths by placeholders."""
    for path, tag in sorted(paths.items(), key=lambda kv: -len(kv[0])):
        text = text.replace(path, tag)
    for pattern, repl in TIMINGS:
        text = pattern.sub(repl, text)
    return text


def compare_text(a: str, b: str, where: str, t: Tally):
    """Line by line: the text between numbers exactly, the numbers by column groups (module docstring)."""
    try:
        ja, jb = json.loads(a), json.loads(b)
    except ValueError:
        pass
    else:
        return compare_json(ja, jb, where, t)
    la, lb = a.splitlines(), b.splitlines()
    if len(la) != len(lb):
        diff = "\n".join(list(difflib.unified_diff(la, lb, "old", "new", lineterm="", n=0))[:12])
        return t.fail(f"{where}: {len(la)} lines (old) vs {len(lb)} (new):\n{diff}")
    groups: dict = {}
    for k, (x, y) in enumerate(zip(la, lb)):
        if NUMBER.sub("#", x) != NUMBER.sub("#", y):
            t.fail(f"{where}, line {k + 1}: text differs:\n  old: {x}\n  new: {y}")
            continue
        nx, ny = NUMBER.findall(x), NUMBER.findall(y)
        for j, (u, v) in enumerate(zip(nx, ny)):
            groups.setdefault((len(nx), j), []).append(
                (f"{where}, line {k + 1}, number {j + 1}", float(u), float(v))
            )
    for key, rows in groups.items():
        paths, x, y = zip(*rows)
        compare_arrays(np.array(x), np.array(y), f"{where}, column {key}", t, labels=paths)


def compare_npz(a: Path, b: Path, where: str, t: Tally):
    def load(path):
        try:
            with np.load(path, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except ValueError:  # object arrays
            t.notes.append(f"{where}: holds pickled objects, compared by repr")
            with np.load(path, allow_pickle=True) as z:
                return {k: np.array(repr(z[k].tolist())) for k in z.files}

    da, db = load(a), load(b)
    for k in sorted(set(da) ^ set(db)):
        t.fail(f"{where}: array {k!r} only in the {'old' if k in da else 'new'} tree")
    for k in sorted(set(da) & set(db)):
        x, y = da[k], db[k]
        t.arrays += 1
        if x.dtype.kind == "U" and y.dtype.kind == "U" and x.shape == y.shape == ():
            try:
                jx, jy = json.loads(str(x)), json.loads(str(y))
            except ValueError:
                pass
            else:
                compare_json(jx, jy, f"{where}:{k}", t)
                continue
        compare_arrays(x, y, f"{where}:{k}", t)


def compare_trees(a: Path, b: Path, t: Tally):
    """Every file under the two working directories."""
    fa = {p.relative_to(a).as_posix() for p in a.rglob("*") if p.is_file()}
    fb = {p.relative_to(b).as_posix() for p in b.rglob("*") if p.is_file()}
    for rel in sorted(fa ^ fb):
        t.fail(f"{rel}: only in the {'old' if rel in fa else 'new'} tree")
    for rel in sorted(fa & fb):
        t.files += 1
        pa, pb = a / rel, b / rel
        suffix = pa.suffix.lower()
        if suffix == ".png":
            continue
        if suffix == ".npz":
            compare_npz(pa, pb, rel, t)
        elif suffix == ".json":
            compare_json(json.loads(pa.read_text()), json.loads(pb.read_text()), rel, t)
        else:
            try:
                compare_text(pa.read_text(), pb.read_text(), rel, t)
            except UnicodeDecodeError:
                if pa.read_bytes() != pb.read_bytes():
                    t.fail(f"{rel}: binary files differ")


# ------------------------------------------------------------------------------------------------ running


def source_digest(tree: Path) -> str:
    """Hash of the package's sources (.py, .toml): shows whether a tree changed during the run."""
    h = hashlib.sha256()
    for p in sorted((tree / "pgtjax").rglob("*")):
        if p.is_file() and p.suffix in (".py", ".toml"):
            h.update(p.relative_to(tree).as_posix().encode() + b"\0" + p.read_bytes())
    return h.hexdigest()[:16]


def tree_info(tree: Path, python: str, env: dict) -> dict:
    """Where ``import pgtjax`` resolves with this tree first on the path, and the tree's git state."""
    out = subprocess.run(
        [python, "-c", "import pgtjax; print(pgtjax.__file__)"],
        env=env,
        cwd=tempfile.gettempdir(),
        capture_output=True,
        text=True,
    )

    def git(*a):
        return subprocess.run(["git", "-C", str(tree), *a], capture_output=True, text=True).stdout.strip()

    return dict(
        path=str(tree),
        pgtjax=out.stdout.strip() or out.stderr.strip()[-500:],
        commit=git("rev-parse", "HEAD"),
        modified_files=len([x for x in git("status", "--porcelain").splitlines() if x.strip()]),
        source_digest=source_digest(tree),
    )


def run_study(
    label: str, tree: Path, name: str, commands: list, root: Path, python: str, env: dict, timeout: float
) -> dict:
    """Run one study's commands with one tree, in ``root/label/name/work``; logs beside ``work``."""
    base = root / label / name
    work = base / "work"
    work.mkdir(parents=True)
    runs = []
    for i, argv in enumerate(commands):
        cmd = [python, "-m", "pgtjax.cli", *argv]
        start = time.perf_counter()
        try:
            p = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True, timeout=timeout)
            rc, stdout, stderr = p.returncode, p.stdout, p.stderr
        except subprocess.TimeoutExpired as err:
            rc, stdout, stderr = "timeout", err.stdout or "", f"timed out after {timeout} s"
            stdout = stdout.decode() if isinstance(stdout, bytes) else stdout
        (base / f"cmd{i}.stdout").write_text(stdout)
        (base / f"cmd{i}.stderr").write_text(stderr)
        runs.append(
            dict(
                argv=cmd,
                cwd=str(work),
                pythonpath=env["PYTHONPATH"],
                returncode=rc,
                wall_s=round(time.perf_counter() - start, 2),
                stdout=stdout,
                stderr_tail=stderr[-2000:],
            )
        )
        print(f"  [{label}] {name} #{i + 1}: rc {rc}, {runs[-1]['wall_s']:.1f} s", flush=True)
    return dict(work=work, runs=runs)


def compare_study(name: str, old: dict, new: dict, paths: dict) -> Tally:
    t = Tally()
    for i, (ro, rn) in enumerate(zip(old["runs"], new["runs"])):
        for label, r in (("old", ro), ("new", rn)):
            if r["returncode"] != 0:
                t.fail(
                    f"command {i + 1} ({' '.join(r['argv'][3:])}) failed in the {label} tree "
                    f"(rc {r['returncode']}): {r['stderr_tail'][-600:]}"
                )
        if ro["returncode"] == 0 and rn["returncode"] == 0:
            so = normalize(ro["stdout"], {**paths, str(old["work"]): "<WORK>"})
            sn = normalize(rn["stdout"], {**paths, str(new["work"]): "<WORK>"})
            compare_text(so, sn, f"stdout of command {i + 1}", t)
    compare_trees(old["work"], new["work"], t)
    return t


def write_json_atomic(path: Path, payload: dict):
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    with os.fdopen(fd, "w") as fh:
        json.dump(payload, fh, indent=2, default=str)
    os.replace(tmp, path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog=__doc__,
    )
    ap.add_argument(
        "--old", type=Path, default=Path("/tmp/baseline"), help="pre-refactor tree (default %(default)s)"
    )
    ap.add_argument(
        "--new", type=Path, default=REPO, help="refactored tree (default: this repository, %(default)s)"
    )
    ap.add_argument(
        "--only", default=None, help="comma-separated studies to run (default: all; --list names them)"
    )
    ap.add_argument(
        "--seed", type=int, default=7, help="Monte Carlo seed passed to both trees (default %(default)s)"
    )
    ap.add_argument("--jobs", type=int, default=2, help="subprocesses at once (default %(default)s)")
    ap.add_argument("--timeout", type=float, default=1200.0, help="seconds per command (default %(default)s)")
    ap.add_argument("--python", default=sys.executable, help="interpreter of the subprocesses")
    ap.add_argument(
        "--scratch", type=Path, default=Path(tempfile.gettempdir()), help="parent of the scratch folder"
    )
    ap.add_argument(
        "--keep", action="store_true", help="keep the scratch folder (outputs, stdout/stderr logs)"
    )
    ap.add_argument("--report", type=Path, default=DEFAULT_REPORT, help="JSON report (default %(default)s)")
    ap.add_argument("--list", action="store_true", help="print the studies and their commands, run nothing")
    args = ap.parse_args(argv)

    all_studies = studies(args.seed)
    if args.list:
        for name, s in all_studies.items():
            print(f"{name}: {s['what']}")
            for c in s["commands"]:
                print("    python3 -m pgtjax.cli " + " ".join(c))
        return 0
    names = list(all_studies) if args.only is None else [n.strip() for n in args.only.split(",") if n.strip()]
    unknown = [n for n in names if n not in all_studies]
    if unknown or not names:
        ap.error(f"unknown studies {unknown}; known: {', '.join(all_studies)}")
    trees = {"old": args.old.resolve(), "new": args.new.resolve()}
    for label, tree in trees.items():
        if not (tree / "pgtjax" / "__init__.py").is_file():
            ap.error(f"--{label} {tree}: no pgtjax package there")

    base_env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    base_env.update(MPLBACKEND="Agg", PYTHONHASHSEED="0", PYTHONDONTWRITEBYTECODE="1")
    envs = {label: {**base_env, "PYTHONPATH": str(tree)} for label, tree in trees.items()}
    infos = {label: tree_info(tree, args.python, envs[label]) for label, tree in trees.items()}
    for label, info in infos.items():
        if not info["pgtjax"].startswith(str(trees[label]) + os.sep):
            print(
                f"error: with PYTHONPATH={trees[label]}, pgtjax imports from {info['pgtjax']}",
                file=sys.stderr,
            )
            return 2
        print(
            f"{label}: {info['pgtjax']} (commit {info['commit'][:10]}, "
            f"{info['modified_files']} modified files)"
        )
    if trees["old"] == trees["new"]:
        print("warning: --old and --new are the same tree", file=sys.stderr)

    root = Path(tempfile.mkdtemp(prefix="compare_outputs_", dir=args.scratch)).resolve()
    paths = {str(tree): f"<{label.upper()}>" for label, tree in trees.items()}
    print(f"scratch: {root}; {len(names)} studies, seed {args.seed}, {args.jobs} jobs", flush=True)
    start = time.perf_counter()
    with concurrent.futures.ThreadPoolExecutor(max_workers=max(args.jobs, 1)) as pool:
        futures = {
            (n, label): pool.submit(
                run_study,
                label,
                trees[label],
                n,
                all_studies[n]["commands"],
                root,
                args.python,
                envs[label],
                args.timeout,
            )
            for n in names
            for label in ("old", "new")
        }
        done = {key: f.result() for key, f in futures.items()}
    total_s = time.perf_counter() - start
    for label, tree in trees.items():
        infos[label]["source_digest_at_end"] = end = source_digest(tree)
        infos[label]["changed_during_run"] = end != infos[label]["source_digest"]
        if infos[label]["changed_during_run"]:
            print(f"warning: the {label} tree's sources changed during the run", file=sys.stderr)

    rows, report_studies = [], {}
    for n in names:
        old, new = done[(n, "old")], done[(n, "new")]
        t = compare_study(n, old, new, paths)
        wall = {label: sum(r["wall_s"] for r in done[(n, label)]["runs"]) for label in ("old", "new")}
        rows.append(
            (
                n,
                len(all_studies[n]["commands"]),
                t.files,
                t.arrays,
                t.values,
                t.max_rel,
                t.where or "-",
                t.floored,
                "PASS" if t.ok else "FAIL",
                wall,
            )
        )
        report_studies[n] = dict(
            what=all_studies[n]["what"],
            status="PASS" if t.ok else "FAIL",
            files_compared=t.files,
            arrays_compared=t.arrays,
            values_compared=t.values,
            max_rel_diff=t.max_rel,
            max_rel_diff_at=t.where,
            values_passing_by_floor_only=t.floored,
            max_rel_diff_ignoring_floor=t.max_rel_raw,
            max_rel_diff_ignoring_floor_at=t.where_raw,
            failures=t.failures[:MAX_LISTED],
            n_failures=len(t.failures),
            notes=t.notes,
            wall_s=wall,
            commands={
                label: [{k: v for k, v in r.items() if k != "stdout"} for r in done[(n, label)]["runs"]]
                for label in ("old", "new")
            },
        )

    head = (
        f"{'study':20s} {'cmds':>4s} {'files':>5s} {'arrays':>6s} {'values':>8s} {'max rel diff':>12s} "
        f"{'floored':>7s} {'old s':>6s} {'new s':>6s}  status  where"
    )
    print("\n" + head + "\n" + "-" * len(head))
    for n, c, f, a, v, m, w, fl, st, wall in rows:
        print(
            f"{n:20s} {c:4d} {f:5d} {a:6d} {v:8d} {m:12.3g} {fl:7d} {wall['old']:6.1f} {wall['new']:6.1f}  "
            f"{st:6s}  {w}"
        )
    failed = [n for n, *_, st, _ in rows if st != "PASS"]
    for n in failed:
        s = report_studies[n]
        print(f"\n{n}: {s['n_failures']} failure(s)")
        for msg in s["failures"][:10]:
            print("  - " + msg.replace("\n", "\n    "))
    print(
        f"\ntolerance: |a-b| <= {RTOL:g} max(|a|,|b|) + {FLOOR:g} x (largest magnitude of the array); "
        f"'floored' = values passing only by that absolute floor; total {total_s:.0f} s"
    )

    payload = dict(
        date=time.strftime("%Y-%m-%d %H:%M:%S"),
        status="PASS" if not failed else "FAIL",
        failed=failed,
        tolerance=dict(
            rtol=RTOL,
            absolute_floor=f"{FLOOR:g} x largest magnitude of the array (both trees)",
            floor_factor=FLOOR,
            groups="npz: one array; JSON: values sharing a path with list indices "
            "wildcarded; stdout: one column of lines with the same count of numbers; no floor for a "
            "value alone in its group",
            integers_booleans_strings="exact",
            skipped_json_keys=TIMING_KEYS.pattern,
            stdout_normalization=[p.pattern for p, _ in TIMINGS] + ["scratch/tree paths -> <WORK>"],
        ),
        seed=args.seed,
        trees=infos,
        python=args.python,
        platform=platform.platform(),
        cpu_count=os.cpu_count(),
        scratch=str(root) if args.keep else None,
        total_wall_s=round(total_s, 1),
        command=[sys.executable, *sys.argv],
        studies=report_studies,
    )
    write_json_atomic(args.report, payload)
    print(f"report: {args.report.resolve()}")
    if args.keep:
        print(f"scratch kept: {root}")
    else:
        shutil.rmtree(root, ignore_errors=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
