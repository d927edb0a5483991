"""Design study on the planetary train: a TOML design specification (variables, objective, costs,
optimizer, horizon, verification, Pareto weights) turned into a :class:`pgtjax.design.DesignProblem`,
optimized, verified by Monte Carlo and written out (history, optimized parameter file, figures, summary)."""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax

from .. import design as pd
from .. import params as _params
from .. import plots
from .._files import write_text
from .._summary import write_summary
from .._system import check_count
from ..models import planetary as pm

SPEC_SECTIONS = ("horizon", "variables", "objective", "costs", "optimizer", "verification", "pareto")


@dataclasses.dataclass
class DesignSpec:
    """A validated design specification (see the embedded ``design.toml``)."""

    periods: float
    dt: float
    variables: list[dict]
    objective: dict
    costs: list[dict]
    optimizer: dict
    verification: dict
    pareto_weights: list[float]


def _entry(section: str, data: dict, allowed: dict, where: str):
    """Check a table's keys and value types: ``allowed`` maps key -> (types, default or ``...`` if required)."""
    if not isinstance(data, dict):
        raise ValueError(f"design spec {where}: must be a table, got {data!r}")
    unknown = set(data) - set(allowed)
    if unknown:
        raise ValueError(f"design spec {where}: unknown key(s) {sorted(unknown)}; allowed: {sorted(allowed)}")
    out = {}
    for key, (types, default) in allowed.items():
        if key not in data:
            if default is ...:
                raise ValueError(f"design spec {where}: `{key}` is required")
            out[key] = default
            continue
        value = data[key]
        types = types if isinstance(types, tuple) else (types,)
        if (isinstance(value, bool) and bool not in types) or not isinstance(value, types):
            raise ValueError(f"design spec {where}: `{key}` has the wrong type ({value!r})")
        out[key] = value
    return out


NUMBER = (int, float)


