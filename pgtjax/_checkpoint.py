"""Checkpoints of long runs: arrays and a description of the run in one ``.npz``, written atomically, read
back only by a run with the same description (so a resumed run cannot mix two different computations)."""

from __future__ import annotations

import functools
import hashlib
import inspect
import json
import os
import re
import types
import zipfile
from pathlib import Path

import jax
import numpy as np

from ._files import write_atomic

CHECKPOINT_FORMAT = "pgtjax-checkpoint-1"


_ADDRESS = re.compile(r" at 0x[0-9a-fA-F]+")


def _const_bytes(const) -> bytes:
    """A code object's constant, the same in every process (frozensets sorted: their order follows the
    string hash seed)."""
    if isinstance(const, types.CodeType):
        return _code_bytes(const)
    if isinstance(const, tuple):
        return b"(" + b",".join(_const_bytes(c) for c in const) + b")"
    if isinstance(const, frozenset):
        return b"{" + b",".join(sorted(_const_bytes(c) for c in const)) + b"}"
    return repr(const).encode()


def _code_bytes(code: types.CodeType) -> bytes:
    return code.co_code + _const_bytes(code.co_consts) + repr(code.co_names).encode()


def _callable_bytes(fn, seen: frozenset) -> bytes:
    """A function as what it computes: its name and bytecode, and the values it carries (a partial's
    arguments, defaults, closure cells, a bound method's object, a wrapper's wrapped function). Globals it
    reads are not included."""
    if isinstance(fn, functools.partial):  # jax.tree_util.Partial too
        return b"partial:" + _callable_bytes(fn.func, seen) + _tree_bytes((fn.args, fn.keywords), seen)
    if inspect.ismethod(fn):
        return b"method:" + _callable_bytes(fn.__func__, seen) + _object_bytes(fn.__self__, seen)
    name = f"{getattr(fn, '__module__', '')}.{getattr(fn, '__qualname__', type(fn).__name__)}".encode()
    code = getattr(fn, "__code__", None)
    if isinstance(code, types.CodeType):
        cells = []
        for cell in fn.__closure__ or ():
            try:
                cells.append(cell.cell_contents)
            except ValueError:  # a cell not yet filled
                cells.append(None)
        carried = (fn.__defaults__, fn.__kwdefaults__, cells)
        return name + _code_bytes(code) + _tree_bytes(carried, seen)
    wrapped = getattr(fn, "__wrapped__", None)  # jax.jit, functools.wraps
    if wrapped is not None and wrapped is not fn:
        return b"wrapper:" + name + _callable_bytes(wrapped, seen)
    if isinstance(fn, types.BuiltinFunctionType | np.ufunc):  # its name says what it computes
        return name
    # an instance of a class with __call__: the method, and the instance's attributes
    return b"instance:" + _callable_bytes(type(fn).__call__, seen) + _object_bytes(fn, seen)


def _object_bytes(obj, seen: frozenset) -> bytes:
    """An object that is not a pytree: its type and attributes, or its repr where it has none."""
    kind = f"{type(obj).__module__}.{type(obj).__qualname__}".encode()
    try:
        attributes = getattr(obj, "__dict__", None)
        if isinstance(attributes, dict) and not isinstance(obj, types.ModuleType):
            return kind + _tree_bytes(attributes, seen)
        if jax.tree.leaves(obj) != [obj]:  # a pytree after all (an equinox module's bound method's object)
            return _tree_bytes(obj, seen)
        return _ADDRESS.sub("", repr(obj)).encode()
    except Exception:  # an object that cannot be read so: its type alone
        return kind


