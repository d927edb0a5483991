"""``pgtjax optimize``: the design study of :mod:`pgtjax.studies.design` (a TOML design specification on a
planetary parameter file) with its outputs."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from .._files import publish
from ._params import add_parameter_options, parameters, write_parameters
from ._types import positive_int


def _run_optimize(args) -> int:
    from .. import params as embedded
    from ..design._problem import check_samples
    from ..models import planetary as pm
    from ..studies import design as study

    params_file = args.params if args.params is not None else embedded.path("planetary.toml")
    if args.sets:
        params_file = f"{params_file} with " + ", ".join(f"{k} = {v!r}" for k, v in args.sets)
    data = parameters(args, "planetary")
    params = pm.load_params(data)
    spec = study.load_spec(args.design)
    if args.samples is not None:
        try:
            check_samples(args.samples, spec.verification["batches"])
        except ValueError as err:
            raise ValueError(f"`--samples`: {err}") from None
        spec.verification["n_samples"] = args.samples
    if args.max_iter is not None:
        spec.optimizer["max_iter"] = args.max_iter
    if args.periods is not None:
        spec.periods = args.periods
    out = (
        args.out
    )  # created and checked by main() before this: the history is written from the first iteration
    history = out / "history.json"
    if args.resume and not history.exists():
        raise ValueError(f"`--resume`: no history to resume in {str(out)!r} (run without --resume first)")
    start = time.perf_counter()

    def say(msg):
        print(f"[{time.perf_counter() - start:7.1f} s] {msg}", flush=True)

    say(
        f"parameters: {params_file}; design: {args.design or 'embedded design.toml'}; "
        f"horizon {spec.periods:g} carrier periods"
    )
    if args.resume:
        say(f"resuming from {history}: {_iterations_done(history)} iterations done")
    result = study.run_design(
        params, spec, history=history, resume=args.resume, pareto=not args.no_pareto, say=say
    )
    during = [
        p for p in (history, history.with_name(history.name + ".state.npz")) if p.is_file()
    ]  # resumable state
    written = publish(
        out,
        lambda folder: (
            study.write_outputs(result, spec, folder, data)
            + during
            + [write_parameters(folder, data, "planetary", args.command)]
        ),
        index=study.FILE_INDEX,
        title="pgtjax optimize: design optimization of the planetary train",
    )
    s = study.summary(result, spec)
    print(
        f"objective ({s['objective']['name']}, {s['objective']['unit']}): symmetric "
        f"{s['objective']['symmetric']:.6g} -> optimum {s['objective']['optimum']:.6g} "
        f"({100 * s['objective']['relative_change']:+.2f} %)"
    )
    for c in s["costs"]:
        print(f"cost ({c['name']}, {c['unit']}): {c['symmetric']:.6g} -> {c['optimum']:.6g}")
    print(s["monte_carlo"]["statement"])
    say(
        f"done; {len(written)} files written to {out.resolve()} (history.json, optimized_params.toml, "
        "summary.json, figures)"
    )
    return 0


def _iterations_done(history) -> str:
    """The number of iterations a history holds, as text ("?" if it cannot be read: resuming says why)."""
    try:
        return str(max(0, len(json.loads(history.read_text())["iterations"]) - 1))  # entry 0: the start
    except (OSError, ValueError, KeyError, TypeError):
        return "?"


def register(subparsers: argparse._SubParsersAction) -> None:
    about = (
        "design optimization (optax) of the planetary train: by default the stiffness of each of the "
        "6 ring bolts against the ring's deformation at the meshes, verified by Monte Carlo"
    )
    opt = subparsers.add_parser(
        "optimize",
        help=about,
        description=about + ". The defaults of --samples, --max-iter and --periods are the design file's "
        "(the embedded one: 2000 samples per design, 50 iterations, 1 carrier period).",
    )
    add_parameter_options(opt, "planetary")
    opt.add_argument(
        "--design",
        type=Path,
        default=None,
        help="design specification (TOML: variables, objective, costs, optimizer, horizon, "
        "verification, pareto); default: the embedded bolt study (pgtjax/params/design.toml)",
    )
    opt.add_argument(
        "--out",
        type=Path,
        default=Path("pgtjax-output") / "design",
        help="output folder (default: pgtjax-output/design)",
    )
    opt.add_argument("--resume", action="store_true", help="continue from the history in --out")
    opt.add_argument("--no-pareto", action="store_true", help="skip the Pareto front")
    opt.add_argument(
        "--samples",
        type=positive_int,
        default=None,
        help="Monte Carlo samples per design (default: the design file's)",
    )
    opt.add_argument(
        "--max-iter", type=positive_int, default=None, help="iteration limit (default: the design file's)"
    )
    opt.add_argument(
        "--periods", type=float, default=None, help="horizon in carrier periods (default: the design file's)"
    )
    opt.set_defaults(func=_run_optimize)
