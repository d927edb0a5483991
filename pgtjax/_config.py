"""Numerical configuration applied when pgtjax is imported, and the process-wide compilation cache.

Mesh stiffnesses are ~1e10 N/m and deflections ~1e-6 m: single precision cannot represent the
products, so pgtjax switches JAX to float64 before any array is created.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)


def require_x64(what: str) -> None:
    """``ValueError`` saying so plainly if float64 was switched off after pgtjax was imported."""
    if not jax.config.jax_enable_x64:
        raise ValueError(
            f"{what}: pgtjax needs 64-bit floats, but `jax_enable_x64` was switched off after pgtjax was imported "
            "(mesh stiffness times deflection is beyond float32); call jax.config.update('jax_enable_x64', True)"
        )


def default_compilation_cache() -> Path:
    """``$XDG_CACHE_HOME/pgtjax/xla``, or ``~/.cache/pgtjax/xla`` where that variable is not set."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "pgtjax" / "xla"


def use_compilation_cache(path: str | os.PathLike | None = None, *, option: str = "path") -> Path:
    """Keep XLA's compiled programs in the folder ``path`` (default :func:`default_compilation_cache`), so that
    a later process running the same computations loads them instead of compiling them again (JAX's persistent
    compilation cache, for every program however quickly it compiled: most of pgtjax's take well under JAX's
    default threshold of a second). ``pgtjax run`` took 30-32 s instead of 53-54 s the second time (2026-11-28,
    AMD EPYC, docs/performance.md). Results are the same doubles: the cache holds the very programs compiled.

    Call it before the computations whose programs it should keep (any time: programs compiled before it
    stay uncached; a folder set before, by an earlier call or ``JAX_COMPILATION_CACHE_DIR``, gives way). It
    sets JAX's thresholds (``jax_persistent_cache_min_compile_time_secs``, ``..._min_entry_size_bytes``) to 0
    and keeps JAX's other rules: programs with host callbacks are not kept, in a run of several processes only
    the first writes, and the folder is never pruned. JAX checks that a cached CPU program suits this
    machine's CPU and compiles again where it does not; share a folder only with users you trust, since what
    it holds is run. ``ValueError`` if the folder cannot be created or written (``option`` names ``path`` in
    the message: the CLI's ``--compilation-cache``). Returns the folder."""
    folder = Path(os.path.abspath(os.path.expanduser(default_compilation_cache() if path is None else path)))
    probe = folder / f".pgtjax-write-check-{os.getpid()}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        try:
            probe.write_bytes(b"")
        finally:
            probe.unlink(missing_ok=True)
    except OSError as err:
        raise ValueError(
            f"`{option}`: the compilation cache folder {str(folder)!r} cannot be created or written: "
            f"{err.strerror or err}"
        ) from None
    from jax.experimental.compilation_cache import compilation_cache

    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    compilation_cache.reset_cache()  # a folder JAX already writes to gives way to this one
    return folder
