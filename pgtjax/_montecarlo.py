"""Monte Carlo (MC) of the *nonlinear* system (thesis 3.6, 4.5), with the same stochastic Newmark
discretization as the moment recursion: for a linear system MC statistics converge to the recursion's
moments up to sampling error.

Samples are processed in chunks (a Python loop that only bounds memory and drives the progress bar); inside a
chunk the samples are a batch (``vmap``-style matrix products) and time is a ``lax.scan``. Nothing of size
``n_samples x n_steps`` is kept: means and centred sums of squares are accumulated per saved time (Chan's
parallel update between chunks), and histograms of chosen quantities are counted on the fly.

Noise of sample ``s`` in saved block ``j`` is ``normal(fold_in(fold_in(key, s), j))``: a pure function of the key
and the indices, so the same key gives the same statistics (to rounding) whatever the chunk size, the number of
devices (each batch is sharded over a one-axis device mesh, each device reducing its own samples) and of
processes (``jax.distributed``; the per-process statistics are gathered and merged at the end). The running
statistics can be checkpointed and a run resumed to exactly the uninterrupted result.
"""

from __future__ import annotations

import math
import zipfile
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from ._checkpoint import (
    check_checkpoint,
    load_checkpoint,
    process_checkpoint_file,
    save_checkpoint,
    tree_digest,
)
from ._eigenbasis import (
    eigen_advance,
    eigen_initial_state,
    eigen_output_rows,
    eigen_outputs,
    eigen_propagator,
    eigen_recorded,
    eigen_step_inputs,
)
from ._failure import SolverError, raise_if_nonfinite
from ._loop import saved_scan
from ._newmark import (
    AbstractIntegrator,
    initial_sample_state,
    resolve_integrator,
    sample_step,
    snapshot,
)
from ._numerics import materialized
from ._parallel import (
    WIDE_VECTORS,
    default_chunk_size,
    device_mesh,
    draw_budget,
    fail_together,
    gather_processes,
    local_devices,
    refuse_together,
    wide_vectors,
)
from ._progress import progress_bar
from ._random import block_normals, is_threefry
from ._random import normal as standard_normal
from ._random import stream as normals_stream
from ._results import MonteCarloResult
from ._system import (
    Observables,
    System,
    check_contact_stiffness_over_time,
    check_count,
    check_initial_covariance,
    check_memory,
    check_observables,
    check_stability,
    covariance_index,
    initial_state,
    validate_system,
    validate_time_grid,
)

PROPAGATIONS = ("auto", "eigen", "physical")
_INITIAL_STATE_TAG = 0xFFFFFFFF  # fold_in tag of a sample's initial-state draw (block indices are smaller)


def _is_typed_key(key) -> bool:
    return isinstance(key, jax.Array) and jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key)


def check_key(key) -> None:
    """``ValueError`` unless ``key`` is one JAX PRNG key (``jax.random.key(seed)``, or a legacy uint32 key
    ``jax.random.PRNGKey(seed)``)."""
    typed = _is_typed_key(key)
    # raw uint32 key data (jax.random.PRNGKey, a NumPy copy of one): 2 words (threefry) or 4 (rbg)
    legacy = isinstance(key, jax.Array | np.ndarray) and key.dtype == np.uint32 and key.shape in ((2,), (4,))
    if typed and key.shape != ():
        raise ValueError(
            f"`key` must be one PRNG key, got a batch of shape {key.shape}; for several independent runs "
            "call monte_carlo once per key (or raise n_samples: samples already draw independent noise)"
        )
    if not (typed or legacy):
        raise ValueError(f"`key` must be a JAX PRNG key such as jax.random.key(0), got {key!r}")


def _check_histogram_times(histogram_times, histograms, t0, duration, save_interval) -> list[float]:
    """The histogram times (s) as floats, each finite and within the run (half a save interval of slack: each
    is reported at the nearest saved time)."""
    try:
        values = [float(t) for t in np.atleast_1d(np.asarray(histogram_times, dtype=np.float64))]
    except (TypeError, ValueError):
        raise ValueError(f"`histogram_times` must be numbers (s), got {histogram_times!r}") from None
    if values and not histograms:
        raise ValueError(
            "`histogram_times` were given without `histograms` or `peaks` (quantity -> bin edges) to count"
        )
    t0, end = float(t0), float(t0) + float(duration)
    for t in values:
        if not (np.isfinite(t) and t0 - 0.5 * float(save_interval) <= t <= end + 0.5 * float(save_interval)):
            raise ValueError(
                f"`histogram_times` must lie within the run, [{t0:.6g}, {end:.6g}] s (each is reported at the "
                f"nearest saved time), got {t!r}"
            )
    return values


