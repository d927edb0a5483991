"""Options shared by the Monte Carlo commands for running beyond one device and one process, and across
interruptions: checkpoints, resume, and JAX's distributed runtime."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from ._types import positive_int

CHECKPOINT_NAME = "monte_carlo.checkpoint.npz"


def add_scale_out_options(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("checkpoints and several processes")
    g.add_argument(
        "--checkpoint",
        type=Path,
        default=None,
        help=f"Monte Carlo checkpoint (.npz), rewritten atomically after every --checkpoint-every batches "
        f"(default: {CHECKPOINT_NAME} in the output folder)",
    )
    g.add_argument(
        "--checkpoint-every", type=positive_int, default=1, help="batches between checkpoints (default 1)"
    )
    g.add_argument(
        "--resume",
        action="store_true",
        help="continue the Monte Carlo of an interrupted run of the same command from its checkpoint",
    )
    g.add_argument(
        "--distributed",
        action="store_true",
        help="split the Monte Carlo over the processes of a job started by SLURM or Open MPI "
        "(jax.distributed.initialize detects them); process 0 prints and writes the outputs",
    )
    g.add_argument(
        "--coordinator", default=None, help="HOST:PORT of process 0 (with --processes, --process-id)"
    )
    g.add_argument("--processes", type=positive_int, default=None, help="number of processes")
    g.add_argument("--process-id", type=int, default=None, help="this process's index, 0 to --processes - 1")


def checkpoint_path(args, out: Path) -> Path:
    return args.checkpoint if args.checkpoint is not None else out / CHECKPOINT_NAME


def checkpoints_of_run(base: Path | None, since: float, resumed: bool, processes: int | None = None) -> list:
    """The Monte Carlo checkpoints a run wrote or resumed: ``base``, or each process's file of a distributed
    run of ``processes`` (None: any process count found beside ``base``), where this folder holds them. A file
    older than the run (``since``, time.time()) is an earlier run's, unless this run resumed it."""
    if base is None:
        return []
    from .._checkpoint import process_checkpoint_name  # here: the parser itself does not import JAX

    if processes is None:
        candidates = [base, *sorted(base.parent.glob(f"{base.stem}.process-*-of-*.npz"))]
    else:
        candidates = [process_checkpoint_name(base, p, processes) for p in range(processes)]
    try:
        # 1 s of slack: a file system may store times more coarsely than time.time() reads them
        return [p for p in candidates if p.is_file() and (resumed or p.stat().st_mtime >= since - 1.0)]
    except OSError:
        return []


#: the Python names of Monte Carlo's options as the command line spells them, for messages raised below it
_OPTION_NAMES = {
    "`checkpoint`": "`--checkpoint`",
    "`chunk_size`": "`--chunk-size`",
    "`n_samples`": "`--samples`",
    "`dt`": "`--dt`",
    "`periods`": "`--periods`",
    "`resume=True`": "`--resume`",
    "run without resume": "run without --resume",
    "key: checkpoint": "key, from --seed: checkpoint",
}


def as_command_line(err: ValueError) -> ValueError:
    """``err`` with Monte Carlo's Python option names replaced by their command-line options."""
    text = str(err)
    for python, option in _OPTION_NAMES.items():
        text = text.replace(python, option)
    return ValueError(text)


def _check_coordinator(address: str) -> None:
    host, _, port = address.rpartition(":")
    ipv6_unbracketed = ":" in host and not (host.startswith("[") and host.endswith("]"))
    if not host or ipv6_unbracketed or not re.fullmatch(r"[0-9]{1,5}", port) or not 1 <= int(port) <= 65535:
        raise ValueError(
            "`--coordinator` must be HOST:PORT with a port from 1 to 65535, an IPv6 host in brackets "
            f"(e.g. 127.0.0.1:12355 or [::1]:12355), got {address!r}"
        )


def start_processes(args) -> int:
    """Join JAX's distributed runtime if asked to (before any JAX computation); returns this process's index
    (0 when running alone). ``ValueError`` for an incomplete or inconsistent set of options."""
    explicit = (args.coordinator, args.processes, args.process_id)
    if all(v is None for v in explicit) and not args.distributed:
        return 0
    if any(v is None for v in explicit) and not all(v is None for v in explicit):
        raise ValueError("`--coordinator`, `--processes` and `--process-id` must be given together")
    if args.process_id is not None and not 0 <= args.process_id < args.processes:
        raise ValueError(
            f"`--process-id` must be in 0..{args.processes - 1} (--processes {args.processes}), "
            f"got {args.process_id}"
        )
    if args.coordinator is not None:
        _check_coordinator(args.coordinator)
    import jax

    if args.coordinator is None:
        jax.distributed.initialize()  # SLURM / Open MPI: address, count and index from the environment
    else:
        jax.distributed.initialize(args.coordinator, num_processes=args.processes, process_id=args.process_id)
    return jax.process_index()
