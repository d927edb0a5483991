"""Where batched work runs: the local devices a batch is sharded over (one mesh axis), for Monte Carlo samples
and design batches alike."""

from __future__ import annotations

import contextlib
import functools
import importlib.metadata
import os
import re
import warnings

import jax
import numpy as np

from ._failure import ProcessFailedError

CPU_CHUNK_SIZE = 5000
ACCELERATOR_CHUNK_SIZE = 100_000
#: bytes of a saved block's random draws (uniforms and normals) and step inputs that Monte Carlo forms at once,
#: per device: a longer block is formed a part at a time. On a CPU the part stays in cache until its steps read
#: it (gear pair, 2,000 steps saved once: 11.5 ns per sample-step formed whole, 5.2 in parts of 100 steps,
#: benchmarks/results/save_interval.json); on an accelerator the bound only keeps memory small
CPU_DRAW_BYTES = 8 * 2**20
ACCELERATOR_DRAW_BYTES = 256 * 2**20


def only_cpus(devices) -> bool:
    """Whether every one of ``devices`` is a CPU device."""
    return all(d.platform == "cpu" for d in devices)


def default_chunk_size(devices, cpu: int = CPU_CHUNK_SIZE) -> int:
    """Monte Carlo samples per compiled batch and device when none is given: ``cpu`` where every device is a
    CPU, else 100,000. A GPU runs each time step as a few kernel launches whose cost a small batch does not
    cover (one H100, planetary MC: 26.9 ns per sample-step at 5,000 samples per batch, 10.3 at 20,000, 5.1
    at 100,000; ``benchmarks/results/gpu_chunks.json``); on CPU devices the default stays what it always
    was, and memory stays small."""
    return cpu if only_cpus(devices) else ACCELERATOR_CHUNK_SIZE


def draw_budget(devices) -> int:
    """:data:`CPU_DRAW_BYTES` where every device is a CPU, else :data:`ACCELERATOR_DRAW_BYTES`."""
    return CPU_DRAW_BYTES if only_cpus(devices) else ACCELERATOR_DRAW_BYTES


#: XLA options that make its CPU loops use 512-bit vectors (XLA's default is 256 bits whatever the CPU)
WIDE_VECTORS = {"xla_cpu_prefer_vector_width": 512}


@functools.cache
def cpu_has_avx512() -> bool:
    """Whether this machine's CPU has AVX-512 (``avx512f`` among the flags of ``/proc/cpuinfo``; False where
    that file does not exist)."""
    try:
        with open("/proc/cpuinfo") as f:
            return any(line.startswith("flags") and " avx512f" in line for line in f)
    except OSError:  # pragma: no cover - not Linux
        return False


def wide_vectors(devices) -> bool:
    """Whether Monte Carlo's program for ``devices`` is compiled with :data:`WIDE_VECTORS`: every device is a
    CPU, the CPU has AVX-512, and ``XLA_FLAGS`` does not choose a vector width itself
    (``--xla_cpu_prefer_vector_width=256`` turns this off). The statistics agree to rounding (the gear pair's
    were the same doubles); on two devices of an AMD EPYC the gear pair's Monte Carlo ran in about 0.7x the
    time (measured there only; docs/performance.md)."""
    return (
        only_cpus(devices)
        and cpu_has_avx512()
        and "xla_cpu_prefer_vector_width" not in os.environ.get("XLA_FLAGS", "")
    )


def local_devices(devices=None) -> list:
    """The devices of this process a batch is sharded over: ``None`` for all of ``jax.local_devices()``;
    ``ValueError`` for an empty list, a repeated device or another process's device."""
    if devices is None:
        return list(jax.local_devices())
    devices = list(devices)
    if not devices or not all(isinstance(d, jax.Device) for d in devices):
        raise ValueError(
            "`devices` must be None or a non-empty sequence of jax devices (e.g. jax.local_devices())"
        )
    if len(set(devices)) != len(devices):
        raise ValueError("`devices` lists a device twice")
    foreign = [d for d in devices if d.process_index != jax.process_index()]
    if foreign:
        raise ValueError(f"`devices` must belong to this process (jax.local_devices()); {foreign} do not")
    return devices


def device_mesh(devices, axis: str) -> jax.sharding.Mesh:
    """A one-axis mesh over ``devices``."""
    return jax.sharding.Mesh(np.array(devices), (axis,))


def _available_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))  # the cores this process may run on (a job's allocation)
    except AttributeError:  # pragma: no cover - macOS, Windows
        return os.cpu_count() or 1


