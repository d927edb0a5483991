"""Thesis ch. 6 study: the bolted wind-turbine ring gear under three random moving mesh loads (Sec. 6.4,
Figs. 6.3-6.9), by the stochastic Newmark mean/covariance recursion (:func:`pgtjax.solve_moments`), with a
Monte Carlo check.

What is computed (model: :mod:`pgtjax.models.ring_moving_load`):

* ``base``  (Figs. 6.3-6.4): mean and standard deviation of u_r at the contact point under load 1 and at the
  mid-node between the first two bolts, at the base speed (2.8 rad/s), with Monte Carlo overlaid.
* ``speeds`` (Figs. 6.5-6.6): the same at omega_c = 22, 30, 50 rad/s.
* ``sweep``  (Fig. 6.7): maximum over a period of the mean |u_r| and of the standard deviation of the mid-node
  against omega_c from 2.8 to 50 rad/s, normalised by their values at the lowest speed (thesis xi_m, xi_sd).
* ``noise``  (Fig. 6.8): three noise levels at the three speeds; the system is linear, so the standard
  deviation is *exactly* proportional to b-bar and is obtained by scaling one run (stated in the plot).
* ``supports`` (Fig. 6.9): support cases 1 (bolts), 2 (pins), 3 (soft pins) at the three speeds.

Time windows and steps. The response of the mid-node is periodic with a third of a revolution (three loads
120 degrees apart on a ring with 60-degree bolt symmetry) and that of the contact point with a sixth, so a
third of a revolution shows every feature; ``revolutions`` sets the plotted window (1 = the thesis's). Every
run starts half a window early (at ``t0 = -window / 2``) from the quasi-static state
(:func:`~pgtjax.models.ring_moving_load.static_initial_state`), so the start-up transient and the build-up of
the covariance (time constant ``1 / (2 zeta omega_1)`` ~ 3 ms) are over when the window starts. The step must
resolve the first natural frequency of the bolted ring (8,590 rad/s; period 0.73 ms), not only the mesh
frequency: with a step of a few ms the average-acceleration scheme still gets the quasi-static mean right but
the covariance lags (its modes decay far too slowly when ``omega h >> 1``), so ``dt`` defaults to 4e-5 s
(``omega_1 h`` = 0.34, period error 1 %).

Model size: the modal model with the 36 lowest modes of the 108-DOF ring (``n_modes``, static correction of the
mean) reproduces the full model to 1e-5 (mean) and 0.4 % (standard deviation) and is several times faster;
``n_modes=None`` runs the full model.

Critical speeds (:func:`critical_speed_table`). Project Eq. 6.27 on a mode phi_k of the supported ring. Load n
contributes ``F_n(t) g_k(theta_n(t))`` with ``g_k(theta) = sum_m c_km e^{i m theta}`` (the mode's work
per unit mesh force, periodic in theta). Summing over N equally spaced loads keeps only the harmonics
``m = p N`` (``sum_n e^{i m 2 pi (n-1)/N} = N`` if N divides m, else 0), so the constant part F_0 drives mode k
at ``p N omega_c`` and the mesh part ``f_a sin(z_m omega_c t)`` at ``(z_m +- p N) omega_c`` - also multiples of
``N omega_c`` when N divides z_m (36 = 12 x 3). Resonance (a critical speed) is therefore

    j omega_c = omega_k,   j = p N,   i.e.   omega_c = omega_k / j.

The strength of harmonic j is |c_kj|: the discretised load path has kinks at the nodes (shape functions are
only C^0 in theta across elements), and the mesh force repeats every element (z_m = L = 36), so the harmonics
``j = 36 q`` (q = 1, 2, ...) stand out: the "mesh" family ``omega_c = omega_k / (36 q)``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .. import plots
from .._files import write_text
from .._linearization import solve_moments
from .._montecarlo import monte_carlo
from .._results import MomentResult, MonteCarloResult, save_results
from ..models import ring_moving_load as rml
from ..models.ring import (
    RingParams,
    natural_frequencies,
    nodal_diameter,
    ring_displacement_at,
    ring_matrices,
    ring_natural_frequencies,
)

#: thesis Sec. 6.4.1: critical speeds read from Fig. 6.7 [rad/s]
THESIS_CRITICAL_SPEEDS = (31.3, 34.19, 36.6, 40.55, 44.0)
#: thesis Sec. 6.4: maxima of the mid-node mean and standard deviation at 22, 30, 50 rad/s [m]
THESIS_MID_NODE_MAX = {"mean": (4.76e-5, 9.59e-5, 4.12e-5), "std": (1.97e-6, 1.82e-6, 1.66e-6)}
SPEEDS = (22.0, 30.0, 50.0)
DEFAULT_DT = 4e-5


# ------------------------------------------------------------------------------------------------ runs


def _grid(p: rml.RingMovingLoadParams, revolutions: float, dt: float, n_saves: int):
    """(t0, dt, n_steps, save_every) for a window of ``revolutions`` preceded by half a window of warm-up."""
    window = revolutions * float(p.revolution_time)
    n_window = max(int(math.ceil(window / dt / n_saves)), 1) * n_saves
    save_every = n_window // n_saves
    n_warm = int(math.ceil(0.5 * n_window / save_every)) * save_every
    h = window / n_window
    return -n_warm * h, h, n_window + n_warm, save_every


def run_response(
    p: rml.RingMovingLoadParams,
    *,
    revolutions: float = 1.0,
    dt: float = DEFAULT_DT,
    n_saves: int = 360,
    n_modes: int | None = 36,
    n_samples: int = 0,
    key=None,
    progress: bool = False,
) -> tuple[MomentResult, MonteCarloResult | None]:
    """Moments (and optionally MC) of the contact point and the mid-node over ``revolutions`` (times >= 0
    cover the window; earlier saved times are the warm-up). ``dt`` [s] is rounded down to fit the window."""
    system = rml.build(p, n_modes=n_modes)
    outputs = rml.observables(p, n_modes=n_modes)
    t0, h, n, every = _grid(p, revolutions, dt, n_saves)
    u0, v0 = rml.static_initial_state(system, t0)
    kw = dict(
        t0=t0,
        dt=h,
        n_steps=n,
        save_every=every,
        initial_displacement=u0,
        initial_velocity=v0,
        observables=outputs,
    )
    sl = solve_moments(system, **kw)
    mc = None
    if n_samples:
        mc = monte_carlo(
            system,
            n_samples=n_samples,
            key=jax.random.key(0) if key is None else key,
            progress=progress,
            chunk_size=min(n_samples, 500),
            **kw,
        )
    return sl, mc


def point_series(result, which: str):
    """(times [s], mean [m], std [m]) of u_r at ``which`` = "contact" or "mid" over the window (t >= 0)."""
    name = {"contact": rml.OBSERVER_NAME, "mid": rml.MID_NAME}[which]
    t = np.asarray(result.times)
    keep = t >= -1e-12
    j = result.observable(name)
    return t[keep], np.asarray(result.mean_obs[keep, j]), np.asarray(result.std_obs[keep, j])


def sweep(
    p: rml.RingMovingLoadParams,
    speeds,
    *,
    steps: int = 1536,
    save_every: int = 16,
    n_modes: int | None = 36,
    batch: int = 4,
    progress: bool = False,
) -> dict:
    """Fig. 6.7: maxima over one load period (a third of a revolution, after a warm-up of half a period) of
    the mid-node mean |u_r| and standard deviation [m], for each speed [rad/s]. Every speed uses the same
    number of steps over warm-up + window (``dt = pi / (omega_c steps)``), so one compiled function serves all
    speeds: ``batch > 1`` (default 4) uses ``jax.vmap`` over batches of speeds, ``batch=1`` loops over speeds
    calling it under ``jax.jit``. Measured on the shared 2-core CPU (36 modes, 1536 steps, other jobs running):
    vmap batch 4: 20 s for 4 speeds including ~18 s compilation; vmap batch 8: 77 s for 8 speeds; jitted loop:
    35 s compilation then ~10 s per speed; an un-jitted loop (eager model assembly per speed) was slower
    still. Timings on this machine varied by 3-5x with the load of other jobs."""
    if steps % save_every:
        raise ValueError(f"`steps` ({steps}) must be a multiple of `save_every` ({save_every})")
    speeds = np.asarray(speeds, dtype=np.float64)
    if speeds.ndim != 1 or speeds.size == 0 or np.any(~np.isfinite(speeds)) or np.any(speeds <= 0):
        raise ValueError("`speeds` must be a non-empty 1-D list of finite speeds > 0 rad/s")

    def one(w):
        q = p.replace(carrier_speed=w)
        system = rml.build(q, n_modes=n_modes)
        period = 2.0 * jnp.pi / (3.0 * w)
        t0 = -0.5 * period
        u0, v0 = rml.static_initial_state(system, t0)
        r = solve_moments(
            system,
            t0=t0,
            dt=1.5 * period / steps,
            n_steps=steps,
            save_every=save_every,
            initial_displacement=u0,
            initial_velocity=v0,
            throw=False,
            observables=rml.observables(q, contact=False, n_modes=n_modes),
        )
        late = r.times >= -1e-9 * period
        return (
            jnp.max(jnp.where(late, jnp.abs(r.mean_obs[:, 0]), 0.0)),
            jnp.max(jnp.where(late, r.std_obs[:, 0], 0.0)),
        )

    means, stds = [], []
    if (
        batch <= 1
    ):  # a Python loop over speeds of one jitted run (the speed is a traced argument: one compile)
        run = jax.jit(one)
        for i, w in enumerate(speeds):
            m, s = run(jnp.asarray(w))
            means.append(np.asarray(m)[None])
            stds.append(np.asarray(s)[None])
            if progress and (i + 1) % 8 == 0 or progress and i + 1 == speeds.size:
                print(f"  sweep: {i + 1}/{speeds.size} speeds", flush=True)
    else:  # jax.vmap over batches of speeds (no outer jit: solve_moments is jitted inside)
        run = jax.vmap(one)
        batch = min(batch, speeds.size)
        for start in range(0, speeds.size, batch):
            chunk = speeds[start : start + batch]
            padded = np.concatenate([chunk, np.full(batch - chunk.size, chunk[-1])])
            m, s = run(jnp.asarray(padded))
            means.append(np.asarray(m)[: chunk.size])
            stds.append(np.asarray(s)[: chunk.size])
            if progress:
                print(f"  sweep: {min(start + batch, speeds.size)}/{speeds.size} speeds", flush=True)
    means, stds = np.concatenate(means), np.concatenate(stds)
    if not (np.all(np.isfinite(means)) and np.all(np.isfinite(stds))):
        raise FloatingPointError("speed sweep produced NaN/inf: check the parameters and `steps`")
    return dict(
        speeds=speeds,
        max_mean=means,
        max_std=stds,
        xi_m=means / means[0],
        xi_sd=stds / stds[0],
        peaks=find_peaks(speeds, means),
    )


def find_peaks(speeds, values, prominence: float = 0.005, reach: int = 4) -> list[float]:
    """Speeds of the interior local maxima of ``values`` standing ``prominence`` (relative) above the lowest
    value within ``reach`` samples on either side."""
    v = np.asarray(values)
    out = []
    for i in range(1, v.size - 1):
        if v[i] >= v[i - 1] and v[i] > v[i + 1]:
            lo = max(v[max(0, i - reach) : i].min(), v[i + 1 : i + 1 + reach].min())
            if v[i] - lo > prominence * v[i]:
                out.append(float(speeds[i]))
    return out


# ------------------------------------------------------------------------------------------ critical speeds


def supported_ring_frequencies(ring: RingParams) -> np.ndarray:
    """Natural angular frequencies [rad/s] of the supported ring, ascending."""
    f, _ = natural_frequencies(*ring_matrices(ring))
    return 2.0 * math.pi * np.asarray(f)


def critical_speed_table(
    p: rml.RingMovingLoadParams, speed_range=(2.8, 50.0), n_groups: int = 2, thesis=THESIS_CRITICAL_SPEEDS
) -> dict:
    """Critical speeds ``omega_c = omega_k / j`` (module docstring) in ``speed_range`` for the lowest
    ``n_groups`` groups of (nearly) equal natural frequencies, split into the mesh family ``j = z_m q`` and
    the other load-pattern harmonics ``j = p N``; plus, for each thesis value, the nearest mesh-family speed."""
    w = supported_ring_frequencies(p.ring)
    groups = []
    for wk in w:
        if not groups or wk > 1.05 * groups[-1][0]:
            groups.append([wk])
        else:
            groups[-1].append(wk)
    groups = [(min(g), max(g)) for g in groups[:n_groups]]
    zm, N = float(p.mesh_frequency_ratio), p.n_loads
    lo, hi = speed_range
    mesh = []
    for gi, (wa, wb) in enumerate(groups):
        q = 1
        while wa / (zm * q) >= lo:
            if wa / (zm * q) <= hi or wb / (zm * q) <= hi:
                mesh.append(
                    dict(
                        group=gi + 1,
                        harmonic=int(round(zm * q)),
                        q=q,
                        speed_low=wa / (zm * q),
                        speed_high=wb / (zm * q),
                    )
                )
            q += 1
    comparison = []
    for ts in thesis:
        best = min(mesh, key=lambda r: min(abs(ts - r["speed_low"]), abs(ts - r["speed_high"])), default=None)
        if best is not None:
            inside = best["speed_low"] <= ts <= best["speed_high"]
            dist = 0.0 if inside else min(abs(ts - best["speed_low"]), abs(ts - best["speed_high"]))
            comparison.append(
                dict(
                    thesis=ts,
                    group=best["group"],
                    harmonic=best["harmonic"],
                    band=(best["speed_low"], best["speed_high"]),
                    distance=dist,
                    implied_frequency=ts * best["harmonic"],
                )
            )
    return dict(
        groups_rad_s=groups,
        mesh_family=mesh,
        load_harmonic_spacing=N,
        thesis_comparison=comparison,
        lowest_harmonic_in_range=int(math.ceil(groups[0][0] / hi)),
    )


# ------------------------------------------------------------------------------------------------ study


@dataclass
class RingMovingLoadStudy:
    params: rml.RingMovingLoadParams
    base: tuple  # (MomentResult, MonteCarloResult | None)
    speeds: dict  # speed -> MomentResult
    sweep: dict | None
    supports: dict  # (case, speed) -> MomentResult
    noise_levels: tuple
    critical: dict
    settings: dict = field(default_factory=dict)


def run_study(
    p: rml.RingMovingLoadParams | None = None,
    *,
    revolutions: float = 1.0 / 3.0,
    dt: float = DEFAULT_DT,
    n_modes: int | None = 36,
    n_samples: int = 200,
    sweep_speeds=None,
    sweep_steps: int = 1536,
    speeds=SPEEDS,
    noise_levels=(0.5, 1.0, 2.0),
    support_cases=(1, 2, 3),
    progress: bool = True,
) -> RingMovingLoadStudy:
    """All ch. 6 studies (module docstring). ``sweep_speeds=()`` skips the sweep; defaults are the quick size
    (a third of a revolution, 48 sweep speeds); ``revolutions=1`` and a finer sweep give the thesis's views."""
    p = rml.default_params() if p is None else p
    bad = [c for c in support_cases if c not in rml.SUPPORT_CASES]
    if bad:
        raise ValueError(f"`support_cases` (--supports) must be among 1, 2, 3 (Sec. 6.4.3), got {bad}")
    say = print if progress else (lambda *a, **k: None)
    say(f"  base case: omega_c = {float(p.carrier_speed):g} rad/s, MC {n_samples} samples")
    base = run_response(p, revolutions=revolutions, dt=dt, n_modes=n_modes, n_samples=n_samples)
    by_speed = {}
    for w in speeds:
        say(f"  speed {w:g} rad/s")
        by_speed[w] = run_response(
            p.replace(carrier_speed=w), revolutions=revolutions, dt=dt, n_modes=n_modes
        )[0]
    sw = None
    if sweep_speeds is None:
        sweep_speeds = np.linspace(2.8, 50.0, 48)
    if len(sweep_speeds):
        say(f"  sweep: {len(sweep_speeds)} speeds from {min(sweep_speeds):g} to {max(sweep_speeds):g} rad/s")
        sw = sweep(p, sweep_speeds, steps=sweep_steps, n_modes=n_modes, progress=progress)
    sup = {}
    for case in support_cases:
        for w in speeds:
            say(f"  support case {case}, {w:g} rad/s")
            q = rml.support_case(p, case).replace(carrier_speed=w)
            sup[(case, w)] = run_response(q, revolutions=revolutions, dt=dt, n_modes=n_modes)[0]
    crit = critical_speed_table(p)
    return RingMovingLoadStudy(
        p,
        base,
        by_speed,
        sw,
        sup,
        tuple(noise_levels),
        crit,
        settings=dict(
            revolutions=revolutions, dt_s=dt, n_modes=n_modes, n_samples=n_samples, sweep_steps=sweep_steps
        ),
    )


