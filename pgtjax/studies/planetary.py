"""Thesis ch. 3 study: the wind-turbine planetary gear train with an elastic ring under random wind torque.

- mean and standard deviation of every DOF over one carrier period by SL + the moment recursion and by
  Monte Carlo of the nonlinear system (Figs. 3.5-3.8, App. A.1-A.18);
- the ring at the moving contact point of planet 1 (Fig. 3.9) through an observable;
- mean and mean square of the equivalent meshing forces (Figs. 3.10-3.11);
- rim thickness 87 / 128 / 168 mm (Figs. 3.12-3.15) and the number of bolt supports;
- modal analysis with mode types; sensitivities by automatic differentiation, checked by central differences.

Every run starts from the deterministic static equilibrium (:func:`pgtjax.static_equilibrium`) with the wind
filter in its stationary distribution (the wind has been blowing before t = 0).
"""

from __future__ import annotations

import dataclasses
import functools
import numbers
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import (
    AbstractCriterion,
    ForceCriterion,
    MomentResult,
    MonteCarloResult,
    Observables,
    modal_analysis,
    monte_carlo,
    plots,
    save_results,
    solve_moments,
    static_equilibrium,
)
from .._contact import check_criterion
from .._montecarlo import check_options as check_monte_carlo_options
from .._results import every_nth_save
from .._summary import write_summary
from .._system import check_count
from ..models import planetary as pm
from ..models.ring import ring_interpolation, ring_nodal_inverse, without_supports

# Thesis node 3 (1-based) is our 0-based ring node 2.
FIGURE_DOFS = (("ring_node2_tangential", "m"), ("sun_u", "m"), ("carrier_u", "m"), ("planet1_eta", "m"))


@dataclasses.dataclass
class PlanetaryStudy:
    params: pm.PlanetaryParams
    sl: dict[str, MomentResult]  # by SL criterion
    mc: MonteCarloResult | None
    dt: float
    carrier_period: float
    settings: dict
    # with peak_force_bins: SL's estimate of each meshing force's peak (sl_peak_estimates), else None
    sl_peaks: dict | None = None

    def sl_result(self, criterion: str | None = None) -> MomentResult:
        """The SL result of ``criterion`` (default: the first criterion run)."""
        criterion = next(iter(self.sl)) if criterion is None else criterion
        if criterion not in self.sl:
            raise ValueError(f"`criterion` {criterion!r} was not run; run: {', '.join(self.sl)}")
        return self.sl[criterion]

    def sl_on_mc_grid(self, criterion: str | None = None) -> MomentResult:
        """The SL result at the Monte Carlo's saved times (SL is saved ``sl_refine`` times as often)."""
        return every_nth_save(self.sl_result(criterion), self.settings["sl_refine"])


def carrier_period(p: pm.PlanetaryParams) -> float:
    """T_c = 2 pi / omega_c (s)."""
    return float(2.0 * np.pi / p.mesh.carrier_speed)


class _ContactPointMatrix(eqx.Module):
    """C(t) of :func:`contact_point_observables`, as a module: its arrays are pytree leaves, so that runs of
    models of equal shape (a second run, a rim-thickness sweep) reuse one compiled solver, where a closure
    would be a new static function, compiled anew, each time."""

    # the elastic ring with its centre radius derived, without its bolts (without_supports)
    ring: pm.RingParams
    inverse: jax.Array
    carrier_speed: jax.Array  # rad/s
    psi: float = eqx.field(static=True)  # rad, the planet's angle
    layout: pm.Layout  # DOF indices (static fields only)

    def __call__(self, t):
        lay = self.layout
        rows = ring_interpolation(self.ring, self.carrier_speed * t + self.psi, self.inverse)[:2]
        return jnp.zeros((2, lay.n_dof)).at[:, lay.ring_start : lay.ring_start + lay.n_ring].set(rows)


def contact_point_observables(p: pm.PlanetaryParams, planet: int = 0) -> Observables:
    """Ring displacement (inward radial, tangential; m) at the moving contact point of a planet (Fig. 3.9)."""
    lay = pm.layout(p)
    ring = without_supports(p.elastic_ring)  # derived and inverted once, not at every time step
    matrix = _ContactPointMatrix(
        ring,
        ring_nodal_inverse(ring),
        jnp.asarray(p.mesh.carrier_speed, jnp.float64),
        float(p.planet_angles()[planet]),
        lay,
    )
    return Observables(
        matrix, names=[f"ring_contact{planet + 1}_radial", f"ring_contact{planet + 1}_tangential"]
    )