def use_cpu_cores(n: int | None = None) -> int:
    """Make JAX's CPU platform ``n`` devices (default: the cores this process may run on), so that Monte
    Carlo and design batches, which are sharded over ``jax.local_devices()``, keep every core busy: XLA runs
    one device's batch on about one core. Only the CPU platform changes (a GPU process keeps its GPUs as
    local devices); single-device work is unaffected.

    Call it right after ``import jax`` / ``import pgtjax``, before any JAX computation: the device count is
    fixed when JAX starts. Later, ``n=None`` leaves the devices as they are and ``n`` different from the
    count in force is a ``ValueError``. A device count forced through ``XLA_FLAGS``
    (``--xla_force_host_platform_device_count``) is respected when ``n`` is None. Returns the number of CPU
    devices in force (or that will be).

    The statistics of a run do not depend on the device count (to rounding), but a checkpoint records it:
    resume with the same count.

    Known problem (docs/performance.md): jaxlib 0.10.0 to 0.11.0 split a batched LAPACK call (an LU,
    Cholesky or eigendecomposition of stacked matrices, as a ``vmap``-ed design batch's SL makes) over XLA's
    intra-op thread pool and block the calling pool thread until the pieces are done. When every thread of
    that pool waits so, the process hangs: two devices each in such a call, or two such calls of one program.
    It was seen three times in one of our benchmarks on two devices, and in a ``vmap`` of 14 designs on one.
    jaxlib 0.11.1 and later (and 0.9 and earlier) run such calls on the calling thread; with an affected jaxlib
    on a machine of several cores, a count above one gives a ``RuntimeWarning``. If a run stops using the CPU,
    interrupt it and run it again on one device (a checkpoint resumes only with the device count it was
    written with).
    """
    if n is not None and (isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1):
        raise ValueError(f"`n` (CPU devices) must be a whole number >= 1 or None, got {n!r}")
    if _backends_started():
        current = len(jax.devices("cpu"))
        if n is not None and n != current:
            raise ValueError(
                f"cannot make JAX's CPU platform {n} devices: JAX has started with {current}; call "
                "pgtjax.use_cpu_cores before any JAX computation (or restart the kernel)"
            )
        return current
    forced = re.search(r"--xla_force_host_platform_device_count=(\d+)", os.environ.get("XLA_FLAGS", ""))
    if n is None and forced:
        n = int(forced.group(1))
    else:
        n = _available_cores() if n is None else int(n)
        jax.config.update("jax_num_cpu_devices", n)
    if n > 1:
        warn_if_lapack_batches_can_hang(f"{n} CPU devices", stacklevel=3)
    return n


def warn_if_lapack_batches_can_hang(what: str, stacklevel: int = 2) -> None:
    """A ``RuntimeWarning`` that ``what`` (e.g. "2 CPU devices") can hang this process, where jaxlib splits
    batched LAPACK calls over an intra-op pool of more than one thread (:func:`lapack_batches_wait_on_pool`)."""
    if lapack_batches_wait_on_pool() and _available_cores() > 1:  # a one-thread pool never splits a call
        warnings.warn(
            f"jaxlib {_jaxlib_version_text()} splits batched LAPACK calls over XLA's thread pool and waits for "
            f"them from a thread of that pool; with {what} a run can hang (docs/performance.md). jaxlib "
            ">= 0.11.1 or <= 0.9.2 does not; one CPU device and designs evaluated one at a time avoid it.",
            RuntimeWarning,
            stacklevel=stacklevel,
        )


def _jaxlib_version_text() -> str:
    try:
        return importlib.metadata.version("jaxlib")
    except importlib.metadata.PackageNotFoundError:  # pragma: no cover - a source build of JAX
        return jax.__version__


def lapack_batches_wait_on_pool(version: str | None = None) -> bool:
    """Whether this jaxlib (or ``version``) is one of 0.10.0-0.11.0, whose CPU LAPACK kernels split a batch
    over XLA's intra-op pool and wait for it from a pool thread (upstream jax commit 859992407d turned this
    off in open-source builds after 0.11.0)."""
    text = _jaxlib_version_text() if version is None else version
    parts = re.match(r"(\d+)\.(\d+)\.(\d+)", text)
    if parts is None:
        return False
    release = tuple(int(p) for p in parts.groups())
    return (0, 10, 0) <= release < (0, 11, 1)


def _backends_started() -> bool:
    """Whether JAX has started its backends (after which the CPU device count is fixed)."""
    try:
        from jax._src import xla_bridge  # JAX offers no public test of this

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):  # pragma: no cover - a JAX without it: ask the config instead
        try:
            jax.config.update("jax_num_cpu_devices", jax.config.jax_num_cpu_devices)
            return False
        except RuntimeError:
            return True


def gather_processes(array: np.ndarray) -> np.ndarray:
    """Every process's ``array`` (the same shape in each), stacked in process order: (n_processes, ...)."""
    from jax.experimental import multihost_utils

    gathered = np.asarray(multihost_utils.process_allgather(np.asarray(array)))
    return gathered.reshape((jax.process_count(),) + np.shape(array))


def refuse_together(refusal: ValueError | None, what: str) -> None:
    """In a distributed run of ``what``, ``ValueError`` in every process where any process refused its options
    (the others would otherwise wait for it at the end); the refusing process raises its own ``refusal``."""
    refused = gather_processes(np.array([refusal is not None])).reshape(-1)
    if refusal is None:
        raise_if_others_refused(refused, what)


@contextlib.contextmanager
def fail_together(what: str, distributed: bool, stage: str):
    """Around a part of a distributed run of ``what`` that each process does alone (no collective inside):
    where it raises an ``Exception`` in any process, every process raises once all have done their part,
    instead of the others waiting for the failed one in the next collective. The failing process raises its
    own error, the others :class:`ProcessFailedError` naming it and the ``stage`` ("before the run", "during
    the run"). Not distributed: nothing is exchanged."""
    failure = None
    try:
        yield
    except Exception as err:  # not KeyboardInterrupt: an interrupted process stops at once
        failure = err
    failed = gather_processes(np.array([failure is not None])).reshape(-1) if distributed else None
    if failure is not None:
        raise failure
    others = [] if failed is None else [p for p in np.flatnonzero(failed) if p != jax.process_index()]
    if others:
        done = (
            "this process finished its share, and saved it where a checkpoint was given"
            if stage == "during the run"
            else "nothing was computed"
        )
        raise ProcessFailedError(
            f"{what}: process(es) {', '.join(map(str, others))} failed {stage} (their messages say why); {done}"
        )


def raise_if_others_refused(refused: np.ndarray, what: str) -> None:
    """``ValueError`` naming the other processes whose flag in ``refused`` (one per process) is set."""
    others = [p for p in np.flatnonzero(refused) if p != jax.process_index()]
    if others:
        raise ValueError(
            f"{what}: process(es) {', '.join(map(str, others))} refused this run's options; "
            "their messages say why"
        )