def load_params(
    source=None, *, n_elements: int | None = None, support: int | None = None
) -> rml.RingMovingLoadParams:
    """The study's parameters: :func:`pgtjax.models.ring_moving_load.load_params` (``None``: the embedded
    ``ring_ch6.toml``; ``n_elements`` and the support case of Sec. 6.4.3 override the file's)."""
    return rml.load_params(source, n_elements=n_elements, support=support)


def resolve_settings(
    p: rml.RingMovingLoadParams,
    *,
    revolutions: float = 1.0 / 3.0,
    n_modes: int = 36,
    n_samples: int = 200,
    n_sweep: int = 48,
    sweep_min: float = 2.8,
    sweep_max: float = 50.0,
    full: bool = False,
) -> dict:
    """Checked keywords of :func:`run_study` from the command-line sizes: ``full`` is the thesis size (one
    revolution, 190 sweep speeds, >= 1000 MC samples), ``n_modes = 0`` the full FE model, ``n_sweep`` equally
    spaced sweep speeds from ``sweep_min`` to ``sweep_max`` (0 skips the sweep). A bad size is a
    ``ValueError``. Returns ``dict(revolutions, n_modes, n_samples, sweep_speeds)``."""
    if full:
        revolutions, n_sweep, n_samples = 1.0, 190, max(n_samples, 1000)
    if revolutions <= 0:
        raise ValueError(f"`--revolutions` must be > 0, got {revolutions}")
    n_modes = None if n_modes == 0 else n_modes
    if n_modes is not None and n_modes > p.ring.n_dof:
        raise ValueError(
            f"`--modes` must be <= 3 x n_elements = {p.ring.n_dof} (0 = full model), got {n_modes}"
        )
    sweep_speeds = np.linspace(sweep_min, sweep_max, n_sweep) if n_sweep else np.array([])
    return dict(revolutions=revolutions, n_modes=n_modes, n_samples=n_samples, sweep_speeds=sweep_speeds)


