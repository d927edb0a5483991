"""Atomic file writes: a temporary name in the target's folder, renamed into place, so that an interrupted
run leaves the previous file (or none), never a truncated one under the final name."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path


def write_atomic(path, write: Callable[[Path], None]) -> Path:
    """Call ``write(temporary_path)`` and rename the result to ``path``; returns ``path``."""
    path = Path(path)
    partial = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
    try:
        write(partial)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
    return path


def write_text(path, text: str) -> Path:
    return write_atomic(path, lambda p: p.write_text(text))


def write_json(path, data) -> Path:
    return write_text(path, json.dumps(data, indent=2, default=float) + "\n")