def _saved_times(t0, dt, n_steps: int, save_every: int) -> np.ndarray:
    """The saved times (s) of a run, (n_steps // save_every + 1,): ``t0`` and every block's end."""
    return float(t0) + float(dt) * save_every * np.arange(n_steps // save_every + 1)


def _peak_start_step(peak_start, peaks, histogram_times, t0, dt, n_steps: int, save_every: int) -> int:
    """The step (its end's index; 0: ``t0``) from which the peaks are taken: the saved step nearest
    ``peak_start`` (s; None: ``t0``). ``ValueError`` unless it lies within the run, there are peaks, and every
    histogram time (at its nearest saved time) is at or after it: before it no peak has been taken."""
    if peak_start is None:
        return 0
    if not peaks:
        raise ValueError("`peak_start` was given without `peaks` (quantity -> bin edges) to count")
    try:
        start = float(peak_start)
    except (TypeError, ValueError):
        raise ValueError(f"`peak_start` must be a time (s), got {peak_start!r}") from None
    t0, dt = float(t0), float(dt)
    end = t0 + dt * n_steps
    slack = 0.5 * dt * save_every
    if not (np.isfinite(start) and t0 - slack <= start <= end + slack):
        raise ValueError(
            f"`peak_start` must lie within the run, [{t0:.6g}, {end:.6g}] s (the nearest saved time is taken), "
            f"got {peak_start!r}"
        )
    times = _saved_times(t0, dt, n_steps, save_every)  # as the result reports them
    step = save_every * int(np.argmin(np.abs(times - start)))
    early = [t for t in histogram_times if save_every * int(np.argmin(np.abs(times - t))) < step]
    if early:
        raise ValueError(
            f"`histogram_times` {early} (each at its nearest saved time) come before `peak_start` "
            f"({t0 + dt * step:.6g} s, at the nearest saved time): no peak has been taken by then"
        )
    return step


def _symmetric_square_root(p0: np.ndarray) -> np.ndarray:
    """``F = V sqrt(L) V^T`` (2n, 2n) with ``F F^T = p0``, or (2n, 0) for ``p0 = 0``: the factor each sample's
    initial state is drawn with (``x0 = mean + F z``). Unlike ``V sqrt(L)`` it does not depend on LAPACK's
    choice of eigenvector signs, nor of the basis of a repeated eigenvalue; both can flip under a
    rounding-level change of ``p0`` (another thread count or BLAS), which then drew other samples from the
    same distribution. This factor moves continuously with ``p0``. Rounding-level negative eigenvalues
    count as zero."""
    lam, vec = np.linalg.eigh(p0)
    if not np.any(lam > 0.0):
        return np.zeros((p0.shape[0], 0))
    return (vec * np.sqrt(np.maximum(lam, 0.0))[None, :]) @ vec.T


def quantity_names(system: System, observables: Observables | None = None) -> list[str]:
    """Names of the per-sample quantities MC records: ``u:<dof>``, ``v:<dof>``, ``delta:<contact>``,
    ``force:<contact>`` and ``obs:<observable>`` (the keys for ``histograms``)."""
    names = [f"u:{d}" for d in system.dof_names] + [f"v:{d}" for d in system.dof_names]
    names += [f"delta:{c}" for c in system.contact_names()] + [f"force:{c}" for c in system.contact_names()]
    if observables is not None:
        names += [f"obs:{o}" for o in observables.names]
    return names


def _is_force_column(system: System, column: int) -> bool:
    """Whether column ``column`` of :func:`quantity_names` is a contact force (the others are linear in the
    state: displacements, velocities, contact deflections, observables)."""
    n, nc = system.n_dof, system.n_contacts
    return 2 * n + nc <= column < 2 * n + 2 * nc


def _output_maps(system: System, snap, observables, t, columns):
    """``(A_u, A_v, offset)`` of the recorded quantities ``columns`` (of :func:`quantity_names`, no contact
    force) at time ``t`` (s; ``snap`` its snapshot): quantity j is ``u A_u[:, j] + v A_v[:, j] + offset[j]``,
    A_u and A_v (n, k), offset (k,)."""
    n, nc = system.n_dof, system.n_contacts
    eye, zero = jnp.eye(n), jnp.zeros(n)
    if observables is not None:
        observation, shift = observables(t).T, observables.shift(t)  # (n, n_obs), (n_obs,)
    a_u, a_v, offset = [], [], []
    for c in columns:
        u_col, v_col, off = zero, zero, jnp.zeros(())
        if c < n:
            u_col = eye[:, c]
        elif c < 2 * n:
            v_col = eye[:, c - n]
        elif c < 2 * n + nc:
            u_col = snap.direction[:, c - 2 * n]
        else:
            u_col, off = observation[:, c - 2 * n - 2 * nc], shift[c - 2 * n - 2 * nc]
        a_u, a_v, offset = a_u + [u_col], a_v + [v_col], offset + [off]
    return jnp.stack(a_u, axis=1), jnp.stack(a_v, axis=1), jnp.stack(offset)


def _eigen_flat_inputs(system, eigen, integrator, observables, output_columns):
    """``(s0, s1, t1) -> flat array``: what a step in eigen-coordinates needs besides the state (its
    :class:`pgtjax._eigenbasis.EigenStepInputs`), and the rows of the ``output_columns`` peaks at its end
    (time ``t1``), raveled into one array; and the function that unravels it."""

    def inputs(s0, s1, t1):
        rows = ()
        if output_columns:
            a_u, a_v, offset = _output_maps(system, s1, observables, t1, output_columns)
            rows = (*eigen_output_rows(eigen, s1, a_u, a_v), offset)
        return eigen_step_inputs(system, eigen, s0, s1, integrator), rows

    def flat(s0, s1, t1):
        return ravel_pytree(inputs(s0, s1, t1))[0]

    return flat, inputs


def _sample_statistics(
    system,
    key,
    sample_ids,
    weights,
    u0,
    v0,
    init_factor,
    t0,
    dt,
    peak_from,
    hist_edges,
    observables,
    eigen,
    *,
    n_steps,
    save_every,
    integrator,
    hist_columns,
    peak_columns=(),
    cov_columns=(),
    rows_per_input=None,
):
    n_batch = sample_ids.shape[0]
    nd = integrator.noise_dimension(system)
    sample_keys = jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, sample_ids)
    s0 = snapshot(system, t0)
    n = u0.shape[0]
    x0 = jnp.broadcast_to(jnp.concatenate([u0, v0]), (n_batch, 2 * n))
    if init_factor.shape[1]:  # random initial state: mean + F z, F F^T = initial covariance
        z = jax.vmap(
            lambda k: standard_normal(jax.random.fold_in(k, _INITIAL_STATE_TAG), (init_factor.shape[1],))
        )(sample_keys)
        x0 = x0 + z @ init_factor.T
    state = initial_sample_state(system, s0, x0[:, :n], x0[:, n:])
    total = jnp.maximum(jnp.sum(weights), 1.0)  # a device given only padding (weights 0) returns zeros
    clearance = system.contact_clearance()
    if eigen is None:  # physical coordinates
        prop = integrator.init(system, dt)  # None if K or C varies in time

        def step(state, snap0, snap1, draws):
            return sample_step(system, state, snap0, snap1, dt, draws, integrator, prop)

        def recorded(state, snap, t):  # the quantities of quantity_names, (batch, n_quantities)
            u = state.u
            parts = [u, state.v, u @ snap.direction, state.force]
            if observables is not None:
                y = u @ observables(t).T
                parts.append(y if observables.offset is None else y + observables.shift(t)[None, :])
            return jnp.concatenate(parts, axis=1)
    else:  # eigen-coordinates of the contact-free map (pgtjax._eigenbasis)
        state = eigen_initial_state(eigen, state.u, state.v, state.force, s0)

        def recorded(state, snap, t):  # straight from the eigen-coordinates: (u, v) are never formed
            c = jnp.zeros((n, 0), state.real.dtype) if observables is None else observables(t).T
            q = eigen_recorded(eigen, state, snap, c)
            if observables is not None and observables.offset is not None:
                shift = observables.shift(t)
                q = q + jnp.concatenate([jnp.zeros(q.shape[1] - shift.shape[0], q.dtype), shift])[None, :]
            return q

    nc = clearance.shape[0]
    # every peak follows every step: a contact force's from the forces the step's state carries, any other
    # quantity's (linear in the state) from its rows at the step's end
    force_peaks = [(j, c - 2 * n - nc) for j, c in enumerate(peak_columns) if _is_force_column(system, c)]
    output_peaks = [(j, c) for j, c in enumerate(peak_columns) if not _is_force_column(system, c)]
    output_columns = [c for _, c in output_peaks]

    def peak_of_step(peak, state, outputs):
        """``peak`` (batch, n_peaks) after a step: with each contact force's |value| and the |value| of the
        other quantities, ``outputs`` (batch, len(output_peaks)), at its end."""
        if not peak_columns:
            return peak
        # this step's magnitudes in the peaks' order, then one elementwise maximum (a scatter per kind of
        # quantity into the peaks' columns cost more)
        force_at, output_at = dict(force_peaks), {j: i for i, (j, _) in enumerate(output_peaks)}
        current = [
            state.force[:, force_at[j], None] if j in force_at else outputs[:, output_at[j], None]
            for j in range(len(peak_columns))
        ]
        return jnp.maximum(peak, jnp.abs(jnp.concatenate(current, axis=1)))

    def count(edges, values):  # weighted counts of values (batch,) in the bins of edges; outside: not counted
        idx = jnp.clip(jnp.searchsorted(edges, values, side="right") - 1, 0, edges.shape[0] - 2)
        inside = (values >= edges[0]) & (values <= edges[-1])
        return jnp.zeros(edges.shape[0] - 1).at[idx].add(weights * inside)

    def statistics(state, snap, t, peak, step_number):
        """The saved time's sums, and ``peak`` (batch, n_peaks), each sample's largest magnitude of each of
        the ``peaks`` quantities so far (None at the first), updated with this saved time's (the end of step
        ``step_number``). At the saved step ``peak_from`` and before, the peak restarts from this time's
        magnitude: it is taken from there on (a select per save; within the step loop, a per-step condition
        made XLA split the gear pair's step, docs/performance.md)."""
        q = recorded(state, snap, t)
        delta = q[:, 2 * n : 2 * n + nc]
        mean = weights @ q / total
        m2 = weights @ (q - mean[None, :]) ** 2
        loss = weights @ (jnp.abs(delta) < clearance[None, :]).astype(q.dtype)
        magnitude = jnp.abs(q[:, list(peak_columns)])
        peak = magnitude if peak is None else jnp.maximum(peak, magnitude)
        peak = jnp.where(step_number <= peak_from, magnitude, peak)
        # the values' counts, then the peaks': (n_hist + n_peaks, n_bins)
        n_hist = len(hist_columns)
        counts = [count(hist_edges[j], q[:, c]) for j, c in enumerate(hist_columns)]
        counts += [count(hist_edges[n_hist + j], peak[:, j]) for j in range(len(peak_columns))]
        counts = jnp.stack(counts) if counts else jnp.zeros((0, 0))
        if cov_columns:  # centred sums of cross products of the selected (u, v) columns
            centred = q[:, cov_columns] - mean[jnp.asarray(cov_columns)][None, :]
            comoment = (weights[:, None] * centred).T @ centred
        else:
            comoment = jnp.zeros((0, 0))
        return (mean, m2, loss, counts, comoment), peak

    def block_draws(block_index, first_row, rows):
        # One RNG key per sample and saved block (not per step): the draws of sample s in block j are
        # normal(fold_in(fold_in(key, s), j), (save_every, nd)), independent of how samples are chunked and of
        # how many of the block's rows are drawn at once.
        if not nd:
            return jnp.zeros((rows, n_batch, 0))
        keys = jax.vmap(lambda k: jax.random.fold_in(k, block_index))(sample_keys)
        return block_normals(keys, rows, nd, first_row, save_every)  # (rows, batch, nd)

    if eigen is None:

        def advance(c, step_number, step_draws):
            state, snap0, bad, peak = c
            t1 = t0 + dt * step_number
            snap1 = snapshot(system, t1)
            state, ok = step(state, snap0, snap1, step_draws)
            outputs = None
            if output_peaks:
                a_u, a_v, offset = _output_maps(system, snap1, observables, t1, output_columns)
                outputs = state.u @ a_u + state.v @ a_v + offset[None, :]
            peak = peak_of_step(peak, state, outputs)
            return (state, snap1, bad + jnp.sum(weights * (~ok)), peak), None

        block_inputs = block_draws
    else:  # what a step needs besides the state, formed for the block's steps at once, outside the step loop
        flat_inputs, structured_inputs = _eigen_flat_inputs(
            system, eigen, integrator, observables, output_columns
        )
        _, unflatten = ravel_pytree(structured_inputs(s0, s0, t0))

        def block_inputs(block_index, first_row, rows):
            steps = block_index * save_every + first_row + jnp.arange(rows + 1)
            snaps = jax.vmap(lambda k: snapshot(system, t0 + dt * k))(steps)
            inputs = jax.vmap(flat_inputs)(
                jax.tree.map(lambda a: a[:-1], snaps),
                jax.tree.map(lambda a: a[1:], snaps),
                t0 + dt * steps[1:],
            )
            return block_draws(block_index, first_row, rows), inputs  # (rows, batch, nd), (rows, n_inputs)

        def advance(c, step_number, x):
            state, snap, bad, peak = c  # snap: the start's, unused here (the record forms its own)
            step_draws, inputs = x
            # the step's inputs in one small array of their own: read through the scan's slice inside the
            # batch's loops, they made those loops 2.6 times slower (docs/performance.md)
            inputs, output_rows = unflatten(materialized(inputs))
            state, ok = eigen_advance(system, eigen, state, inputs, step_draws)
            outputs = None
            if output_peaks:  # a product of their own, so that the step itself is the same with peaks or not
                rows, force_rows, offset = output_rows
                outputs = eigen_outputs(eigen, state, rows, force_rows) + offset[None, :]
            peak = peak_of_step(peak, state, outputs)
            return (state, snap, bad + jnp.sum(weights * (~ok)), peak), None

    def record(c, _, block_index):
        state, snap, bad, peak = c
        t = t0 + dt * (block_index + 1) * save_every
        if eigen is not None:  # not carried through the steps
            snap = snapshot(system, t0 + dt * ((block_index + 1) * save_every))
        saved, peak = statistics(state, snap, t, peak, (block_index + 1) * save_every)
        return (state, c[1], bad, peak), saved

    first, peak = statistics(state, s0, t0, None, 0)
    carry = (state, s0, jnp.array(0.0), peak)
    carry, saved = saved_scan(
        advance,
        record,
        carry,
        first,
        n_blocks=n_steps // save_every,
        save_every=save_every,
        block_inputs=block_inputs,
        rows_per_input=rows_per_input,
        record_updates_carry=True,
    )
    return saved, carry[2]