def load_spec(source=None) -> DesignSpec:
    """Read and check a design specification (TOML file or dict; default: the embedded ``design.toml``).
    Every problem is a ``ValueError`` naming the entry."""
    if source is None:
        source = _params.path("design.toml")
    data = _params.read_toml(source) if isinstance(source, (str, Path)) else copy.deepcopy(dict(source))
    unknown = set(data) - set(SPEC_SECTIONS)
    if unknown:
        raise ValueError(f"design spec: unknown section(s) {sorted(unknown)}; allowed: {list(SPEC_SECTIONS)}")
    horizon = _entry(
        "horizon", data.get("horizon", {}), {"periods": (NUMBER, 1.0), "dt": (NUMBER, 0.0027)}, "[horizon]"
    )
    variables = data.get("variables")
    if not isinstance(variables, list) or not variables:
        raise ValueError("design spec: [[variables]] must list at least one variable")
    var_keys = {
        "path": (str, ...),
        "name": (str, None),
        "per_bolt": (bool, False),
        "lower": (NUMBER, ...),
        "upper": (NUMBER, ...),
        "transform": (str, "log"),
        "unit": (str, ""),
    }
    variables = [_entry("variables", v, var_keys, f"[[variables]] #{i + 1}") for i, v in enumerate(variables)]
    for key in ("periods", "dt"):
        if not (math.isfinite(horizon[key]) and horizon[key] > 0):
            raise ValueError(
                f"design spec [horizon]: `{key}` must be a finite number > 0, got {horizon[key]!r}"
            )
    for i, v in enumerate(variables):
        where = f"design spec [[variables]] #{i + 1}"
        if v["path"] not in pm.PARAMETER_FILE_KEYS:
            raise ValueError(
                f"{where}: unknown or unsupported path {v['path']!r}; supported: {', '.join(pm.PARAMETER_FILE_KEYS)}"
            )
        if v["transform"] not in pd._variables.TRANSFORMS:
            raise ValueError(
                f"{where}: `transform` must be one of {', '.join(pd._variables.TRANSFORMS)}, got {v['transform']!r}"
            )
        if not (math.isfinite(v["lower"]) and math.isfinite(v["upper"]) and v["lower"] < v["upper"]):
            raise ValueError(
                f"{where}: `lower` ({v['lower']!r}) must be finite and below `upper` ({v['upper']!r})"
            )
        if v["transform"] == "log" and v["lower"] <= 0:
            raise ValueError(f"{where}: a log transform needs `lower` > 0, got {v['lower']!r}")
    objective = _entry(
        "objective",
        data.get("objective", {}),
        {
            "kind": (str, ...),
            "quantities": (list, ...),
            "over": (str, "mean"),
            "n_sigma": (NUMBER, 3.0),
            "order": (NUMBER, 8.0),
            "start": (NUMBER, 0.0),
        },
        "[objective]",
    )
    if objective["kind"] not in pd._objectives.OBJECTIVES:
        raise ValueError(
            f"design spec [objective]: unknown kind {objective['kind']!r}; known: "
            f"{list(pd._objectives.OBJECTIVES)}"
        )
    if objective["over"] not in pd._objectives.REDUCTIONS:
        raise ValueError(
            f"design spec [objective]: unknown `over` {objective['over']!r}; known: "
            f"{list(pd._objectives.REDUCTIONS)}"
        )
    costs = [
        _entry("costs", c, {"kind": (str, ...), "weight": (NUMBER, 1.0)}, f"[[costs]] #{i + 1}")
        for i, c in enumerate(data.get("costs", []))
    ]
    for i, c in enumerate(costs):
        if c["kind"] not in pd._objectives.COSTS:
            raise ValueError(
                f"design spec [[costs]] #{i + 1}: unknown kind {c['kind']!r}; known: "
                f"{list(pd._objectives.COSTS)}"
            )
    optimizer = _entry(
        "optimizer",
        data.get("optimizer", {}),
        {
            "name": (str, "lbfgs"),
            "max_iter": (int, 50),
            "rtol": (NUMBER, 1e-6),
            "gtol": (NUMBER, 1e-6),
            "learning_rate": (NUMBER, 0.05),
        },
        "[optimizer]",
    )
    if optimizer["name"] not in ("lbfgs", "adam"):
        raise ValueError(f"design spec [optimizer]: unknown name {optimizer['name']!r}; known: lbfgs, adam")
    verification = _entry(
        "verification",
        data.get("verification", {}),
        {"n_samples": (int, 2000), "batches": (int, 10), "save_every": (int, 10), "seed": (int, 0)},
        "[verification]",
    )
    try:
        pd._problem.check_samples(verification["n_samples"], verification["batches"])
        check_count("save_every", verification["save_every"])
    except ValueError as err:
        raise ValueError(f"design spec [verification]: {err}") from None
    pareto = _entry("pareto", data.get("pareto", {}), {"weights": (list, [])}, "[pareto]")
    if not all(isinstance(w, NUMBER) and not isinstance(w, bool) and w >= 0 for w in pareto["weights"]):
        raise ValueError(f"design spec [pareto]: `weights` must be numbers >= 0, got {pareto['weights']!r}")
    if pareto["weights"] and len(costs) != 1:
        raise ValueError("design spec [pareto]: a front needs exactly one [[costs]] entry to weigh")
    return DesignSpec(
        periods=float(horizon["periods"]),
        dt=float(horizon["dt"]),
        variables=variables,
        objective=objective,
        costs=costs,
        optimizer=optimizer,
        verification=verification,
        pareto_weights=[float(w) for w in pareto["weights"]],
    )


