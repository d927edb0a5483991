"""Ring-gear subcommands of the ``pgtjax`` CLI (thesis ch. 5-6): ``ring-modal``, ``ring-free-vibration``,
``ring-moving-load``. :func:`register` adds them to the subparsers of :func:`pgtjax.cli.build_parser`; the
work is done by :mod:`pgtjax.studies.ring_free_vibration` and :mod:`pgtjax.studies.ring_moving_load`.

Like the rest of the CLI, a bad input (a ``ValueError`` with a clear message) prints ``pgtjax: error: ...`` on
stderr and returns exit code 2; the handlers do that themselves so that they behave the same whichever
parser calls them.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path

from .._files import publish
from ._params import add_parameter_options, parameters, write_parameters
from ._types import csv_floats as _csv_floats
from ._types import csv_ints as _csv_ints
from ._types import element_count as _element_count
from ._types import nonneg_int as _nonneg_int
from ._types import positive_float as _positive_float
from ._types import sample_count as _sample_count


def _clear_errors(func):
    """ValueError -> ``pgtjax: error: ...`` on stderr, exit code 2 (the CLI's convention)."""

    @functools.wraps(func)
    def wrapper(args):
        try:
            return func(args)
        except ValueError as err:
            print(f"pgtjax: error: {err}", file=sys.stderr)
            return 2

    return wrapper


def _load(args):
    from ..studies import ring_moving_load as study

    return study.load_params(_data(args), support=args.support)


_SUPPORT_OPTION = "--support, which replaces [supports] by the chosen [support_cases] entry"


def _data(args) -> dict:
    return parameters(args, "ring_ch6", {"ring.n_elements": args.n_elements})


# --------------------------------------------------------------------------------------------- ring-modal


@_clear_errors
def _run_modal(args) -> int:
    from ..studies import ring_moving_load as study

    p = _load(args)
    table = study.modal_table(p, args.modes)
    print(json.dumps(table, indent=2) if args.json else study.format_modal_table(p, table))
    return 0


# ------------------------------------------------------------------------------------ ring-free-vibration


@_clear_errors
def _run_free_vibration(args) -> int:
    from ..studies import ring_free_vibration as fv

    table = fv.ring_gear_free_vibration_table(
        pitch_radius=args.pitch_radius, face_width=args.face_width, n_elements=args.n_elements
    )
    print(json.dumps(fv.json_table(table), indent=2) if args.json else fv.format_table(table))
    if not args.json:
        print(f"note: {fv.DISAGREEMENT_NOTE}")
    if args.out is not None:
        written = publish(
            args.out,
            lambda folder: fv.write_outputs(
                folder, pitch_radius=args.pitch_radius, face_width=args.face_width, n_elements=args.n_elements
            ),
            index=fv.FILE_INDEX,
            title="pgtjax ring-free-vibration: free Table 5.1 ring gear, Models I and II against Table 5.3 "
            "(thesis ch. 5)",
        )
        print(f"{len(written)} files written to {Path(args.out).resolve()}")
    return 0


# ---------------------------------------------------------------------------------------- ring-moving-load


@_clear_errors
def _run_moving_load(args) -> int:
    from ..studies import ring_moving_load as study

    data = _data(args)
    p = study.load_params(data, support=args.support)
    settings = study.resolve_settings(
        p,
        revolutions=args.revolutions,
        n_modes=args.modes,
        n_samples=args.samples,
        n_sweep=args.sweep_speeds,
        sweep_min=args.sweep_min,
        sweep_max=args.sweep_max,
        full=args.full,
    )
    out = args.out
    print(study.format_header(p, dt=args.dt, **settings), flush=True)
    start = time.perf_counter()
    result = study.run_study(
        p,
        dt=args.dt,
        **settings,
        sweep_steps=args.sweep_steps,
        speeds=args.speeds,
        noise_levels=args.noise_levels,
        support_cases=args.supports,
        progress=not args.quiet,
    )
    written = publish(
        out,
        lambda folder: (
            study.write_outputs(result, folder)
            + [
                write_parameters(
                    folder, data, "ring_ch6", args.command, _SUPPORT_OPTION if args.support else ""
                )
            ]
        ),
        index=study.FILE_INDEX,
        title="pgtjax ring-moving-load: bolted ring gear under random moving loads (thesis ch. 6, Figs. 6.3-6.9)",
    )
    print(study.format_summary(result))
    print(
        f"done in {time.perf_counter() - start:.1f} s; {len(written)} files written to {Path(out).resolve()}"
    )
    return 0


# --------------------------------------------------------------------------------------------- register


def _ring_file_options(p: argparse.ArgumentParser) -> None:
    add_parameter_options(p, "ring_ch6")
    p.add_argument(
        "--n-elements",
        type=_element_count,
        default=None,
        help="number of curved-beam elements (a multiple of the bolt count; default: the file's)",
    )
    p.add_argument(
        "--support",
        type=int,
        choices=(1, 2, 3),
        default=None,
        help="support case of Sec. 6.4.3: 1 bolts, 2 pins, 3 soft pins (default: the file's [supports])",
    )


def register(subparsers) -> None:
    """Add ``ring-modal``, ``ring-free-vibration`` and ``ring-moving-load`` to an argparse subparsers
    object."""
    modal = subparsers.add_parser(
        "ring-modal",
        help="natural frequencies of a supported ring (TOML parameter file)",
        description="Modal analysis of the curved-beam ring described by a parameter file: frequencies "
        "(Hz, rad/s) and circumferential wave numbers.",
    )
    _ring_file_options(modal)
    modal.add_argument(
        "--modes", type=_nonneg_int, default=24, help="modes listed (0 = all; default %(default)s)"
    )
    modal.add_argument("--json", action="store_true", help="print JSON instead of a table")
    modal.set_defaults(func=_run_modal)

    free = subparsers.add_parser(
        "ring-free-vibration",
        help="thesis ch. 5: free ring gear, Models I and II against Table 5.3",
        description="Free vibration of the Table 5.1 ring gear (Models I and II) for wave numbers n = 2..7, "
        "against Table 5.3.",
    )
    free.add_argument(
        "--pitch-radius",
        type=_positive_float,
        default=176.0e-3,
        help="pitch radius in m (ASSUMED, not in Table 5.1; default %(default)s)",
    )
    free.add_argument(
        "--face-width",
        type=_positive_float,
        default=33.5e-3,
        help="face width in m (ASSUMED, not in Table 5.1; default %(default)s)",
    )
    free.add_argument(
        "--n-elements", type=_element_count, default=64, help="elements (default %(default)s = Z)"
    )
    free.add_argument("--json", action="store_true", help="print JSON instead of a table")
    free.add_argument(
        "--out",
        type=Path,
        default=None,
        help="also write the table (JSON) and mode-shape PNGs into this folder",
    )
    free.set_defaults(func=_run_free_vibration)

    ml = subparsers.add_parser(
        "ring-moving-load",
        help="thesis ch. 6: ring gear under random moving loads (Figs. 6.3-6.9)",
        description="Stochastic Newmark moments of the bolted ring under N random moving mesh loads: base "
        "case with Monte Carlo (Figs. 6.3-6.4), three speeds (6.5-6.6), a speed sweep (6.7), "
        "noise levels (6.8), support cases (6.9), critical speeds against the ring's natural "
        "frequencies, mode shapes. Writes labelled .npz results, summary.json and PNGs.",
    )
    _ring_file_options(ml)
    ml.add_argument(
        "--revolutions",
        type=float,
        default=1.0 / 3.0,
        help="plotted window in revolutions (the mid-node response repeats every 1/3; default "
        "%(default).3g, --full: 1)",
    )
    ml.add_argument(
        "--dt",
        type=_positive_float,
        default=4e-5,
        help="time step in s; must resolve the first ring mode (8,590 rad/s; default %(default)s)",
    )
    ml.add_argument(
        "--modes",
        type=_nonneg_int,
        default=36,
        help="modal model with this many modes (0 = full FE model; default %(default)s)",
    )
    ml.add_argument(
        "--samples",
        type=_sample_count,
        default=200,
        help="Monte Carlo samples of the base case (0 skips MC; default %(default)s)",
    )
    ml.add_argument(
        "--speeds",
        type=_csv_floats,
        default=(22.0, 30.0, 50.0),
        help="comma-separated load speeds in rad/s of Figs. 6.5, 6.6, 6.8, 6.9 (default 22,30,50)",
    )
    ml.add_argument(
        "--sweep-speeds",
        type=_nonneg_int,
        default=48,
        help="number of speeds of the sweep (0 skips it; default %(default)s, --full: 190)",
    )
    ml.add_argument(
        "--sweep-min", type=_positive_float, default=2.8, help="lowest sweep speed (default %(default)s)"
    )
    ml.add_argument(
        "--sweep-max", type=_positive_float, default=50.0, help="highest sweep speed (default %(default)s)"
    )
    ml.add_argument(
        "--sweep-steps",
        type=_nonneg_int,
        default=1536,
        help="steps per sweep run (half a load period of warm-up + one load period; a multiple "
        "of 16; default %(default)s)",
    )
    ml.add_argument(
        "--noise-levels",
        type=_csv_floats,
        default=(0.5, 1.0, 2.0),
        help="noise levels of Fig. 6.8 as multiples of the file's b (default 0.5,1,2)",
    )
    ml.add_argument(
        "--supports",
        type=_csv_ints,
        default=(1, 2, 3),
        help="support cases of Fig. 6.9 (comma-separated among 1,2,3; empty skips; default 1,2,3)",
    )
    ml.add_argument(
        "--full",
        action="store_true",
        help="thesis size: one revolution, 190 sweep speeds, >= 1000 MC samples",
    )
    ml.add_argument(
        "--out",
        type=Path,
        default=Path("pgtjax-output") / "ring_moving_load",
        help="output folder (default: pgtjax-output/ring_moving_load)",
    )
    ml.add_argument("--quiet", action="store_true", help="no progress messages")
    ml.set_defaults(func=_run_moving_load)