def format_header(
    p: rml.RingMovingLoadParams,
    *,
    revolutions: float,
    n_modes: int | None,
    n_samples: int,
    sweep_speeds,
    dt: float,
) -> str:
    """One line describing a :func:`run_study` call (the CLI's first line)."""
    return (
        f"pgtjax ring under moving loads (thesis ch. 6): L = {p.ring.n_elements}, N = {p.n_loads} loads, "
        f"{'full model' if n_modes is None else f'{n_modes} modes'}, dt = {dt:g} s, "
        f"{revolutions:g} revolution(s), MC {n_samples} samples, sweep {len(sweep_speeds)} speeds"
    )


# ------------------------------------------------------------------------------------------------ plots


def _axes_pair(title, n_rows=2):
    plt = plots.plt
    fig, axes = plt.subplots(n_rows, 1, figsize=(5.2, 1.9 * n_rows + 0.6), sharex=True, squeeze=False)
    if title:
        fig.suptitle(title)
    return fig, axes[:, 0]


def response_figure(curves: dict, which: str, title: str = "", angle_axis=True):
    """Mean and std of u_r (µm, inward positive) against the load angle omega_c t (deg) for each labelled
    result; ``curves[label] = (result, omega_c)``."""
    with plots.plt.rc_context(plots.STYLE):
        fig, (a0, a1) = _axes_pair(title)
        for label, (res, w) in curves.items():
            t, m, s = point_series(res, which)
            x = np.degrees(w * t) if angle_axis else t * 1e3
            style = plots.LINESTYLES.get(label, {})
            a0.plot(x, m * 1e6, label=label, **style)
            a1.plot(x, s * 1e6, label=label, **style)
        a0.set_ylabel("mean u_r (µm)")
        a1.set_ylabel("std u_r (µm)")
        a1.set_xlabel("load angle ω_c t (deg)" if angle_axis else "time (ms)")
        a0.legend(loc="best")
        fig.tight_layout()
    return fig


