"""The optimization loop: any optax transformation, a jitted update (update, projection, the line
search's value and gradient), stopping rules, a history written after every iteration and resumable from it."""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import optax.tree_utils as otu

from .. import SolverError
from .._files import write_atomic, write_json
from .._progress import progress_bar
from .._system import check_count
from ._problem import DesignProblem

HISTORY_FORMAT = "pgtjax-design-history/1"


_DEFAULT = []


def default_optimizer() -> optax.GradientTransformationExtraArgs:
    """L-BFGS with optax's zoom line search (strong Wolfe): the usual choice for a smooth deterministic
    objective of a few dozen variables. The same object on every call: its functions are part of the
    compiled update's cache key, so a second run (a resume, a weight sweep) reuses the compiled update."""
    if not _DEFAULT:
        _DEFAULT.append(optax.lbfgs())
    return _DEFAULT[0]


def _strongly_typed(state):
    """The optimizer state with weakly typed scalars made strong: optax's line search starts with weak
    scalars that its first update returns strong, which would compile the update a second time."""
    return jax.tree.map(
        lambda x: jnp.array(x, dtype=jnp.asarray(x).dtype) if eqx.is_array_like(x) else x, state
    )


@dataclass
class OptimizeResult:
    """``z``: optimal coordinates; ``params``: the design's parameters; ``history``: one dict per iteration
    (``iteration``, ``objective``, ``response``, ``costs``, ``gradient_norm``, ``variables``, ``z``,
    ``wall_s``), iteration 0 the start; ``converged`` and ``reason`` say why it stopped."""

    z: np.ndarray
    params: object
    history: list[dict]
    converged: bool
    reason: str
    problem: dict = field(default_factory=dict)

    @property
    def value(self) -> float:
        return self.history[-1]["objective"]

    @property
    def initial_z(self) -> np.ndarray:
        return np.asarray(self.history[0]["z"])


def _projected_gradient(problem: DesignProblem, z, grad):
    return z - problem.space.project(z - grad)


@eqx.filter_jit
def _evaluate(problem: DesignProblem, z):
    """Value, gradient and record at ``z``: at the start, and after an update whose point needs a new
    evaluation. Compiled once, apart from the update, so that the update holds only the line search's copy
    of the gradient program (compilation dominates a short optimization)."""
    value, grad = jax.value_and_grad(problem.value)(z)
    return value, grad, _record(problem, z, value, grad)


def _record(problem: DesignProblem, z, value, grad):
    """What the history keeps of an iterate: costs, the response (recovered from the value and the costs,
    without another simulation) and the projected gradient's norm."""
    params = problem.space.params(z)
    costs = jnp.stack([c(params) for c in problem.costs]) if problem.costs else jnp.zeros((0,))
    response = problem.scales[0] * (value - jnp.sum(problem.weights * costs / problem.scales[1:]))
    return dict(
        response=response,
        costs=costs,
        gradient_norm=jnp.linalg.norm(_projected_gradient(problem, z, grad)),
        variables=problem.space.physical(z),
    )


@eqx.filter_jit
def _update(problem: DesignProblem, optimizer, z, state, value, grad):
    """The optimizer's update, applied and projected on the bounds. Returns the new point, the state and,
    where the line search already evaluated that point, its value, gradient and record (else None)."""
    updates, state = optimizer.update(grad, state, z, value=value, grad=grad, value_fn=problem.value)
    trial = optax.apply_updates(z, updates)
    z_new = problem.space.project(trial)
    cached_value = otu.tree_get(state, "value", None)
    cached_grad = otu.tree_get(state, "grad", None)
    if cached_value is None or cached_grad is None:  # no line search: the new point needs an evaluation
        return z_new, state, None
    # the line search evaluated the trial point: valid unless the projection moved it
    moved = jnp.any(z_new != trial)
    return (
        z_new,
        state,
        (moved, cached_value, cached_grad, _record(problem, z_new, cached_value, cached_grad)),
    )


def _step(problem: DesignProblem, optimizer, z, state, value, grad):
    """One iteration: the update, then a separate evaluation only where the new point has none."""
    z, state, cached = _update(problem, optimizer, z, state, value, grad)
    if cached is None:
        value, grad, record = _evaluate(problem, z)
        return z, state, value, grad, record
    moved, value, grad, record = cached
    if bool(moved):
        value, grad, record = _evaluate(problem, z)
        state = otu.tree_set(state, value=value, grad=grad)
    return z, state, value, grad, record


def _entry(iteration, z, value, record, labels, started):
    return dict(
        iteration=iteration,
        objective=float(value),
        response=float(record["response"]),
        costs=np.asarray(record["costs"]).tolist(),
        gradient_norm=float(record["gradient_norm"]),
        variables={
            k: float(v) for k, v in zip(labels, np.concatenate([np.ravel(x) for x in record["variables"]]))
        },
        z=np.asarray(z).tolist(),
        wall_s=time.perf_counter() - started,
    )


