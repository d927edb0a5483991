"""Gear-pair subcommands of the ``pgtjax`` CLI (thesis ch. 4): ``gear-pair``, ``gear-pair-step`` and
``gear-pair-modal``. :func:`register` adds them to the subparsers of :func:`pgtjax.cli.build_parser`; the work
is done by :mod:`pgtjax.studies.gear_pair`.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from .._files import publish
from ._params import add_parameter_options, parameters, write_parameters
from ._types import (
    criteria,
    csv_nonneg_floats,
    csv_positive_floats,
    positive_float,
    positive_int,
    sample_count,
    seed,
)


def _add_gear_pair_options(p: argparse.ArgumentParser, quick: bool) -> None:
    add_parameter_options(p, "gear_pair")
    p.add_argument(
        "--samples",
        type=sample_count,
        default=2000 if quick else 20_000,
        help="Monte Carlo samples per regime (0 skips MC; default %(default)s)",
    )
    p.add_argument("--dt", type=positive_float, default=1e-5, help="time step in s (default %(default)s)")
    p.add_argument(
        "--t-end", type=positive_float, default=0.04, help="simulated time in s (default %(default)s)"
    )
    p.add_argument(
        "--saves",
        type=positive_int,
        default=400,
        help="number of saved times (default %(default)s: about 19 per mesh period of the default run, "
        "so that the meshing ripple is resolved)",
    )
    p.add_argument(
        "--criteria",
        type=criteria,
        default="force,energy",
        help="comma-separated SL criteria among force, energy (default %(default)s)",
    )
    p.add_argument(
        "--pdf-times",
        type=csv_nonneg_floats,
        default=None,
        help="comma-separated times in s for the PDF of the mesh deflection (default: 3/4 of --t-end, 0.03 s)",
    )
    p.add_argument("--seed", type=seed, default=0, help="PRNG seed of the Monte Carlo (default %(default)s)")
    p.add_argument(
        "--chunk-size",
        type=positive_int,
        default=None,
        help="MC samples per compiled batch and device; bounds memory (default 10000 on a CPU, 100000 on a GPU)",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=Path("pgtjax-output") / "gear_pair",
        help="output folder (default: pgtjax-output/gear_pair)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _run_gear_pair(args) -> int:
    import jax

    from ..studies import gear_pair as study

    data = parameters(args, "gear_pair")
    params, regimes = study.load_inputs(data)
    out = args.out
    print(
        study.format_header(
            regimes, criteria=args.criteria, n_samples=args.samples, dt=args.dt, t_end=args.t_end
        )
    )
    start = time.perf_counter()
    result = study.run_study(
        params,
        regimes=regimes,
        criteria=args.criteria,
        n_samples=args.samples,
        dt=args.dt,
        t_end=args.t_end,
        n_saves=args.saves,
        pdf_times=args.pdf_times,
        key=jax.random.key(args.seed),
        chunk_size=args.chunk_size,
        progress=not args.quiet,
    )
    written = publish(
        out,
        lambda folder: (
            study.write_outputs(result, folder) + [write_parameters(folder, data, "gear_pair", args.command)]
        ),
        index=study.FILE_INDEX,
        title="pgtjax gear-pair: spur gear pair with backlash, SL against Monte Carlo (thesis ch. 4)",
    )
    if args.samples:
        rows = study.error_table(result)
        print(study.format_error_table(rows))
        notes = study.format_impact_notes(rows)
        if notes:
            print(notes)
    print(f"done in {time.perf_counter() - start:.1f} s; {len(written)} files written to {out.resolve()}")
    return 0


def _run_step_study(args) -> int:
    from ..studies import gear_pair as study

    rows = study.step_convergence(
        study.load_params(parameters(args, "gear_pair")), dts=args.dts, t_end=args.t_end
    )
    print(json.dumps(rows, indent=2) if args.json else study.format_step_table(rows))
    return 0


def _run_modal(args) -> int:
    from ..studies import gear_pair as study

    rows = study.modal_table(study.load_params(parameters(args, "gear_pair")))
    print(json.dumps(rows, indent=2) if args.json else study.format_modal_table(rows))
    return 0


def register(subparsers) -> None:
    """Add ``gear-pair``, ``gear-pair-step`` and ``gear-pair-modal`` to an argparse subparsers object."""
    gear = subparsers.add_parser(
        "gear-pair", help="thesis ch. 4: gear pair with backlash, SL vs MC in three regimes"
    )
    _add_gear_pair_options(gear, quick=False)
    gear.set_defaults(func=_run_gear_pair)

    step = subparsers.add_parser(
        "gear-pair-step", help="time-step convergence study of the gear-pair SL moments"
    )
    add_parameter_options(step, "gear_pair")
    step.add_argument(
        "--dts",
        type=csv_positive_floats,
        default="4e-5,2e-5,1e-5,5e-6,2.5e-6",
        help="comma-separated steps in s, the last the reference (default %(default)s)",
    )
    step.add_argument(
        "--t-end", type=positive_float, default=0.04, help="simulated time in s (default %(default)s)"
    )
    step.add_argument("--json", action="store_true", help="print JSON instead of a table")
    step.set_defaults(func=_run_step_study)

    modal = subparsers.add_parser(
        "gear-pair-modal",
        help="natural frequencies and mode shapes of the gear pair (mesh closed at its mean stiffness)",
    )
    add_parameter_options(modal, "gear_pair")
    modal.add_argument("--json", action="store_true", help="print JSON instead of a table")
    modal.set_defaults(func=_run_modal)
