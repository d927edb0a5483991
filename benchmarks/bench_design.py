"""Benchmark of the design optimization (pgtjax.design) on the project's study: the ring-mesh deformation's
standard deviation (time mean over the three ring-planet meshes) plus 0.2 x the total support stiffness,
over the radial and tangential stiffness of the six bolts (12 log-mapped variables), each design simulated
from its own static equilibrium over ``--periods`` carrier periods (1.0 = 10,022 SL steps of 2.7 ms).

1. One value-and-gradient against one forward value of the objective, calls alternating (forward, gradient,
   forward, ...), medians over ``--repeats`` runs; the first (compiling) calls reported apart.
2. The full L-BFGS optimization (``pd.optimize``, the default optimizer) from the symmetric design. A warm-up
   run of two iterations compiles its jitted functions; the timed run then reuses them (the same
   optimizer object is passed to both, so that the compiled update is found again; results/design.json was
   measured before pgtjax made the line search's initial state strongly typed, when the update compiled
   twice per run). Evaluations are counted exactly:
   the problem's ``value`` is wrapped to report every forward pass and every reverse pass to the host
   (``jax.debug.callback``), which also records the time and value of each evaluation.
3. Gradient-free baselines on the same objective, coordinates and bounds, using the forward function
   compiled in 1: CMA-ES (``cma``) and scipy's Nelder-Mead, each until its best value comes within ``--tol``
   (relative) of the L-BFGS optimum, or ``--max-evals`` evaluations.

Usage: python3 benchmarks/bench_design.py [--periods 1.0] [--repeats 5] [--max-evals 300] [--out PATH]
Writes benchmarks/results/design.json (atomically).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import tempfile
import time
from pathlib import Path

import cma
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy
import scipy.optimize as so
from _common import RESULTS, machine, timed_interleaved

from pgtjax import design as pd
from pgtjax.models import planetary as pm

TARGET_GRADIENT_RATIO = 4.0
TARGET_ITERATIONS = 50
TARGET_WALL_S = 600.0
TARGET_CMA_EVAL_RATIO = 10.0


# ------------------------------------------------------------------------------ counting the L-BFGS evaluations


class Counter:
    """Host-side record of the evaluations made inside the jitted optimizer: the time (s since ``reset``)
    and value of every forward pass, and the number of reverse passes (gradients)."""

    def __init__(self):
        self.reset()

    def reset(self):
        self.t0 = time.perf_counter()
        self.times, self.values, self.gradients = [], [], 0

    def on_value(self, value):
        self.times.append(time.perf_counter() - self.t0)
        self.values.append(float(value))

    def on_gradient(self):
        self.gradients += 1


COUNTER = Counter()


@jax.custom_vjp
def _tap(z):
    """Identity whose reverse pass tells :data:`COUNTER` that a gradient was taken."""
    return z


def _tap_fwd(z):
    return z, None


def _tap_bwd(_, g):
    jax.debug.callback(COUNTER.on_gradient)
    return (g,)


_tap.defvjp(_tap_fwd, _tap_bwd)


class CountedProblem(pd.DesignProblem):
    """The same problem (built with the original's scales: no re-normalization), its ``value`` reporting
    each forward and each reverse pass to :data:`COUNTER`; the numbers it computes are unchanged."""

    def value(self, z):
        value = self.terms(_tap(z)).value
        jax.debug.callback(COUNTER.on_value, value)
        return value


# ---------------------------------------------------------------------------------- gradient-free baselines


class Trace:
    """Every evaluation of a baseline: time since start, value, running best; stops it (``Done``) once the
    best is within the target or the evaluation cap is reached."""

    class Done(Exception):
        pass

    def __init__(self, fwd, target, max_evals, penalty):
        self.fwd, self.target, self.max_evals, self.penalty = fwd, target, max_evals, penalty
        self.times, self.values, self.best = [], [], []
        self.nonfinite = 0
        self.reached = None  # (evaluations, wall_s) when the best first came within the target
        self.t0 = time.perf_counter()

    def __call__(self, z):
        if len(self.values) >= self.max_evals:
            raise Trace.Done
        value = float(self.fwd(jnp.asarray(np.asarray(z, dtype=np.float64))))
        self.times.append(time.perf_counter() - self.t0)
        self.values.append(value)
        if not np.isfinite(value):
            self.nonfinite += 1
            value = self.penalty
        self.best.append(min(value, self.best[-1]) if self.best else value)
        if self.reached is None and self.best[-1] <= self.target:
            self.reached = (len(self.values), self.times[-1])
            raise Trace.Done
        return value

    def best_at_time(self, t):
        i = int(np.searchsorted(np.asarray(self.times), t, side="right"))
        return (self.best[i - 1], i) if i else (None, 0)

    def best_at_evals(self, n):
        return self.best[min(n, len(self.best)) - 1] if self.best else None

    def summary(self, lbfgs_wall, lbfgs_evals, lbfgs_value, ratio_denominator, ratio_basis):
        at_time, evals_at_time = self.best_at_time(lbfgs_wall)
        reached = self.reached is not None
        n = self.reached[0] if reached else len(self.values)
        return dict(
            reached_target=reached,
            evaluations_to_target=self.reached[0] if reached else None,
            wall_s_to_target=self.reached[1] if reached else None,
            evaluations_used=len(self.values),
            wall_s_used=self.times[-1] if self.times else 0.0,
            best_value=self.best[-1] if self.best else None,
            best_relative_gap_to_lbfgs=(self.best[-1] - lbfgs_value) / abs(lbfgs_value)
            if self.best
            else None,
            nonfinite_evaluations=self.nonfinite,
            at_lbfgs_wall_time=dict(
                wall_s=lbfgs_wall,
                evaluations=evals_at_time,
                best_value=at_time,
                relative_gap_to_lbfgs=None if at_time is None else (at_time - lbfgs_value) / abs(lbfgs_value),
            ),
            at_lbfgs_evaluation_count=dict(
                evaluations=lbfgs_evals,
                best_value=self.best_at_evals(lbfgs_evals),
            ),
            evaluation_ratio=dict(
                value=n / ratio_denominator,
                basis=ratio_basis,
                lower_bound=not reached,
                note="baseline evaluations to the target / L-BFGS value-and-gradient evaluations"
                + (
                    "" if reached else "; the target was not reached within the cap, so this is a lower bound"
                ),
            ),
            trace=dict(wall_s=self.times, value=self.values, best=self.best),
        )


def run_cma(trace, z0, lo, hi, sigma0, seed):
    es = cma.CMAEvolutionStrategy(
        np.asarray(z0),
        sigma0,
        {"bounds": [lo.tolist(), hi.tolist()], "seed": seed, "verbose": -9, "maxfevals": trace.max_evals},
    )
    stop, generations = {}, 0
    try:
        while not es.stop():
            xs = es.ask()
            values = [trace(np.clip(x, lo, hi)) for x in xs]
            es.tell(xs, values)
            generations += 1
        stop = {k: (v if isinstance(v, (int, float, str)) else str(v)) for k, v in es.stop().items()}
    except Trace.Done:
        pass
    return dict(
        generations_completed=generations,
        popsize=es.popsize,
        sigma0=sigma0,
        seed=seed,
        own_stop=stop,
        boundary_handling="cma BoundTransform (bounds option); points clipped to the box before evaluation",
    )


def run_nelder_mead(trace, z0, lo, hi, step):
    z0 = np.asarray(z0)
    simplex = np.vstack([z0] + [np.clip(z0 + step * e, lo, hi) for e in np.eye(z0.size)])
    message = None
    try:
        res = so.minimize(
            trace,
            z0,
            method="Nelder-Mead",
            bounds=so.Bounds(lo, hi),
            options=dict(
                maxfev=10 * trace.max_evals,
                maxiter=10 * trace.max_evals,
                initial_simplex=simplex,
                xatol=1e-10,
                fatol=1e-12,
                adaptive=True,
            ),
        )
        message = str(res.message)
    except Trace.Done:
        pass
    return dict(
        initial_simplex_step=step,
        adaptive=True,
        own_stop=message,
        note="scipy's simplex started at z0 + step e_i (the default 0.00025 step at z = 0 would not move); "
        "adaptive (Gao-Han) coefficients, recommended for n >= 10",
    )


# -------------------------------------------------------------------------------------------------- main


def write_atomic_json(path: Path, payload: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=".partial")
    try:
        with os.fdopen(fd, "w") as fh:
            json.dump(payload, fh, indent=2, default=float)
            fh.write("\n")
        os.chmod(tmp, 0o644)  # mkstemp creates it 0600
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--periods", type=float, default=1.0, help="carrier periods simulated per design")
    ap.add_argument("--repeats", type=int, default=5, help="timed forward / gradient pairs")
    ap.add_argument(
        "--max-evals",
        type=int,
        default=300,
        help="cap on each baseline's evaluations (300 x ~1.5 s ~ 8 min at --periods 1)",
    )
    ap.add_argument(
        "--tol", type=float, default=1e-3, help="baseline target: within this of the L-BFGS optimum"
    )
    ap.add_argument(
        "--sigma0", type=float, default=0.4, help="CMA-ES initial step (and Nelder-Mead's simplex)"
    )
    ap.add_argument("--seed", type=int, default=20240601, help="CMA-ES seed")
    ap.add_argument("--out", type=Path, default=RESULTS / "design.json")
    args = ap.parse_args()
    command = "python3 benchmarks/bench_design.py" + (" " + shlex.join(sys.argv[1:]) if sys.argv[1:] else "")
    load_start = os.getloadavg()
    started = time.perf_counter()

    # --- the problem (its construction simulates the initial design once, to normalize)
    t = time.perf_counter()
    p = pm.default_params()
    space = pd.DesignSpace(p, pd.bolt_variables(p))
    response = pd.planetary_response(p, periods=args.periods)
    objective = pd.Std([f"ring_mesh{n}" for n in (1, 2, 3)])
    costs = [pd.SupportStiffness(weight=0.2)]
    problem = pd.DesignProblem(space, response, objective, costs)
    setup_s = time.perf_counter() - t
    z0 = problem.space.initial()
    lo, hi = problem.space.bounds()
    print(
        f"problem: {space.n} variables, {response.n_steps} steps of {response.dt} s ({args.periods} periods); "
        f"set-up {setup_s:.1f} s"
    )

    # --- 1. forward value vs value-and-gradient, calls alternating
    fwd = eqx.filter_jit(lambda z: problem.value(z))
    vg = eqx.filter_jit(jax.value_and_grad(lambda z: problem.value(z)))
    tm = timed_interleaved({"forward": fwd, "value_and_gradient": vg}, z0, repeats=args.repeats)
    f_row, g_row = tm["forward"], tm["value_and_gradient"]
    ratio = g_row["median_s"] / f_row["median_s"]
    value0 = float(fwd(z0))
    v_check, g_check = vg(z0)
    print(
        f"forward {f_row['median_s']:.2f} s (first {f_row['first_call_s']:.1f} s), value-and-gradient "
        f"{g_row['median_s']:.2f} s (first {g_row['first_call_s']:.1f} s): ratio {ratio:.2f}"
    )

    # --- 2. L-BFGS: warm-up run of two iterations (compiles: the first evaluation once, the update twice, as
    # optax's initial line-search state is weak-typed and the next one is not), then the timed run reusing them
    counted = CountedProblem(space, response, objective, costs, scales=problem.scales)
    optimizer = pd.default_optimizer()  # one object for both runs: its update functions key the jit cache
    n_warm = 2
    COUNTER.reset()
    t = time.perf_counter()
    warm = pd.optimize(counted, optimizer=optimizer, max_iter=n_warm, progress=False)
    warm_wall = time.perf_counter() - t
    warm_counts = dict(forward_passes=len(COUNTER.values), gradients=COUNTER.gradients)
    print(f"L-BFGS warm-up ({n_warm} iterations incl. compilation): {warm_wall:.1f} s, {warm_counts}")

    COUNTER.reset()
    t = time.perf_counter()
    result = pd.optimize(counted, optimizer=optimizer, progress=False)
    lbfgs_wall = time.perf_counter() - t
    lb_times, lb_values, lb_grads = list(COUNTER.times), list(COUNTER.values), COUNTER.gradients
    hist = result.history
    iterations = hist[-1]["iteration"]
    final = result.value
    target = final + args.tol * abs(final)
    # the first iterations cost the same in both runs (same start, same computations): the warm-up's excess
    # over the timed run's first iterations is the compilation (and tracing) of the jitted functions
    n_same = min(len(warm.history), len(hist)) - 1
    compile_s = warm_wall - hist[n_same]["wall_s"]
    warm_steps = np.diff([0.0] + [h["wall_s"] for h in warm.history[: n_same + 1]])
    timed_steps = np.diff([0.0] + [h["wall_s"] for h in hist[: n_same + 1]])
    compile_parts = (warm_steps - timed_steps).tolist()
    first_eval_within = next((i + 1 for i, v in enumerate(lb_values) if v <= target), None)
    first_iter_within = next(h for h in hist if h["objective"] <= target)
    print(
        f"L-BFGS: {iterations} iterations, {len(lb_values)} forward passes / {lb_grads} gradients, "
        f"{lbfgs_wall:.1f} s (+ {compile_s:.1f} s compilation), J {hist[0]['objective']:.6g} -> {final:.6g}; "
        f"{result.reason}"
    )

    # --- 3. gradient-free baselines on the same objective (the forward function compiled in 1)
    denominator = lb_grads if lb_grads else iterations
    basis = "L-BFGS value-and-gradient evaluations (counted)" if lb_grads else "L-BFGS iterations"
    penalty = 10.0 * value0
    baselines = {}
    for name, run in (
        ("cma_es", lambda tr: run_cma(tr, z0, lo, hi, args.sigma0, args.seed)),
        ("nelder_mead", lambda tr: run_nelder_mead(tr, z0, lo, hi, args.sigma0)),
    ):
        trace = Trace(fwd, target, args.max_evals, penalty)
        info = run(trace)
        baselines[name] = dict(
            info, **trace.summary(lbfgs_wall, lb_grads or iterations, final, denominator, basis)
        )
        b = baselines[name]
        print(
            f"{name}: {b['evaluations_used']} evaluations, {b['wall_s_used']:.1f} s, best {b['best_value']:.6g} "
            f"({'reached' if b['reached_target'] else 'did not reach'} {target:.6g}); at the L-BFGS wall time "
            f"{b['at_lbfgs_wall_time']['best_value']}; evaluation ratio {b['evaluation_ratio']['value']:.1f}"
            f"{' (lower bound)' if b['evaluation_ratio']['lower_bound'] else ''}"
        )

    cma_ratio = baselines["cma_es"]["evaluation_ratio"]
    payload = dict(
        machine=machine(),
        date=time.strftime("%Y-%m-%d %H:%M:%S"),
        command=command,
        arguments={k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        versions=dict(cma=cma.__version__, scipy=scipy.__version__, numpy=np.__version__),
        notes=[
            "The machine is shared and noisy (other jobs run beside this one): timings carry that noise; the "
            "forward / gradient calls alternate so that their ratio sees the same load. Load averages at start "
            "and end are recorded below.",
            "All figures are measured in this one run. Compilation is reported apart: first calls in 1; for "
            "L-BFGS, a warm-up run of one iteration compiles, and the timed run reuses the compiled functions.",
            "L-BFGS evaluations are counted, not estimated: the problem's value is wrapped (CountedProblem, same "
            "numbers) with jax.debug.callback on each forward pass and on each reverse pass (custom_vjp "
            "identity on z), so line-search trials inside the jitted update are counted too.",
            "Baselines evaluate the forward function compiled in 1 (no compilation in their wall time), on the "
            "same coordinates z and bounds (problem.space.bounds()); a non-finite value (failed SL fixed "
            "point) is replaced by a penalty of 10 x the initial value and counted.",
        ],
        load_average=dict(start=list(load_start), end=list(os.getloadavg())),
        problem=dict(
            n_variables=int(space.n),
            labels=space.labels(),
            periods=args.periods,
            n_steps=response.n_steps,
            dt_s=response.dt,
            description=problem.describe(),
            setup_s=setup_s,
            setup_note="DesignProblem construction: builds and simulates the initial design once (normalization)",
            bounds_z=dict(lower=lo.tolist(), upper=hi.tolist()),
            initial_value=value0,
        ),
        gradient_cost=dict(
            forward_median_s=f_row["median_s"],
            value_and_gradient_median_s=g_row["median_s"],
            ratio=ratio,
            target_ratio_max=TARGET_GRADIENT_RATIO,
            meets_target=ratio <= TARGET_GRADIENT_RATIO,
            forward_runs_s=f_row["runs_s"],
            value_and_gradient_runs_s=g_row["runs_s"],
            forward_first_call_s=f_row["first_call_s"],
            value_and_gradient_first_call_s=g_row["first_call_s"],
            repeats=args.repeats,
            timing="calls alternating forward, value-and-gradient, ...; medians; first calls (compilation) apart",
            check=dict(
                forward_value=value0,
                value_and_gradient_value=float(v_check),
                gradient_norm=float(jnp.linalg.norm(g_check)),
            ),
        ),
        lbfgs=dict(
            optimizer="pd.default_optimizer() (optax.lbfgs, zoom line search), passed explicitly as one object",
            iterations=iterations,
            converged=result.converged,
            reason=result.reason,
            forward_passes=len(lb_values),
            value_and_gradient_evaluations=lb_grads,
            evaluations_note="every forward pass here was part of a value-and-gradient evaluation"
            if len(lb_values) == lb_grads
            else "forward passes and gradients differ: some evaluations were value-only",
            wall_s_excluding_compile=lbfgs_wall,
            compile_s=compile_s,
            wall_s_including_compile=lbfgs_wall + compile_s,
            compile_note=f"warm-up run (max_iter={n_warm}, cold) wall time minus the timed run's wall time at "
            f"the same iteration ({n_same}); both runs make the same computations up to there",
            compile_s_by_iteration=dict(
                seconds=compile_parts,
                note="warm-up minus timed run, per history entry: [0] the first evaluation (_first), [1] the "
                "update with optax's initial (weak-typed) line-search state, [2] the update with the later "
                "(strongly typed) state: pd.optimize compiles its update twice in every run",
            ),
            warmup=dict(
                wall_s=warm_wall,
                iterations=warm.history[-1]["iteration"],
                history_wall_s=[h["wall_s"] for h in warm.history],
                **warm_counts,
            ),
            initial_value=hist[0]["objective"],
            final_value=final,
            final_response=hist[-1]["response"],
            final_costs=hist[-1]["costs"],
            final_gradient_norm=hist[-1]["gradient_norm"],
            final_variables=hist[-1]["variables"],
            final_z=hist[-1]["z"],
            final_z_at_bounds=int(np.sum(np.isclose(result.z, lo) | np.isclose(result.z, hi))),
            within_tol_of_final=dict(
                tol=args.tol,
                first_iteration=first_iter_within["iteration"],
                first_iteration_wall_s=first_iter_within["wall_s"],
                first_evaluation=first_eval_within,
                first_evaluation_wall_s=lb_times[first_eval_within - 1] if first_eval_within else None,
            ),
            targets=dict(
                iterations_max=TARGET_ITERATIONS,
                wall_s_max=TARGET_WALL_S,
                meets_iterations=iterations <= TARGET_ITERATIONS,
                meets_wall_including_compile=lbfgs_wall + compile_s <= TARGET_WALL_S,
            ),
            history=[
                dict(
                    iteration=h["iteration"],
                    objective=h["objective"],
                    gradient_norm=h["gradient_norm"],
                    wall_s=h["wall_s"],
                )
                for h in hist
            ],
            evaluations=dict(wall_s=lb_times, value=lb_values),
        ),
        baselines=dict(
            target_value=target,
            target_note=f"best value <= L-BFGS optimum x (1 + {args.tol:g})",
            max_evals=args.max_evals,
            **baselines,
        ),
        cma_es_evaluation_ratio=dict(
            value=cma_ratio["value"],
            lower_bound=cma_ratio["lower_bound"],
            basis=cma_ratio["basis"],
            target_min=TARGET_CMA_EVAL_RATIO,
            meets_target=cma_ratio["value"] >= TARGET_CMA_EVAL_RATIO,
        ),
        total_wall_s=time.perf_counter() - started,
    )
    write_atomic_json(args.out, payload)
    print("wrote", args.out)


if __name__ == "__main__":
    main()
