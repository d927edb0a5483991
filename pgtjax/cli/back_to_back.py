"""CLI of the back-to-back bench study (bench paper, Hammami et al.): ``pgtjax back-to-back`` and
``pgtjax back-to-back-modal``.

``register(subparsers)`` adds both subcommands to the ``pgtjax`` parser (called from :mod:`pgtjax.cli`); the
work is done by :mod:`pgtjax.studies.back_to_back`.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from .._files import publish
from ._params import add_parameter_options, parameters, write_parameters
from ._types import nonneg_float as _nonnegative_float
from ._types import positive_float as _positive_float
from ._types import positive_int as _positive_int


def _load(args, data=None):
    from ..studies import back_to_back as study

    return study.load_params(
        parameters(args, "back_to_back") if data is None else data,
        speed_start_rpm=getattr(args, "speed_start_rpm", None),
        speed_end_rpm=getattr(args, "speed_end_rpm", None),
        ramp_start=getattr(args, "ramp_start", None),
        ramp_duration=getattr(args, "ramp_duration", None),
        torque=getattr(args, "torque", None),
        torque_end=getattr(args, "torque_end", None),
        face_width=getattr(args, "face_width", None),
    )


def _run(args) -> int:
    from ..studies import back_to_back as study

    data = parameters(args, "back_to_back")
    params = _load(args, data)
    out = args.out
    t_end = study.run_up_end(params) if args.t_end is None else args.t_end
    print(study.format_header(params, dt=args.dt, t_end=t_end), flush=True)
    start = time.perf_counter()
    result = study.run_study(
        params,
        t_end=t_end,
        dt=args.dt,
        stationary_t_end=args.stationary_t_end,
        save_every=args.save_every,
        stft_window=args.stft_window,
        progress=not args.quiet,
    )
    print("  writing results and figures ...", flush=True)
    outside = (
        "the operating-point options (--torque, --torque-end, --speed-start-rpm, --speed-end-rpm, --ramp-start, "
        "--ramp-duration, --face-width), which act on the model directly"
    )
    written = publish(
        out,
        lambda folder: (
            study.write_outputs(result, folder)
            + [write_parameters(folder, data, "back_to_back", args.command, outside)]
        ),
        index=study.FILE_INDEX,
        title="pgtjax back-to-back: planetary bench of the bench paper (Hammami et al.), stationary regime and run-up",
    )
    print(study.format_hertz(result.hertz))
    print(f"note: {study.hertz_note(result.hertz)}")
    print(study.format_ridges(result.ridges))
    print(
        f"done in {time.perf_counter() - start:.1f} s; {len(written)} files written to {Path(out).resolve()}"
    )
    return 0


def _modal(args) -> int:
    from ..studies import back_to_back as study

    rows = study.modal_table(_load(args), motor=args.motor)
    print(json.dumps(rows, indent=2) if args.json else study.format_modal_table(rows))
    return 0


def _common(p: argparse.ArgumentParser) -> None:
    add_parameter_options(p, "back_to_back")
    p.add_argument(
        "--torque",
        type=_nonnegative_float,
        default=None,
        help="circulating test-sun torque in N m (stationary regime / start of the run-up)",
    )
    p.add_argument(
        "--face-width",
        type=_positive_float,
        default=None,
        help="face width = Hertz contact length in m (default 0.020, assumed)",
    )


def register(subparsers) -> None:
    """Add ``back-to-back`` and ``back-to-back-modal`` to an ``argparse`` subparsers object."""
    run = subparsers.add_parser(
        "back-to-back",
        help="bench paper, Hammami et al.: back-to-back planetary bench, stationary regime and run-up (Newmark-Newton, "
        "Hertzian mesh stiffness, transmission error, STFT)",
        description="Simulate the back-to-back planetary bench in a stationary regime and in a run-up; write "
        "labelled trajectories (.npz), mesh histories (Hertzian and mesh stiffness, transmission "
        "error, mesh forces, ring accelerations), summary.json (Hertzian stiffness against the paper, "
        "STFT ridge checks, natural frequencies) and PNG figures (including STFT maps).",
    )
    _common(run)
    run.add_argument(
        "--dt", type=_positive_float, default=1e-4, help="time step in s (default %(default)s, as the paper)"
    )
    run.add_argument(
        "--t-end",
        type=_positive_float,
        default=None,
        help="run-up simulation length in s (default: ramp start + ramp duration)",
    )
    run.add_argument(
        "--stationary-t-end",
        type=_positive_float,
        default=0.2,
        help="length of the separate stationary run in s (default %(default)s)",
    )
    run.add_argument(
        "--speed-start-rpm",
        type=_nonnegative_float,
        default=None,
        help="motor speed of the stationary regime in rpm (default 900, assumed)",
    )
    run.add_argument(
        "--speed-end-rpm",
        type=_nonnegative_float,
        default=None,
        help="motor speed at the end of the run-up in rpm (default 1500, assumed)",
    )
    run.add_argument(
        "--ramp-start", type=_nonnegative_float, default=None, help="start of the run-up in s (default 0.5)"
    )
    run.add_argument(
        "--ramp-duration",
        type=_positive_float,
        default=None,
        help="duration of the linear run-up in s (default 1.0)",
    )
    run.add_argument(
        "--torque-end",
        type=_nonnegative_float,
        default=None,
        help="circulating torque at the end of the run-up in N m (default 300, assumed)",
    )
    run.add_argument(
        "--save-every",
        type=_positive_int,
        default=1,
        help="save every n-th step (default %(default)s; STFTs need the sampling rate 1/(n dt))",
    )
    run.add_argument(
        "--stft-window",
        type=_positive_float,
        default=0.1,
        help="STFT window length in s (default %(default)s)",
    )
    run.add_argument(
        "--out",
        type=Path,
        default=Path("pgtjax-output") / "back_to_back",
        help="output folder (default: pgtjax-output/back_to_back)",
    )
    run.add_argument("--quiet", action="store_true", help="no progress lines")
    run.set_defaults(func=_run)

    modal = subparsers.add_parser(
        "back-to-back-modal",
        help="natural frequencies and mode shapes of the back-to-back bench (meshes at their mean stiffness)",
        description="Modal analysis of the 12-DOF bench with every mesh a linear spring of its mean tangent "
        "stiffness at the circulating torque. Without --motor the train has one rigid rotation (0 Hz).",
    )
    _common(modal)
    modal.add_argument("--motor", action="store_true", help="include the motor shaft (rotor held fixed)")
    modal.add_argument("--json", action="store_true", help="print JSON instead of a table")
    modal.set_defaults(func=_modal)
