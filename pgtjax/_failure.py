"""One failure story for every solver: a :class:`SolverError` that says what failed, when and where, the
likely causes and the knob to turn (in the manner of lineax's result codes)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

NONFINITE_CAUSES = (
    "likely causes: an unstable system (negative damping or stiffness, a contact stiffness that turns "
    "negative), a time function that returns NaN/inf, or a step too large for the contact law; check the "
    "parameters, reduce `dt`, or pass throw=False to inspect the result"
)


class SolverError(RuntimeError):
    """A numerical failure of a pgtjax solver (non-finite values, a fixed point or contact solve that did not
    converge), with the first time and quantity where it happened."""


class ProcessFailedError(RuntimeError):
    """Another process of a distributed run failed during the run; its own output says why. This process
    finished its share (and saved it where a checkpoint was given), so a resume reruns only what is missing."""


def is_concrete(tree) -> bool:
    """True if no leaf of ``tree`` is traced (the check can then run in Python, with a detailed message)."""
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(tree))


def first_nonfinite(times, fields: Mapping[str, tuple[jax.Array, Sequence[str]]]):
    """``(time, quantity, label)`` of the first saved time at which a field is not finite, else None.
    ``fields``: name -> (array (n_times, k), the k column labels)."""
    times = np.asarray(times)
    first = None
    for name, (values, labels) in fields.items():
        values = np.asarray(values).reshape(times.shape[0], -1)
        bad = ~np.isfinite(values)
        if bad.any():
            row = int(np.argmax(bad.any(axis=1)))
            col = int(np.argmax(bad[row]))
            if first is None or row < first[0]:
                first = (row, name, labels[col] if col < len(labels) else str(col))
    return None if first is None else (float(times[first[0]]), first[1], first[2])


def raise_if_nonfinite(solver: str, times, fields) -> None:
    """Raise :class:`SolverError` naming the first non-finite saved value (concrete results only)."""
    found = first_nonfinite(times, fields)
    if found is not None:
        t, name, label = found
        raise SolverError(
            f"{solver}: non-finite {name} of {label!r} first at t = {t:.6g} s; {NONFINITE_CAUSES}"
        )


def error_if_nonfinite(solver: str, tree, arrays):
    """The in-``jit`` counterpart of :func:`raise_if_nonfinite` (the time cannot go in a traced message): every
    array leaf of ``tree`` carries the check, so that no part of a result escapes it."""
    bad = jnp.array(False)
    for a in arrays:
        bad = bad | ~jnp.all(jnp.isfinite(a))
    return eqx.error_if(tree, bad, f"{solver}: non-finite values in the result; {NONFINITE_CAUSES}")
