"""Checkpoints of long runs: arrays and a description of the run in one ``.npz``, written atomically, read
back only by a run with the same description (so a resumed run cannot mix two different computations)."""

from __future__ import annotations

import hashlib
import json
import re
import zipfile
from pathlib import Path

import jax
import numpy as np

from ._files import write_atomic

CHECKPOINT_FORMAT = "pgtjax-checkpoint-1"


def _leaf_bytes(leaf) -> bytes:
    if isinstance(leaf, jax.Array) and jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
        leaf = jax.random.key_data(leaf)
    if isinstance(leaf, jax.Array | np.ndarray | np.generic | int | float | complex | bool):
        a = np.asarray(leaf)
        return str(a.dtype).encode() + str(a.shape).encode() + np.ascontiguousarray(a).tobytes()
    if callable(leaf):  # a plain function: its name only (a changed body is not detected)
        return (
            f"{getattr(leaf, '__module__', '')}.{getattr(leaf, '__qualname__', type(leaf).__name__)}".encode()
        )
    return repr(leaf).encode()


def tree_digest(*trees) -> str:
    """A fingerprint of pytrees' structure and values (array bytes; names of plain functions), to recognise
    the same computation when a run is resumed."""
    h = hashlib.sha256()
    for tree in trees:
        leaves, treedef = jax.tree.flatten(tree)
        h.update(re.sub(r" at 0x[0-9a-fA-F]+", "", str(treedef)).encode())  # no memory addresses
        for leaf in leaves:
            h.update(_leaf_bytes(leaf))
    return h.hexdigest()[:24]


def checkpoint_file(checkpoint, resume: bool) -> Path | None:
    """``checkpoint`` as a path (None for none), checked before any computation: a ``.npz`` name in an
    existing folder; ``resume`` needs one."""
    if checkpoint is None:
        if resume:
            raise ValueError("`resume=True` needs a `checkpoint` path to resume from")
        return None
    path = Path(checkpoint)
    if path.suffix != ".npz":
        raise ValueError(f"`checkpoint` must be a path ending in .npz, got {str(path)!r}")
    if not path.parent.is_dir():
        raise ValueError(f"`checkpoint`: folder {str(path.parent)!r} does not exist")
    if path.is_dir():
        raise ValueError(f"`checkpoint` {str(path)!r} is a folder")
    return path


def save_checkpoint(path, arrays: dict[str, np.ndarray], description: dict) -> Path:
    """Write ``arrays`` and the run's ``description`` (JSON-able) to ``path`` (``.npz``) atomically."""
    meta = json.dumps(dict(format=CHECKPOINT_FORMAT, **description), sort_keys=True)
    return write_atomic(path, lambda p: np.savez(p, __checkpoint__=np.asarray(meta), **arrays))


def load_checkpoint(path, description: dict, *, what: str) -> dict[str, np.ndarray]:
    """The arrays of the checkpoint at ``path``; ``ValueError`` if it is missing, unreadable, not a pgtjax
    checkpoint, or written by a run whose description differs (the differing entries are named)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"cannot resume {what}: no checkpoint at {str(path)!r}; run without resume to start")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise ValueError(f"cannot resume {what}: {str(path)!r} is not a readable .npz ({err})") from None
    try:
        saved = json.loads(str(arrays.pop("__checkpoint__")))
    except (KeyError, ValueError):
        raise ValueError(f"cannot resume {what}: {str(path)!r} is not a pgtjax checkpoint") from None
    if saved.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"cannot resume {what}: {str(path)!r} is not a pgtjax checkpoint")
    expected = json.loads(json.dumps(dict(format=CHECKPOINT_FORMAT, **description)))
    if set(saved) != set(expected):  # another description altogether: not worth listing value by value
        unknown = ", ".join(sorted(set(saved) - set(expected))) or "nothing"
        missing = ", ".join(sorted(set(expected) - set(saved))) or "nothing"
        raise ValueError(
            f"cannot resume {what} from {str(path)!r}: it was written by another version of pgtjax "
            f"(it records {unknown} that this version does not, and lacks {missing}); run without resume to "
            "start again"
        )
    differ = sorted(k for k in set(saved) | set(expected) if saved.get(k) != expected.get(k))
    if differ:
        detail = "; ".join(f"{k}: checkpoint {saved.get(k)!r}, this run {expected.get(k)!r}" for k in differ)
        hint = ""
        # the defaults of these follow the machine: say how to match them
        if set(differ) & {"devices", "samples_per_device"}:
            hint = (
                "; resume with the interrupted run's device count and batch size (`pgtjax --cpu-devices N`, "
                "`--chunk-size`; in Python `pg.use_cpu_cores(N)`, `chunk_size=`)"
            )
        raise ValueError(
            f"cannot resume {what} from {str(path)!r}: it was written by another run ({detail}){hint}"
        )
    return arrays