def sweep_figure(sw: dict, critical: dict | None = None, thesis=THESIS_CRITICAL_SPEEDS):
    """Fig. 6.7: xi_m and xi_sd against omega_c, with the predicted mesh-family critical speeds (bands) and the
    thesis's critical speeds (dotted)."""
    with plots.plt.rc_context(plots.STYLE):
        fig, (a0, a1) = _axes_pair("mid-node maxima against load speed (normalised at the lowest speed)")
        a0.plot(sw["speeds"], sw["xi_m"], "k.-", ms=3, label="ξ_m (max mean)")
        a1.plot(sw["speeds"], sw["xi_sd"], "b.-", ms=3, label="ξ_sd (max std)")
        for ax in (a0, a1):
            if critical:
                for i, r in enumerate(critical["mesh_family"]):
                    ax.axvspan(
                        r["speed_low"],
                        r["speed_high"],
                        color="tab:orange",
                        alpha=0.3,
                        label="ω_k / (36 q), this ring" if i == 0 else None,
                    )
            for i, ts in enumerate(thesis):
                ax.axvline(
                    ts, color="tab:red", ls=":", lw=0.9, label="thesis critical speeds" if i == 0 else None
                )
        a0.set_ylabel("ξ_m")
        a1.set_ylabel("ξ_sd")
        a1.set_xlabel("load speed ω_c (rad/s)")
        a0.legend(loc="best")
        fig.tight_layout()
    return fig


