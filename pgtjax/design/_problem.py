"""A design problem: variables over a model's parameters, how a design is simulated (:class:`Response`),
an objective on the SL result and weighted costs on the design."""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import AbstractCriterion, ForceCriterion, SolverError, monte_carlo, solve_moments, static_equilibrium
from .._checkpoint import load_checkpoint, process_checkpoint_file, save_checkpoint, tree_digest
from .._parallel import (
    device_mesh,
    fail_together,
    gather_processes,
    local_devices,
    raise_if_others_refused,
    warn_if_lapack_batches_can_hang,
)
from .._results import every_nth_save
from .._system import check_count, validate_time_grid
from ._objectives import AbstractCost, AbstractObjective, Names, _series, as_objective, check_costs
from ._variables import DesignSpace


class Response(eqx.Module):
    """How one design is simulated, re-solving its operating point inside the differentiated function:
    ``build(params) -> System``; the mean start at the static equilibrium of that system (``static_start``,
    else at rest at zero); the initial covariance ``initial_covariance(params, system)`` ((2n, 2n), default 0);
    optional ``observables(params) -> Observables``; the horizon ``n_steps`` steps of ``dt`` (s), saved
    every ``save_every`` steps; SL with ``criterion`` and the per-step tolerance ``rtol``; reverse mode keeps the
    state once per ``checkpoint_blocks`` saved blocks (``solve_moments``'s option: less memory for long runs of
    large models, for 0.6 to 1.5 forward runs more per gradient, measured); ``covariance_dofs``: DOF names (or
    ``"all"``) whose joint covariance SL keeps, for objectives that read it (e.g. a :class:`Custom` one with
    ``result.peak_exceedance``, Rice's estimate of a displacement's peak); ``deflection_lag``: SL also keeps
    each contact deflection's, displacement's and observable's covariance with the step before (needs
    ``save_every = 1``), for SL's peak probability of any of them, or of a contact force, counted between
    steps."""

    build: Callable = eqx.field(static=True)
    dt: float = eqx.field(static=True)
    n_steps: int = eqx.field(static=True)
    save_every: int = eqx.field(static=True, default=1)
    initial_covariance: Callable | None = eqx.field(static=True, default=None)
    observables: Callable | None = eqx.field(static=True, default=None)
    static_start: bool = eqx.field(static=True, default=True)
    criterion: AbstractCriterion = eqx.field(static=True, default=ForceCriterion())
    rtol: float = eqx.field(static=True, default=1e-10)
    checkpoint_blocks: int = eqx.field(static=True, default=1)
    covariance_dofs: tuple[str, ...] | str | None = eqx.field(
        static=True, default=None, converter=lambda d: d if d is None or isinstance(d, str) else tuple(d)
    )
    deflection_lag: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        if not callable(self.build):
            raise ValueError(f"Response `build` must be a function params -> System, got {self.build!r}")
        n_steps, save_every = validate_time_grid(self.dt, self.n_steps, self.save_every)
        if not isinstance(self.deflection_lag, bool):
            raise ValueError(f"Response `deflection_lag` must be True or False, got {self.deflection_lag!r}")
        if self.deflection_lag and save_every != 1:
            raise ValueError(f"Response `deflection_lag` needs save_every = 1, got {save_every}")
        check_count(
            "Response.checkpoint_blocks", self.checkpoint_blocks, 1, n_steps // save_every, " (saved blocks)"
        )

    def _start(self, params):
        system = self.build(params)
        u0 = static_equilibrium(system) if self.static_start else None
        p0 = None if self.initial_covariance is None else self.initial_covariance(params, system)
        obs = None if self.observables is None else self.observables(params)
        return system, u0, p0, obs

    def moments(self, params, *, save_every: int | None = None, throw: bool = True):
        """``(system, MomentResult)`` of the design ``params``."""
        system, u0, p0, obs = self._start(params)
        every = save_every or self.save_every
        result = solve_moments(
            system,
            dt=self.dt,
            n_steps=self.n_steps,
            save_every=every,
            initial_displacement=u0,
            initial_covariance=p0,
            observables=obs,
            criterion=self.criterion,
            rtol=self.rtol,
            throw=throw,
            # a run saved at another interval reports (not differentiated): its blocks are kept one by one
            checkpoint_blocks=self.checkpoint_blocks if every == self.save_every else 1,
            covariance_dofs=self.covariance_dofs,
            # a report at another interval (not differentiated) goes without: it pairs consecutive steps
            deflection_lag=self.deflection_lag and every == 1,
        )
        return system, result

    def monte_carlo(self, params, *, n_samples: int, key, save_every: int, chunk_size: int | None = None):
        """``(system, MonteCarloResult)`` of the nonlinear system at the design ``params``."""
        system, u0, p0, obs = self._start(params)
        result = monte_carlo(
            system,
            n_samples=n_samples,
            key=key,
            dt=self.dt,
            n_steps=self.n_steps,
            save_every=save_every,
            initial_displacement=u0,
            initial_covariance=p0,
            observables=obs,
            chunk_size=chunk_size,
            progress=False,
        )
        return system, result

    def names(self, params) -> Names:
        system = self.build(params)
        obs = None if self.observables is None else self.observables(params)
        units = dict(zip(system.dof_names, system.dof_units))
        units.update({c: "N" for c in system.contact_names()})
        if obs is not None:
            units.update(zip(obs.names, obs.units))
        return Names(
            dofs=tuple(system.dof_names),
            contacts=tuple(system.contact_names()),
            observables=() if obs is None else tuple(obs.names),
            units=tuple(units.items()),
        )


