"""Command-line interface: ``pgtjax <study> [options]``; ``pgtjax run`` is the main job on embedded defaults.

One module per study family registers its subcommands on the parser of :func:`build_parser`:
:mod:`~pgtjax.cli.planetary` (``run``, ``planetary``, ``planetary-modal``), :mod:`~pgtjax.cli.gear_pair`
(``gear-pair``, ``gear-pair-step``, ``gear-pair-modal``), :mod:`~pgtjax.cli.ring` (``ring-modal``,
``ring-free-vibration``, ``ring-moving-load``) and :mod:`~pgtjax.cli.back_to_back` (``back-to-back``,
``back-to-back-modal``); :mod:`~pgtjax.cli.design` (``optimize``). The handlers only wire options to the functions of :mod:`pgtjax.studies` and print
what those return; ``python3 -m pgtjax.cli`` runs :func:`main` like the ``pgtjax`` console script.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
import threading
import time
import warnings
from pathlib import Path

from .. import ProcessFailedError, SolverError, use_compilation_cache, use_cpu_cores
from .._files import interrupted_message
from .._parallel import lapack_batches_wait_on_pool
from . import back_to_back, design, gear_pair, planetary, ring
from ._scale import checkpoint_path, checkpoints_of_run
from ._types import positive_int

__all__ = ["build_parser", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pgtjax",
        description="Differentiable stochastic dynamics of planetary gear trains: statistical linearization, "
        "stochastic Newmark moments and Monte Carlo on JAX.",
    )
    parser.add_argument(
        "--cpu-devices",
        type=positive_int,
        default=None,
        metavar="N",
        help="on a CPU, shard Monte Carlo samples and design batches over N JAX devices, one core each "
        "(default: one per core with jaxlib 0.11.1 or later; with jaxlib 0.10.0-0.11.0, on which a run on "
        "several CPU devices has hung (README, 'Scaling out'), JAX's one CPU device; either way the count "
        "forced in XLA_FLAGS if set)",
    )
    parser.add_argument(
        "--compilation-cache",
        default=None,
        metavar="DIR",
        help="keep XLA's compiled programs in the folder DIR (no default; e.g. ~/.cache/pgtjax/xla), so that "
        "the next run loads them instead of compiling them again (`pgtjax run`: 31 s instead of 53 s the "
        "second time); results are the same. Give it before COMMAND",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    planetary.register(sub)
    gear_pair.register(sub)
    ring.register(sub)
    back_to_back.register(sub)
    design.register(sub)
    for p in (parser, *sub.choices.values()):
        _accept_negative_exponents(p)
    return parser


def _accept_negative_exponents(parser: argparse.ArgumentParser) -> None:
    """Let a value such as ``-1e-5`` reach its option's check (which then names the accepted range): the
    argparse of Python 3.11 takes a token for a negative number only without an exponent, and reads
    ``--dt -1e-5`` as an option ``-1e-5`` ("expected one argument"). The attribute is argparse's own; where it
    is missing, nothing changes."""
    if hasattr(parser, "_negative_number_matcher"):
        parser._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def _check_writable(out) -> list[Path]:
    """``ValueError`` naming ``--out`` unless the folder can be created and written, checked before any
    computation (a read-only place or a regular file would otherwise fail only after the whole study).
    Returns the folders this check created itself, deepest first, for :func:`_remove_if_empty`."""
    path = Path(os.path.abspath(out))  # ".." resolved first: a folder is one of ours only if we made it
    probe = path / f".pgtjax-write-check-{os.getpid()}"
    created: list[Path] = []
    try:
        for folder in reversed([path, *path.parents]):
            try:
                folder.mkdir()
            except FileExistsError:
                continue
            created.append(folder)
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        _remove_if_empty(created[::-1])
        raise ValueError(
            f"`--out` {str(out)!r} cannot be created or written: {err.strerror or err}"
        ) from None
    return created[::-1]


def _remove_if_empty(folders) -> None:
    """Remove the folders the write check created (deepest first) where a failed command left them empty: bad
    input found by the study itself then leaves no output folder behind that looks like a run's."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:  # not empty (a checkpoint, a file another run wrote there) or already gone: keep it
            return


def _resume_files(args, started: float) -> list[Path]:
    """The files an interrupted run of a resumable command leaves for ``--resume``: its Monte Carlo checkpoints
    (one per process in a distributed run) or its optimization history, if this run wrote them or resumed
    from them (a checkpoint older than the run, left by an earlier one, is not this run's)."""
    if hasattr(args, "checkpoint"):  # the Monte Carlo commands
        return checkpoints_of_run(checkpoint_path(args, Path(args.out)), started, bool(args.resume))
    history = Path(args.out) / "history.json"  # optimize
    try:
        return (
            [history]
            if history.is_file() and (args.resume or history.stat().st_mtime >= started - 1.0)
            else []
        )
    except OSError:
        return []


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    out = getattr(args, "out", None)
    resumable = getattr(args, "resume", None) is not None
    started = time.time()

    def interrupted(signum, frame):
        # leave from the handler itself: a KeyboardInterrupt raised inside a callback (JAX's garbage-collection
        # hook, say) is swallowed there, and the interpreter's teardown while XLA threads run can crash
        kept = _resume_files(args, started) if resumable else []
        os.write(2, f"pgtjax: {interrupted_message(resumable, kept)}\n".encode())
        os._exit(130)

    created: list[Path] = []  # folders made by the write check, removed again if the command fails empty
    succeeded = False
    main_thread = threading.current_thread() is threading.main_thread()  # handlers live there only
    previous = signal.signal(signal.SIGINT, interrupted) if main_thread else None
    try:
        if args.cpu_devices is not None:  # before any JAX computation (docs/performance.md: the jaxlib hang)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                use_cpu_cores(args.cpu_devices)
            for warning in caught:  # one line each, as the CLI's other messages
                print(f"pgtjax: warning: {warning.message}", file=sys.stderr)
        elif not lapack_batches_wait_on_pool():  # every core, on a jaxlib that cannot hang so
            use_cpu_cores()
        if args.compilation_cache is not None:
            use_compilation_cache(args.compilation_cache, option="--compilation-cache")
        if out is not None:
            created = _check_writable(out)
        status = args.func(args)
        succeeded = not status
        return status
    except (ValueError, argparse.ArgumentTypeError) as err:  # bad input: a clear message, no traceback
        print(f"pgtjax: error: {err}", file=sys.stderr)
        return 2
    except ProcessFailedError as err:  # another process of a distributed run failed: its output says why
        print(f"pgtjax: error: {err}", file=sys.stderr)
        return 1
    except SolverError as err:  # a numerical failure, with when and where
        print(f"pgtjax: numerical failure: {err}", file=sys.stderr)
        return 1
    except OSError as err:  # a file that could not be read or written: one line
        print(f"pgtjax: error: {err}", file=sys.stderr)
        return 1
    finally:
        if not succeeded:
            _remove_if_empty(created)
        if main_thread:
            signal.signal(signal.SIGINT, previous)