def _state_path(history: Path) -> Path:
    return history.with_name(history.name + ".state.npz")


def _save(history: Path, problem_info, optimizer_name, entries, status, z, state, value, grad):
    leaves = jax.tree.leaves(state)
    arrays = {f"leaf{i}": np.asarray(x) for i, x in enumerate(leaves)}
    # the iterate's number and z tie this state to the history's last entry (the two files are written one
    # after the other; an interruption between them is detected on resume)
    arrays.update(
        z=np.asarray(z),
        value=np.asarray(value),
        grad=np.asarray(grad),
        iteration=np.asarray(entries[-1]["iteration"]),
    )
    write_atomic(_state_path(history), lambda p: np.savez(p, **arrays))
    write_json(
        history,
        dict(
            format=HISTORY_FORMAT,
            problem=problem_info,
            optimizer=optimizer_name,
            status=status,
            iterations=entries,
        ),
    )


def _comparable(info: dict) -> dict:
    return {k: info.get(k) for k in ("variables", "objective", "costs", "horizon", "scales", "base")}


def _difference(name: str, saved, this) -> str:
    """One entry of a refused resume: the name, with both values when they are short enough to read."""
    both = f"{name}: history {saved!r}, this run {this!r}"
    return both if len(both) <= 200 else name


def _load(history: Path, problem_info, state_template):
    try:
        data = json.loads(history.read_text())
        saved = np.load(_state_path(history))
    except (OSError, ValueError) as err:
        raise ValueError(f"cannot resume from `history` {str(history)!r}: {err}") from None
    if data.get("format") != HISTORY_FORMAT:
        raise ValueError(f"`history` {str(history)!r} is not a pgtjax design history")
    saved_problem, this_problem = (
        _comparable(data["problem"]),
        _comparable(json.loads(json.dumps(problem_info))),
    )
    differ = [k for k in saved_problem if saved_problem[k] != this_problem[k]]
    if differ:
        detail = "; ".join(_difference(k, saved_problem[k], this_problem[k]) for k in differ)
        raise ValueError(
            f"cannot resume from `history` {str(history)!r}: it was written for another problem ({detail}); "
            "start again without resume"
        )
    leaves, treedef = jax.tree.flatten(state_template)
    try:
        restored = [jnp.asarray(saved[f"leaf{i}"], dtype=jnp.asarray(x).dtype) for i, x in enumerate(leaves)]
    except KeyError:
        raise ValueError(
            f"cannot resume: {str(_state_path(history))!r} holds another optimizer's state"
        ) from None
    if any(r.shape != jnp.shape(x) for r, x in zip(restored, leaves)):
        raise ValueError(f"cannot resume: {str(_state_path(history))!r} holds another optimizer's state")
    state = jax.tree.unflatten(treedef, restored)
    entries = data["iterations"]
    if (
        not entries
        or "iteration" not in saved
        or int(saved["iteration"]) != entries[-1]["iteration"]
        or not np.array_equal(np.asarray(saved["z"]), np.asarray(entries[-1]["z"]))
    ):
        raise ValueError(
            f"cannot resume: {str(_state_path(history))!r} and {str(history)!r} do not hold the same iterate "
            "(a run interrupted between their writes); start again without resume"
        )
    return entries, jnp.asarray(saved["z"]), state, jnp.asarray(saved["value"]), jnp.asarray(saved["grad"])