def _rows_per_input(save_every: int, bytes_per_row: int, budget: int, partial_draws: bool) -> int:
    """Steps of a saved block whose random draws and step inputs (``bytes_per_row`` per step) are formed at
    once: as many as ``budget`` bytes hold (at least 1), preferring a divisor of ``save_every`` not under half
    of that, so that the block's rest does not compile the step a second time; the whole block where it fits,
    or where its draws cannot be drawn in parts (``partial_draws`` False: keys other than threefry's)."""
    if not partial_draws or save_every * bytes_per_row <= budget:
        return save_every
    rows = max(1, budget // bytes_per_row)
    small = [d for d in range(1, math.isqrt(save_every) + 1) if save_every % d == 0]
    divisor = max(d for d in small + [save_every // d for d in small] if d <= rows)
    return divisor if 2 * divisor >= rows else rows


def _block_rows(
    system,
    eigen,
    integrator,
    key,
    t0,
    save_every: int,
    per_device: int,
    devices,
    observables=None,
    output_columns=(),
) -> int:
    """:func:`_rows_per_input` for a device's batch of ``per_device`` samples, within
    :func:`pgtjax._parallel.draw_budget`: per step, the batch's uniforms and normals (and their transpose for
    several noise inputs, pgtjax._random.block_normals) and the flat step inputs of eigen-coordinates."""
    nd = integrator.noise_dimension(system)
    n_inputs = 0
    if eigen is not None:  # the flat step inputs of pgtjax._eigenbasis, formed for every step of a part
        flat, _ = _eigen_flat_inputs(system, eigen, integrator, observables, output_columns)

        def flat_inputs():  # traced for its size only: run op by op, the snapshot took 1.9 s the first time
            s0 = snapshot(system, t0)
            return flat(s0, s0, jnp.asarray(t0, jnp.float64))

        n_inputs = jax.eval_shape(flat_inputs).size
    copies = 2 if nd == 1 else 3
    return _rows_per_input(
        save_every,
        8 * (copies * per_device * nd + n_inputs),
        draw_budget(devices),
        not nd or is_threefry(key),
    )


_SAMPLE_AXIS = "samples"
MAX_SAMPLES = 2**32  # sample ids are folded into the key as 32-bit integers


def _chunk(system, key, sample_ids, weights, *args, mesh, **static):
    """:func:`_sample_statistics` of the samples ``sample_ids`` (n_devices, per_device), one row per device
    of ``mesh``: every device computes the statistics of its own row, with no communication; the results
    keep a leading device axis and are merged on the host like chunks."""
    arrays, rest = eqx.partition((system, key, args), eqx.is_array)

    def local(arrays, ids, w):
        system, key, args = eqx.combine(arrays, rest)
        out = _sample_statistics(system, key, ids[0], w[0], *args, **static)
        return jax.tree.map(lambda a: a[None], out)

    spec = jax.sharding.PartitionSpec(_SAMPLE_AXIS)
    sharded = jax.shard_map(
        local, mesh=mesh, in_specs=(jax.sharding.PartitionSpec(), spec, spec), out_specs=spec, check_vma=False
    )
    return sharded(arrays, sample_ids, weights)


_compiled_chunk = eqx.filter_jit(_chunk)
# the same program with XLA's 512-bit vectors, for CPUs with AVX-512 (pgtjax._parallel.wide_vectors)
_compiled_chunk_wide_vectors = eqx.filter_jit(_chunk, compiler_options=WIDE_VECTORS)


class _Moments(NamedTuple):
    """Running statistics of a set of samples (host arrays): sample count, means and centred sums of squares
    per saved time, contact-loss and histogram counts, centred sums of cross products, failed solves."""

    count: float
    mean: np.ndarray
    m2: np.ndarray
    loss: np.ndarray
    counts: np.ndarray
    comoment: np.ndarray
    bad: float

    def merge(self, other: _Moments, cov_columns: Sequence[int]) -> _Moments:
        """Chan et al.'s parallel combination (exact up to rounding for any split of the samples)."""
        bad = self.bad + other.bad
        if other.count == 0:
            return self._replace(bad=bad)
        if self.count == 0:
            return other._replace(bad=bad)
        n = self.count + other.count
        delta = other.mean - self.mean
        d_sel = delta[:, list(cov_columns)]
        weight = self.count * other.count / n
        return _Moments(
            count=n,
            mean=self.mean + delta * (other.count / n),
            m2=self.m2 + other.m2 + delta**2 * weight,
            loss=self.loss + other.loss,
            counts=self.counts + other.counts,
            comoment=self.comoment + other.comoment + np.einsum("ti,tj->tij", d_sel, d_sel) * weight,
            bad=bad,
        )

    def arrays(self) -> dict[str, np.ndarray]:
        return {f: np.asarray(getattr(self, f), dtype=np.float64) for f in self._fields}

    @classmethod
    def from_arrays(cls, arrays) -> _Moments:
        return cls(
            **{f: (float(arrays[f]) if f in ("count", "bad") else np.asarray(arrays[f])) for f in cls._fields}
        )


def checkpoint_samples(checkpoint, *, distributed=True) -> int | None:
    """The number of samples whose statistics the Monte Carlo checkpoint ``checkpoint`` holds (this process's
    share in a distributed run), or None where there is no readable pgtjax checkpoint (resuming says why)."""
    n_proc, proc = (jax.process_count(), jax.process_index()) if distributed else (1, 0)
    try:
        path = process_checkpoint_file(checkpoint, False, n_proc, proc, writable=False)
        with np.load(path, allow_pickle=False) as data:
            return int(data["count"]) if "__checkpoint__" in data.files else None
    except (OSError, KeyError, ValueError, zipfile.BadZipFile, EOFError):
        return None


def _recorded_key(key) -> list[int]:
    """The key as a checkpoint's description records it (its data words)."""
    return np.asarray(jax.random.key_data(key) if _is_typed_key(key) else key).tolist()


def _samples_per_device(n_samples: int, chunk_size, devices: list, n_proc: int) -> int:
    """Samples per device and round: ``chunk_size`` (the devices' default where None), fewer where the run is
    smaller than one round."""
    chunk_size = default_chunk_size(devices) if chunk_size is None else chunk_size
    return min(chunk_size, -(-n_samples // (n_proc * len(devices))))


def check_options(
    n_samples,
    chunk_size,
    checkpoint=None,
    resume: bool = False,
    *,
    key=None,
    devices=None,
    distributed=True,
    checkpoint_every=1,
):
    """The sizes and checkpoint options of :func:`monte_carlo`, checked before any computation (a study calls
    this before its other work, so that a bad option fails at once). With ``resume``, a checkpoint of another
    sample count, key (where given), device count or batch size is refused here too. Returns this process's
    checkpoint path."""
    check_count("n_samples", n_samples, minimum=2)
    if n_samples > MAX_SAMPLES:  # a sample's stream is fold_in(key, id) with a 32-bit id
        raise ValueError(
            f"`n_samples` must be at most 2**32 = {MAX_SAMPLES:,} (sample ids are 32-bit; beyond, samples "
            f"would repeat earlier samples' noise), got {n_samples:,}; split the run over several keys"
        )
    if chunk_size is not None:  # None: the devices' default (default_chunk_size)
        check_count("chunk_size", chunk_size)
    check_count("checkpoint_every", checkpoint_every)
    if key is not None:
        check_key(key)
    n_proc, proc = (jax.process_count(), jax.process_index()) if distributed else (1, 0)
    devices = local_devices(devices)
    per_device = _samples_per_device(n_samples, chunk_size, devices, n_proc)
    if n_proc > 1:
        _check_processes_agree(len(devices), per_device)
    try:  # this process's own checks, which may fail in one process only (a node-local file)
        path = process_checkpoint_file(checkpoint, resume, n_proc, proc)
        if resume:
            entries = dict(
                n_samples=int(n_samples),
                samples_per_device=per_device,
                devices=len(devices),
                processes=n_proc,
                process=proc,
            )
            if key is not None:
                entries["key"] = _recorded_key(key)
            check_checkpoint(path, entries, what="monte_carlo")
        refusal = None
    except ValueError as err:
        refusal = err
    if n_proc > 1:  # one process refusing stops them all, rather than leaving the others waiting for it
        refuse_together(refusal, "monte_carlo")
    if refusal is not None:
        raise refusal
    return path


def _check_processes_agree(n_dev: int, per_device: int) -> None:
    """Every process must split the samples alike: each one computes the sample ids of every process's rows
    from its own device count and batch size, so a mismatch would skip or repeat samples."""
    sizes = gather_processes(np.array([n_dev, per_device], dtype=np.int64))
    if np.any(sizes != sizes[0]):
        listed = "; ".join(
            f"process {p}: {d} device(s), {b} samples per device" for p, (d, b) in enumerate(sizes)
        )
        raise ValueError(
            f"monte_carlo: the processes of a distributed run must have the same number of devices and "
            f"`chunk_size` ({listed}); give every process as many devices (e.g. one GPU each, or "
            "`pg.use_cpu_cores(N)` alike) and the same `chunk_size`"
        )


def _gather_processes(moments: _Moments, cov_columns) -> _Moments:
    """Merge every process's statistics, in process order; every process gets the merged result."""
    from jax.experimental import multihost_utils

    gathered = {k: np.asarray(multihost_utils.process_allgather(v)) for k, v in moments.arrays().items()}
    merged = None
    for p in range(jax.process_count()):
        part = _Moments.from_arrays({k: v[p] for k, v in gathered.items()})
        merged = part if merged is None else merged.merge(part, cov_columns)
    return merged


def monte_carlo(
    system: System,
    *,
    n_samples: int,
    key,
    t0: float = 0.0,
    dt: float,
    n_steps: int,
    initial_displacement=None,
    initial_velocity=None,
    initial_covariance=None,
    observables: Observables | None = None,
    integrator: AbstractIntegrator | None = None,
    save_every: int = 1,
    chunk_size: int | None = None,
    histograms: Mapping[str, Sequence[float]] | None = None,
    histogram_times: Sequence[float] = (),
    peaks: Mapping[str, Sequence[float]] | None = None,
    peak_start: float | None = None,
    progress: bool = True,
    propagation: str = "auto",
    throw: bool = True,
    covariance_dofs: Sequence[str] | str | None = None,
    devices=None,
    distributed: bool = True,
    checkpoint=None,
    checkpoint_every: int = 1,
    resume: bool = False,
) -> MonteCarloResult:
    """Monte Carlo statistics of the nonlinear system driven by sampled white noise.

    Args:
        system, t0, dt, n_steps, save_every, integrator, initial_*, observables: as in
            :func:`pgtjax.solve_moments`; with ``initial_covariance`` each sample starts from a Gaussian draw.
        n_samples: number of samples (>= 2).
        key: a ``jax.random`` key (e.g. ``jax.random.key(0)``).
        chunk_size: samples per compiled batch and device (bounds memory: about ``chunk_size * 4 n`` floats);
            default 5,000 on CPU devices and 100,000 on a GPU, where small batches leave it idle between
            kernel launches. The statistics do not depend on it (to rounding). A long saved block's random
            draws and step inputs are formed a part at a time, about 8 MiB per CPU device and at most 256 MiB
            per GPU (threefry keys, JAX's default; another generator's draws are formed for the whole block),
            so that a long ``save_every`` costs neither memory nor time.
        histograms: ``{quantity: bin_edges}`` with quantity names from :func:`quantity_names`
            (e.g. ``"delta:mesh"``); all edge arrays (these and ``peaks``'s) must have the same length; values
            outside the edges are not counted.
        histogram_times: times (s) at which the histograms and peaks are reported (nearest saved time).
        peaks: ``{quantity: bin_edges}``: each sample's largest magnitude ``|value|`` of the quantity from
            ``t0`` (or ``peak_start``) to each histogram time, counted in those bins (the result's ``peak_histograms``: the
            distribution of the peak, e.g. of a meshing force's, whence the probability that it has reached a
            level by then). Every peak is taken over every step, not only the saved times: a contact force's
            from the forces each step carries, any other quantity's from the state at each step's end (for
            those, a small product per step; docs/performance.md, "Peaks of a quantity").
        peak_start: time (s) from which the peaks are taken (the nearest saved time; default ``t0``), e.g.
            after a start-up transient; every histogram time must be at or after it.
        progress: show the progress over chunks (process 0 only): a tqdm bar on a terminal or in a notebook, a
            line per tenth of the samples on any other stream (a log file).
        propagation: coordinates the samples are stepped in. ``"eigen"``: the real eigenbasis of the
            contact-free Newmark map (:mod:`pgtjax._eigenbasis`; constant K and C only), O(n (nc + n_draws))
            per sample and step instead of O(n^2), the same scheme to rounding; ``"physical"``: the DOFs themselves;
            ``"auto"`` (default): eigen where the basis is accepted, else physical.
        covariance_dofs: as in :func:`pgtjax.solve_moments`: the sample covariance (1/(N-1)) of the selected
            DOFs' displacements and velocities, ``result.covariance`` (n_times, 2m, 2m).
        devices: the devices of this process the samples are sharded over (``jax.sharding`` mesh, one batch of
            ``chunk_size`` samples per device at a time); default all of ``jax.local_devices()``.
        distributed: when JAX's distributed runtime is initialized (``jax.distributed.initialize``, more than
            one process), split the samples over all processes and return the merged statistics on every
            process; ``False``: this process runs all ``n_samples`` alone. An error in one process during
            the run stops every process once all have run their shares (the others raise
            :class:`~pgtjax.ProcessFailedError`).
        checkpoint: a ``.npz`` path where the running statistics and the position in the sample sequence are
            written atomically every ``checkpoint_every`` rounds (a round: ``chunk_size`` samples on each
            device) and at the end; with several processes each writes its own file
            (``<stem>.process-<p>-of-<n>.npz``).
        resume: continue from ``checkpoint`` (written by the same run: system, key, sizes, devices and
            processes; ``ValueError`` otherwise). The result equals that of an uninterrupted run.
        throw: raise :class:`pgtjax.SolverError` naming the first time and quantity where a statistic is not
            finite, or if a contact solve did not converge; with ``False`` the result is returned as it is
            (``unconverged`` counts the failed solves).
    """
    validate_system(system, t0)
    n_steps, save_every = validate_time_grid(dt, n_steps, save_every, t0)
    check_key(key)
    check_observables(system, observables, t0)
    check_contact_stiffness_over_time(system, t0, dt, n_steps)
    check_stability(system, t0, horizon=n_steps * float(dt))
    integrator = resolve_integrator(integrator)
    checkpoint = check_options(
        n_samples,
        chunk_size,
        checkpoint,
        resume,
        key=key,
        devices=devices,
        distributed=distributed,
        checkpoint_every=checkpoint_every,
    )
    n_proc, proc = (jax.process_count(), jax.process_index()) if distributed else (1, 0)
    moments, first_round = None, 0
    # checks and work that may fail in one process only (its memory, its node-local checkpoint): all stop
    with fail_together("monte_carlo", n_proc > 1, stage="before the run"):
        if propagation not in PROPAGATIONS:
            raise ValueError(f"`propagation` must be one of {PROPAGATIONS}, got {propagation!r}")
        eigen = None
        if propagation != "physical":
            eigen, reason = eigen_propagator(system, dt, integrator)
            if eigen is None and propagation == "eigen":
                raise ValueError(f"`propagation='eigen'` is not available for this system: {reason}")
        n = system.n_dof
        u0, v0 = initial_state(system, initial_displacement, initial_velocity)
        if initial_covariance is None:
            init_factor = jnp.zeros((2 * n, 0))
        else:
            p0 = np.asarray(check_initial_covariance(system, initial_covariance))
            init_factor = jnp.asarray(_symmetric_square_root(0.5 * (p0 + p0.T)))
        names = quantity_names(system, observables)
        if histograms is not None and not isinstance(histograms, Mapping):
            raise ValueError(
                f"`histograms` must be a dict {{quantity name: bin edges}}, e.g. {{'u:x': np.linspace(-1e-4, 1e-4, 41)}}, "
                f"got {type(histograms).__name__}"
            )
        if peaks is not None and not isinstance(peaks, Mapping):
            raise ValueError(
                f"`peaks` must be a dict {{quantity name: bin edges}}, e.g. {{'force:mesh': np.linspace(0, 5e5, 51)}}, "
                f"got {type(peaks).__name__}"
            )
        histograms, peaks = dict(histograms or {}), dict(peaks or {})
        hist_columns, peak_columns, edges = [], [], []
        for option, bins, columns in (
            ("histograms", histograms, hist_columns),
            ("peaks", peaks, peak_columns),
        ):
            for name, e in bins.items():
                if name not in names:
                    raise ValueError(f"unknown quantity {name!r} in `{option}`; choose from {names}")
                e = np.asarray(e, dtype=np.float64)
                if e.ndim != 1 or e.size < 2 or np.any(np.diff(e) <= 0) or not np.all(np.isfinite(e)):
                    raise ValueError(
                        f"`{option}` edges for {name!r} must be a finite increasing 1-D array (>= 2 edges)"
                    )
                columns.append(names.index(name))
                edges.append(e)
        if len({e.size for e in edges}) > 1:
            raise ValueError("all edge arrays of `histograms` and `peaks` must have the same length")
        histogram_times = _check_histogram_times(
            histogram_times, histograms or peaks, t0, dt * n_steps, dt * save_every
        )
        if peaks and not histogram_times:
            raise ValueError(
                "`peaks` are reported at `histogram_times` (the peak from t0, or `peak_start`, to each): give at "
                "least one, "
                f"e.g. the run's end, {float(t0) + float(dt) * n_steps:.6g} s"
            )
        peak_from = _peak_start_step(peak_start, peaks, histogram_times, t0, dt, n_steps, save_every)
        n_saved = n_steps // save_every + 1
        cov_size = len(covariance_index(system, covariance_dofs))
        per_save = (
            2 * len(names) + sum(e.size + 1 for e in edges) + cov_size**2
        )  # mean, M2, counts, comoments
        check_memory("monte_carlo", n_saved, per_save)
        hist_edges = jnp.asarray(np.stack(edges)) if edges else jnp.zeros((0, 2))
        cov_columns = covariance_index(system, covariance_dofs)  # u then v: the columns of q, too
        devices = local_devices(devices)
        n_dev = len(devices)
        mesh = device_mesh(devices, _SAMPLE_AXIS)
        chunk = _compiled_chunk_wide_vectors if wide_vectors(devices) else _compiled_chunk
        # round r: n_proc x n_dev rows of per_device consecutive sample ids, row (p, d) on device d of process p
        per_device = _samples_per_device(n_samples, chunk_size, devices, n_proc)
        round_size = n_proc * n_dev * per_device
        n_rounds = -(-n_samples // round_size)
        checkpoint_every = int(checkpoint_every)
        description = dict(
            # one entry per input, so that a refused resume names what differs (a changed seed shows as the key)
            system=tree_digest(system),
            key=_recorded_key(key),
            initial_state=tree_digest(u0, v0, init_factor),
            observables=tree_digest(observables),
            histogram_edges=tree_digest(hist_edges),
            integrator=tree_digest(integrator),
            normals=normals_stream(key),
            quantities=names,
            histograms=list(histograms),
            covariance_columns=list(cov_columns),
            peaks=list(peaks),
            propagation="physical" if eigen is None else "eigen",
            t0=float(t0),
            dt=float(dt),
            n_steps=n_steps,
            save_every=save_every,
            n_samples=int(n_samples),
            samples_per_device=per_device,
            devices=n_dev,
            processes=n_proc,
            process=proc,
        )
        output_columns = [c for c in peak_columns if not _is_force_column(system, c)]
        rows_per_input = _block_rows(
            system, eigen, integrator, key, t0, save_every, per_device, devices, observables, output_columns
        )
        if eigen is not None:  # the steps' inputs formed per saved block, or per part of a long one, since
            # 2026-11-28 (rounding differs): a checkpoint of an eigen run from before, or with parts of another
            # length (they follow from the devices' draw budget, pgtjax._parallel.draw_budget), is refused rather
            # than resumed to last-bit differences
            description["step_inputs"] = (
                "per block" if rows_per_input == save_every else f"per {rows_per_input} steps"
            )
        # every quantity's peak follows every step since 2026-11-28 (before, only contact forces' did, and the
        # others' followed the saves): a checkpoint from before with such peaks is refused, not resumed
        description["peak_updates"] = "every step"
        description["peak_start_step"] = peak_from
        if resume:
            # `peaks` entered the description on 2026-11-28, and their start later that day: a checkpoint from
            # before had no peaks, or peaks from t0
            absent = {
                "peaks": [],
                "peak_updates": "saves" if output_columns else "every step",
                "peak_start_step": 0,
            }
            saved = load_checkpoint(checkpoint, description, what="monte_carlo", absent=absent)
            first_round = int(saved.pop("next_round"))
            moments = _Moments.from_arrays(saved)
    bar = None
    if progress and proc == 0:
        bar = progress_bar(
            n_samples, "Monte Carlo", "samples", initial=min(first_round * round_size, n_samples)
        )
    with fail_together(
        "monte_carlo", n_proc > 1, stage="during the run"
    ):  # one failing stops all, at the end
        for r in range(first_round, n_rounds):
            ids = (
                r * round_size
                + proc * n_dev * per_device
                + np.arange(n_dev * per_device).reshape(n_dev, per_device)
            )
            weights = (ids < n_samples).astype(np.float64)
            # padding rows (weight 0) repeat the last sample: a sample of their own could be NaN where every real
            # one is finite, and 0 x NaN would spoil the sums
            parts, bad = chunk(
                system,
                key,
                jnp.asarray(np.minimum(ids, n_samples - 1)),
                jnp.asarray(weights),
                u0,
                v0,
                init_factor,
                jnp.asarray(t0, jnp.float64),
                jnp.asarray(dt, jnp.float64),
                jnp.asarray(peak_from, jnp.int32),
                hist_edges,
                observables,
                eigen,
                mesh=mesh,
                n_steps=n_steps,
                save_every=save_every,
                integrator=integrator,
                hist_columns=tuple(hist_columns),
                peak_columns=tuple(peak_columns),
                cov_columns=cov_columns,
                rows_per_input=rows_per_input,
            )
            parts, bad = [np.asarray(a) for a in parts], np.asarray(bad)
            for d in range(n_dev):
                part = _Moments(float(weights[d].sum()), *(a[d] for a in parts), bad=float(bad[d]))
                moments = part if moments is None else moments.merge(part, cov_columns)
            if checkpoint is not None and ((r + 1) % checkpoint_every == 0 or r + 1 == n_rounds):
                save_checkpoint(
                    checkpoint,
                    dict(moments.arrays(), next_round=np.asarray(r + 1)),
                    description,
                    what="monte_carlo",
                )
            if bar is not None:
                bar.update(min(round_size, n_samples - r * round_size))
    if bar is not None:
        bar.close()
    if n_proc > 1:
        moments = _gather_processes(moments, cov_columns)
    total_n, mean, m2, loss, counts, comoment, bad = moments
    std = np.sqrt(np.maximum(m2, 0.0) / (total_n - 1.0))
    nc = system.n_contacts
    cut = np.cumsum([n, n, nc, nc])
    times = _saved_times(t0, dt, n_steps, save_every)
    if throw:
        raise_if_nonfinite("monte_carlo", times, {"sample mean": (mean, names), "sample std": (std, names)})
        if bad:
            raise SolverError(
                f"monte_carlo: the contact Newton solve did not converge in {int(bad)} (sample, step) pairs; "
                "reduce `dt` or check the contact law, or pass throw=False to read `unconverged`"
            )
    hist_idx = np.array([int(np.argmin(np.abs(times - t))) for t in histogram_times], dtype=int)
    split = lambda a: np.split(a, cut, axis=1)  # noqa: E731
    mu_u, mu_v, mu_d, mu_f, mu_o = split(mean)
    sd_u, sd_v, sd_d, sd_f, sd_o = split(std)
    return MonteCarloResult(
        times=jnp.asarray(times),
        dof_names=system.dof_names,
        dof_units=system.dof_units,
        contact_names=system.contact_names(),
        n_samples=int(total_n),
        mean_u=jnp.asarray(mu_u),
        std_u=jnp.asarray(sd_u),
        mean_v=jnp.asarray(mu_v),
        std_v=jnp.asarray(sd_v),
        mean_delta=jnp.asarray(mu_d),
        std_delta=jnp.asarray(sd_d),
        force_mean=jnp.asarray(mu_f),
        force_std=jnp.asarray(sd_f),
        histogram_times=jnp.asarray(times[hist_idx]),
        histogram_edges={name: jnp.asarray(e) for name, e in zip(histograms, edges)},
        histograms={name: jnp.asarray(counts[hist_idx, j]) for j, name in enumerate(histograms)},
        peak_edges={name: jnp.asarray(e) for name, e in zip(peaks, edges[len(histograms) :])},
        peak_start=float(times[peak_from // save_every]) if peaks else None,
        peak_histograms={
            name: jnp.asarray(counts[hist_idx, len(histograms) + j]) for j, name in enumerate(peaks)
        },
        contact_loss_probability=jnp.asarray(loss / total_n),
        unconverged=jnp.asarray(bad),
        mean_obs=jnp.asarray(mu_o),
        std_obs=jnp.asarray(sd_o),
        observable_names=() if observables is None else observables.names,
        propagation="physical" if eigen is None else "eigen",
        covariance=jnp.asarray(comoment / (total_n - 1.0)),
        covariance_dofs=tuple(system.dof_names[i] for i in cov_columns[: len(cov_columns) // 2]),
    )