def ring_shape_points(ring: RingParams, u, scale: float, n_points: int = 361):
    """(x, y) [m] of the deformed centre line for nodal DOFs ``u`` magnified by ``scale`` (u_r inward)."""
    th = np.linspace(0.0, 2.0 * math.pi, n_points)
    d = np.asarray(jax.vmap(lambda a: ring_displacement_at(ring, a, jnp.asarray(u)))(jnp.asarray(th)))
    r = float(ring.radius) - scale * d[:, 0]
    phi = th + scale * d[:, 1] / float(ring.radius)
    return r * np.cos(phi), r * np.sin(phi)


def mode_shape_figure(ring: RingParams, n_modes: int = 6, title: str = "", amplitude: float = 0.15):
    """Deformed rings of the ``n_modes`` lowest modes (dashed: undeformed; dots: supports)."""
    from ..models.ring import nodal_diameter

    f, x = natural_frequencies(*ring_matrices(ring))
    f, x = np.asarray(f), np.asarray(x)
    cols = min(n_modes, 3)
    rows = int(math.ceil(n_modes / cols))
    R = float(ring.radius)
    with plots.plt.rc_context(plots.STYLE):
        fig, axes = plots.plt.subplots(rows, cols, figsize=(2.4 * cols, 2.5 * rows), squeeze=False)
        for k in range(rows * cols):
            ax = axes[k // cols, k % cols]
            ax.set_aspect("equal")
            ax.axis("off")
            if k >= n_modes:
                continue
            u = x[:, k]
            peak = np.max(np.abs(u.reshape(-1, 3)[:, :2]))
            xs, ys = ring_shape_points(ring, u, amplitude * R / max(peak, 1e-300))
            th = np.linspace(0, 2 * math.pi, 200)
            ax.plot(R * np.cos(th), R * np.sin(th), color="0.6", ls="--", lw=0.8)
            ax.plot(xs, ys, color="tab:blue")
            for s in ring.support_nodes:
                a = 2 * math.pi * s / ring.n_elements
                ax.plot(R * math.cos(a), R * math.sin(a), "ks", ms=3)
            ax.set_title(f"mode {k + 1}: {f[k]:.0f} Hz, n = {nodal_diameter(u)}")
        if title:
            fig.suptitle(title)
        fig.tight_layout()
    return fig


# ------------------------------------------------------------------------------------------------ output


def _summary(study: RingMovingLoadStudy) -> dict:
    mid = {}
    for w, r in study.speeds.items():
        _, m, s = point_series(r, "mid")
        _, mc_, sc = point_series(r, "contact")
        mid[str(w)] = dict(
            mid_max_abs_mean_m=float(np.max(np.abs(m))),
            mid_max_std_m=float(np.max(s)),
            contact_max_abs_mean_m=float(np.max(np.abs(mc_))),
            contact_max_std_m=float(np.max(sc)),
        )
    sup = {f"case{c}_{w:g}": float(np.max(point_series(r, "mid")[2])) for (c, w), r in study.supports.items()}
    out = dict(
        settings=study.settings,
        speeds=mid,
        thesis_mid_node_max=THESIS_MID_NODE_MAX,
        supports_mid_max_std_m=sup,
        critical_speeds=study.critical,
        thesis_critical_speeds=list(THESIS_CRITICAL_SPEEDS),
    )
    sl, mc = study.base
    if mc is not None:
        z = []
        for name in (rml.OBSERVER_NAME, rml.MID_NAME):
            j = sl.observable(name)
            se_m, se_s = mc.standard_error("obs")
            sd = np.asarray(mc.std_obs[:, j])
            # skip times where the spread is still ~0 (start of the run): the standard errors vanish there
            ok = (sd > 1e-3 * sd.max()) & (np.asarray(mc.times) >= 0.0)
            z.append(
                dict(
                    dof=name,
                    max_mean_z=float(
                        np.max(
                            np.abs(np.asarray(mc.mean_obs[ok, j] - sl.mean_obs[ok, j]))
                            / np.asarray(se_m[ok, j])
                        )
                    ),
                    max_std_z=float(
                        np.max(
                            np.abs(np.asarray(mc.std_obs[ok, j] - sl.std_obs[ok, j]))
                            / np.asarray(se_s[ok, j])
                        )
                    ),
                )
            )
        out["mc_vs_recursion"] = z
    if study.sweep is not None:
        sw = study.sweep
        out["sweep"] = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in sw.items()}
    return out