def build_problem(params: pm.PlanetaryParams, spec: DesignSpec) -> pd.DesignProblem:
    """The :class:`pgtjax.design.DesignProblem` of ``spec`` on the planetary train ``params``."""
    n_bolts = len(params.ring.support_nodes)
    variables = []
    for i, v in enumerate(spec.variables):
        if v["path"] not in pm.PARAMETER_FILE_KEYS:
            raise ValueError(
                f"design spec [[variables]] #{i + 1}: unknown or unsupported path {v['path']!r}; "
                f"supported: {', '.join(pm.PARAMETER_FILE_KEYS)}"
            )
        if v["per_bolt"] and not v["path"].startswith("ring.k_support"):
            raise ValueError(
                f"design spec [[variables]] #{i + 1}: `per_bolt` applies to ring.k_support_* only"
            )
        try:
            variables.append(
                pd.Variable(
                    v["path"],
                    v["lower"],
                    v["upper"],
                    v["transform"],
                    size=n_bolts if v["per_bolt"] else None,
                    name=v["name"],
                    unit=v["unit"],
                )
            )
        except ValueError as err:
            raise ValueError(f"design spec [[variables]] #{i + 1}: {err}") from None
    o = spec.objective
    over = (
        pd.TimeMean(start=o["start"])
        if o["over"] == "mean"
        else pd.SmoothMax(order=o["order"], start=o["start"])
    )
    kind = pd._objectives.OBJECTIVES[o["kind"]]
    extra = {"n_sigma": o["n_sigma"]} if o["kind"] == "dynamic_factor" else {}
    try:
        objective = kind(o["quantities"], over=over, **extra)
    except ValueError as err:
        raise ValueError(f"design spec [objective]: {err}") from None
    costs = [pd._objectives.COSTS[c["kind"]](weight=float(c["weight"])) for c in spec.costs]
    # a whole number of Monte Carlo save intervals (10022 steps per carrier period -> 10020 at save_every 10)
    response = pd.planetary_response(
        params, periods=spec.periods, dt=spec.dt, step_multiple=spec.verification["save_every"]
    )
    try:
        return pd.DesignProblem(pd.DesignSpace(params, variables), response, objective, costs)
    except ValueError as err:
        raise ValueError(f"design spec: {err}") from None


def make_optimizer(spec: DesignSpec):
    if spec.optimizer["name"] == "adam":
        return optax.adam(spec.optimizer["learning_rate"])
    return pd.default_optimizer()


def optimized_parameter_data(data: dict, problem: pd.DesignProblem, z) -> dict:
    """The parameter file's dict with the design variables set from ``z`` (per-bolt values as lists)."""
    out = copy.deepcopy(data)
    for v, x in zip(problem.space.variables, problem.space.physical(jnp.asarray(z))):
        table, key = pm.PARAMETER_FILE_KEYS[v.path]
        values = [float(a) for a in np.asarray(x).reshape(-1)]
        out[table][key] = values if len(values) > 1 else values[0]
    return out


@dataclasses.dataclass
class DesignStudy:
    problem: pd.DesignProblem
    result: pd.OptimizeResult
    check: dict
    front: list[dict]
    series: dict
    timings: dict