class Terms(eqx.Module):
    """The parts of a design's objective: ``response`` (the objective on the SL result, its own units),
    ``costs`` (n_costs,) in their units, and ``value`` = response / scale_0 + sum_i w_i cost_i / scale_i."""

    value: jax.Array
    response: jax.Array
    costs: jax.Array
    converged: jax.Array


class DesignProblem(eqx.Module):
    """Minimize ``J(z) = R(z) / R_ref + sum_i w_i C_i(z) / C_i,ref`` over the coordinates ``z`` of ``space``:
    ``R`` the ``objective`` of the SL result of ``response`` at the design, ``C_i`` the ``costs`` with their
    weights. The references are the values at the initial design when ``normalize`` (so ``J = 1 + sum w_i``
    there and a weight reads as "a relative cost is worth w relative response"), else 1.

    Built eagerly: the variables, the objective's quantity names and the costs are checked, and the initial
    design is simulated once (``SolverError`` if it fails), before anything is differentiated."""

    space: DesignSpace
    response: Response
    objective: AbstractObjective
    costs: tuple[AbstractCost, ...]
    weights: jax.Array
    scales: jax.Array
    names: Names

    def __init__(
        self,
        space: DesignSpace,
        response: Response,
        objective,
        costs: Sequence[AbstractCost] = (),
        *,
        normalize: bool = True,
        scales=None,
    ):
        if not isinstance(space, DesignSpace):
            raise ValueError(f"`space` must be a pgtjax.design.DesignSpace, got {type(space).__name__}")
        if not isinstance(response, Response):
            raise ValueError(f"`response` must be a pgtjax.design.Response, got {type(response).__name__}")
        self.space, self.response = space, response
        self.objective = as_objective(objective)
        self.costs = check_costs(costs)
        self.names = response.names(space.base)
        self.objective.check(self.names)
        start = getattr(getattr(self.objective, "over", None), "start", 0.0)
        t_end = response.dt * response.n_steps
        if not 0.0 <= start < t_end:
            raise ValueError(
                f"the objective's `start` ({start!r} s) must lie in [0, {t_end:g}) s, the horizon"
            )
        self.weights = jnp.asarray([c.weight for c in self.costs], jnp.float64).reshape(-1)
        if scales is not None:
            self.scales = jnp.asarray(scales, jnp.float64)
            if not bool(jnp.all(jnp.isfinite(self.scales) & (self.scales > 0))):
                raise ValueError(f"`scales` must be finite and > 0, got {np.asarray(self.scales).tolist()}")
        elif normalize:
            params = space.params(space.initial())
            system, result = response.moments(params)  # throws SolverError with when and where
            raw = [self.objective(result, system, self.names)] + [c(params) for c in self.costs]
            raw = np.asarray(raw, dtype=np.float64)
            if not np.all(np.isfinite(raw)) or np.any(raw <= 0.0):
                raise ValueError(
                    f"cannot normalize by the initial design: objective and costs there are {raw.tolist()} "
                    "(need finite positive values; pass normalize=False)"
                )
            self.scales = jnp.asarray(raw)
        else:
            self.scales = jnp.ones(1 + len(self.costs))
        if self.scales.shape != (1 + len(self.costs),):
            raise ValueError(f"`scales` must have {1 + len(self.costs)} entries, got {self.scales.shape}")

    def with_weights(self, weights) -> DesignProblem:
        """The same problem with other cost weights (same shapes: no recompilation)."""
        w = jnp.asarray(weights, jnp.float64).reshape(self.weights.shape)
        if not bool(jnp.all(jnp.isfinite(w) & (w >= 0.0))):
            raise ValueError(f"cost weights must be finite and >= 0, got {np.asarray(w).tolist()}")
        return eqx.tree_at(lambda p: p.weights, self, w)

    def terms(self, z) -> Terms:
        """Objective parts at coordinates ``z`` (differentiable; a step whose SL fixed point did not
        converge makes ``value`` NaN, so that a line search backs off)."""
        params = self.space.params(z)
        system, result = self.response.moments(params, throw=False)
        response = self.objective(result, system, self.names)
        costs = jnp.stack([c(params) for c in self.costs]) if self.costs else jnp.zeros((0,))
        value = response / self.scales[0] + jnp.sum(self.weights * costs / self.scales[1:])
        converged = jnp.all(result.converged)
        return Terms(
            value=jnp.where(converged, value, jnp.nan), response=response, costs=costs, converged=converged
        )

    def value(self, z) -> jax.Array:
        return self.terms(z).value

    def describe(self) -> dict:
        return dict(
            variables=self.space.describe(),
            objective=self.objective.describe(self.names),
            costs=[dict(c.describe(), weight=float(w)) for c, w in zip(self.costs, np.asarray(self.weights))],
            scales=np.asarray(self.scales).tolist(),
            base=_digest(self.space.base),
            horizon=dict(
                dt_s=self.response.dt,
                n_steps=self.response.n_steps,
                t_end_s=self.response.dt * self.response.n_steps,
            ),
        )