def write_outputs(study: RingMovingLoadStudy, outdir) -> list[Path]:
    """Labelled results (``.npz`` via :func:`pgtjax.save_results`), ``summary.json`` and PNG figures."""
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    p = study.params
    written = []
    attrs = dict(
        study="ring_moving_load",
        n_loads=p.n_loads,
        dt_s=study.settings.get("dt_s"),
        units="u_r in m, inward positive; times in s",
    )
    sl, mc = study.base
    w0 = float(p.carrier_speed)
    written.append(save_results(outdir / "base_sl.npz", sl, carrier_speed_rad_s=w0, **attrs))
    curves = {"SL force": (sl, w0)}
    if mc is not None:
        written.append(save_results(outdir / "base_mc.npz", mc, carrier_speed_rad_s=w0, **attrs))
        curves = {"MC": (mc, w0), **curves}
    names = {"SL force": "stochastic Newmark", "MC": f"Monte Carlo ({mc.n_samples if mc else 0})"}
    for which, fig_no in (("contact", "6.3"), ("mid", "6.4")):
        fig = response_figure(
            {names[k]: v for k, v in curves.items()},
            which,
            f"Fig. {fig_no}: {which} point, ω_c = {w0:g} rad/s",
        )
        written.append(plots.save(fig, outdir / f"fig{fig_no.replace('.', '_')}_{which}_base.png"))
    for w, r in study.speeds.items():
        written.append(save_results(outdir / f"speed_{w:g}.npz", r, carrier_speed_rad_s=w, **attrs))
    for which, fig_no in (("contact", "6.5"), ("mid", "6.6")):
        fig = response_figure(
            {f"ω_c = {w:g} rad/s": (r, w) for w, r in study.speeds.items()},
            which,
            f"Fig. {fig_no}: {which} point at three load speeds",
        )
        written.append(plots.save(fig, outdir / f"fig{fig_no.replace('.', '_')}_{which}_speeds.png"))
    if study.sweep is not None:
        written.append(plots.save(sweep_figure(study.sweep, study.critical), outdir / "fig6_7_sweep.png"))
    # Fig. 6.8: noise levels (exact scaling of the linear system's standard deviation)
    with plots.plt.rc_context(plots.STYLE):
        fig, axes = plots.plt.subplots(
            1, len(study.speeds), figsize=(3.0 * len(study.speeds), 2.8), squeeze=False
        )
        b0 = float(p.noise_intensity[0])
        for ax, (w, r) in zip(axes[0], study.speeds.items()):
            t, _, s = point_series(r, "mid")
            for lvl in study.noise_levels:
                ax.plot(np.degrees(w * t), lvl * s * 1e6, label=f"b = {lvl * b0:.3g}")
            ax.set_title(f"ω_c = {w:g} rad/s")
            ax.set_xlabel("load angle (deg)")
        axes[0, 0].set_ylabel("std u_r mid-node (µm)")
        axes[0, 0].legend(loc="best")
        fig.suptitle("Fig. 6.8: noise levels (std ∝ b for the linear system)")
        fig.tight_layout()
    written.append(plots.save(fig, outdir / "fig6_8_noise.png"))
    if study.supports:
        with plots.plt.rc_context(plots.STYLE):
            ws = sorted({w for _, w in study.supports})
            fig, axes = plots.plt.subplots(1, len(ws), figsize=(3.0 * len(ws), 2.8), squeeze=False)
            for ax, w in zip(axes[0], ws):
                for (c, ww), r in study.supports.items():
                    if ww == w:
                        t, _, s = point_series(r, "mid")
                        ax.plot(np.degrees(w * t), s * 1e6, label=f"case {c}")
                ax.set_title(f"ω_c = {w:g} rad/s")
                ax.set_xlabel("load angle (deg)")
            axes[0, 0].set_ylabel("std u_r mid-node (µm)")
            axes[0, 0].legend(loc="best")
            fig.suptitle("Fig. 6.9: supports (1 bolts, 2 pins, 3 soft pins)")
            fig.tight_layout()
        written.append(plots.save(fig, outdir / "fig6_9_supports.png"))
        for (c, w), r in study.supports.items():
            written.append(
                save_results(
                    outdir / f"support_case{c}_{w:g}.npz", r, carrier_speed_rad_s=w, support_case=c, **attrs
                )
            )
    written.append(
        plots.save(
            mode_shape_figure(p.ring, 6, "bolted ch. 6 ring: lowest modes"), outdir / "modes_ch6_ring.png"
        )
    )
    path = outdir / "summary.json"
    write_text(path, json.dumps(_summary(study), indent=2, default=float))
    written.append(path)
    return written


