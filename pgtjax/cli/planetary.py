"""Planetary subcommands of the ``pgtjax`` CLI (thesis ch. 3): ``run`` (the main job at a quick size),
``planetary`` and ``planetary-modal``. :func:`register` adds them to the subparsers of
:func:`pgtjax.cli.build_parser`; the work is done by :mod:`pgtjax.studies.planetary`.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from .._files import publish
from ._params import add_parameter_options, parameters, write_parameters
from ._scale import (
    add_scale_out_options,
    as_command_line,
    checkpoint_path,
    checkpoints_of_run,
    start_processes,
)
from ._types import (
    criteria,
    csv_ints,
    csv_positive_floats,
    element_count,
    nonneg_float,
    nonneg_int,
    positive_float,
    positive_int,
    sample_count,
    seed,
)


def _add_planetary_options(p: argparse.ArgumentParser, quick: bool) -> None:
    add_parameter_options(p, "planetary")
    p.add_argument(
        "--samples",
        type=sample_count,
        default=300 if quick else 100_000,
        help="Monte Carlo samples (0 skips MC; default %(default)s; the thesis used 100,000)",
    )
    p.add_argument(
        "--periods", type=positive_float, default=1.0, help="carrier periods simulated (default 1)"
    )
    p.add_argument(
        "--dt",
        type=positive_float,
        default=0.0027,
        help="time step in s, below half the period of the mesh stiffness's highest harmonic (0.0273 s for the "
        "embedded parameters; default %(default)s, the thesis's)",
    )
    p.add_argument(
        "--saves",
        type=positive_int,
        default=2000,
        help="Monte Carlo saved times (default %(default)s: about 20 per mesh period, which resolves the "
        "meshing frequency in SL and MC alike)",
    )
    p.add_argument(
        "--sl-refine",
        type=positive_int,
        default=1,
        help="SL is saved this many times as often as MC (default %(default)s; more saves SL more densely "
        "than MC, whose statistics then cost less per save)",
    )
    p.add_argument(
        "--rim-thicknesses",
        type=csv_positive_floats,
        default=(0.087, 0.128, 0.168),
        help="rim thicknesses in m of the rim-thickness sweep (default 0.087,0.128,0.168: thesis Figs. 3.12-3.15)",
    )
    p.add_argument(
        "--support-counts",
        type=csv_ints,
        default=None,
        help="numbers of equally spaced bolts of the support sweep, each dividing the ring elements "
        "(default: those of 3,6,9 that do)",
    )
    p.add_argument(
        "--criteria",
        type=criteria,
        default="force",
        help="comma-separated SL criteria: force, energy (default %(default)s)",
    )
    p.add_argument(
        "--ring-model",
        choices=("elastic", "rigid"),
        default=None,
        help="override the parameter file's ring model",
    )
    p.add_argument(
        "--elements", type=element_count, default=None, help="override the number of ring elements"
    )
    p.add_argument("--no-sweeps", action="store_true", help="skip the rim-thickness and support studies")
    p.add_argument("--no-sensitivities", action="store_true", help="skip the autodiff sensitivities")
    p.add_argument(
        "--seed",
        type=seed,
        default=0,
        help="PRNG seed of the Monte Carlo (any 64-bit integer; default %(default)s)",
    )
    p.add_argument(
        "--peak-forces",
        type=nonneg_int,
        default=0,
        metavar="BINS",
        help="Monte Carlo also counts every meshing force's peak (its largest magnitude over every step "
        "since the start) in BINS bins from 0 N to SL's largest |mean| + 8 std: "
        "planetary_peak_forces.png draws the probability that the peak has reached each level, with SL's "
        "estimate (an SL run saved every step), and peak_meshing_forces in summary.json gives its quantiles "
        "(default 0: off)",
    )
    p.add_argument(
        "--peak-start",
        type=nonneg_float,
        default=0.0,
        metavar="SECONDS",
        help="with --peak-forces: count the peaks from this time on (the nearest Monte Carlo save), e.g. after a "
        "start-up transient (default 0: from the start)",
    )
    p.add_argument(
        "--chunk-size",
        type=positive_int,
        default=None,
        help="MC samples per compiled batch and device; bounds memory (default 5000 on a CPU, 100000 on a GPU)",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=Path("pgtjax-output") / "planetary",
        help="output folder (default: pgtjax-output/planetary)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    add_scale_out_options(p)


def _params(args):
    """``(PlanetaryParams, the checked parameter dict)``: ``--params``, ``--set``, ``--ring-model`` and
    ``--elements``."""
    from ..models import planetary as pm

    data = parameters(args, "planetary", {"ring_model": args.ring_model, "ring.n_elements": args.elements})
    return pm.load_params(data), data


def _run_planetary(args) -> int:
    import jax

    from .._montecarlo import check_options, checkpoint_samples
    from ..studies import planetary as study

    if args.resume and not args.samples:
        raise ValueError("`--resume` continues a Monte Carlo; it needs `--samples` >= 2")
    if args.peak_forces and not args.samples:
        raise ValueError("`--peak-forces` counts Monte Carlo samples; it needs `--samples` >= 2")
    if args.peak_start and not args.peak_forces:
        raise ValueError("`--peak-start` sets where the peaks are counted from; it needs `--peak-forces` > 0")
    started = time.time()
    process = start_processes(args)  # before any JAX computation
    params, data = _params(args)
    if args.support_counts is not None and params.ring_model == "elastic":
        try:  # before any simulation
            study.check_support_counts(params, args.support_counts)
        except ValueError as err:
            raise ValueError(str(err).replace("`support_counts`", "`--support-counts`")) from None
    out = args.out
    study_kw = dict(
        n_samples=args.samples,
        dt=args.dt,
        periods=args.periods,
        n_saves=args.saves,
        sl_refine=args.sl_refine,
        criteria=args.criteria,
        key=jax.random.key(args.seed),
        chunk_size=args.chunk_size,
        checkpoint=checkpoint_path(args, out) if args.samples else None,
        checkpoint_every=args.checkpoint_every,
        resume=args.resume,
        peak_force_bins=args.peak_forces,
        peak_start=args.peak_start,
    )
    if args.samples:  # before any work: the checkpoint's folder, and a checkpoint to resume of this very run
        try:
            check_options(
                args.samples, args.chunk_size, study_kw["checkpoint"], args.resume, key=study_kw["key"]
            )
        except ValueError as err:
            raise as_command_line(err) from None
    if process:  # another process of a distributed run: its share of the Monte Carlo, no output
        try:
            study.run_study(params, progress=False, **study_kw)
        except ValueError as err:
            raise as_command_line(err) from None
        return 0
    try:
        header = study.format_header(
            params,
            periods=args.periods,
            dt=args.dt,
            criteria=args.criteria,
            n_samples=args.samples,
            n_saves=args.saves,
            sl_refine=args.sl_refine,
        )
    except ValueError as err:
        raise as_command_line(err) from None
    print(header)
    if jax.process_count() > 1:
        print(f"Monte Carlo split over {jax.process_count()} processes ({len(jax.devices())} devices in all)")
    elif args.samples:
        local = jax.local_devices()
        kind = local[0].platform.upper()
        one_cpu = local[0].platform == "cpu" and len(local) == 1
        hint = " (`pgtjax --cpu-devices N COMMAND` shards it over N)" if one_cpu else ""
        where = f"sharded over {len(local)} {kind} devices" if len(local) > 1 else f"on 1 {kind} device"
        print(f"Monte Carlo {where}{hint}")
    start = time.perf_counter()
    step = lambda msg: print(f"[{time.perf_counter() - start:7.1f} s] {msg}", flush=True)  # noqa: E731
    resuming = ""
    if args.resume:
        held = checkpoint_samples(study_kw["checkpoint"])
        if held is not None:
            of = f"{args.samples:,}" if jax.process_count() == 1 else "process 0's"
            resuming = f" (resuming: the checkpoint holds {held:,} of {of} samples)"
    step("SL + moment recursion" + (" and Monte Carlo" if args.samples else "") + resuming)
    try:
        result = study.run_study(params, progress=not args.quiet, **study_kw)
    except ValueError as err:
        raise as_command_line(err) from None
    sweeps = None
    if not args.no_sweeps:
        sweeps = study.standard_sweeps(
            params,
            dt=args.dt,
            periods=args.periods,
            n_saves=args.saves,
            sl_refine=args.sl_refine,
            thicknesses=args.rim_thicknesses,
            support_counts=args.support_counts,
            say=step,
        )
    step("modal analysis")
    modal = study.modal_table(params)
    sens = None if args.no_sensitivities else study.elastic_sensitivities(params, dt=args.dt, say=step)
    checkpoint = checkpoints_of_run(
        study_kw["checkpoint"], since=started, resumed=args.resume, processes=jax.process_count()
    )
    written = publish(
        out,
        lambda folder: (
            study.write_outputs(result, folder, sweeps=sweeps, modal=modal, sens=sens)
            + checkpoint
            + [write_parameters(folder, data, "planetary", args.command)]
        ),
        index=study.FILE_INDEX,
        title=f"pgtjax {args.command}: planetary gear train (thesis ch. 3)",
    )
    if result.mc is not None:
        print(study.format_error_summary(study.error_summary(result)))
    if sens is not None:
        print(study.format_sensitivities(sens))
    step(f"done; {len(written)} files written to {out.resolve()}")
    return 0


def _run_planetary_modal(args) -> int:
    from ..studies import planetary as study

    rows = study.modal_table(_params(args)[0])
    print(json.dumps(rows, indent=2) if args.json else study.format_modal_table(rows))
    return 0


def _full(args):
    if args.full:
        args.samples = 100_000
    return args


def register(subparsers) -> None:
    """Add ``run``, ``planetary`` and ``planetary-modal`` to an argparse subparsers object."""
    run = subparsers.add_parser(
        "run",
        help="the main job on the embedded default parameters: the ch. 3 "
        "planetary study at a quick size (--full: the thesis's "
        "100,000 MC samples)",
    )
    _add_planetary_options(run, quick=True)
    run.add_argument("--full", action="store_true", help="thesis size: 100,000 MC samples")
    run.set_defaults(func=lambda a: _run_planetary(_full(a)))

    plan = subparsers.add_parser(
        "planetary",
        help="thesis ch. 3: planetary gear train with elastic ring, SL "
        "vs MC, rim thickness, supports, modes, sensitivities",
    )
    _add_planetary_options(plan, quick=False)
    plan.set_defaults(func=_run_planetary)

    pmodal = subparsers.add_parser(
        "planetary-modal", help="natural frequencies and mode types of the planetary model"
    )
    add_parameter_options(pmodal, "planetary")
    pmodal.add_argument(
        "--ring-model", choices=("elastic", "rigid"), default=None, help="override the ring model"
    )
    pmodal.add_argument(
        "--elements", type=element_count, default=None, help="override the number of ring elements"
    )
    pmodal.add_argument("--json", action="store_true", help="print JSON instead of a table")
    pmodal.set_defaults(func=_run_planetary_modal)