def _grid(p, dt, periods, n_saves, sl_refine):
    """(n_steps, MC save interval, SL save interval) over ``periods`` carrier periods: SL is saved exactly
    ``sl_refine`` times as often as MC (the default 10 resolves the meshing frequency, Figs. 3.10-3.11,
    while MC pays its per-save cost only at its own saves), and MC about ``n_saves`` times: more when
    ``n_saves * sl_refine`` exceeds the number of steps, since SL is saved at most once a step."""
    sl_refine, n_saves = check_count("sl_refine", sl_refine), check_count("n_saves", n_saves)
    # the mesh stiffness, sampled once a step, aliases unless its highest harmonic has two steps a period
    n_harmonics = max(int(p.mesh.harmonics), 1)
    limit = np.pi / (n_harmonics * float(p.mesh.mesh_frequency))
    if not 0.0 < dt < limit:
        raise ValueError(
            f"`dt` must be > 0 and below half the period of the mesh stiffness's highest harmonic (harmonic "
            f"{n_harmonics} of the meshing frequency), {limit:.4g} s; got {dt:g} s (the thesis uses 0.0027 s)"
        )
    if not (np.isfinite(periods) and periods * carrier_period(p) >= dt):
        raise ValueError(
            f"`periods` ({periods:g} carrier periods, {periods * carrier_period(p):.4g} s) must span at least one "
            f"time step of `dt` = {dt:g} s: at least {dt / carrier_period(p):.3g} periods"
        )
    target = int(round(periods * carrier_period(p) / dt))
    sl_every = max(target // (n_saves * sl_refine), 1)
    mc_every = sl_every * sl_refine
    return mc_every * max(target // mc_every, 1), mc_every, sl_every


def _setup(p, dt, periods, n_saves, sl_refine=1, observables=True):
    """The system and the solver keywords shared by SL and MC, with the SL and MC save intervals."""
    system = pm.build(p)
    lay = pm.layout(p)
    n_steps, mc_every, sl_every = _grid(p, dt, periods, n_saves, sl_refine)
    kw = dict(
        dt=dt,
        n_steps=n_steps,
        initial_displacement=static_equilibrium(system),
        initial_covariance=pm.wind_filter_stationary_covariance(p, lay),
    )
    if observables and p.ring_model == "elastic":
        kw["observables"] = contact_point_observables(p)
    return system, kw, mc_every, sl_every


def run_study(
    params=None,
    *,
    n_samples=500,
    dt=0.0027,
    periods=1.0,
    n_saves=2000,
    sl_refine=1,
    criteria=(ForceCriterion(),),
    key=None,
    chunk_size=None,
    progress=True,
    checkpoint=None,
    checkpoint_every=1,
    resume=False,
    peak_force_bins=0,
    peak_start=0.0,
) -> PlanetaryStudy:
    """SL (each criterion) and MC over ``periods`` carrier periods; ``n_samples = 0`` skips MC.
    ``checkpoint``, ``checkpoint_every``, ``resume``: as in :func:`pgtjax.monte_carlo`. ``peak_force_bins``
    > 0: MC also counts every meshing force's peak (its largest magnitude from ``peak_start``, s, the nearest
    Monte Carlo save; default the start) in that many bins (:func:`peak_force_bins_of`).

    MC is saved about ``n_saves`` times and SL ``sl_refine`` times as often (:func:`_grid`;
    :meth:`PlanetaryStudy.sl_on_mc_grid` gives SL on MC's grid)."""
    p = pm.default_params() if params is None else params
    criteria = tuple(criteria)
    if not criteria:
        raise ValueError(
            "`criteria` must give at least one SL criterion, e.g. (pgtjax.ForceCriterion(), pgtjax.EnergyCriterion())"
        )
    for criterion in criteria:
        check_criterion(criterion)
    check_count("peak_force_bins", peak_force_bins, minimum=0)
    if peak_force_bins and not n_samples:
        raise ValueError("`peak_force_bins` counts Monte Carlo samples: it needs `n_samples` >= 2")
    if (
        isinstance(peak_start, bool)
        or not isinstance(peak_start, numbers.Real)
        or not 0.0 <= peak_start < np.inf
    ):
        raise ValueError(f"`peak_start` must be a time >= 0 (s), got {peak_start!r}")
    if peak_start and not peak_force_bins:
        raise ValueError("`peak_start` sets where the peaks are counted from: it needs `peak_force_bins` > 0")
    if n_samples != 0:  # Monte Carlo needs two samples for a standard deviation
        try:
            check_count("n_samples", n_samples, minimum=2)
        except ValueError:
            raise ValueError(
                f"`n_samples` must be 0 (no Monte Carlo) or an integer >= 2, got {n_samples!r}"
            ) from None
        key = jax.random.key(0) if key is None else key
        check_monte_carlo_options(  # before SL: fail at once
            n_samples, chunk_size, checkpoint, resume, key=key, checkpoint_every=checkpoint_every
        )
    system, kw, mc_every, sl_every = _setup(p, dt, periods, n_saves, sl_refine)
    saved = dt * mc_every * np.arange(kw["n_steps"] // mc_every + 1)  # s, Monte Carlo's saved times
    first_peak = int(np.argmin(np.abs(saved - peak_start)))  # the peaks' start: the nearest save
    if peak_force_bins and first_peak == len(saved) - 1:
        raise ValueError(
            f"`peak_start` ({peak_start:g} s) is nearest the last Monte Carlo save ({saved[-1]:g} s): the peaks "
            f"need saved times after it (saves every {saved[1]:g} s)"
        )
    sl = {c.name: solve_moments(system, criterion=c, save_every=sl_every, **kw) for c in criteria}
    mc = None
    if n_samples:
        peaks, histogram_times = {}, ()
        if peak_force_bins:
            peaks, histogram_times = peak_force_bins_of(
                sl[criteria[0].name], peak_force_bins, saved, first_peak
            )
        mc = monte_carlo(
            system,
            n_samples=n_samples,
            key=key,
            chunk_size=chunk_size,
            progress=progress,
            save_every=mc_every,
            checkpoint=checkpoint,
            checkpoint_every=checkpoint_every,
            resume=resume,
            peaks=peaks,
            histogram_times=histogram_times,
            peak_start=float(saved[first_peak]) if first_peak else None,
            **kw,
        )
    sl_peaks = None
    if peak_force_bins:
        sl_peaks = sl_peak_estimates(system, kw, criteria[0], mc, start=float(saved[first_peak]))
    settings = dict(
        n_samples=n_samples,
        periods=periods,
        n_steps=kw["n_steps"],
        t_end_s=kw["n_steps"] * dt,
        criteria=[c.name for c in criteria],
        mc_save_every=mc_every,
        sl_save_every=sl_every,
        sl_refine=mc_every // sl_every,
        peak_force_bins=peak_force_bins,
    )
    if peak_force_bins:
        settings["peak_start_s"] = float(saved[first_peak])
    return PlanetaryStudy(p, sl, mc, dt, carrier_period(p), settings, sl_peaks)


def sl_peak_estimates(
    system, kw: dict, criterion: AbstractCriterion, mc: MonteCarloResult, start: float | None = None
) -> dict:
    """SL's estimate of each meshing force's peak at the Monte Carlo's peak levels (the bins' upper edges) and
    histogram times, the peaks taken from ``start`` (s): ``{quantity: {"levels", "probability", "lower_bound"}}``
    (arrays (n_bins,), (n_hist, n_bins) and (n_hist, n_bins)), from a run saved every step with
    ``deflection_lag`` (crossings between steps; :meth:`pgtjax.MomentResult.peak_exceedance`)."""
    run = {k: v for k, v in kw.items() if k != "observables"}  # only the meshes are needed, at every step
    sl = solve_moments(system, criterion=criterion, save_every=1, deflection_lag=True, **run)
    rows = np.argmin(np.abs(np.asarray(sl.times)[None, :] - np.asarray(mc.histogram_times)[:, None]), axis=1)
    out = {}
    for quantity, edges in mc.peak_edges.items():
        levels = np.asarray(edges)[1:]  # the edges start at 0 (peak_force_bins_of)
        estimate = sl.peak_exceedance(quantity, levels, system=system, start=start)
        out[quantity] = dict(
            levels=levels,
            probability=np.asarray(estimate.probability)[rows],
            lower_bound=np.asarray(estimate.lower_bound)[rows],
        )
    return out


#: the peak histograms' range, from 0 N to SL's largest |mean| + PEAK_FORCE_STDS std of each meshing force
PEAK_FORCE_STDS = 8.0
#: the peak histograms are reported at this many evenly spaced saved times, the last one included
PEAK_FORCE_TIMES = 20


def peak_force_bins_of(sl: MomentResult, bins: int, saved_times, first: int = 0) -> tuple[dict, np.ndarray]:
    """``(peaks, histogram_times)`` for :func:`pgtjax.monte_carlo`: ``bins`` bins per meshing force from 0 N
    to SL's largest ``|mean| + PEAK_FORCE_STDS std`` over the run (``sl``), and ``PEAK_FORCE_TIMES`` of the
    Monte Carlo's ``saved_times`` (s) from the ``first`` on (the peaks' start), evenly spaced, the last
    included. A sample whose peak goes beyond that edge is not counted (:func:`peak_force_summary` reports how
    many were not)."""
    upper = np.max(np.abs(np.asarray(sl.force_mean)) + PEAK_FORCE_STDS * np.asarray(sl.force_std), axis=0)
    peaks = {
        f"force:{name}": np.linspace(0.0, max(float(top), 1.0), bins + 1)
        for name, top in zip(sl.contact_names, upper)
    }
    times = np.asarray(saved_times)
    picks = np.unique(np.round(np.linspace(first, len(times) - 1, PEAK_FORCE_TIMES + 1)[1:]).astype(int))
    return peaks, times[picks]


def peak_force_summary(study: PlanetaryStudy) -> dict | None:
    """Per meshing force, quantiles of its peak (largest magnitude) over the run: the upper edge of the bin
    where the Monte Carlo's cumulative count reaches the quantile (within one bin width above it), where at
    least 10 samples lie beyond it; None without peak histograms."""
    mc = study.mc
    if mc is None or not mc.peak_histograms:
        return None
    levels = {"median": 500, "q90": 900, "q99": 990, "q999": 999}  # per mille
    per_mesh = {}
    for quantity, counts in mc.peak_histograms.items():
        edges = np.asarray(mc.peak_edges[quantity])
        cumulative = np.cumsum(np.asarray(counts)[-1])
        entry = {"bin_width_N": float(edges[1] - edges[0]), "top_edge_N": float(edges[-1])}
        entry["beyond_top_edge_fraction"] = float((mc.n_samples - cumulative[-1]) / mc.n_samples)
        # SL's estimate and its lower bound at the same levels (the bins' upper edges), by the end: ideally
        # 1 - the quantile
        sl_end = None if study.sl_peaks is None else study.sl_peaks[quantity]
        reach = {"sl_reach_probability": {}, "sl_lower_bound_reach_probability": {}}
        for label, per_mille in levels.items():
            # whole numbers of samples (at most n_samples, so doubles hold them exactly): the sample count the
            # quantile needs below it, and the 10 beyond it that make it worth stating
            needed = -(-per_mille * mc.n_samples // 1000)
            reached = np.nonzero(cumulative >= needed)[0]
            stated = mc.n_samples - needed >= 10 and reached.size
            entry[f"{label}_N"] = float(edges[reached[0] + 1]) if stated else None
            for key, field in zip(reach, ("probability", "lower_bound")):
                reach[key][label] = (
                    float(sl_end[field][-1][reached[0]]) if stated and sl_end is not None else None
                )
        if sl_end is not None:
            entry.update(reach)
        per_mesh[quantity.split(":", 1)[1]] = entry
    return dict(
        note="peak (largest magnitude) of each meshing force of each sample over every step from "
        f"t = {_peak_start(mc):g} s to the end of the run; each quantile is the upper edge of the bin where the "
        "Monte Carlo's cumulative count reaches it, so within one bin width above it (null where fewer than 10 "
        "samples lie beyond it, or where it lies beyond the top edge); sl_reach_probability: SL's estimate of the probability "
        "that the peak reaches each quantile stated (1 - the quantile if SL and Monte Carlo agreed; SL counts "
        "the crossings between steps as independent, so it is above that where they come in clumps); "
        "sl_lower_bound_reach_probability: SL's bound from below of the same probability (the largest probability of being "
        "beyond the level at one step), close to the truth where crossings come in long clumps",
        time_s=float(mc.histogram_times[-1]),
        n_samples=mc.n_samples,
        per_mesh=per_mesh,
        units=dict(n_samples="1 (count)"),
    )


def _peak_start(mc: MonteCarloResult) -> float:
    """The time (s) the Monte Carlo's peaks are taken from."""
    return float(mc.times[0]) if mc.peak_start is None else float(mc.peak_start)


def _same_peaks(mc: MonteCarloResult, a: str, b: str) -> bool:
    """Whether two meshes' peak curves are the same: bins equal to rounding (the planets of a symmetric train,
    whose SL forces, and so the bins, agree to rounding) and the same counts in every bin."""
    return bool(
        np.allclose(np.asarray(mc.peak_edges[a]), np.asarray(mc.peak_edges[b]), rtol=1e-9, atol=0.0)
        and np.array_equal(np.asarray(mc.peak_histograms[a]), np.asarray(mc.peak_histograms[b]))
    )


def peak_force_figure(study: PlanetaryStudy):
    """The probability that each meshing force's peak (its largest magnitude since the peaks' start) has reached
    a level, by the end of the run (solid) and by mid-window (dashed), from the Monte Carlo's peak histograms;
    None without them."""
    mc = study.mc
    if mc is None or not mc.peak_histograms:
        return None
    groups = {"sun-planet meshes": "force:sun", "ring-planet meshes": "force:ring"}
    fig = plots.panel_grid_figure((11, 4.4))
    axes = np.atleast_1d(fig.subplots(1, len(groups), sharey=True))
    times = np.asarray(mc.histogram_times)
    rows = {len(times) - 1: "-", (len(times) - 1) // 2: "--"}
    for ax, (title, prefix) in zip(axes, groups.items()):
        # meshes whose counts and bins are equal (the planets of a symmetric train) drawn once, named together
        same: dict[str, list[str]] = {}
        for quantity in (q for q in mc.peak_histograms if q.startswith(prefix)):
            twin = next((q for q in same if _same_peaks(mc, q, quantity)), quantity)
            same.setdefault(twin, []).append(quantity.split(":", 1)[1])
        certain = []  # the highest level every sample's peak reached, for the axis's left end
        for k, (quantity, names) in enumerate(same.items()):
            exceedance = mc.peak_exceedance(quantity)
            levels = exceedance.levels
            for row, style in rows.items():
                p = exceedance.probability[row]
                keep = p > 0
                label = f"{', '.join(names)}{' (the same counts)' if len(names) > 1 else ''}, by t = {times[row]:.3g} s"
                ax.semilogy(levels[keep] / 1e3, p[keep], style, color=f"C{k}", label=label)
                certain.append(np.concatenate([[0.0], levels[p >= 1.0]])[-1] / 1e3)
            if study.sl_peaks is not None:  # SL's estimate by the end, thin and dotted, above its lower bound
                estimate = study.sl_peaks[quantity]
                p = estimate["probability"][-1]
                keep = p >= 1.0 / mc.n_samples
                ax.semilogy(estimate["levels"][keep] / 1e3, p[keep], ":", color=f"C{k}", lw=1.5,
                            label=f"{', '.join(names)}, SL's estimate by t = {times[-1]:.3g} s")  # fmt: skip
                ax.fill_between(estimate["levels"][keep] / 1e3, estimate["lower_bound"][-1][keep], p[keep],
                                color=f"C{k}", alpha=0.12, lw=0,
                                label=f"{', '.join(names)}, SL: from its lower bound to its estimate")  # fmt: skip
        ax.set_xlim(left=max(0.9 * min(certain), 0.0))
        ax.set_title(title)
        ax.set_xlabel("meshing force level (kN)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    axes[0].set_ylabel("probability that the peak has reached the level")
    sl_note = (
        "\nSL's estimate (dotted): crossings between steps counted as independent, conservative where they clump;"
        "\nshaded down to SL's lower bound, the largest probability of being beyond the level at one step"
        if study.sl_peaks
        else ""
    )
    fig.suptitle(
        f"Peak meshing forces (largest magnitude over every step since t = {_peak_start(mc):g} s): Monte Carlo, "
        f"{mc.n_samples:,} samples (smallest probability shown {1 / mc.n_samples:.1g}){sl_note}"
    )
    return fig


def parameter_sweep(
    params, variants: dict, *, dt=0.0027, periods=1.0, n_saves=2000, sl_refine=1, say=None
) -> dict[str, MomentResult]:
    """SL + recursion for each ``{label: PlanetaryParams}`` (rim thickness, supports...), saved as
    :func:`run_study` saves SL; ``say(message)`` is called before each variant."""
    out = {}
    for k, (label, p) in enumerate(variants.items()):
        if say is not None:
            say(f"  {label} ({k + 1} of {len(variants)})")
        system, kw, _, sl_every = _setup(p, dt, periods, n_saves, sl_refine)
        out[label] = solve_moments(system, save_every=sl_every, **kw)
    return out


def rim_thickness_variants(params=None, thicknesses=(0.087, 0.128, 0.168)) -> dict:
    """Thesis 3.7.4: rim thickness (m) with the pitch circle on the rim's inner face."""
    p = pm.default_params() if params is None else params
    out = {}
    for h in thicknesses:
        # the centre radius follows the thickness (PlanetaryParams.elastic_ring)
        out[f"t_r = {h * 1e3:.0f} mm"] = eqx.tree_at(
            lambda q: q.ring.thickness, p, jnp.asarray(h, jnp.float64)
        )
    return out


def support_variants(params=None, counts=(3, 6, 9)) -> dict:
    """Equally spaced bolt supports (each count must divide the number of ring elements)."""
    p = pm.default_params() if params is None else params
    n_el = p.ring.n_elements
    out = {}
    for count in counts:
        if n_el % count:
            raise ValueError(f"support count {count} must divide n_elements = {n_el}")
        nodes = tuple(range(0, n_el, n_el // count))
        ring = dataclasses.replace(p.ring, support_nodes=nodes)
        out[f"{count} supports"] = eqx.tree_at(lambda q: q.ring, p, ring)
    return out


def modal_table(params=None) -> list[dict]:
    """Natural frequencies (Hz) of the full model with the meshes closed at t = 0, and mode types."""
    p = pm.default_params() if params is None else params
    system = pm.build(p)
    lay = pm.layout(p)
    modes = modal_analysis(system)
    return [
        dict(mode=i + 1, frequency_hz=float(f), type=pm.mode_type(p, lay, system.mass, modes.shapes[:, i]))
        for i, f in enumerate(modes.frequencies_hz)
    ]


def sensitivities(
    params=None, *, dt=0.0027, n_steps=200, node=2, mesh="ring_planet1", relative_step=1e-2
) -> dict:
    """Derivatives of the std, at the end of ``n_steps`` steps, of ring node ``node``'s radial displacement
    and of the meshing force of ``mesh`` with respect to the rim thickness and the bolts' radial stiffness:
    reverse-mode autodiff through SL + recursion (one pass per quantity), with Richardson-extrapolated
    central differences for comparison, and the elasticities ``(x / q) dq/dx`` (dimensionless: the relative
    change of q per relative change of x).

    The reference is ``(4 D(h) - D(2h)) / 3`` with ``D(h)`` the central difference at ``h = relative_step x``
    (truncation O(h^4)). Its accuracy is bounded by the SL values' round-off, ~1e-11 relative (jit and eager
    evaluations differ by that much), divided by h: for the default model's mesh force, plain central
    differences at 0.05-0.2 % scatter by 1e-5 around autodiff, while the extrapolation from 1 % and 2 % agrees
    with it to 2e-7 (jit) and 2.4e-6 (eager), with no trend left from truncation."""
    p = pm.default_params() if params is None else params
    lay = pm.layout(p)
    index = lay.ring_start + 3 * node
    system = pm.build(p)
    contact = system.contact_names().index(mesh) if mesh in system.contact_names() else None
    if contact is None:
        raise ValueError(f"`mesh` must be one of {', '.join(system.contact_names())}, got {mesh!r}")
    u_eq = static_equilibrium(system)

    def response(x):
        thickness, support = x
        q = eqx.tree_at(lambda z: (z.ring.thickness, z.ring.k_support_radial), p, (thickness, support))
        r = solve_moments(
            pm.build(q),
            dt=dt,
            n_steps=n_steps,
            save_every=n_steps,
            rtol=1e-13,
            initial_displacement=u_eq,
            initial_covariance=pm.wind_filter_stationary_covariance(q, lay),
        )
        return jnp.stack([r.std_u[-1, index], r.force_std[-1, contact]])

    @jax.jit
    def jacobian(x):
        # one reverse pass per quantity, in a loop: jax.jacrev vmaps them, a batched program that took longer
        # to compile (37.8 s against 29.6 s on a 6-element ring, 2-core CPU, 2026-11-27)
        values, pullback = jax.vjp(response, x)
        (jac,) = jax.lax.map(pullback, jnp.eye(values.shape[0], dtype=values.dtype))
        return jac

    x = jnp.stack([p.ring.thickness, jnp.asarray(p.ring.k_support_radial).reshape(-1)[0]])
    value = response(x)
    jac = jacobian(x)  # (quantity, parameter)

    def central(i, h):
        e = jnp.zeros(2).at[i].set(h)
        return (response(x + e) - response(x - e)) / (2 * h)

    steps = [float(x[i]) * relative_step for i in range(2)]
    fd = jnp.stack([(4.0 * central(i, h) - central(i, 2.0 * h)) / 3.0 for i, h in enumerate(steps)], axis=1)
    t_end = f"{n_steps * dt:.3f} s"
    return dict(
        time_s=n_steps * dt,
        quantity_units=["m", "N"],
        parameter_units=["m", "N/m"],
        quantities=[
            f"std of ring_node{node}_radial at t = {t_end} (m)",
            f"std of the {mesh} meshing force at t = {t_end} (N)",
        ],
        value=[float(v) for v in value],
        parameters=["rim thickness (m)", "bolt radial stiffness (N/m)"],
        gradient=np.asarray(jac).tolist(),
        central_difference=np.asarray(fd).tolist(),
        elasticity=np.asarray(jac * x[None, :] / value[:, None]).tolist(),
    )


# ---------------------------------------------------------------------------------------------- output


def _dof_series(result, name):
    j = result.dof(name)
    return np.asarray(result.mean_u[:, j]), np.asarray(result.std_u[:, j])


def _obs_series(result, name):
    j = result.observable(name)
    return np.asarray(result.mean_obs[:, j]), np.asarray(result.std_obs[:, j])


def _force_series(result, name):
    j = result.contact(name)
    mean = np.asarray(result.force_mean[:, j])
    return mean, mean**2 + np.asarray(result.force_std[:, j]) ** 2  # mean, mean square


ROUNDOFF_LEVEL = 1e-5  # peak std below this fraction of the largest of the same unit: zero but for round-off


def roundoff_dofs(result: MomentResult | MonteCarloResult) -> list[str]:
    """DOFs that the wind does not excite above round-off: the symmetric train (planets equally spaced,
    meshing in phase, bolts in a 3-fold pattern; thesis Sec. 3.7) leaves the sun and carrier translations and
    the planets' radial motions 1e-7 below the other DOFs of the same unit, where the solvers' round-off
    (~1e-14 m) is a visible part of the std. A design without that symmetry normally has none."""
    peak = np.max(np.asarray(result.std_u), axis=0)
    units = np.asarray(result.dof_units)
    return [
        n
        for i, n in enumerate(result.dof_names)
        if peak[i] < ROUNDOFF_LEVEL * np.max(peak[units == units[i]])
    ]


def _z_scores(sl: MomentResult, mc: MonteCarloResult, what: str):
    """|SL - MC| of the mean and of the std of ``what`` (``"u"`` or ``"force"``) in units of MC's standard
    errors (:meth:`MonteCarloResult.standard_error`: normal approximation, optimistic for the std of a
    non-Gaussian quantity such as the force of a mesh that loses contact), after t0."""
    fields = {"u": ("mean_u", "std_u"), "force": ("force_mean", "force_std")}[what]
    sl_mean, sl_std, mc_mean, mc_std = (np.asarray(getattr(r, f))[1:] for r in (sl, mc) for f in fields)
    se_mean, se_std = (np.maximum(np.asarray(a)[1:], 1e-300) for a in mc.standard_error(what))
    return np.abs(sl_mean - mc_mean) / se_mean, np.abs(sl_std - mc_std) / se_std


def error_summary(study: PlanetaryStudy, criterion: str | None = None) -> dict:
    """Largest |SL - MC| over time of the mean and std of every DOF and of every meshing force, in units of
    the MC standard error, at the Monte Carlo's saved times (SL ``criterion``, default the first run). DOFs
    at round-off level in both SL and MC (:func:`roundoff_dofs`) and the wind-filter state are not
    compared."""
    if study.mc is None:
        return {}
    sl, mc = study.sl_on_mc_grid(criterion), study.mc
    if sl.times.shape != mc.times.shape or not np.allclose(
        np.asarray(sl.times), np.asarray(mc.times), rtol=0.0, atol=1e-9 * study.carrier_period
    ):
        raise ValueError("SL and MC saved times differ: the study's grids are inconsistent")
    quiet = sorted(set(roundoff_dofs(study.sl_result(criterion))) & set(roundoff_dofs(mc)))
    compared = [i for i, n in enumerate(sl.dof_names) if n not in quiet and n != "wind_filter_chi"]
    z_mean, z_std = _z_scores(sl, mc, "u")
    f_mean, f_std = _z_scores(sl, mc, "force")

    def worst(z, names, columns):
        return {names[i]: float(np.max(z[:, i])) for i in columns}

    def extremes(z_m, z_s, names, columns):
        wm, ws = worst(z_m, names, columns), worst(z_s, names, columns)
        return dict(
            max_mean_error_in_se=max(wm.values(), default=None),
            max_std_error_in_se=max(ws.values(), default=None),
            fraction_within_3_se=float(np.mean((z_m[:, columns] < 3) & (z_s[:, columns] < 3)))
            if columns
            else None,
            per_mean=wm,
            per_std=ws,
        )

    dofs = extremes(z_mean, z_std, sl.dof_names, compared)
    forces = extremes(f_mean, f_std, sl.contact_names, list(range(len(sl.contact_names))))
    return dict(
        unit="Monte Carlo standard errors",
        units=dict(
            n_samples="1 (count)",
            dofs_compared="1 (count)",
            fraction_of_dof_time_points_within_3_se="1 (fraction)",
            fraction_of_mesh_time_points_within_3_se="1 (fraction)",
            contact_loss_probability_max="1 (probability)",
        ),
        criterion=sl.criterion,
        n_samples=mc.n_samples,
        dofs_compared=len(compared),
        roundoff_dofs_not_compared=quiet,
        max_mean_error_in_se=dofs["max_mean_error_in_se"],
        max_std_error_in_se=dofs["max_std_error_in_se"],
        fraction_of_dof_time_points_within_3_se=dofs["fraction_within_3_se"],
        mesh_force=dict(
            max_mean_error_in_se=forces["max_mean_error_in_se"],
            max_std_error_in_se=forces["max_std_error_in_se"],
            fraction_of_mesh_time_points_within_3_se=forces["fraction_within_3_se"],
            per_mesh_mean=forces["per_mean"],
            per_mesh_std=forces["per_std"],
        ),
        contact_loss_probability_max=float(np.max(mc.contact_loss_probability)),
        per_dof_mean=dofs["per_mean"],
        per_dof_std=dofs["per_std"],
    )


# ------------------------------------------------------------------------------ inputs and text reports


def load_params(
    path=None, *, ring_model: str | None = None, n_elements: int | None = None
) -> pm.PlanetaryParams:
    """Parameters from a TOML file (layout of ``planetary.toml``; ``None``: the embedded thesis set), with the
    ring model and the number of ring elements overridden when given (``None``: the file's)."""
    overrides = {}
    if ring_model:
        overrides["ring_model"] = ring_model
    if n_elements is not None:
        overrides["n_elements"] = n_elements
    return pm.load_params(path, **overrides) if path is not None else pm.default_params(**overrides)


def mean_rotor_torque(params: pm.PlanetaryParams) -> float:
    """The mean aerodynamic torque on the carrier (N m, thesis Eq. 3.28 at the mean wind speed): the load of
    the train, set through ``wind.mean_wind_speed`` (and the rotor entries of ``[wind]``)."""
    return float(params.wind.mean_torque(params.mesh.carrier_speed))


def format_header(
    params: pm.PlanetaryParams,
    *,
    periods: float,
    dt: float,
    criteria,
    n_samples: int,
    n_saves=2000,
    sl_refine=1,
) -> str:
    """One line describing a :func:`run_study` call (the CLI's first line): the simulated time as run (a whole
    number of save intervals, so slightly short of ``periods`` carrier periods)."""
    n_steps, mc_every, _ = _grid(params, dt, periods, n_saves, sl_refine)
    t_end = n_steps * dt
    return (
        f"pgtjax planetary gear train (thesis ch. 3): {params.ring_model} ring, {params.n_planets} planets; "
        f"{n_steps} steps of {dt:g} s = {t_end:.2f} s ({t_end / carrier_period(params):.3f} carrier periods of "
        f"{carrier_period(params):.2f} s); mean rotor torque {mean_rotor_torque(params) / 1e3:.1f} kN m "
        f"(wind {float(params.wind.mean_wind_speed):g} m/s); SL {', '.join(c.name for c in criteria)}, "
        + (f"MC {n_samples} samples saved every {_steps(mc_every)}" if n_samples else "no MC")
    )


def _steps(n: int) -> str:
    return "step" if n == 1 else f"{n} steps"


def check_support_counts(params: pm.PlanetaryParams, counts) -> tuple[int, ...]:
    """``counts`` (each a whole number >= 2 dividing the ring elements), or by default those of 3, 6, 9 that
    divide them; a ``ValueError`` names the others."""
    n_elements = params.ring.n_elements
    if counts is None:
        return tuple(c for c in (3, 6, 9) if n_elements % c == 0)
    bad = [c for c in counts if not isinstance(c, int) or c < 2 or n_elements % c]
    if bad:
        raise ValueError(
            f"`support_counts` must be whole numbers >= 2 dividing the {n_elements} ring elements; {bad} are not"
        )
    return tuple(counts)


def standard_sweeps(
    params: pm.PlanetaryParams,
    *,
    dt=0.0027,
    periods=1.0,
    n_saves=2000,
    sl_refine=1,
    thicknesses=(0.087, 0.128, 0.168),
    support_counts=None,
    say=None,
) -> dict | None:
    """The SL sweeps of the thesis (rim thickness ``thicknesses`` in m, default 87 / 128 / 168 mm as in Figs.
    3.12-3.15; ``support_counts`` equally spaced bolts, each dividing the number of ring elements; default:
    those of 3, 6, 9 that do), ``{title: {label: MomentResult}}`` for :func:`write_outputs`; ``None`` for a rigid ring.
    ``say(message)`` is called before each sweep."""
    if params.ring_model != "elastic":
        return None
    say = say or (lambda msg: None)
    kw = dict(dt=dt, periods=periods, n_saves=n_saves, sl_refine=sl_refine, say=say)
    sweeps = {}
    if thicknesses:
        say(f"rim thickness {' / '.join(f'{h * 1e3:g}' for h in thicknesses)} mm (SL)")
        variants = rim_thickness_variants(params, thicknesses)
        sweeps["Rim thickness: thesis Figs. 3.12-3.15"] = parameter_sweep(params, variants, **kw)
    support_counts = check_support_counts(params, support_counts)
    if support_counts:
        say(f"bolt supports {' / '.join(map(str, support_counts))} (SL)")
        variants = support_variants(params, tuple(support_counts))
        sweeps["Supports: number of bolts"] = parameter_sweep(params, variants, **kw)
    return sweeps


def elastic_sensitivities(params: pm.PlanetaryParams, *, dt=0.0027, say=None) -> dict | None:
    """:func:`sensitivities` for an elastic ring, ``None`` for a rigid one (no rim thickness or bolt
    stiffness); ``say(message)`` is called before the computation."""
    if params.ring_model != "elastic":
        return None
    n_steps = 200  # short: the gradient and its central-difference check cost several SL runs
    (say or (lambda msg: None))(
        "sensitivities by autodiff (checked by extrapolated central differences), of a separate SL run of "
        f"{n_steps} steps from the static equilibrium"
    )
    return sensitivities(params, dt=dt, n_steps=n_steps)


def _percent(fraction: float) -> str:
    """A fraction as a percentage with two decimals, never rounded up to 100.00 % when some points fail."""
    text = f"{100 * fraction:.2f} %"
    return "> 99.99 %" if fraction < 1.0 and text == "100.00 %" else text


def format_error_summary(e: dict) -> str:
    """Plain-text summary of :func:`error_summary` (SL against MC in MC standard errors)."""
    f = e["mesh_force"]
    quiet = ", ".join(e["roundoff_dofs_not_compared"]) or "none"
    return (
        f"SL ({e['criterion']}) vs MC ({e['n_samples']} samples), in MC standard errors (s.e.):\n"
        f"  {e['dofs_compared']} DOFs (all but the wind-filter state and those zero by symmetry): "
        f"{_percent(e['fraction_of_dof_time_points_within_3_se'])} "
        f"of (DOF, time) points within 3 s.e.; largest deviation {e['max_mean_error_in_se']:.1f} "
        f"(mean), {e['max_std_error_in_se']:.1f} (std)\n"
        f"  meshing forces: {_percent(f['fraction_of_mesh_time_points_within_3_se'])} within 3 s.e.; "
        f"largest deviation {f['max_mean_error_in_se']:.1f} (mean), "
        f"{f['max_std_error_in_se']:.1f} (std)\n"
        f"  max contact-loss probability {e['contact_loss_probability_max']:.3g}; "
        f"zero by symmetry (not compared): {quiet}"
    )


def format_sensitivities(sens: dict) -> str:
    """Plain-text lines of :func:`sensitivities`: gradient, extrapolated central differences, elasticities."""
    return "\n".join(
        f"d {q} / d(rim thickness (m), bolt k_r (N/m)): autodiff [{grad[0]:.8e}, {grad[1]:.8e}], "
        f"extrapolated central differences [{fd[0]:.8e}, {fd[1]:.8e}]; "
        f"elasticities [{el[0]:+.3f}, {el[1]:+.3f}]"
        for q, grad, fd, el in zip(
            sens["quantities"], sens["gradient"], sens["central_difference"], sens["elasticity"]
        )
    )


def format_modal_table(rows: list[dict]) -> str:
    """Plain-text table of :func:`modal_table`."""
    lines = [f"{'mode':>4s} {'f (Hz)':>12s}  type"]
    lines += [f"{r['mode']:4d} {r['frequency_hz']:12.3f}  {r['type']}" for r in rows]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------- figures

# Thesis App. A DOFs beyond FIGURE_DOFS, in the order shown when they carry more than round-off.
APPENDIX_DOFS = (
    ("ring_node0_radial", "m"),
    ("ring_node1_radial", "m"),
    ("ring_node2_radial", "m"),
    ("ring_node2_rotation", "rad"),
    ("planet1_u", "m"),
    ("sun_x", "m"),
    ("carrier_x", "m"),
    ("planet1_xi", "m"),
    ("ring_x", "m"),
    ("ring_u", "m"),
)
MC_MARKERS = dict(color="k", ls="none", marker="o", ms=2.0, mfc="white", mew=0.6)  # hollow: SL shows through


def _present(quantities, result) -> list[tuple[str, str]]:
    """The (name, unit) pairs that are DOFs of this model (the rigid-ring model has no ring nodes)."""
    return [q for q in quantities if q[0] in result.dof_names]


_STANDARD_ERROR_KIND = {"_dof_series": "u", "_obs_series": "obs", "_force_series": "force"}


def _sl_mc_curves(study: PlanetaryStudy, series, names, with_mc=True) -> tuple[dict, dict]:
    """(times, curves) of every SL criterion and of MC, for plots; MC's curves carry their standard errors
    (4-tuples, :func:`pgtjax.plots.mean_std_figure`)."""
    times, curves = {}, {}
    for c, r in study.sl.items():
        times[f"SL {c}"], curves[f"SL {c}"] = np.asarray(r.times), {n: series(r, n) for n in names}
    if with_mc and study.mc is not None:
        mc = study.mc
        what = _STANDARD_ERROR_KIND[series.__name__]
        se_mean, se_std = (np.asarray(a) for a in mc.standard_error(what))
        index = {"u": mc.dof, "obs": mc.observable, "force": mc.contact}[what]
        times["MC"] = np.asarray(mc.times)
        curves["MC"] = {n: (*series(mc, n), se_mean[:, index(n)], se_std[:, index(n)]) for n in names}
    return times, curves


def mesh_period(study: PlanetaryStudy) -> float:
    """The mesh period 2 pi / omega_m (s): long runs are drawn per mesh cycle."""
    return 2.0 * np.pi / float(study.params.mesh.mesh_frequency)


def dof_figure(
    study: PlanetaryStudy,
    quantities=FIGURE_DOFS,
    title="Planetary gear train: SL vs MC (thesis Figs. 3.5-3.8)",
    subtitle="",
):
    """Mean and std of DOFs: SL as lines, MC as markers with 95 % error bars; a run of many mesh cycles per
    mesh cycle (the range within each cycle as a band, cycle averages as the line and the markers). None if
    no DOF is present."""
    quantities = _present(quantities, study.sl_result())
    if not quantities:
        return None
    times, curves = _sl_mc_curves(study, _dof_series, [n for n, _ in quantities])
    return plots.mean_std_figure(
        times,
        curves,
        quantities,
        title=title,
        styles={"MC": MC_MARKERS},
        subtitle=subtitle,
        cycle=mesh_period(study),
    )


def appendix_figure(study: PlanetaryStudy, max_panels: int = 6):
    """Further DOFs of thesis App. A; the DOFs at round-off level are named in the subtitle instead."""
    quiet = roundoff_dofs(study.sl_result())
    shown = [q for q in _present(APPENDIX_DOFS, study.sl_result()) if q[0] not in quiet][:max_panels]
    subtitle = ("at round-off level, zero by symmetry: " + ", ".join(quiet)) if quiet else ""
    return dof_figure(study, shown, title="Further DOFs (thesis App. A)", subtitle=subtitle)


def contact_point_figure(study: PlanetaryStudy):
    """The ring at the moving contact point of planet 1 (Fig. 3.9); None without the observables."""
    names = list(study.sl_result().observable_names)
    if not names:
        return None
    times, curves = _sl_mc_curves(study, _obs_series, names)
    return plots.mean_std_figure(
        times,
        curves,
        [(n, "m") for n in names],
        styles={"MC": MC_MARKERS},
        title="Ring at the moving contact point of planet 1 (thesis Fig. 3.9)",
        cycle=mesh_period(study),
    )


#: the meshing forces' sign, stated on their figures (the thesis's figures do not show it)
FORCE_SIGN_NOTE = "signed as the mesh deflections: under the rotor torque every mesh's force is negative"


def mesh_force_figure(study: PlanetaryStudy, meshes=("sun_planet1", "ring_planet1")):
    """Mean and mean square of the equivalent meshing forces over the whole run (Figs. 3.10-3.11): per mesh
    cycle (its range as a band around the cycle average; the thesis's figures draw every cycle, which at
    this width only shows a solid band), SL against MC's cycle averages."""
    times, curves = _sl_mc_curves(study, _force_series, list(meshes))
    return plots.mean_std_figure(
        times,
        curves,
        [(n, "N") for n in meshes],
        second="mean square",
        styles={"MC": MC_MARKERS},
        title="Equivalent meshing forces (thesis Figs. 3.10-3.11)",
        subtitle=FORCE_SIGN_NOTE,
        cycle=mesh_period(study),
    )


def mesh_force_zoom_figure(study: PlanetaryStudy, meshes=("sun_planet1", "ring_planet1"), mesh_periods=5.0):
    """The meshing forces over ``mesh_periods`` mesh periods (fewer if the run is shorter) at mid-run:
    SL against MC at every saved time."""
    times, curves = _sl_mc_curves(study, _force_series, list(meshes))
    t_all = np.asarray(study.sl_result().times)
    period = mesh_period(study)
    width = min(mesh_periods * period, float(t_all[-1] - t_all[0]))
    t0 = max(0.5 * (t_all[0] + t_all[-1]) - 0.5 * width, float(t_all[0]))
    for label in curves:
        keep = (times[label] >= t0) & (times[label] <= t0 + width)
        times[label] = times[label][keep]
        curves[label] = {n: tuple(np.asarray(a)[keep] for a in ms) for n, ms in curves[label].items()}
    return plots.mean_std_figure(
        times,
        curves,
        [(n, "N") for n in meshes],
        second="mean square",
        styles={"MC": MC_MARKERS},
        title=f"Meshing forces over {width / period:.3g} mesh periods: SL vs MC",
        subtitle=FORCE_SIGN_NOTE,
    )


def coinciding(results: dict[str, MomentResult], quantities, relative=1e-3) -> dict[str, float]:
    """The quantities whose mean and std agree across every variant of a sweep to ``relative`` of their
    range over time: ``{name: largest difference (SI unit)}``; their curves lie on top of each other."""
    out = {}
    for name, _ in quantities:
        series = [np.stack(_dof_series(r, name)) for r in results.values()]
        if len({a.shape for a in series}) != 1:
            continue
        stacked = np.stack(series)  # (variant, mean/std, time)
        difference = float(np.max(np.ptp(stacked, axis=0)))
        scale = float(np.max(np.ptp(stacked[0], axis=-1)))
        if difference <= relative * max(scale, 1e-300):
            out[name] = difference
    return out


def sweep_figure(results: dict[str, MomentResult], title: str, quantities=FIGURE_DOFS, cycle=None):
    """SL of each variant of a parameter sweep (rim thickness, supports), per mesh cycle when ``cycle``
    (s) is given; quantities that do not change across the variants are named in the subtitle."""
    quantities = _present(quantities, next(iter(results.values())))
    times = {label: np.asarray(r.times) for label, r in results.items()}
    curves = {label: {n: _dof_series(r, n) for n, _ in quantities} for label, r in results.items()}
    same = coinciding(results, quantities)
    subtitle = "; ".join(
        f"{n}: the {len(results)} curves coincide (largest difference {d * 1e6:.2g} µm)"
        for n, d in same.items()
    )
    return plots.mean_std_figure(times, curves, quantities, title=title, subtitle=subtitle, cycle=cycle)


SETTING_UNITS = dict(
    n_samples="1 (count)",
    periods="carrier periods",
    n_steps="1 (count of time steps)",
    mc_save_every="time steps",
    sl_save_every="time steps",
    sl_refine="1 (SL saves per MC save)",
    peak_force_bins="1 (count of bins per meshing force's peak histogram; 0: none)",
    peak_start_s="s (the Monte Carlo save the peaks are counted from)",
)
MODES_NOTE = (
    "natural frequencies of the model linearized with every mesh closed at t = 0; the lowest, of type "
    "'filter', is the first-order wind filter's state (its time constant as a frequency), not a structural mode"
)
SENSITIVITY_NOTE = (
    "at the end of a short run (200 steps) from the stationary wind state: the instantaneous std there, not a "
    "period average, so that the check by Richardson-extrapolated central differences (four more SL runs per "
    "parameter) stays cheap; pgtjax.design differentiates period averages"
)

#: one line for every file a planetary run writes (README.txt of the output folder)
FILE_INDEX = {
    "planetary_sl_*.npz": "SL + moment recursion (one file per criterion): mean and std of every DOF, velocity, "
    "mesh deflection and meshing force, and of the ring at planet 1's contact point; pgtjax.load_results",
    "planetary_mc.npz": "Monte Carlo of the nonlinear system, saved at the same times as SL: the same "
    "statistics with their standard errors; pgtjax.load_results",
    "monte_carlo.checkpoint*.npz": "the Monte Carlo's running statistics, for --resume after an interruption",
    "planetary_dofs.png": "thesis Figs. 3.5-3.8: mean and std of four DOFs, SL (lines, band = range within a "
    "mesh cycle) against MC (cycle averages, 95 % error bars)",
    "planetary_more_dofs.png": "thesis App. A: further DOFs; those at round-off level (zero by symmetry) are "
    "named, not drawn",
    "planetary_ring_contact.png": "thesis Fig. 3.9: the ring at planet 1's moving contact point, SL against MC",
    "planetary_mesh_forces.png": "thesis Figs. 3.10-3.11: mean and mean square of the sun-planet 1 and "
    "ring-planet 1 meshing forces over the run, per mesh cycle, SL against MC",
    "planetary_mesh_forces_zoom.png": "the meshing forces over 5 mesh periods at mid-run: SL against every MC "
    "save, 95 % error bars",
    "planetary_peak_forces.png": "with --peak-forces: the probability that each meshing force's peak (largest "
    "magnitude over every step since --peak-start) has reached a level, by mid-window and by the end (MC; SL's "
    "estimate dotted)",
    "planetary_rim_thickness.png": "thesis Figs. 3.12-3.15: SL for each rim thickness (--rim-thicknesses)",
    "planetary_supports.png": "SL for each number of equally spaced bolts (--support-counts)",
}


def _sweep_summary(results: dict[str, MomentResult]) -> dict:
    """Per variant and figure DOF: the extremes and time averages of the mean and std over the run (the
    response is periodic: one instant would say little)."""
    first = next(iter(results.values()))
    names = [n for n, _ in _present(FIGURE_DOFS, first)]
    variants = {}
    for label, r in results.items():
        variants[label] = {}
        for n in names:
            mean, std = _dof_series(r, n)
            if len(mean) > 1:  # the response over the run, after the start
                mean, std = mean[1:], std[1:]
            variants[label][n] = dict(
                unit=str(r.dof_units[r.dof(n)]),
                time_average_of_mean=float(np.mean(mean)),
                min_mean=float(np.min(mean)),
                max_mean=float(np.max(mean)),
                time_average_of_std=float(np.mean(std)),
                max_std=float(np.max(std)),
            )
    out = {"variants": variants}
    same = coinciding(results, _present(FIGURE_DOFS, first))
    if same:
        out["unchanged_across_variants"] = {
            "unit": "m",
            "note": "largest difference between the variants' mean and std curves",
            **same,
        }
    return out


def _sensitivity_summary(sens: dict) -> dict:
    """:func:`sensitivities` with a unit on every number."""
    entries = []
    for i, quantity in enumerate(sens["quantities"]):
        q_unit = sens["quantity_units"][i]
        derivatives = [
            dict(
                parameter=parameter,
                unit=f"{q_unit}/({sens['parameter_units'][j]})",
                autodiff=sens["gradient"][i][j],
                extrapolated_central_difference=sens["central_difference"][i][j],
                elasticity_ratio=sens["elasticity"][i][j],
            )
            for j, parameter in enumerate(sens["parameters"])
        ]
        entries.append(
            dict(quantity=quantity, value=dict(unit=q_unit, value=sens["value"][i]), derivatives=derivatives)
        )
    return dict(time_s=sens["time_s"], note=SENSITIVITY_NOTE, quantities=entries)


def summary(study: PlanetaryStudy, *, sweeps=None, modal=None, sens=None) -> dict:
    """What ``summary.json`` holds, every number with its unit (:mod:`pgtjax._summary`)."""
    out = dict(
        dt_s=study.dt,
        carrier_period_s=study.carrier_period,
        mesh_period_s=mesh_period(study),
        mean_rotor_torque_Nm=mean_rotor_torque(study.params),
        settings=dict(study.settings, units={k: u for k, u in SETTING_UNITS.items() if k in study.settings}),
        sl_vs_mc={c: error_summary(study, c) for c in study.sl} if study.mc is not None else None,
        roundoff_dofs=roundoff_dofs(study.sl_result()),
    )
    for title, results in (sweeps or {}).items():
        out[title.split(":")[0].lower().replace(" ", "_")] = _sweep_summary(results)
    if modal is not None:
        out["modes"] = dict(
            note=MODES_NOTE,
            units=dict(mode="1 (index, lowest frequency first)"),
            table=[dict(r, frequency_hz=float(f"{r['frequency_hz']:.6g}")) for r in modal],
        )
    if sens is not None:
        out["sensitivities"] = _sensitivity_summary(sens)
    peaks = peak_force_summary(study)
    if peaks is not None:
        out["peak_meshing_forces"] = peaks
    return out


def write_outputs(
    study: PlanetaryStudy,
    outdir,
    *,
    sweeps: dict | None = None,
    modal: list | None = None,
    sens: dict | None = None,
) -> list[Path]:
    """Labelled results (.npz), summary.json and PNG figures into ``outdir``."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    written = []
    attrs = dict(dt_s=study.dt, carrier_period_s=study.carrier_period, **study.settings)
    for crit, res in study.sl.items():
        written.append(save_results(outdir / f"planetary_sl_{crit}.npz", res, **attrs))
    if study.mc is not None:
        written.append(save_results(outdir / "planetary_mc.npz", study.mc, **attrs))
    figures = [
        ("planetary_dofs", lambda: dof_figure(study)),
        ("planetary_more_dofs", lambda: appendix_figure(study)),
        ("planetary_ring_contact", lambda: contact_point_figure(study)),
        ("planetary_mesh_forces", lambda: mesh_force_figure(study)),
    ]
    if study.mc is not None:
        figures.append(("planetary_mesh_forces_zoom", lambda: mesh_force_zoom_figure(study)))
        figures.append(("planetary_peak_forces", lambda: peak_force_figure(study)))
    for title, results in (sweeps or {}).items():
        slug = title.split(":")[0].lower().replace(" ", "_")
        build = functools.partial(sweep_figure, results, title, cycle=mesh_period(study))
        figures.append((f"planetary_{slug}", build))
    for name, build in figures:  # each figure is saved (and closed) as soon as it is drawn
        fig = build()
        if fig is not None:
            written.append(plots.save(fig, outdir / f"{name}.png"))
    written.append(
        write_summary(outdir / "summary.json", summary(study, sweeps=sweeps, modal=modal, sens=sens))
    )
    return written