def run_design(params=None, spec=None, *, history=None, resume=False, pareto=True, say=print) -> DesignStudy:
    """Optimize ``spec`` (default: the embedded bolt study) on ``params`` (default: the embedded train),
    trace the Pareto front by re-optimizing for each further cost weight (warm-started), and check the
    symmetric start against the optimum by Monte Carlo with common random numbers."""
    p = pm.default_params() if params is None else params
    spec = load_spec() if spec is None else spec
    timings = {}
    t = time.perf_counter()
    problem = build_problem(p, spec)
    timings["setup_s"] = time.perf_counter() - t
    say(
        f"design: {problem.space.n} variables, objective: {problem.objective.describe(problem.names)['name']}"
    )
    t = time.perf_counter()
    o = spec.optimizer
    optimizer = make_optimizer(spec)  # one object: its update compiles once for the optimum and the front
    result = pd.optimize(
        problem,
        optimizer=optimizer,
        max_iter=o["max_iter"],
        rtol=o["rtol"],
        gtol=o["gtol"],
        history=history,
        resume=resume,
        progress=say is not None,
    )
    timings["optimize_s"] = time.perf_counter() - t
    say(
        f"optimum after {result.history[-1]['iteration']} iterations ({result.reason}): scalarized objective "
        f"(the response plus the weighted costs, each over its reference scale: its value at the start when "
        f"normalized) "
        f"{result.history[0]['objective']:.6g} -> {result.value:.6g}"
    )
    front = []
    if pareto and spec.pareto_weights:
        t = time.perf_counter()
        # each weight starts from the main optimum; the main weight's optimum joins the front as found
        weights = sorted({*spec.pareto_weights, float(problem.weights[0])})
        front = pd.pareto_front(
            problem,
            weights,
            z0=result.z,
            optimizer=optimizer,
            say=say,
            max_iter=o["max_iter"],
            rtol=o["rtol"],
            gtol=o["gtol"],
        )
        for e in front:
            e["cost"] = e["costs"][0]
        timings["pareto_s"] = time.perf_counter() - t
    v = spec.verification
    t = time.perf_counter()
    designs = {"symmetric": result.initial_z, "optimum": result.z}
    first = spec.objective["quantities"][0]
    check = pd.monte_carlo_check(
        problem,
        designs,
        n_samples=v["n_samples"],
        batches=v["batches"],
        key=jax.random.key(v["seed"]),
        save_every=v["save_every"],
        series=[first] if spec.objective["kind"] in ("std", "variance") else [],
    )
    series = check.pop("series")
    timings["monte_carlo_s"] = time.perf_counter() - t
    opt = check["designs"]["optimum"]
    unit = problem.describe()["objective"]["unit"] or "the custom objective's unit"
    say(
        f"Monte Carlo ({v['n_samples']} samples per design): response {check['designs']['symmetric']['mc']:.6g} "
        f"-> {opt['mc']:.6g} {unit}, improvement {opt['improvement_in_se']:.1f} standard errors"
    )
    return DesignStudy(
        problem=problem, result=result, check=check, front=front, series=series, timings=timings
    )


# ------------------------------------------------------------------------------------------------ outputs


def convergence_figure(study: DesignStudy):
    h = study.result.history
    it = [e["iteration"] for e in h]
    with plots.mpl.rc_context(plots.STYLE):
        fig, (a, b) = plots.plt.subplots(1, 2, figsize=(9, 3.4))
        a.plot(it, [e["objective"] for e in h], "o-")
        a.set(xlabel="iteration", ylabel="objective J (1 at the start + cost weights)", title="objective")
        b.semilogy(it, [max(e["gradient_norm"], 1e-300) for e in h], "o-")
        for ax in (a, b):
            ax.xaxis.set_major_locator(plots.mpl.ticker.MaxNLocator(integer=True))
        b.set(xlabel="iteration", ylabel="projected gradient norm", title="gradient")
        fig.tight_layout()
    return fig


def variables_figure(study: DesignStudy):
    """Each variable at the symmetric start and at the optimum (bars from zero, one panel per variable)."""
    problem = study.problem
    start = problem.space.physical(jnp.asarray(study.result.initial_z))
    opt = problem.space.physical(jnp.asarray(study.result.z))
    n = len(problem.space.variables)
    with plots.mpl.rc_context(plots.STYLE):
        fig, axes = plots.plt.subplots(1, n, figsize=(4.2 * n, 3.7), squeeze=False, layout="constrained")
        for ax, v, x0, x1 in zip(axes[0], problem.space.variables, start, opt):
            factor, unit = (1e-9, "GN/m") if v.unit == "N/m" else (1.0, v.unit)
            idx = np.arange(np.size(x0))
            ax.bar(idx - 0.2, factor * np.ravel(x0), 0.4, label="symmetric start")
            ax.bar(idx + 0.2, factor * np.ravel(x1), 0.4, label="optimum")
            top = 1.25 * factor * max(float(np.max(x0)), float(np.max(x1)))
            ax.axhline(factor * v.lower, color="0.5", ls=":", lw=1, label="bounds")
            if factor * v.upper <= top:
                ax.axhline(factor * v.upper, color="0.5", ls=":", lw=1)
            shown = f"{factor * v.lower:.3g} to {factor * v.upper:.3g} {unit}".rstrip()
            ax.set(
                xlabel="bolt" if v.size else "",
                ylabel=f"{v.name} ({unit})" if unit else v.name,
                title=f"{v.name}: bounds {shown}",
            )
            ax.set_ylim(0.0, top)
            ax.set_xticks(idx)
        handles, labels = axes[0, 0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncol=len(labels))
    return fig