def _digest(tree) -> str:
    """A fingerprint of a parameter pytree's values and structure, to recognise the same model on resume."""
    h = hashlib.sha256(str(jax.tree.structure(tree)).encode())
    for leaf in jax.tree.leaves(tree):
        h.update(np.ascontiguousarray(np.asarray(leaf, dtype=np.float64)).tobytes())
    return h.hexdigest()[:16]


_DESIGN_AXIS = "designs"


@eqx.filter_jit
def _batch_terms(problem: DesignProblem, zs, batch_size, *, mesh):
    """``problem.terms`` of ``zs`` (n_devices, per_device, n_z): each device of ``mesh`` runs its own row in a
    ``lax.map`` loop, with no communication."""
    arrays, rest = eqx.partition(problem, eqx.is_array)

    def local(arrays, z):
        terms = jax.lax.map(eqx.combine(arrays, rest).terms, z[0], batch_size=batch_size)
        return jax.tree.map(lambda a: a[None], terms)

    spec = jax.sharding.PartitionSpec(_DESIGN_AXIS)
    sharded = jax.shard_map(
        local, mesh=mesh, in_specs=(jax.sharding.PartitionSpec(), spec), out_specs=spec, check_vma=False
    )
    return sharded(arrays, zs)


def evaluate(
    problem: DesignProblem,
    designs,
    *,
    batch_size: int | None = None,
    devices=None,
    group_size: int | None = None,
    checkpoint=None,
    resume: bool = False,
    distributed: bool = True,
) -> Terms:
    """Objective parts of many designs (sweeps, Pareto fronts, design batches): ``designs`` is (n_designs, n_z)
    coordinates. Returns :class:`Terms` with a leading design axis.

    The designs are split over ``devices`` (default all of ``jax.local_devices()``); on each device they run
    one after the other in one compiled loop, or ``vmap``-ed ``batch_size`` at a time (on the 2-core CPU a
    ``vmap`` of 14 planetary designs deadlocked inside XLA's CPU runtime in two of seven runs, so batching is
    opt-in: jaxlib 0.10.0-0.11.0 wait on their own thread pool in batched LAPACK calls, and warn here;
    docs/performance.md). ``group_size``: designs per device per compiled call (default: all at once, or 1 with a
    checkpoint). ``distributed`` (default True; matters only after ``jax.distributed.initialize``): split
    the designs over all processes in contiguous shares and return every design's terms in every process;
    ``False``: this process evaluates all of them. ``checkpoint``: a ``.npz`` rewritten atomically after
    every group with the terms so far (``<stem>.process-<p>-of-<n>.npz`` in each process of a distributed
    run); ``resume=True`` continues from it (same problem, designs, split and ``batch_size`` required)."""
    n_proc, proc = (jax.process_count(), jax.process_index()) if distributed else (1, 0)
    # In a distributed job every check below (the checkpoint's too) is made in every process before the processes
    # compare notes once, so that one refusing process stops all instead of leaving the others in a collective.
    zs, digest, n_all, refusal, saved = None, _NO_DIGEST, -1, None, None
    problem_digest = tree_digest(problem)
    try:
        zs = np.asarray(designs, dtype=np.float64)
        if zs.ndim != 2 or zs.shape[1] != problem.space.n or zs.shape[0] < 1:
            raise ValueError(f"`designs` must have shape (n_designs >= 1, {problem.space.n}), got {zs.shape}")
        if not np.all(np.isfinite(zs)):
            raise ValueError("`designs` must be finite")
        digest, n_all = tree_digest(zs), zs.shape[0]
        if batch_size is not None:
            batch_size = check_count("batch_size", batch_size)
            if batch_size > 1:
                warn_if_lapack_batches_can_hang(f"designs vmap-ed {batch_size} at a time", stacklevel=3)
        devices = local_devices(devices)
        path = process_checkpoint_file(checkpoint, resume, n_proc, proc)
        n = -(-n_all // n_proc)  # designs per process; the last shares are padded with the last design
        n_dev = len(devices)
        if group_size is not None:
            per_device = min(check_count("group_size", group_size), -(-n // n_dev))
        else:
            per_device = 1 if path is not None else -(-n // n_dev)
        description = dict(
            problem=problem_digest,
            designs=digest,
            n_designs=n_all,
            devices=n_dev,
            designs_per_device=per_device,
            batch_size=batch_size,  # vmap-ed or one by one: equal to rounding, not digit for digit
            processes=n_proc,
            process=proc,
        )
        if resume:  # this process's checkpoint, which may be missing in one process only (a node-local file)
            saved = load_checkpoint(path, description, what="evaluate")
    except ValueError as err:
        refusal = err
    if n_proc > 1:  # each process takes its share by position: all must hold the same problem and designs
        _check_processes_agree(refusal, problem_digest, digest, n_all)
    if refusal is not None:
        raise refusal
    zs = np.concatenate([zs, np.repeat(zs[-1:], n_proc * n - n_all, axis=0)])[proc * n : (proc + 1) * n]
    group = n_dev * per_device
    n_groups = -(-n // group)
    padded = np.concatenate([zs, np.repeat(zs[-1:], n_groups * group - n, axis=0)])  # repeats are dropped
    fields = Terms.__dataclass_fields__
    done: dict[str, list] = {f: [] for f in fields}
    first = 0
    if saved is not None:
        first = int(saved.pop("next_group"))
        done = {f: [saved[f]] for f in fields}
    mesh = device_mesh(devices, _DESIGN_AXIS)
    with fail_together("evaluate", n_proc > 1, stage="during the run"):  # one failing stops all, at the end
        for g in range(first, n_groups):
            block = padded[g * group : (g + 1) * group].reshape(n_dev, per_device, -1)
            terms = _batch_terms(problem, jnp.asarray(block), batch_size, mesh=mesh)
            for f in fields:
                value = np.asarray(getattr(terms, f))
                done[f].append(value.reshape((group,) + value.shape[2:]))
            if path is not None:
                so_far = {f: np.concatenate(done[f]) for f in fields}
                save_checkpoint(
                    path, dict(so_far, next_group=np.asarray(g + 1)), description, what="evaluate"
                )
    mine = {f: np.concatenate(done[f])[:n] for f in fields}
    if n_proc > 1:  # every process's share, in process order, in every process
        mine = {f: gather_processes(v).reshape((n_proc * n,) + v.shape[1:]) for f, v in mine.items()}
    return Terms(**{f: jnp.asarray(v[:n_all]) for f, v in mine.items()})


_NO_DIGEST = "00" * 12  # tree_digest's length: a process whose designs were refused compares as this


def _check_processes_agree(refusal, problem_digest: str, designs_digest: str, n_designs: int) -> None:
    """One exchange between the processes of a distributed run: ``ValueError`` in every process where any
    refused its options or where they hold different problems or designs."""
    record = np.concatenate(
        [
            np.array([refusal is not None], dtype=np.uint8),
            np.frombuffer(bytes.fromhex(problem_digest), dtype=np.uint8),
            np.frombuffer(bytes.fromhex(designs_digest), dtype=np.uint8),
            np.frombuffer(np.int64(n_designs).tobytes(), dtype=np.uint8),
        ]
    )
    records = gather_processes(record)
    if refusal is not None:
        raise refusal
    raise_if_others_refused(records[:, 0], "evaluate")
    if np.any(records[:, 1:13] != records[0, 1:13]):
        raise ValueError(
            "evaluate: the processes of a distributed run must be given the same `problem` (parameters, "
            "response, objective and costs); build it alike everywhere, or pass `distributed=False`"
        )
    if np.any(records[:, 13:] != records[0, 13:]):
        counts = [int(np.frombuffer(r[-8:].tobytes(), dtype=np.int64)[0]) for r in records]
        listed = "; ".join(f"process {p}: {c} designs" for p, c in enumerate(counts))
        raise ValueError(
            f"evaluate: the processes of a distributed run must be given the same `designs` ({listed}; "
            "equal counts mean different values); pass the same array everywhere, or `distributed=False`"
        )


def check_samples(n_samples, batches) -> tuple[int, int]:
    n_samples, batches = check_count("n_samples", n_samples, 4), check_count("batches", batches, 2)
    if n_samples % batches or n_samples // batches < 2:
        raise ValueError(
            f"`n_samples` ({n_samples}) must be a multiple of `batches` ({batches}) with >= 2 samples per batch"
        )
    return n_samples, batches


def _moments_saved_every(response: Response, params, save_every: int):
    """SL of ``response`` saved every ``save_every`` steps: from the response's own run (the program that the
    problem's normalization compiled already) where its save interval divides ``save_every``, else a run of its
    own."""
    if save_every % response.save_every:
        return response.moments(params, save_every=save_every)
    system, result = response.moments(params)
    return system, every_nth_save(result, save_every // response.save_every)


def monte_carlo_check(
    problem: DesignProblem,
    designs: dict,
    *,
    n_samples: int = 2000,
    batches: int = 10,
    key=None,
    save_every: int = 10,
    series: Sequence[str] = (),
) -> dict:
    """Monte Carlo of the nonlinear system at each design (name -> coordinates ``z``) with the same keys
    (common random numbers), in ``batches`` independent batches: the objective's MC estimate with its
    standard error (batch means), the SL value on the same time grid, and for each design after the first
    the improvement over the first in standard errors of the paired batch differences. ``series``: names of
    quantities whose standard deviation over time is returned too (``"series"``: per quantity and design,
    the times, SL, and the MC batch mean with its standard error)."""
    n_samples, batches = check_samples(n_samples, batches)
    save_every = check_count("save_every", save_every)
    if problem.response.n_steps % save_every:
        raise ValueError(
            f"`save_every` ({save_every}) must divide the horizon's {problem.response.n_steps} steps"
        )
    for q in series:
        problem.names.kind(q)  # ValueError naming an unknown quantity, before any simulation
    key = jax.random.key(0) if key is None else key
    keys = jax.random.split(key, batches)
    per_batch, sl, curves = {}, {}, {q: {} for q in series}
    for name, z in designs.items():
        params = problem.space.params(jnp.asarray(z, jnp.float64))
        values, batch_curves = [], []
        for b in range(batches):
            system, result = problem.response.monte_carlo(
                params, n_samples=n_samples // batches, key=keys[b], save_every=save_every
            )
            if float(result.unconverged) > 0:
                raise SolverError(
                    f"Monte Carlo of design {name!r}: {int(result.unconverged)} contact solves did not converge"
                )
            values.append(float(problem.objective(result, system, problem.names)))
            batch_curves.append([np.asarray(_series(result, problem.names, q, "std")) for q in series])
        per_batch[name] = np.asarray(values)
        system, result = _moments_saved_every(problem.response, params, save_every)
        sl[name] = float(problem.objective(result, system, problem.names))
        stacked = np.asarray(batch_curves)  # (batches, quantity, time)
        for i, q in enumerate(series):
            curves[q][name] = dict(
                times=np.asarray(result.times),
                sl=np.asarray(_series(result, problem.names, q, "std")),
                mc=stacked[:, i].mean(axis=0),
                mc_se=stacked[:, i].std(axis=0, ddof=1) / np.sqrt(batches),
            )
    first = next(iter(designs))
    out = {}
    for name, values in per_batch.items():
        entry = dict(sl=sl[name], mc=float(values.mean()), mc_se=float(values.std(ddof=1) / np.sqrt(batches)))
        if name != first:
            diff = per_batch[first] - values
            se = float(diff.std(ddof=1) / np.sqrt(batches))
            entry.update(
                improvement=float(diff.mean()),
                improvement_se=se,
                improvement_in_se=float(diff.mean() / se) if se > 0 else float("nan"),
                relative_improvement=float(diff.mean() / per_batch[first].mean()),
            )
        out[name] = entry
    return dict(
        designs=out,
        note=(
            "sl: the objective by SL on the Monte Carlo's saved times (every save_every steps), the grid its mc "
            "estimate uses; the optimization's value, on every step, differs from it slightly"
        ),
        n_samples=n_samples,
        batches=batches,
        save_every=save_every,
        objective=problem.objective.describe(problem.names),
        series=curves,
    )