def format_critical_table(crit: dict) -> str:
    """Plain-text comparison of the thesis's critical speeds with the mesh family omega_k / (36 q)."""
    lines = [
        "natural-frequency groups of the bolted ring (rad/s): "
        + ", ".join(f"{a:.0f}-{b:.0f}" for a, b in crit["groups_rad_s"]),
        f"{'thesis (rad/s)':>14s} {'harmonic j':>10s} {'band omega_k/j (rad/s)':>24s} {'distance':>9s}",
    ]
    for r in crit["thesis_comparison"]:
        lines.append(
            f"{r['thesis']:14.2f} {r['harmonic']:10d} {r['band'][0]:11.2f} - {r['band'][1]:9.2f} "
            f"{r['distance']:9.2f}"
        )
    return "\n".join(lines)


def format_summary(study: RingMovingLoadStudy) -> str:
    """Plain-text summary of a study: :func:`format_critical_table` and the peaks of the speed sweep."""
    text = format_critical_table(study.critical)
    if study.sweep is not None:
        text += "\npeaks of the maximum mean in the sweep (rad/s): " + (
            ", ".join(f"{w:.2f}" for w in study.sweep["peaks"]) or "none"
        )
    return text


# ------------------------------------------------------------------------------------------- ring modes


def modal_table(p: rml.RingMovingLoadParams | None = None, n_modes: int = 24) -> dict:
    """Natural frequencies (Hz, rad/s) and circumferential wave numbers of the supported ring of ``p``, the
    ``n_modes`` lowest (0 = all): ``dict(n_elements, support_nodes, modes=[{mode, frequency_hz,
    angular_frequency_rad_s, wave_number}])``, ``json.dumps``-ready."""
    p = rml.default_params() if p is None else p
    f, x = ring_natural_frequencies(p.ring)
    f, x = np.asarray(f), np.asarray(x)
    k = min(n_modes, f.size) if n_modes else f.size
    rows = [
        dict(
            mode=i + 1,
            frequency_hz=float(f[i]),
            angular_frequency_rad_s=float(2 * np.pi * f[i]),
            wave_number=nodal_diameter(x[:, i]),
        )
        for i in range(k)
    ]
    return dict(n_elements=p.ring.n_elements, support_nodes=list(p.ring.support_nodes), modes=rows)


def format_modal_table(p: rml.RingMovingLoadParams, table: dict) -> str:
    """Plain-text :func:`modal_table` of ``p``'s ring, headed by its dimensions and supports."""
    r = p.ring
    lines = [
        f"ring R = {float(r.radius) * 1e3:.2f} mm, h = {float(r.thickness) * 1e3:.2f} mm, "
        f"b = {float(r.face_width) * 1e3:.1f} mm, L = {r.n_elements} elements, "
        f"supports at nodes {list(r.support_nodes)}",
        f"{'mode':>4s} {'f (Hz)':>12s} {'omega (rad/s)':>14s} {'n':>3s}",
    ]
    lines += [
        f"{row['mode']:4d} {row['frequency_hz']:12.2f} {row['angular_frequency_rad_s']:14.1f} "
        f"{row['wave_number']:3d}"
        for row in table["modes"]
    ]
    return "\n".join(lines)