def _leaf_bytes(leaf, seen: frozenset = frozenset()) -> bytes:
    if isinstance(leaf, jax.Array) and jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
        leaf = jax.random.key_data(leaf)
    if isinstance(leaf, jax.Array | np.ndarray | np.generic | int | float | complex | bool):
        a = np.asarray(leaf)
        head = str(a.dtype).encode() + str(a.shape).encode()
        if a.dtype == object:  # its bytes would be pointers
            return head + b",".join(_leaf_bytes(x, seen) for x in a.ravel())
        return head + np.ascontiguousarray(a).tobytes()
    if isinstance(leaf, str | bytes | type(None)):
        return repr(leaf).encode()
    if isinstance(leaf, set | frozenset):  # sorted: their order follows the string hash seed
        return b"{" + b",".join(sorted(_leaf_bytes(x, seen) for x in leaf)) + b"}"
    if id(leaf) in seen:  # reachable from itself (a recursive closure, a cyclic object)
        return b"<recursive>"
    seen = seen | {id(leaf)}
    if callable(leaf) and not isinstance(leaf, type):
        return _callable_bytes(leaf, seen)
    return _object_bytes(leaf, seen)


def _is_partial(x) -> bool:  # jax.tree_util.Partial keeps its function in the tree structure: take it whole
    return isinstance(x, jax.tree_util.Partial)


def _nests_itself(tree, path: frozenset = frozenset(), depth: int = 0) -> bool:
    """Whether a list, tuple or dict contains itself (or nests deeper than any model does): JAX's flatten
    would exhaust the stack, and jaxlib 0.10 then leaves Python's recursion count spent."""
    if not isinstance(tree, list | tuple | dict):
        return False
    if id(tree) in path or depth > 100:
        return True
    path = path | {id(tree)}
    children = tree.values() if isinstance(tree, dict) else tree
    return any(_nests_itself(child, path, depth + 1) for child in children)


def _tree_bytes(tree, seen: frozenset = frozenset()) -> bytes:
    if _nests_itself(tree):
        return f"<cyclic {type(tree).__qualname__}>".encode()
    leaves, treedef = jax.tree.flatten(tree, is_leaf=_is_partial)
    out = [_ADDRESS.sub("", str(treedef)).encode()]  # no memory addresses
    out += [_leaf_bytes(leaf, seen) for leaf in leaves]
    return b"|".join(out)


def tree_digest(*trees) -> str:
    """A fingerprint of pytrees' structure and values, to recognise the same computation when a run is
    resumed: array bytes, and functions by name, bytecode and the values they carry (closures, defaults,
    ``functools.partial`` arguments); module-level globals a function reads are not part of it."""
    h = hashlib.sha256()
    for tree in trees:
        h.update(_tree_bytes(tree))
    return h.hexdigest()[:24]


def checkpoint_file(checkpoint, resume: bool, *, writable: bool = True) -> Path | None:
    """``checkpoint`` as a path (None for none), checked before any computation: a ``.npz`` name in an
    existing folder (one this process can write in, unless ``writable`` is False); ``resume`` needs one."""
    if checkpoint is None:
        if resume:
            raise ValueError("`resume=True` needs a `checkpoint` path to resume from")
        return None
    if not isinstance(checkpoint, str | os.PathLike):
        raise ValueError(
            f"`checkpoint` must be a path (str or pathlib.Path) ending in .npz, got {type(checkpoint).__name__}"
        )
    path = Path(checkpoint)
    if path.suffix != ".npz":
        raise ValueError(f"`checkpoint` must be a path ending in .npz, got {str(path)!r}")
    if path.parent.exists() and not path.parent.is_dir():
        raise ValueError(f"`checkpoint`: {str(path.parent)!r} is a file, not a folder")
    if not path.parent.is_dir():
        raise ValueError(f"`checkpoint`: folder {str(path.parent)!r} does not exist")
    if path.is_dir():
        raise ValueError(f"`checkpoint` {str(path)!r} is a folder")
    if not writable:
        return path
    probe = path.with_name(f".{path.stem}.write-check-{os.getpid()}")
    try:  # a folder that cannot be written would otherwise fail at the first checkpoint, after a batch's work
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as err:
        raise ValueError(
            f"`checkpoint`: folder {str(path.parent)!r} cannot be written: {err.strerror or err}"
        ) from None
    return path


