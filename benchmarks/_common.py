"""Shared helpers of the benchmark scripts: machine description, timing, JSON output."""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from pathlib import Path

import jax

RESULTS = Path(__file__).parent / "results"


def machine() -> dict:
    """What the figures were measured on."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            names = [line.split(":", 1)[1].strip() for line in fh if line.startswith("model name")]
        cpu = names[0] if names else cpu
    except OSError:
        pass
    return dict(
        platform=platform.platform(),
        python=platform.python_version(),
        cpu=cpu,
        cpu_count=os.cpu_count(),
        jax=jax.__version__,
        backend=jax.default_backend(),
        devices=[str(d) for d in jax.devices()],
    )


def timed(fn, *args, repeats: int = 3, **kwargs):
    """(first-call seconds incl. compilation, median seconds of `repeats` further calls, all times, result)."""
    t = time.perf_counter()
    out = jax.block_until_ready(fn(*args, **kwargs))
    first = time.perf_counter() - t
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = jax.block_until_ready(fn(*args, **kwargs))
        times.append(time.perf_counter() - t)
    return first, statistics.median(times), times, out


def timed_interleaved(fns: dict, *args, repeats: int = 3, serpentine: bool = False) -> dict:
    """Like :func:`timed` for several functions of the same arguments, their timed calls alternating
    (f, g, f, g, ...) so that a ratio between them sees the same machine load. With ``serpentine`` every other
    round runs them in reverse order (f, g, h, h, g, f, f, ...), so that no function always follows the same
    one: a run can slow the next one of the process (the gear pair's peers slowed pgtjax's next run by 10-20 %,
    2026-11-26), and the median then drops that round. Returns, per name, ``dict(first_call_s, median_s,
    runs_s)``."""
    out = {}
    for name, fn in fns.items():
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        out[name] = dict(first_call_s=time.perf_counter() - t, runs_s=[])
    for round_index in range(repeats):
        names = list(fns)
        for name in reversed(names) if serpentine and round_index % 2 else names:
            t = time.perf_counter()
            jax.block_until_ready(fns[name](*args))
            out[name]["runs_s"].append(time.perf_counter() - t)
    for row in out.values():
        row["median_s"] = statistics.median(row["runs_s"])
    return out


def write(name: str, payload: dict, machine_info: dict | None = None, keep_machine: bool = False) -> Path:
    """``results/<name>.json`` (atomically) with the machine (``machine_info``: measured in another process,
    e.g. one with forced host devices) and the date; ``keep_machine``: the payload's own ``machine`` and
    ``date`` are kept (a file of which one section was measured again, with its own machine and date)."""
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / f"{name}.json"
    if not keep_machine:
        payload = dict(machine=machine_info or machine(), date=time.strftime("%Y-%m-%d %H:%M:%S"), **payload)
    # imported here, not at the top: compare_timing.py imports this module with older trees too
    from pgtjax._files import write_text

    return write_text(path, json.dumps(payload, indent=2))
