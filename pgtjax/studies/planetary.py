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
import json
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import plots
from ..deterministic import static_equilibrium
from ..linearization import solve_moments
from ..modal import modal_analysis
from ..models import planetary as pm
from ..models.ring import ring_interpolation, ring_nodal_inverse
from ..montecarlo import monte_carlo
from ..results import MomentResult, MonteCarloResult, save_results
from ..system import Observables

# Thesis node 3 (1-based) is our 0-based ring node 2.
FIGURE_DOFS = (("ring_node2_tangential", "m"), ("sun_u", "m"), ("carrier_u", "m"), ("planet1_eta", "m"))


@dataclasses.dataclass
class PlanetaryStudy:
    params: pm.PlanetaryParams
    sl: dict[str, MomentResult]
    mc: MonteCarloResult | None
    dt: float
    carrier_period: float
    settings: dict


def carrier_period(p: pm.PlanetaryParams) -> float:
    """T_c = 2 pi / omega_c (s)."""
    return float(2.0 * np.pi / p.mesh.carrier_speed)


def contact_point_observables(p: pm.PlanetaryParams, planet: int = 0) -> Observables:
    """Ring displacement (inward radial, tangential; m) at the moving contact point of a planet (Fig. 3.9)."""
    lay = pm.layout(p)
    psi = float(p.planet_angles()[planet])
    inverse = ring_nodal_inverse(p.ring)  # formed once, not at every time step

    def matrix(t):
        rows = ring_interpolation(p.ring, p.mesh.carrier_speed * t + psi, inverse)[:2]
        return jnp.zeros((2, lay.n_dof)).at[:, lay.ring_start: lay.ring_start + lay.n_ring].set(rows)

    return Observables(matrix, names=[f"ring_contact{planet + 1}_radial", f"ring_contact{planet + 1}_tangential"])


