"""The one range checker every model's parameters use."""

from __future__ import annotations

import jax
import numpy as np


def check_range(
    name: str, value, *, lo=None, hi=None, lo_closed: bool = True, hi_closed: bool = True, unit: str = ""
) -> None:
    """``ValueError`` naming ``name`` and the accepted range unless every entry of ``value`` is finite and in
    the interval from ``lo`` to ``hi`` (closed or open at each end; ``None``: unbounded). Traced values (under
    ``jit``/``grad``/``vmap``) cannot be checked and pass."""
    if any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(value)):
        return
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"`{name}` must be a number, got {value!r}") from None
    ok = bool(np.all(np.isfinite(arr)))
    parts = []
    if lo is not None:
        ok = ok and bool(np.all(arr >= lo) if lo_closed else np.all(arr > lo))
        parts.append(f"{'>=' if lo_closed else '>'} {lo:g}")
    if hi is not None:
        ok = ok and bool(np.all(arr <= hi) if hi_closed else np.all(arr < hi))
        parts.append(f"{'<=' if hi_closed else '<'} {hi:g}")
    if not ok:
        accepted = " and ".join(parts) + (f" {unit}" if unit else "")
        shown = arr.item() if arr.ndim == 0 else arr.tolist()
        raise ValueError(f"`{name}` must be finite{' and ' + accepted if parts else ''}, got {shown}")
