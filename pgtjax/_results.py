"""Labelled results of the solvers, and a reloadable on-disk format.

Every result carries its time grid (s), the DOF names and units and the contact names, so that a
70-DOF response stays readable. ``save_results``/``load_results`` write one ``.npz`` file whose arrays are
the result's fields and whose ``__meta__`` entry is JSON (class, labels, units, attributes).
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._config import require_x64
from ._numerics import safe_sqrt
from ._typing import Array, Bool, Float64, Int, typechecked


class _Labelled(eqx.Module):
    times: Float64[Array, " n_times"]
    dof_names: tuple[str, ...] = eqx.field(static=True)
    dof_units: tuple[str, ...] = eqx.field(static=True)
    contact_names: tuple[str, ...] = eqx.field(static=True)


class _Covariance(eqx.Module):
    """The joint covariance of the displacements and velocities of ``covariance_dofs`` (the solvers'
    option of that name): ``covariance`` (n_times, 2m, 2m) ordered ``(u_1..u_m, v_1..v_m)``."""

    @property
    def cov_uu(self) -> jax.Array:
        """Displacement covariance (n_times, m, m) [m^2 or the DOFs' units squared]."""
        m = len(self.covariance_dofs)
        return self._covariance()[:, :m, :m]

    @property
    def cov_uv(self) -> jax.Array:
        """Displacement-velocity covariance E[(u - mu_u)(v - mu_v)^T] (n_times, m, m)."""
        m = len(self.covariance_dofs)
        return self._covariance()[:, :m, m:]

    @property
    def cov_vv(self) -> jax.Array:
        """Velocity covariance (n_times, m, m)."""
        m = len(self.covariance_dofs)
        return self._covariance()[:, m:, m:]

    def _covariance(self) -> jax.Array:
        if not self.covariance_dofs:
            raise ValueError(
                "no covariance was saved: pass `covariance_dofs` (DOF names or 'all') to the solver"
            )
        return self.covariance

    def observable(self, name: str) -> int:
        """Index of an observable (see :class:`pgtjax.Observables`) by name."""
        names = getattr(self, "observable_names", ())
        if name not in names:
            raise ValueError(f"unknown observable {name!r}; known: {', '.join(names)}")
        return names.index(name)

    def dof(self, name: str) -> int:
        """Index of a DOF by name."""
        try:
            return self.dof_names.index(name)
        except ValueError:
            raise ValueError(f"unknown DOF {name!r}; known: {', '.join(self.dof_names)}") from None

    def contact(self, name: str) -> int:
        try:
            return self.contact_names.index(name)
        except ValueError:
            raise ValueError(f"unknown contact {name!r}; known: {', '.join(self.contact_names)}") from None


@typechecked
class MomentResult(_Labelled, _Covariance):
    """Mean and standard deviation from SL + the stochastic Newmark recursion.

    Shapes: ``(n_times, n_dof)`` for DOFs (displacement ``*_u``, velocity ``*_v``), ``(n_times, n_contacts)``
    for contacts. ``force_mean``/``force_std`` are the moments of the *nonlinear* contact force under the
    Gaussian deflection (N); ``k_e``/``f_0`` the linearization coefficients (N/m, N); ``mean_obs``/``std_obs``
    the moments of the observables (``observable_names``), if any. ``iterations``,
    ``residual`` (scaled) and ``converged`` report the per-step fixed point (worst step of each saved block).
    """

    mean_u: Float64[Array, "n_times n_dof"]
    std_u: Float64[Array, "n_times n_dof"]
    mean_v: Float64[Array, "n_times n_dof"]
    std_v: Float64[Array, "n_times n_dof"]
    mean_delta: Float64[Array, "n_times n_contacts"]
    std_delta: Float64[Array, "n_times n_contacts"]
    force_mean: Float64[Array, "n_times n_contacts"]
    force_std: Float64[Array, "n_times n_contacts"]
    k_e: Float64[Array, "n_times n_contacts"]
    f_0: Float64[Array, "n_times n_contacts"]
    iterations: Int[Array, " n_times"]
    residual: Float64[Array, " n_times"]
    converged: Bool[Array, " n_times"]
    mean_obs: Float64[Array, "n_times n_obs"]
    std_obs: Float64[Array, "n_times n_obs"]
    criterion: str = eqx.field(static=True)
    observable_names: tuple[str, ...] = eqx.field(static=True, default=())
    covariance: Float64[Array, "n_times n_cov n_cov"] | None = None  # see covariance_dofs
    covariance_dofs: tuple[str, ...] = eqx.field(static=True, default=())
    # each contact deflection's (m^2), displacement's and observable's (their unit squared) covariance with
    # its value one step earlier (0 at the first time), saved with solve_moments(deflection_lag=True), else None
    cov_delta_lag: Float64[Array, "n_times n_contacts"] | None = None
    cov_u_lag: Float64[Array, "n_times n_dof"] | None = None
    cov_obs_lag: Float64[Array, "n_times n_obs"] | None = None

    def contact_loss_probability(self, clearance) -> jax.Array:
        """P(|delta| < b) of each contact at each saved time under SL's Gaussian deflection, (n_times, nc), for
        any criterion; ``clearance``: the half-clearances b (m), or the :class:`pgtjax.System` solved.
        (Monte Carlo's counterpart is the field of the same name.)"""
        if hasattr(clearance, "contact_clearance"):
            clearance = clearance.contact_clearance()
        b = jnp.asarray(clearance, jnp.float64)
        nc = len(self.contact_names)
        if b.ndim > 1 or (b.ndim == 1 and b.shape[0] not in (1, nc)):
            raise ValueError(f"`clearance` must be a number or one per contact ({nc}), got shape {b.shape}")
        b = jnp.broadcast_to(b, (nc,))
        return _gaussian_gap_probability(self.mean_delta, self.std_delta, b[None, :])

    def peak_exceedance(
        self, quantity: str, levels, *, start: float | None = None, system=None, method: str = "auto"
    ) -> CrossingExceedance:
        """SL's counterpart of :meth:`MonteCarloResult.peak_exceedance`: the probability that a quantity's peak
        (its largest magnitude from ``start``, s, the nearest saved time; default the first) has reached each of
        ``levels`` (>= 0, the quantity's unit) by each saved time, from the level crossings of the Gaussian
        response (:class:`CrossingExceedance`; rows before ``start`` are 0; docs/peaks.md). Quantities:

        - ``"u:<dof>"``, a displacement (the DOF's unit), ``"delta:<contact>"``, a contact deflection (m),
          ``"force:<contact>"``, a contact force (N), and ``"obs:<observable>"``, an observable (its unit; solve
          with ``observables``), by ``method="steps"``: the probability of crossing between each pair of
          consecutive steps, as Monte Carlo takes the peaks (solve with ``deflection_lag=True``, saved every
          step);
        - ``"u:<dof>"`` also by ``method="rice"``: Rice's continuous-time rate, integrated over the saved times;
          needs the DOF's joint displacement-velocity covariance (solve with ``covariance_dofs`` including it).
          Save every few steps, and far more often than ``std / |d mean / dt|`` where the response is nearly
          deterministic; the step must resolve the response (its velocity stands for the displacement's rate),
          else the estimate is far off (docs/peaks.md).

        ``method="auto"`` (default) takes the steps wherever the result has the step lags (``cov_u_lag`` for a
        displacement), else Rice's rate for a displacement.

        A force level ``F``: ``|f| >= F`` puts the deflection outside barriers that move with the contact's
        inputs (``b + F / k(t)`` for :class:`pgtjax.Backlash`). Pass the ``system`` solved (its law must
        implement ``deflections_at_force``; its contact names and DOFs, and the contact's force mean and std
        for SL's deflection at every saved time, are checked against the result, except on traced values).

        ``lower_bound``, the largest probability of being beyond a level at one saved time since ``start``,
        bounds the probability from below with no assumption on the crossings, and ``upper_bound`` from above
        (both for the Gaussian response with SL's moments); the Poisson ``probability`` lies between them where
        crossings are rare and independent, and above the truth where they come in clumps.

        A deterministic quantity (std 0) counts the crossings of its mean. Works under ``jax.jit`` and
        ``jax.grad`` (the levels and ``start`` are not differentiated)."""
        from ._crossings import (
            crossing_rate,
            cumulative_trapezoid,
            exceedance_at_start,
            outside_probability,
            step_crossings,
        )

        if not isinstance(quantity, str):
            raise ValueError(f"`quantity` must be a name 'u:<dof>', 'delta:<contact>', 'force:<contact>' or "
                             f"'obs:<observable>', got {type(quantity).__name__}")  # fmt: skip
        kind, _, name = quantity.partition(":")
        if kind not in ("u", "delta", "force", "obs"):
            raise ValueError(
                "`quantity` must be a displacement 'u:<dof>', a contact deflection 'delta:<contact>', a contact "
                f"force 'force:<contact>' or an observable 'obs:<observable>', got {quantity!r}"
            )
        try:
            a = np.asarray(levels, dtype=np.float64)
        except (TypeError, ValueError):
            a = None
        if a is None or a.ndim != 1 or a.size == 0 or not np.all(np.isfinite(a)) or np.any(a < 0):
            raise ValueError(f"`levels` must be a 1-D array of finite levels >= 0, got {levels!r}")
        if method not in ("auto", "steps", "rice"):
            raise ValueError(f"`method` must be 'auto', 'steps' or 'rice', got {method!r}")
        if method == "rice" and kind != "u":
            raise ValueError(f"`method='rice'` estimates displacements ('u:<dof>') only, got {quantity!r}")
        # per kind: (index by name, mean, std, covariance with the step before), arrays (n_times, k)
        index, means, stds, lags = {
            "u": (self.dof, self.mean_u, self.std_u, self.cov_u_lag),
            "obs": (self.observable, self.mean_obs, self.std_obs, self.cov_obs_lag),
        }.get(kind, (self.contact, self.mean_delta, self.std_delta, self.cov_delta_lag))
        rice = method == "rice" or (method == "auto" and kind == "u" and lags is None)
        i = index(name)
        mean, std = means[:, i], stds[:, i]
        if rice and name not in self.covariance_dofs:
            raise ValueError(
                f"the peak of {quantity!r} needs each step's covariance with the step before (solve with "
                "`deflection_lag=True` and save_every=1) or, for Rice's rate, its displacement-velocity "
                f"covariance (solve with `covariance_dofs` including {name!r}; saved: "
                f"{list(self.covariance_dofs) or 'none'})"
            )
        if not rice and lags is None:
            raise ValueError(
                f"the peak of {quantity!r} needs each step's covariance with the step before: solve with "
                "`deflection_lag=True` (and save_every=1)"
            )
        times = self.times
        n_times = times.shape[0]
        first = 0
        if start is not None:
            try:
                t_start = float(start)
            except (TypeError, ValueError):
                raise ValueError(f"`start` must be a time (s), got {start!r}") from None
            if not isinstance(times, jax.core.Tracer):  # a result of a traced solve: not checked
                grid = np.asarray(times)
                if not (np.isfinite(t_start) and grid[0] <= t_start <= grid[-1]):
                    raise ValueError(
                        f"`start` must lie within the run, [{grid[0]:g}, {grid[-1]:g}] s, got {start!r}"
                    )
            first = jnp.argmin(jnp.abs(times - t_start))
        if rice:
            j = self.covariance_dofs.index(name)
            rate = crossing_rate(a, mean, std, self.mean_v[:, i], self.std_v[:, i], self.cov_uv[:, j, j])
            crossings = cumulative_trapezoid(rate, times, first)
            at_start = exceedance_at_start(a, mean[first], std[first])[None, :]
            level = jnp.broadcast_to(jnp.asarray(a)[None, :], (n_times, a.size))
            outside = outside_probability(level, -level, mean[:, None], std[:, None])
        else:
            if kind == "force":
                upper, lower = self._force_barriers(quantity, i, jnp.asarray(a), system)
            else:
                upper = jnp.broadcast_to(jnp.asarray(a)[None, :], (n_times, a.size))
                lower = -upper
            per_step = step_crossings(upper, lower, mean, std, lags[:, i])  # step j -> j + 1
            per_step = jnp.where((jnp.arange(n_times - 1) >= first)[:, None], per_step, 0.0)
            crossings = jnp.concatenate([jnp.zeros_like(per_step[:1]), jnp.cumsum(per_step, axis=0)])
            at_start = outside_probability(upper[first], lower[first], mean[first], std[first])[None, :]
            outside = outside_probability(upper, lower, mean[:, None], std[:, None])
            if kind == "force":
                # |f| >= 0 always: a level of 0 N is reached at the start, whatever the clearance
                at_start = jnp.where(jnp.asarray(a)[None, :] == 0.0, 1.0, at_start)
                outside = jnp.where(jnp.asarray(a)[None, :] == 0.0, 1.0, outside)
        counted = (jnp.arange(n_times) >= first)[:, None]
        # the peak since the start is at least the magnitude at each saved time since: P(|X(t)| >= a) at the
        # most likely of them bounds the probability from below, with no assumption on the crossings
        lower_bound = jax.lax.cummax(jnp.where(counted, outside, 0.0), axis=0)
        return CrossingExceedance(
            levels=jnp.asarray(a),
            # 1 - (1 - P0) exp(-N) written as a sum of two terms >= 0: no cancellation at small P0 and N, where the
            # difference lost every digit below about 1e-16 / P (a few per cent at 1e-14)
            probability=jnp.where(counted, at_start - (1.0 - at_start) * jnp.expm1(-crossings), 0.0),
            upper_bound=jnp.where(counted, jnp.minimum(1.0, at_start + crossings), 0.0),
            expected_crossings=crossings,
            times=times,
            start=times[first],
            lower_bound=lower_bound,
        )

    def _force_barriers(self, quantity: str, contact: int, levels, system):
        """The deflection barriers ``(upper, lower)`` of a contact force's levels at the saved times, (n_times, k)
        each, from the system's contact inputs and law."""
        if system is None or not hasattr(system, "contact_inputs"):
            raise ValueError(
                f"the peak of {quantity!r} needs the `system` solved: its contact inputs (the mesh stiffness) set "
                f"the deflection at each force level; got system={system!r}"
            )
        if system.contact_names() != self.contact_names or system.dof_names != self.dof_names:
            raise ValueError(
                f"`system` has the contacts {list(system.contact_names())} and {system.n_dof} DOFs, the result "
                f"{list(self.contact_names)} and {len(self.dof_names)}: pass the system that was solved"
            )
        law = system.contacts.law
        clearance = system.contacts.clearance[contact]

        def barriers(t):
            inputs = jax.tree.map(lambda x: x[..., contact], system.contact_inputs(t))
            return law.deflections_at_force(levels, inputs, clearance)

        try:
            upper_lower = jax.vmap(barriers)(self.times)
        except NotImplementedError:
            raise ValueError(
                f"the peak of {quantity!r} needs the deflections at a force level, which the contact law "
                f"{type(law).__name__} does not give (it implements no `deflections_at_force`)"
            ) from None
        self._check_force_law(system, contact)
        return upper_lower

    def _check_force_law(self, system, contact: int) -> None:
        """Refuse a ``system`` whose contact law or inputs (a mesh stiffness) differ from those solved: for SL's
        deflection, its force's mean and std at every saved time must be those SL saved, within 1e-8 of
        ``|mean| + std`` there plus 1e-8 of its largest value (the std tells the stiffness where a contact
        carries no mean load). Times whose saved values are not finite are skipped; nothing is checked on
        traced values (a traced result or system)."""
        leaves = jax.tree.leaves(
            (self.times, self.force_mean, self.force_std, self.mean_delta, self.std_delta)
        )
        if any(isinstance(x, jax.core.Tracer) for x in leaves):
            return
        times, mean_delta, std_delta = (np.asarray(x) for x in (self.times, self.mean_delta, self.std_delta))
        law, clearance = system.contacts.law, system.contacts.clearance

        def moments(t, mu, sigma):
            mean, std = law.force_moments(mu, sigma, system.contact_inputs(t), clearance)
            return mean[contact], std[contact]

        with jax.ensure_compile_time_eval():  # evaluated now, also while a jit traces around concrete values
            got = jax.vmap(moments)(times, mean_delta, std_delta)
        if any(isinstance(x, jax.core.Tracer) for x in got):  # e.g. a system closing over traced values
            return
        got_mean, got_std = (np.asarray(x) for x in got)
        saved_mean, saved_std = (
            np.asarray(self.force_mean)[:, contact],
            np.asarray(self.force_std)[:, contact],
        )
        scale = np.abs(saved_mean) + saved_std
        finite = np.isfinite(scale)
        # relative to each time's force and to the largest one: far in the tails (a contact barely touching)
        # the force's last significant digits differ between the solve's compiled program and this one
        tolerance = 1e-8 * (scale + np.max(scale, where=finite, initial=0.0))
        off = finite & (
            (np.abs(got_mean - saved_mean) > tolerance) | (np.abs(got_std - saved_std) > tolerance)
        )
        if np.any(off):
            j = int(np.argmax(off))
            raise ValueError(
                f"`system` gives the force on contact {self.contact_names[contact]!r} at t = {times[j]:g} s a "
                f"mean of {got_mean[j]:.10g} N and a std of {got_std[j]:.10g} N for the deflection solved, the "
                f"result saved {saved_mean[j]:.10g} N and {saved_std[j]:.10g} N: pass the system that was solved "
                "(with the contact law and stiffness it was solved with)"
            )

    @classmethod
    def from_saved(cls, system, times, saved, *, criterion, observables=None, covariance_dofs=()):
        n, nc = system.n_dof, system.n_contacts
        sd = safe_sqrt(saved.var)
        return cls(
            times=times,
            dof_names=system.dof_names,
            dof_units=system.dof_units,
            contact_names=system.contact_names(),
            mean_u=saved.mean[:, :n],
            std_u=sd[:, :n],
            mean_v=saved.mean[:, n:],
            std_v=sd[:, n:],
            mean_delta=saved.z[:, :nc],
            std_delta=saved.z[:, nc:],
            force_mean=saved.force_mean,
            force_std=saved.force_std,
            k_e=saved.k_e,
            f_0=saved.f_0,
            iterations=saved.iterations,
            residual=saved.residual,
            converged=saved.converged,
            mean_obs=saved.obs_mean,
            std_obs=saved.obs_std,
            criterion=criterion,
            observable_names=() if observables is None else observables.names,
            covariance=saved.covariance,
            covariance_dofs=tuple(covariance_dofs),
            cov_delta_lag=saved.delta_lag,
            cov_u_lag=saved.u_lag,
            cov_obs_lag=saved.obs_lag,
        )


class TimeAverage(NamedTuple):
    """Time averages over a window of Monte Carlo statistics, with batch-means standard errors."""

    mean: np.ndarray  # (k,) time average of the sample mean
    mean_se: np.ndarray  # (k,) its standard error
    std: np.ndarray  # (k,) time average of the sample standard deviation
    std_se: np.ndarray  # (k,) its standard error
    n_times: int  # saved times averaged (the window's, trimmed to whole batches)


class CrossingExceedance(NamedTuple):
    """SL's estimate of the probability that a quantity's peak (largest magnitude since ``start``) has reached
    each level by each saved time, from the level crossings of the Gaussian response: crossings between
    consecutive steps, or Rice's rate for a displacement of a run without the step lags
    (:meth:`MomentResult.peak_exceedance`; :mod:`pgtjax._crossings`). Rows before ``start`` are 0."""

    levels: jax.Array  # (k,) in the quantity's unit
    probability: jax.Array  # (n, k) 1 - (1 - P0) exp(-N): the crossings as a Poisson stream
    upper_bound: jax.Array  # (n, k) min(1, P0 + N): a bound (Rice's: up to the trapezoids' error)
    expected_crossings: jax.Array  # (n, k) N, the mean number of times |value| reached the level since start
    times: jax.Array  # (n,) the saved times (s)
    start: jax.Array  # s, the saved time the peaks are taken from
    # (n, k) the largest P(|value| >= level) at one saved time since start: a bound from below that, unlike
    # the Poisson stream, holds when crossings come in clumps
    lower_bound: jax.Array


class PeakExceedance(NamedTuple):
    """The probability that a quantity's peak (its largest magnitude since ``start``) has reached each level by
    each histogram time, from Monte Carlo's peak counts (:meth:`MonteCarloResult.peak_exceedance`)."""

    levels: np.ndarray  # (n_bins,) the bins' upper edges, in the quantity's unit
    # (n_hist, n_bins) P(peak >= level) by each of histogram_times (> at the top edge)
    probability: np.ndarray
    standard_error: np.ndarray  # (n_hist, n_bins) sqrt(p (1 - p) / n_samples), the binomial one
    times: np.ndarray  # (n_hist,) the histogram times (s)
    start: float  # the time (s) the peaks are taken from


def every_nth_save(result: MomentResult, n: int) -> MomentResult:
    """``result`` at every ``n``-th saved time (first included). The per-block solver diagnostics
    (``iterations``, ``residual``, ``converged``) are reduced over the ``n`` blocks merged into each, so that
    a step that did not converge is not dropped with its block; the covariances with the step before
    (``cov_delta_lag``, ``cov_u_lag``, ``cov_obs_lag``) are dropped for n > 1."""
    if (len(result.times) - 1) % n:
        raise ValueError(f"{len(result.times) - 1} saved blocks cannot be merged by {n}")
    out = jax.tree.map(lambda a: a[::n], result)

    def merged(a, reduce):
        return jnp.concatenate([a[:1], reduce(a[1:].reshape(-1, n, *a.shape[1:]), axis=1)])

    out = eqx.tree_at(
        lambda r: (r.iterations, r.residual, r.converged),
        out,
        (
            merged(result.iterations, jnp.max),
            merged(result.residual, jnp.max),
            merged(result.converged, jnp.all),
        ),
    )
    lags = lambda r: (r.cov_delta_lag, r.cov_u_lag, r.cov_obs_lag)  # noqa: E731
    if n > 1 and any(
        lag is not None for lag in lags(result)
    ):  # a one-step lag no longer pairs the kept times
        out = eqx.tree_at(lags, out, (None, None, None), is_leaf=lambda x: x is None)
    return out


def _gaussian_gap_probability(mean, std, clearance):
    """P(|delta| < b) for delta ~ N(mean, std^2), elementwise; a deterministic delta (std = 0) gives 0 or 1."""
    from jax.scipy.special import ndtr

    positive = std > 0.0
    safe = jnp.where(positive, std, 1.0)
    # symmetric in the mean: with |mean| both terms are small far from the gap (no cancellation of two ~1s)
    distance = jnp.abs(mean)
    inside = (distance < clearance).astype(mean.dtype)
    prob = ndtr((clearance - distance) / safe) - ndtr((-clearance - distance) / safe)
    return jnp.where(positive, prob, inside)


@typechecked
class MonteCarloResult(_Labelled, _Covariance):
    """Sample statistics of the nonlinear system (Monte Carlo).

    ``mean_*``/``std_*`` as in :class:`MomentResult` (``std`` with the 1/(N-1) normalisation, thesis
    Eq. 4.66); ``histograms`` maps a quantity name to counts of shape ``(len(histogram_times), n_bins)`` over
    ``histogram_edges[name]``; ``peak_histograms`` likewise counts, over ``peak_edges[name]``, each sample's
    largest magnitude of the quantity over every step from ``peak_start`` (s; ``t0`` where None) to each
    histogram time (the distribution of its peak, whence the probability of reaching a level by then:
    :meth:`peak_exceedance`); ``unconverged`` counts (sample, step) pairs whose contact Newton solve did not
    reach its tolerance; ``propagation`` says whether the samples were stepped in physical or eigen-coordinates
    (:mod:`pgtjax._eigenbasis`).
    """

    n_samples: int = eqx.field(static=True)
    mean_u: Float64[Array, "n_times n_dof"]
    std_u: Float64[Array, "n_times n_dof"]
    mean_v: Float64[Array, "n_times n_dof"]
    std_v: Float64[Array, "n_times n_dof"]
    mean_delta: Float64[Array, "n_times n_contacts"]
    std_delta: Float64[Array, "n_times n_contacts"]
    force_mean: Float64[Array, "n_times n_contacts"]
    force_std: Float64[Array, "n_times n_contacts"]
    histogram_times: Float64[Array, " n_hist"]
    histogram_edges: dict
    histograms: dict
    contact_loss_probability: Float64[Array, "n_times n_contacts"]
    unconverged: Float64[Array, ""]
    mean_obs: Float64[Array, "n_times n_obs"]
    std_obs: Float64[Array, "n_times n_obs"]
    observable_names: tuple[str, ...] = eqx.field(static=True, default=())
    propagation: str = eqx.field(static=True, default="physical")  # coordinates the samples were stepped in
    covariance: Float64[Array, "n_times n_cov n_cov"] | None = None  # 1/(N-1); see covariance_dofs
    covariance_dofs: tuple[str, ...] = eqx.field(static=True, default=())
    # empty in files written before peak histograms existed (2026-11-28)
    peak_edges: dict = eqx.field(default_factory=dict)
    peak_histograms: dict = eqx.field(default_factory=dict)
    peak_start: float | None = eqx.field(static=True, default=None)  # s; the peaks' start (None: t0 or none)

    def peak_exceedance(self, quantity: str) -> PeakExceedance:
        """:class:`PeakExceedance` of one of the ``peaks`` the run counted: P(peak >= each bin's upper edge)
        by each histogram time, the peak taken from ``peak_start``: ``1 - cumsum(counts) / n_samples``. A
        sample whose peak lies beyond the top edge counts as beyond every level (a peak equal to the top edge
        lies in the last bin, so at that level the probability is of ``>``). The edges must start at 0 or
        below, so that no peak (a magnitude) lies below the first edge, where it could not be told from one
        beyond the top."""
        if quantity not in self.peak_histograms:
            known = ", ".join(self.peak_histograms) or "none: pass `peaks` to monte_carlo"
            raise ValueError(f"no peaks of {quantity!r} were counted; counted: {known}")
        edges = np.asarray(self.peak_edges[quantity])
        if edges[0] > 0:
            raise ValueError(
                f"the peak edges of {quantity!r} start at {edges[0]:g} > 0: peaks below it were not counted and "
                "cannot be told from those beyond the top edge; count with edges from 0"
            )
        counts = np.asarray(self.peak_histograms[quantity])
        probability = (self.n_samples - np.cumsum(counts, axis=1)) / self.n_samples  # whole counts: exact
        error = np.sqrt(probability * (1.0 - probability) / self.n_samples)
        start = float(self.times[0]) if self.peak_start is None else self.peak_start
        return PeakExceedance(edges[1:], probability, error, np.asarray(self.histogram_times), start)

    def standard_error(self, what: str = "u"):
        """Standard errors (mean, std) of ``mean_<what>`` and ``std_<what>`` (``what`` = u, v, delta, obs)
        or, for ``what = "force"``, of ``force_mean`` and ``force_std`` (normal approximation)."""
        fields = {"u": "std_u", "v": "std_v", "delta": "std_delta", "obs": "std_obs", "force": "force_std"}
        if what not in fields:
            raise ValueError(f"`what` must be one of {', '.join(fields)}, got {what!r}")
        sd = getattr(self, fields[what])
        n = self.n_samples
        return sd / np.sqrt(n), sd / np.sqrt(2.0 * (n - 1))

    def time_average(
        self,
        what: str = "u",
        *,
        t_start: float | None = None,
        t_end: float | None = None,
        n_batches: int = 10,
    ) -> TimeAverage:
        """Time averages of ``mean_<what>`` and ``std_<what>`` (``what`` as in :meth:`standard_error`) over the
        saved times in ``[t_start, t_end]`` (s; default: the whole run) of a statistically stationary response,
        with batch-means standard errors: the window is cut into ``n_batches`` consecutive batches of saved
        times and the error is the standard deviation of the batch averages over sqrt(n_batches). The saved
        statistics are correlated in time (the same samples), which the batches account for when each batch
        is longer than the response's correlation time."""
        fields = {
            "u": ("mean_u", "std_u"),
            "v": ("mean_v", "std_v"),
            "delta": ("mean_delta", "std_delta"),
            "obs": ("mean_obs", "std_obs"),
            "force": ("force_mean", "force_std"),
        }
        if what not in fields:
            raise ValueError(f"`what` must be one of {', '.join(fields)}, got {what!r}")
        if isinstance(n_batches, bool) or not isinstance(n_batches, int | np.integer) or n_batches < 2:
            raise ValueError(f"`n_batches` must be an integer >= 2, got {n_batches!r}")
        times = np.asarray(self.times)
        lo = times[0] if t_start is None else float(t_start)
        hi = times[-1] if t_end is None else float(t_end)
        if not (np.isfinite(lo) and np.isfinite(hi) and times[0] <= lo <= hi <= times[-1]):
            raise ValueError(
                f"the window `t_start`..`t_end` must lie in the run, [{times[0]:g}, {times[-1]:g}] s; "
                f"got [{lo:g}, {hi:g}]"
            )
        window = np.flatnonzero((times >= lo) & (times <= hi))
        count = window.size
        if count < 2 * n_batches:
            raise ValueError(
                f"the window holds {count} saved times: at least 2 per batch ({2 * n_batches}) are "
                "needed; widen it, save more often (`save_every`), or lower `n_batches`"
            )
        window = window[: (count // n_batches) * n_batches]  # whole batches from the window's start, for both
        out = []
        for name in fields[what]:
            series = np.asarray(getattr(self, name))[window]
            batches = series.reshape(n_batches, -1, series.shape[1]).mean(axis=1)
            out += [series.mean(axis=0), batches.std(axis=0, ddof=1) / np.sqrt(n_batches)]
        return TimeAverage(out[0], out[1], out[2], out[3], window.size)


@typechecked
class Trajectory(_Labelled):
    """A deterministic response: displacement ``u``, velocity ``v`` (n_times, n_dof), contact deflection
    ``delta`` and force ``force`` (n_times, n_contacts)."""

    u: Float64[Array, "n_times n_dof"]
    v: Float64[Array, "n_times n_dof"]
    delta: Float64[Array, "n_times n_contacts"]
    force: Float64[Array, "n_times n_contacts"]
    unconverged: Float64[Array, ""] | Int[Array, ""]  # failed steps


def _to_numpy_dict(result) -> tuple[dict, dict]:
    arrays, meta = {}, {"class": type(result).__name__}
    for name in result.__dataclass_fields__:
        value = getattr(result, name)
        if isinstance(value, dict):
            for key, sub in value.items():
                arrays[f"{name}/{key}"] = np.asarray(sub)
            meta.setdefault("dicts", []).append(name)
        elif eqx.is_array(value):
            arrays[name] = np.asarray(value)
        else:
            meta[name] = list(value) if isinstance(value, tuple) else value
    return arrays, meta


def save_results(path, result, **attributes) -> Path:
    """Write a result (any class of this module) to ``path`` with its labels and units: ``.npz``, or a netCDF-4
    file for a ``.nc`` path (:func:`pgtjax.to_xarray`'s Dataset; needs ``pgtjax[netcdf]``); ``attributes``
    (JSON-serialisable: parameters, units of derived quantities...) are stored too."""
    path = _as_path(path)
    if path.suffix not in (".npz", ".nc"):  # numpy would append it; return the path that really exists
        path = path.with_name(path.name + ".npz")
    if not isinstance(result, tuple(_CLASSES.values())):
        raise ValueError(
            f"save_results writes a MomentResult, MonteCarloResult or Trajectory, got {type(result).__name__}"
        )
    if not path.parent.is_dir():
        raise ValueError(f"cannot write {str(path)!r}: the folder {str(path.parent)!r} does not exist")
    if path.is_dir():
        raise ValueError(f"cannot write {str(path)!r}: it is a folder")
    for name, value in attributes.items():
        try:
            json.dumps(value)
        except (TypeError, ValueError):
            raise ValueError(
                f"save_results attribute `{name}` must be JSON-serialisable (numbers, strings, lists, dicts; "
                f"convert arrays with .tolist()), got {type(value).__name__}"
            ) from None
    arrays, meta = _to_numpy_dict(result)
    meta["attributes"] = attributes
    # a temporary name in the same folder, renamed into place: a run killed while writing leaves the
    # previous file (or none), never a truncated one under the final name
    partial = path.with_name(f".{path.name}.partial-{os.getpid()}{path.suffix}")
    try:
        if path.suffix == ".nc":
            from ._netcdf import write_netcdf

            write_netcdf(partial, result, attributes)
        else:
            np.savez_compressed(partial, __meta__=np.array(json.dumps(meta)), **arrays)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
    return path


_CLASSES = {"MomentResult": MomentResult, "MonteCarloResult": MonteCarloResult, "Trajectory": Trajectory}


def load_results(path):
    """Inverse of :func:`save_results` (``.npz`` or ``.nc``): returns ``(result, attributes)``; ``ValueError``
    naming the file for anything that is not a readable pgtjax result."""
    require_x64("load_results")
    path = _as_path(path)
    if path.is_dir():
        raise ValueError(f"result file {str(path)!r} is a folder, not a file written by save_results")
    try:
        if path.suffix == ".nc":
            from ._netcdf import read_netcdf

            arrays, meta = read_netcdf(path)
        else:
            with np.load(path, allow_pickle=False) as data:
                meta = json.loads(str(data["__meta__"]))
                arrays = {k: data[k] for k in data.files if k != "__meta__"}
        cls = _CLASSES[meta.pop("class")]
    except FileNotFoundError:
        raise ValueError(f"result file {str(path)!r} does not exist") from None
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as err:
        raise ValueError(
            f"{str(path)!r} is not a readable pgtjax result file (.npz or .nc written by save_results): "
            f"{type(err).__name__}: {err}"
        ) from None
    attributes = meta.pop("attributes", {})
    dict_fields = meta.pop("dicts", [])
    kwargs = {}
    for name in dict_fields:
        prefix = name + "/"
        kwargs[name] = {k[len(prefix) :]: jnp.asarray(v) for k, v in arrays.items() if k.startswith(prefix)}
    for name, value in arrays.items():
        if "/" not in name:
            kwargs[name] = jnp.asarray(value)
    for name, value in meta.items():
        kwargs[name] = tuple(value) if isinstance(value, list) else value
    for name in dict_fields:
        kwargs.setdefault(name, {})
    _check_loaded_shapes(kwargs, path)
    try:
        result = cls(**kwargs)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{str(path)!r} is not a complete pgtjax result file: {err}") from None
    return result, attributes


def _as_path(path) -> Path:
    if not isinstance(path, str | os.PathLike):
        raise ValueError(f"`path` must be a file name (str or Path), got {path!r}")
    return Path(path)


def _check_loaded_shapes(fields: dict, path) -> None:
    """``ValueError`` naming the file if a loaded array does not fit the result's times and labels."""
    times = fields.get("times")
    if times is None or times.ndim != 1:
        raise ValueError(f"{str(path)!r} is not a complete pgtjax result file: no 1-D `times`")
    n_times = times.shape[0]
    columns = {name: len(fields.get(name, ())) for name in ("dof_names", "contact_names", "observable_names")}
    expected = {
        "mean_u": "dof_names", "std_u": "dof_names", "mean_v": "dof_names", "std_v": "dof_names",
        "u": "dof_names", "v": "dof_names", "cov_u_lag": "dof_names", "mean_delta": "contact_names",
        "std_delta": "contact_names", "force_mean": "contact_names", "force_std": "contact_names",
        "force": "contact_names", "k_e": "contact_names", "f_0": "contact_names", "cov_delta_lag": "contact_names",
        "mean_obs": "observable_names", "std_obs": "observable_names", "cov_obs_lag": "observable_names",
    }  # fmt: skip
    for name, labels in expected.items():
        value = fields.get(name)
        if value is not None and tuple(value.shape) != (n_times, columns[labels]):
            raise ValueError(
                f"{str(path)!r} is not a consistent pgtjax result file: `{name}` has shape {tuple(value.shape)}, "
                f"expected ({n_times}, {columns[labels]}) (saved times x {labels})"
            )