def process_checkpoint_name(path: Path, process: int, processes: int) -> Path:
    """The checkpoint of process ``process`` of a run of ``processes`` (``<stem>.process-<p>-of-<n>.npz``; the
    path itself for one process): processes sharing a folder must not write one file."""
    return path if processes == 1 else path.with_name(f"{path.stem}.process-{process}-of-{processes}.npz")


def process_checkpoint_file(
    checkpoint, resume: bool, processes: int, process: int, *, writable: bool = True
) -> Path | None:
    """:func:`checkpoint_file`, then this process's own file (:func:`process_checkpoint_name`)."""
    path = checkpoint_file(checkpoint, resume, writable=writable)
    return None if path is None else process_checkpoint_name(path, process, processes)


def save_checkpoint(path, arrays: dict[str, np.ndarray], description: dict, *, what: str) -> Path:
    """Write ``arrays`` and the ``description`` (JSON-able) of a run of ``what`` (the function checkpointed)
    to ``path`` (``.npz``) atomically."""
    meta = json.dumps(dict(format=CHECKPOINT_FORMAT, run=what, **description), sort_keys=True)
    return write_atomic(path, lambda p: np.savez(p, __checkpoint__=np.asarray(meta), **arrays))


def _read(path: Path, what: str) -> tuple[dict[str, np.ndarray], dict]:
    """The arrays and the description of the checkpoint at ``path``, or a ``ValueError`` saying why not."""
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
    if not isinstance(saved, dict) or saved.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"cannot resume {what}: {str(path)!r} is not a pgtjax checkpoint")
    if saved.get("run", what) != what:
        raise ValueError(
            f"cannot resume {what} from {str(path)!r}: it is a checkpoint of {saved['run']}, not of {what}"
        )
    return arrays, saved


def _refuse_differences(path: Path, what: str, saved: dict, expected: dict) -> None:
    """``ValueError`` naming every entry of ``expected`` whose value ``saved`` does not share."""
    differ = sorted(k for k in expected if saved.get(k) != expected[k])
    if not differ:
        return
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


def _as_json(description: dict, what: str) -> dict:
    return json.loads(json.dumps(dict(format=CHECKPOINT_FORMAT, run=what, **description)))


def check_checkpoint(path, entries: dict, *, what: str) -> None:
    """Refuse at once a checkpoint whose description differs in any of ``entries`` (a part of the full
    description, known before the run's other work): the full comparison comes when it is loaded."""
    path = Path(path)
    _, saved = _read(path, what)
    expected = _as_json(entries, what)
    _refuse_differences(path, what, saved, {k: v for k, v in expected.items() if k in saved})


def load_checkpoint(
    path, description: dict, *, what: str, absent: dict | None = None
) -> dict[str, np.ndarray]:
    """The arrays of the checkpoint at ``path``; ``ValueError`` if it is missing, unreadable, not a pgtjax
    checkpoint, or written by a run whose description differs (the differing entries are named). ``absent``:
    entries added to the description since, with the value a checkpoint written before them stands for."""
    path = Path(path)
    arrays, saved = _read(path, what)
    saved = {**_as_json(absent or {}, what), **saved}
    expected = _as_json(description, what)
    if set(saved) != set(expected):  # another description altogether: not worth listing value by value
        unknown = ", ".join(sorted(set(saved) - set(expected))) or "nothing"
        missing = ", ".join(sorted(set(expected) - set(saved))) or "nothing"
        raise ValueError(
            f"cannot resume {what} from {str(path)!r}: it was written by another version of pgtjax "
            f"(it records {unknown} that this version does not, and lacks {missing}); run without resume to "
            "start again"
        )
    _refuse_differences(path, what, saved, expected)
    return arrays