def response_figure(study: DesignStudy):
    ((quantity, data),) = study.series.items()
    factor, unit = plots.scaled(study.problem.names.unit(quantity))
    with plots.mpl.rc_context(plots.STYLE):
        fig, ax = plots.plt.subplots(figsize=(8, 3.9), layout="constrained")
        for name, d in data.items():
            (line,) = ax.plot(d["times"], factor * d["sl"], label=f"{name}: SL", zorder=3)
            every = max(len(d["times"]) // 40, 1)
            ax.errorbar(
                d["times"][::every],
                factor * d["mc"][::every],
                yerr=1.96 * factor * d["mc_se"][::every],
                **{**plots.MC_ERRORBARS, "color": line.get_color(), "ecolor": line.get_color()},
                label=f"{name}: Monte Carlo, 95 % error bars",
            )
        ax.set(
            xlabel="time (s)",
            ylabel=f"std of {quantity} ({unit})",
            title="symmetric bolts against the optimum: SL lines, Monte Carlo markers",
        )
        n_quantities = len(getattr(study.problem.objective, "quantities", (quantity,)))
        if n_quantities > 1:  # the objective averages several: say this is one of them
            ax.set_title(
                f"symmetric bolts against the optimum: SL lines, Monte Carlo markers\n{quantity}, the first of "
                f"the objective's {n_quantities} quantities",
                fontsize=9,
            )
        ax.set_ylim(0.0, None)
        fig.legend(loc="outside lower center", ncol=2, frameon=False)
    return fig


def pareto_figure(study: DesignStudy):
    problem = study.problem
    r_factor, r_unit = plots.scaled(problem.objective.describe(problem.names)["unit"])
    cost = problem.costs[0].describe()
    c_factor, c_unit = (1e-9, "GN/m") if cost["unit"] == "N/m" else (1.0, cost["unit"])
    with plots.mpl.rc_context(plots.STYLE):
        fig, ax = plots.plt.subplots(figsize=(6, 4))
        costs = [c_factor * e["cost"] for e in study.front]
        responses = [r_factor * e["response"] for e in study.front]
        ax.plot(costs, responses, "o-", label="optimum for each cost weight w")
        for e, x, y in zip(study.front, costs, responses):
            ax.annotate(f"w={e['weight']:g}", (x, y), textcoords="offset points", xytext=(4, 4))
        start = study.result.history[0]
        ax.plot(
            c_factor * start["costs"][0], r_factor * start["response"], "s", ms=8, label="symmetric start"
        )
        ax.set(
            xlabel=f"{cost['name'].split(' (')[0]} ({c_unit})",
            ylabel=f"objective ({r_unit})",
            title="Pareto front: response against cost",
        )
        ax.legend(loc="best")
        fig.tight_layout()
    return fig


def _verdict(opt: dict, unit: str) -> str:
    """What the Monte Carlo check says of the optimum, in words that follow its sign and size."""
    z = opt["improvement_in_se"]
    size = (
        f"{abs(opt['improvement']):.4g} {unit} ({100 * abs(opt['relative_improvement']):.2f} %), "
        f"{abs(z):.1f} standard errors of the paired batch differences"
    )
    if z > 3:
        return f"Monte Carlo confirms the optimum: the objective drops by {size}"
    if z < -3:
        return f"Monte Carlo contradicts SL: at the optimum the objective rises by {size}"
    return f"Monte Carlo does not resolve a change: {size} (not more than 3)"


def summary(study: DesignStudy, spec: DesignSpec) -> dict:
    problem, r = study.problem, study.result
    desc = problem.describe()
    start, end = r.history[0], r.history[-1]
    units = {v["name"]: v["unit"] for v in desc["variables"]}
    opt = study.check["designs"]["optimum"]
    response_unit = desc["objective"]["unit"] or "the custom objective's (not given)"
    return dict(
        objective=dict(
            desc["objective"],
            unit=response_unit,
            symmetric=start["response"],
            optimum=end["response"],
            relative_change=end["response"] / start["response"] - 1.0,
        ),
        costs=[
            dict(c, symmetric=s, optimum=e) for c, s, e in zip(desc["costs"], start["costs"], end["costs"])
        ],
        total_objective=dict(symmetric=start["objective"], optimum=end["objective"], unit="1 (normalized)"),
        variables={
            k: dict(
                symmetric=start["variables"][k],
                optimum=end["variables"][k],
                unit=units.get(k.split("[")[0], ""),
            )
            for k in end["variables"]
        },
        convergence=dict(
            iterations=end["iteration"],
            converged=r.converged,
            reason=r.reason,
            gradient_norm=end["gradient_norm"],
        ),
        monte_carlo=dict(study.check, statement=_verdict(opt, desc["objective"]["unit"])),
        pareto_front=[{k: e[k] for k in ("weight", "response", "cost", "converged")} for e in study.front],
        horizon=desc["horizon"],
        timings_s=study.timings,
        # the unit of every number whose key or enclosing object does not name it (pgtjax._summary)
        units=dict(
            response=response_unit,
            cost=desc["costs"][0]["unit"] if desc["costs"] else "1",
            cost_units=[c["unit"] for c in desc["costs"]],
            timings="s",
            weight="1 (cost weight)",
            relative_change="1 (ratio)",
            relative_improvement="1 (ratio)",
            iterations="1 (count)",
            gradient_norm="1 (norm of the objective's gradient in the optimizer's variables z)",
            sl=response_unit,
            mc=response_unit,
            mc_se=response_unit,
            improvement=response_unit,
            improvement_se=response_unit,
            n_samples="1 (count)",
            batches="1 (count)",
            save_every="time steps",
            n_steps="1 (count of time steps)",
        ),
    )


#: one line for every file ``pgtjax optimize`` writes (README.txt of the output folder)
FILE_INDEX = {
    "history.json": "every iteration: objective, its parts, gradient norm and design variables (--resume reads it)",
    "history.json.state.npz": "the optimizer's state after the last iteration, for --resume",
    "optimized_params.toml": "the parameter file at the optimum: pgtjax run --params optimized_params.toml",
    "convergence.png": "objective and projected-gradient norm against the iteration",
    "variables.png": "each design variable at the symmetric start and at the optimum, with its bounds",
    "response.png": "the objective's quantities over the horizon at both designs: SL lines, MC markers with "
    "error bars",
    "pareto.png": "the Pareto front of response against cost, one optimization per cost weight, and the "
    "symmetric design",
}


def write_outputs(study: DesignStudy, spec: DesignSpec, out, parameter_data: dict) -> list[Path]:
    """Figures, the optimized parameter file (loadable by ``pgtjax run --params``) and ``summary.json``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = [
        plots.save(convergence_figure(study), out / "convergence.png"),
        plots.save(variables_figure(study), out / "variables.png"),
    ]
    if study.series:
        written.append(plots.save(response_figure(study), out / "response.png"))
    if study.front:
        written.append(plots.save(pareto_figure(study), out / "pareto.png"))
    data = optimized_parameter_data(parameter_data, study.problem, study.result.z)
    header = (
        "Optimized by pgtjax optimize: design variables "
        + ", ".join(v.name for v in study.problem.space.variables)
        + " set to the optimum."
    )
    written.append(write_text(out / "optimized_params.toml", _params.dumps_toml(data, header)))
    written.append(write_summary(out / "summary.json", summary(study, spec)))
    return written