def optimize(
    problem: DesignProblem,
    *,
    optimizer: optax.GradientTransformation | None = None,
    z0=None,
    max_iter: int = 50,
    rtol: float = 1e-6,
    gtol: float = 1e-6,
    history=None,
    resume: bool = False,
    progress: bool = True,
) -> OptimizeResult:
    """Minimize ``problem`` from ``z0`` (default: the base design) with ``optimizer`` (any optax
    transformation; default :func:`default_optimizer`). Each iteration is one jitted update (apply,
    projection on the bounds), with the value and gradient at the new point taken from the line search or,
    where it has none or the projection moved its point, from one further jitted evaluation.

    Stops when the relative change of the objective falls below ``rtol``, when the projected gradient's norm
    (in the coordinates ``z``) falls below ``gtol``, or after ``max_iter`` iterations (then ``converged`` is
    False). ``history``: a JSON file rewritten atomically after every iteration, with the optimizer's state
    beside it (``<history>.state.npz``); ``resume=True`` continues from it (same problem required), so an
    interrupted run loses at most one iteration. ``SolverError`` if an accepted iterate's value is not
    finite (its SL fixed point failed), naming the iteration."""
    if not isinstance(problem, DesignProblem):
        raise ValueError(f"`problem` must be a pgtjax.design.DesignProblem, got {type(problem).__name__}")
    max_iter = check_count("max_iter", max_iter)
    for label, tol in (("rtol", rtol), ("gtol", gtol)):
        if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not tol >= 0.0:
            raise ValueError(f"`{label}` must be a number >= 0, got {tol!r}")
    optimizer = default_optimizer() if optimizer is None else optimizer
    if not isinstance(optimizer, optax.GradientTransformation):
        raise ValueError(
            f"`optimizer` must be an optax GradientTransformation, got {type(optimizer).__name__}"
        )
    optimizer = optax.with_extra_args_support(optimizer)
    optimizer_name = type(optimizer).__name__
    history = None if history is None else Path(history)
    info = problem.describe()
    labels = problem.space.labels()
    started = time.perf_counter()

    z = problem.space.initial() if z0 is None else jnp.asarray(z0, jnp.float64)
    if z.shape != (problem.space.n,) or not bool(jnp.all(jnp.isfinite(z))):
        raise ValueError(f"`z0` must be finite with shape ({problem.space.n},), got shape {z.shape}")
    if resume and z0 is not None:
        raise ValueError("`z0` and `resume` exclude each other: a resumed run continues from its history")
    z = problem.space.project(z)
    state = _strongly_typed(optimizer.init(z))
    if resume:
        if history is None or not history.exists():
            raise ValueError(f"`resume` needs an existing `history` file, got {history!r}")
        entries, z, state, value, grad = _load(history, info, state)
        offset = entries[-1]["wall_s"] if entries else 0.0
        started -= offset
    else:
        value, grad, record = _evaluate(problem, z)
        entries = [_entry(0, z, value, record, labels, started)]
        if not math.isfinite(entries[0]["objective"]):
            raise SolverError("design optimization: the objective at the initial design is not finite")
    status = dict(converged=False, reason="running")
    if history is not None:
        _save(history, info, optimizer_name, entries, status, z, state, value, grad)

    bar = (
        progress_bar(max_iter, "optimize", "iterations", initial=entries[-1]["iteration"])
        if progress
        else None
    )
    try:
        while True:
            k = entries[-1]["iteration"]
            if entries[-1]["gradient_norm"] <= gtol:
                status = dict(converged=True, reason=f"projected gradient norm below gtol = {gtol:g}")
                break
            if k >= 1:
                previous, current = entries[-2]["objective"], entries[-1]["objective"]
                if abs(previous - current) <= rtol * max(abs(current), 1e-300):
                    status = dict(converged=True, reason=f"relative objective change below rtol = {rtol:g}")
                    break
            if k >= max_iter:
                status = dict(converged=False, reason=f"max_iter = {max_iter} iterations reached")
                break
            z, state, value, grad, record = _step(problem, optimizer, z, state, value, grad)
            entry = _entry(k + 1, z, value, record, labels, started)
            if not math.isfinite(entry["objective"]):
                raise SolverError(
                    f"design optimization, iteration {k + 1}: the objective is not finite at the accepted design "
                    f"{entry['variables']} (its SL fixed point failed); tighten the bounds or the step"
                )
            entries.append(entry)
            if bar is not None:
                bar.set_postfix(J=f"{entry['objective']:.6g}", grad=f"{entry['gradient_norm']:.2e}")
                bar.update(1)  # after the postfix: a log line shows this iteration's
            if history is not None:
                _save(history, info, optimizer_name, entries, status, z, state, value, grad)
    finally:
        if bar is not None:
            bar.close()
    if history is not None:
        _save(history, info, optimizer_name, entries, status, z, state, value, grad)
    return OptimizeResult(
        z=np.asarray(z),
        params=problem.space.params(z),
        history=entries,
        converged=status["converged"],
        reason=status["reason"],
        problem=info,
    )


def pareto_front(
    problem: DesignProblem, weights, *, z0=None, optimizer=None, say=None, **optimize_options
) -> list[dict]:
    """Optima of ``problem`` for each cost weight in ``weights`` (one cost: a list of numbers; several: a list
    of weight vectors), each started from ``z0`` (default: the base design; an optimum found already is a
    good start). Returns one dict per weight, sorted as given: ``weight``, ``response`` and ``costs`` (in
    their units, as the optimum's last history entry records them), ``converged``, ``iterations``,
    ``reason``, ``z``. ``optimize_options`` go to :func:`optimize`."""
    optimizer = default_optimizer() if optimizer is None else optimizer
    runs = []
    for w in weights:
        r = optimize(
            problem.with_weights(np.atleast_1d(w)),
            optimizer=optimizer,
            z0=z0,
            progress=False,
            **optimize_options,
        )
        runs.append((w, r))
        if say is not None:
            say(f"front: cost weight {w}: {r.history[-1]['iteration']} iterations, {r.reason}")
    # the last entry holds the optimum's response and costs: evaluating them again compiled a program of its own
    return [
        dict(
            weight=w,
            response=r.history[-1]["response"],
            costs=list(r.history[-1]["costs"]),
            converged=r.converged,
            iterations=r.history[-1]["iteration"],
            reason=r.reason,
            z=np.asarray(r.z).tolist(),
        )
        for w, r in runs
    ]