def _setup(p, dt, periods, n_saves, observables=True):
    system = pm.planetary(p)
    lay = pm.layout(p)
    n_steps = int(round(periods * carrier_period(p) / dt))
    save_every = max(n_steps // n_saves, 1)
    n_steps = save_every * max(n_steps // save_every, 1)
    kw = dict(dt=dt, n_steps=n_steps, save_every=save_every, initial_displacement=static_equilibrium(system),
              initial_covariance=pm.wind_filter_stationary_covariance(p, lay))
    if observables and p.ring_model == "elastic":
        kw["observables"] = contact_point_observables(p)
    return system, kw


def run_study(params=None, *, n_samples=500, dt=0.0027, periods=1.0, n_saves=200, criteria=("force",),
              key=None, chunk_size=5000, progress=True) -> PlanetaryStudy:
    """SL (each criterion) and MC over ``periods`` carrier periods; ``n_samples = 0`` skips MC."""
    p = pm.default_params() if params is None else params
    system, kw = _setup(p, dt, periods, n_saves)
    sl = {c: solve_moments(system, criterion=c, **kw) for c in criteria}
    mc = None
    if n_samples:
        mc = monte_carlo(system, n_samples=n_samples, key=jax.random.key(0) if key is None else key,
                         chunk_size=chunk_size, progress=progress, **kw)
    return PlanetaryStudy(p, sl, mc, dt, carrier_period(p),
                          dict(n_samples=n_samples, periods=periods, n_steps=kw["n_steps"], criteria=list(criteria)))


def parameter_sweep(params, variants: dict, *, dt=0.0027, periods=1.0, n_saves=200) -> dict[str, MomentResult]:
    """SL + recursion for each ``{label: PlanetaryParams}`` (rim thickness, supports...)."""
    out = {}
    for label, p in variants.items():
        system, kw = _setup(p, dt, periods, n_saves)
        out[label] = solve_moments(system, **kw)
    return out


def rim_thickness_variants(params=None, thicknesses=(0.087, 0.128, 0.168)) -> dict:
    """Thesis 3.7.4: rim thickness (m) with the pitch circle on the rim's inner face."""
    p = pm.default_params() if params is None else params
    out = {}
    for h in thicknesses:
        ring = eqx.tree_at(lambda r: (r.thickness, r.radius), p.ring, (jnp.asarray(h), p.ring_pitch_radius + h / 2))
        out[f"t_r = {h * 1e3:.0f} mm"] = eqx.tree_at(lambda q: q.ring, p, ring)
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
    system = pm.planetary(p)
    lay = pm.layout(p)
    modes = modal_analysis(system)
    return [dict(mode=i + 1, frequency_hz=float(f), type=pm.mode_type(p, lay, system.mass, modes.shapes[:, i]))
            for i, f in enumerate(modes.frequencies_hz)]


def sensitivities(params=None, *, dt=0.0027, n_steps=200, node=2, relative_step=1e-3) -> dict:
    """d std(ring node ``node`` radial displacement at the end) / d(rim thickness, bolt radial stiffness),
    by reverse-mode autodiff through SL + recursion, with central differences for comparison."""
    p = pm.default_params() if params is None else params
    lay = pm.layout(p)
    index = lay.ring_start + 3 * node
    u_eq = static_equilibrium(pm.planetary(p))

    def response(x):
        thickness, support = x
        ring = eqx.tree_at(lambda r: (r.thickness, r.radius, r.k_support_radial), p.ring,
                           (thickness, p.ring_pitch_radius + thickness / 2, support))
        q = eqx.tree_at(lambda z: z.ring, p, ring)
        r = solve_moments(pm.planetary(q), dt=dt, n_steps=n_steps, save_every=n_steps, rtol=1e-13,
                          initial_displacement=u_eq, initial_covariance=pm.wind_filter_stationary_covariance(q, lay))
        return r.std_u[-1, index]

    x = jnp.stack([p.ring.thickness, jnp.asarray(p.ring.k_support_radial).reshape(-1)[0]])
    grad = jax.grad(response)(x)
    fd = []
    for i in range(2):
        h = float(x[i]) * relative_step
        e = jnp.zeros(2).at[i].set(h)
        fd.append(float((response(x + e) - response(x - e)) / (2 * h)))
    return dict(quantity=f"std of ring_node{node}_radial at t = {n_steps * dt:.3f} s (m)",
                value=float(response(x)), parameters=["rim thickness (m)", "bolt radial stiffness (N/m)"],
                gradient=[float(g) for g in grad], central_difference=fd)


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


def error_summary(study: PlanetaryStudy, criterion="force") -> dict:
    """Largest |SL - MC| over time of mean and std, in units of the MC standard error, per DOF group."""
    if study.mc is None:
        return {}
    sl, mc = study.sl[criterion], study.mc
    se_m, se_s = mc.standard_error("u")
    late = np.arange(1, len(mc.times))
    z_mean = np.abs(np.asarray(sl.mean_u - mc.mean_u))[late] / np.maximum(np.asarray(se_m)[late], 1e-300)
    z_std = np.abs(np.asarray(sl.std_u - mc.std_u))[late] / np.maximum(np.asarray(se_s)[late], 1e-300)
    # Only DOFs the wind excites above round-off: the symmetric train leaves the sun translations and the
    # planets' radial motions (sun and ring mesh forces nearly cancel radially) 1e-7 below the other DOFs of
    # the same unit, where the Newmark solves' round-off (~1e-14 m) is a visible part of the std.
    peak = np.max(np.asarray(sl.std_u), axis=0)
    units = np.asarray(sl.dof_units)
    mech = [i for i, n in enumerate(sl.dof_names)
            if n != "wind_filter_chi" and peak[i] > 1e-5 * np.max(peak[units == units[i]])]
    worst = lambda z: {sl.dof_names[i]: float(np.max(z[:, i])) for i in mech}  # noqa: E731
    wm, ws = worst(z_mean), worst(z_std)
    return dict(
        criterion=criterion, n_samples=mc.n_samples, dofs_compared=len(mech),
        max_mean_error_in_se=max(wm.values()), max_std_error_in_se=max(ws.values()),
        fraction_of_dof_time_points_within_3_se=float(np.mean((z_mean[:, mech] < 3) & (z_std[:, mech] < 3))),
        contact_loss_probability_max=float(np.max(mc.contact_loss_probability)),
        per_dof_mean=wm, per_dof_std=ws,
    )


def write_outputs(study: PlanetaryStudy, outdir, *, sweeps: dict | None = None, modal: list | None = None,
                  sens: dict | None = None) -> list[Path]:
    """Labelled results (.npz), summary.json and PNG figures into ``outdir``."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    written = []
    attrs = dict(dt_s=study.dt, carrier_period_s=study.carrier_period, **study.settings)
    for crit, res in study.sl.items():
        written.append(save_results(outdir / f"planetary_sl_{crit}.npz", res, **attrs))
    if study.mc is not None:
        written.append(save_results(outdir / "planetary_mc.npz", study.mc, **attrs))
    times = np.asarray(next(iter(study.sl.values())).times) / study.carrier_period

    def curves(fn, names):
        out = {}
        if study.mc is not None:
            out["MC"] = {n: fn(study.mc, n) for n in names}
        out.update({f"SL {c}": {n: fn(r, n) for n in names} for c, r in study.sl.items()})
        return out

    dof_names = [n for n, _ in FIGURE_DOFS]
    fig = plots.mean_std_figure(times * study.carrier_period, curves(_dof_series, dof_names), list(FIGURE_DOFS),
                                title="Planetary gear train: SL vs MC (thesis Figs. 3.5-3.8)")
    written.append(plots.save(fig, outdir / "planetary_dofs.png"))
    lumped = [("sun_x", "m"), ("sun_y", "m"), ("planet1_xi", "m"), ("planet1_u", "m"), ("carrier_x", "m"),
              ("ring_node0_radial", "m")]
    fig = plots.mean_std_figure(times * study.carrier_period, curves(_dof_series, [n for n, _ in lumped]), lumped,
                                title="Further DOFs (thesis App. A)")
    written.append(plots.save(fig, outdir / "planetary_more_dofs.png"))
    first = next(iter(study.sl.values()))
    if first.observable_names:
        obs = [(n, "m") for n in first.observable_names]
        fig = plots.mean_std_figure(times * study.carrier_period, curves(_obs_series, first.observable_names), obs,
                                    title="Ring at the moving contact point of planet 1 (thesis Fig. 3.9)")
        written.append(plots.save(fig, outdir / "planetary_ring_contact.png"))
    meshes = [("sun_planet1", "N"), ("ring_planet1", "N")]
    fig = plots.mean_std_figure(times * study.carrier_period, curves(_force_series, [n for n, _ in meshes]), meshes,
                                title="Equivalent meshing forces (thesis Figs. 3.10-3.11)", second="mean square")
    written.append(plots.save(fig, outdir / "planetary_mesh_forces.png"))
    summary = dict(dt_s=study.dt, carrier_period_s=study.carrier_period, settings=study.settings,
                   sl_vs_mc=error_summary(study) if study.mc is not None else None)
    if sweeps:
        for title, results in sweeps.items():
            t = np.asarray(next(iter(results.values())).times)
            fig = plots.mean_std_figure(t, {label: {n: _dof_series(r, n) for n in dof_names}
                                            for label, r in results.items()}, list(FIGURE_DOFS), title=title)
            slug = title.split(":")[0].lower().replace(" ", "_")
            written.append(plots.save(fig, outdir / f"planetary_{slug}.png"))
            summary[slug] = {label: {n: dict(max_std=float(np.max(_dof_series(r, n)[1])),
                                             mean_at_end=float(_dof_series(r, n)[0][-1])) for n in dof_names}
                             for label, r in results.items()}
    if modal is not None:
        summary["modes"] = modal
    if sens is not None:
        summary["sensitivities"] = sens
    path = outdir / "summary.json"
    path.write_text(json.dumps(summary, indent=2))
    written.append(path)
    return written
