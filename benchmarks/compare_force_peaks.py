"""SL's peak probabilities of contact forces (crossings between consecutive steps of barriers that move with
the mesh stiffness, ``MomentResult.peak_exceedance("force:...")``) and of displacements (crossings between
steps, and Rice's continuous-time rate from the velocity) against Monte Carlo's peaks counted over every step:

- an oscillator held by a contact whose stiffness varies by +-40 % at 7 Hz (10 Hz, zeta 0.3, linear, so SL's
  moments are exact), with the estimate also formed for the deflection at the mean stiffness's barrier
  (``F / k0``), to show what the moving barrier adds; with a fine step, and with a step that does not resolve
  the oscillator (the discrete process is what both methods see);
- the gear pair of ch. 4 in its no-impact regime (its mesh force, time-varying mesh stiffness);
- the planetary model of ch. 3 (a sun-planet and a ring-planet mesh force, displacements, and the ring's
  displacement at planet 1's moving contact point, from its static equilibrium with the wind filter's
  stationary covariance).

Levels are in standard deviations of SL's force (displacement) above its largest |mean| over the window.
Writes benchmarks/results/force_peaks.json.

Usage: python benchmarks/compare_force_peaks.py [--samples 200000] [--planetary-samples 100000]
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
from _common import write

import pgtjax as pg

OMEGA = 2 * np.pi * 10.0
SIGMAS = [2.0, 3.0, 3.5, 4.0]


def compare(name, system, contacts, n_samples, *, dt, n_steps, start, sl_kwargs=None, mc_kwargs=None,
            fixed_stiffness=None, dofs=(), observables=()) -> dict:  # fmt: skip
    sl_kwargs, mc_kwargs = sl_kwargs or {}, mc_kwargs or {}
    sl = pg.solve_moments(system, dt=dt, n_steps=n_steps, save_every=1, deflection_lag=True,
                          covariance_dofs=list(dofs), **sl_kwargs)  # fmt: skip
    first = int(np.argmin(np.abs(np.asarray(sl.times) - start)))
    levels, peaks = {}, {}
    moments = [
        (f"force:{c}", sl.force_mean[:, sl.contact(c)], sl.force_std[:, sl.contact(c)]) for c in contacts
    ]
    moments += [(f"u:{d}", sl.mean_u[:, sl.dof(d)], sl.std_u[:, sl.dof(d)]) for d in dofs]
    moments += [
        (f"obs:{o}", sl.mean_obs[:, sl.observable(o)], sl.std_obs[:, sl.observable(o)]) for o in observables
    ]
    for q, mean_t, std_t in moments:
        mean = float(jnp.max(jnp.abs(mean_t[first:])))
        std = float(jnp.max(std_t[first:]))
        levels[q] = mean + std * np.asarray(SIGMAS)
        peaks[q] = np.concatenate([[0.0], levels[q], [mean + 20 * std]])
    t0 = time.perf_counter()
    save_every = int(np.gcd(first, n_steps)) if first else n_steps // 4  # the start is a saved time
    assert n_steps // save_every <= 100, "choose a start on a coarser grid"
    mc = pg.monte_carlo(system, n_samples=n_samples, key=jax.random.key(11), dt=dt, n_steps=n_steps,
                        save_every=save_every, peaks=peaks, peak_start=start,
                        histogram_times=[float(sl.times[-1])], progress=False, **mc_kwargs)  # fmt: skip
    wall = time.perf_counter() - t0

    def row(q, label, **extra):
        estimate = sl.peak_exceedance(q, levels[q], start=start, system=system)
        exceedance = mc.peak_exceedance(q)
        return dict(
            label,
            monte_carlo=exceedance.probability[0, : len(SIGMAS)].tolist(),
            monte_carlo_standard_error=exceedance.standard_error[0, : len(SIGMAS)].tolist(),
            sl_poisson=np.asarray(estimate.probability[-1]).tolist(),
            sl_bound=np.asarray(estimate.upper_bound[-1]).tolist(),
            sl_lower_bound=np.asarray(estimate.lower_bound[-1]).tolist(),
            **extra,
        )

    rows = []
    for c in contacts:
        q = f"force:{c}"
        extra = {}
        if fixed_stiffness is not None:  # the deflection's peak at the mean stiffness's barrier, F / k0
            fixed = sl.peak_exceedance(f"delta:{c}", levels[q] / fixed_stiffness, start=start)
            extra["sl_barrier_at_mean_stiffness"] = np.asarray(fixed.probability[-1]).tolist()
        rows.append(row(q, dict(contact=c, levels_N=levels[q].tolist()), **extra))
    dof_rows = []
    for d in dofs:
        q = f"u:{d}"
        rice = sl.peak_exceedance(q, levels[q], start=start, method="rice")
        dof_rows.append(row(q, dict(dof=d, levels=levels[q].tolist()),
                            sl_rice_poisson=np.asarray(rice.probability[-1]).tolist()))  # fmt: skip
    obs_rows = [row(f"obs:{o}", dict(observable=o, levels=levels[f"obs:{o}"].tolist())) for o in observables]
    return dict(case=name, n_samples=n_samples, dt_s=dt, n_steps=n_steps, window_s=[start, float(sl.times[-1])],
                levels_in_std_above_mean=SIGMAS, mc_wall_s=wall, contacts=rows, dofs=dof_rows,
                observables=obs_rows)  # fmt: skip


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=200_000)
    ap.add_argument("--planetary-samples", type=int, default=100_000)
    args = ap.parse_args()
    from pgtjax.models import gear_pair as gp
    from pgtjax.models import planetary as pm
    from pgtjax.studies.planetary import contact_point_observables

    stiffness = pg.FourierSeries(OMEGA**2, sin_coefficients=[0.4 * OMEGA**2], frequency=2 * np.pi * 7.0)
    oscillator = pg.System(mass=[[1.0]], stiffness=[[0.0]], damping=[[2 * 0.3 * OMEGA]], load=[0.0],
                           noise_input=[[1.0]], spectral_density=1.0, dof_names=["x"],
                           contacts=pg.Contacts([[1.0]], stiffness, [0.0], names=["c"]))  # fmt: skip
    regimes = {n: (a, b) for n, a, b in gp.load_regimes()}
    torque_in, torque_out = regimes["no_impact"]
    gear_pair = gp.build(gp.default_params().replace(torque_in=torque_in, torque_out=torque_out))
    p = pm.default_params()
    lay = pm.layout(p)
    planetary = pm.build(p)
    start_kw = dict(initial_displacement=pg.static_equilibrium(planetary),
                    initial_covariance=pm.wind_filter_stationary_covariance(p, lay),
                    observables=contact_point_observables(p))  # fmt: skip
    names = planetary.contact_names()
    cases = [
        compare("oscillator, stiffness +-40 % at 7 Hz", oscillator, ["c"], args.samples, dt=1e-3, n_steps=3000,
                start=1.0, fixed_stiffness=OMEGA**2, dofs=["x"]),
        compare("the same, a step of 0.05 s (omega dt = 3.1, not resolved)", oscillator, ["c"], args.samples,
                dt=0.05, n_steps=600, start=10.0, fixed_stiffness=OMEGA**2, dofs=["x"]),
        compare("gear pair, no impact", gear_pair, ["mesh"], args.samples, dt=1e-5, n_steps=3000, start=0.01,
                dofs=["y1", "z"]),
        compare("planetary", planetary, [names[0], names[3]], args.planetary_samples, dt=0.0027, n_steps=1000,
                start=0.0, sl_kwargs=start_kw, mc_kwargs=start_kw,
                dofs=["planet1_eta", "carrier_u", "ring_node0_radial"],
                observables=["ring_contact1_radial", "ring_contact1_tangential"]),
    ]  # fmt: skip
    for case in cases:
        print(f"{case['case']}: P(peak >= mean + k std), k = {SIGMAS}, window {case['window_s']} s")
        for row in case["contacts"] + case["dofs"] + case["observables"]:
            label = row.get("contact") or ("u:" + row["dof"] if "dof" in row else "obs:" + row["observable"])
            print(f"  {label}")
            for key in (
                "monte_carlo",
                "sl_poisson",
                "sl_bound",
                "sl_barrier_at_mean_stiffness",
                "sl_rice_poisson",
            ):
                if key in row:
                    print(f"    {key:>28s}: " + "  ".join(f"{v:.5f}" for v in row[key]))
    print("wrote", write("force_peaks", dict(cases=cases)))


if __name__ == "__main__":
    main()
