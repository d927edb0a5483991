"""SL's peak probabilities (Rice's crossing rate, ``MomentResult.peak_exceedance``) against Monte Carlo's peaks
counted over every step, for a linear oscillator under white noise (10 Hz, 1 kg, started at rest; the peaks
taken from 1 s on, when the response is stationary). Its response is Gaussian, so the crossing rate is exact
and what separates the two is the Poisson assumption on the crossings, which the damping ratio (the
response's bandwidth) sets. Writes benchmarks/results/peaks_rice.json.

Usage: python benchmarks/compare_peaks_rice.py [--samples 200000] [--zetas 0.05 0.3]
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np
from _common import write

import pgtjax as pg

OMEGA = 2 * np.pi * 10.0  # rad/s
SIGMAS = [2.0, 2.5, 3.0, 3.5, 4.0]  # levels in stationary std of the displacement
TIMES = [1.5, 2.0, 3.0]  # s: the windows [1 s, t]


def compare(zeta: float, n_samples: int) -> dict:
    system = pg.System(mass=[[1.0]], stiffness=[[OMEGA**2]], damping=[[2 * zeta * OMEGA]], load=[0.0],
                       noise_input=[[1.0]], spectral_density=1.0, dof_names=["x"])  # fmt: skip
    dt, n_steps = 1e-3, 3000
    sl = pg.solve_moments(system, dt=dt, n_steps=n_steps, save_every=1, covariance_dofs="all")
    s = float(sl.std_u[-1, 0])
    levels = s * np.asarray(SIGMAS)
    rice = sl.peak_exceedance("u:x", levels, start=1.0)
    start = time.perf_counter()
    mc = pg.monte_carlo(system, n_samples=n_samples, key=jax.random.key(1), dt=dt, n_steps=n_steps,
                        save_every=500, peaks={"u:x": np.concatenate([[0.0], levels, [12 * s]])}, peak_start=1.0,
                        histogram_times=TIMES, progress=False)  # fmt: skip
    wall = time.perf_counter() - start
    exceedance = mc.peak_exceedance("u:x")
    rows = []
    for row, t in enumerate(TIMES):
        k = int(np.argmin(np.abs(np.asarray(rice.times) - t)))
        rows.append(
            dict(
                window_s=[1.0, t],
                monte_carlo=exceedance.probability[row, :5].tolist(),
                monte_carlo_standard_error=exceedance.standard_error[row, :5].tolist(),
                rice_poisson=np.asarray(rice.probability[k]).tolist(),
                rice_bound=np.asarray(rice.upper_bound[k]).tolist(),
            )
        )
    return dict(zeta=zeta, std_m=s, levels_in_std=SIGMAS, n_samples=n_samples, mc_wall_s=wall, windows=rows)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=200_000)
    ap.add_argument("--zetas", type=float, nargs="+", default=[0.05, 0.3])
    args = ap.parse_args()
    out = dict(cases=[compare(z, args.samples) for z in args.zetas])
    for case in out["cases"]:
        print(f"zeta = {case['zeta']}: P(peak >= level) from 1 s to 3 s, levels {SIGMAS} std")
        last = case["windows"][-1]
        for name in ("monte_carlo", "rice_poisson", "rice_bound"):
            print(f"  {name:>12s}: " + "  ".join(f"{p:.5f}" for p in last[name]))
    print("wrote", write("peaks_rice", out))


if __name__ == "__main__":
    main()
