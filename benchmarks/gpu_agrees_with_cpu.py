"""Correctness on a GPU: the same runs on the GPU and on the CPU of one process, compared.

The ch. 3 planetary model (SL + recursion, and Monte Carlo through the eigen-coordinates, both with the study's
contact-point observables) and the gear pair (Monte Carlo) are run at small sizes on JAX's first GPU and on its
CPU device, from the same parameters and the same key. Threefry draws the same normals on both, so the
statistics may differ only by rounding (the GPU's fused multiply-adds and reduction orders). Reported per
statistic: the largest difference over the largest magnitude of the CPU's array.

How large a rounding-level difference can grow is a property of the computation, not of the device, so the
same comparison is made on the CPU alone between the model and the model with its mass matrix scaled by
1 + 1e-15 (a change at the last digit): a GPU that computes correctly differs from the CPU by about as much.

Usage: python benchmarks/gpu_agrees_with_cpu.py [--allow-cpu]
Writes benchmarks/results/gpu_agrees_with_cpu.json. On a machine without a GPU it stops with exit status 1
unless ``--allow-cpu`` is given (then it compares the CPU with itself: a check of the script only, written to
cpu_agrees_check.json so that it never replaces a GPU's figures).
"""

from __future__ import annotations

import argparse
import sys

import equinox as eqx
import numpy as np

NUDGE = 1.0 + 1e-15  # a relative change of the mass matrix at its last digit (float64's epsilon is 2.2e-16)
STATISTICS = ("mean_u", "std_u", "mean_v", "std_v", "force_mean", "force_std", "mean_obs", "std_obs")


def _relative_differences(a, b) -> dict:
    out = {}
    for name in STATISTICS:
        x, y = getattr(a, name, None), getattr(b, name, None)
        if x is None or y is None:
            continue
        x, y = np.asarray(x), np.asarray(y)
        if x.size == 0:
            continue
        scale = float(np.max(np.abs(y)))
        out[name] = float(np.max(np.abs(x - y)) / scale) if scale > 0 else float(np.max(np.abs(x - y)))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--allow-cpu", action="store_true", help="compare the CPU with itself (a check of the script)"
    )
    args = ap.parse_args()

    import jax
    from _common import write

    import pgtjax as pg
    from pgtjax.models import gear_pair as gp
    from pgtjax.models import planetary as pm
    from pgtjax.studies import planetary as study

    cpu = jax.devices("cpu")[0]
    accelerator = jax.devices()[0]
    if accelerator.platform != "gpu" and not args.allow_cpu:
        print(f"gpu_agrees_with_cpu: no GPU here (JAX's devices: {jax.devices()})", file=sys.stderr)
        return 1

    dt, n_steps, n_samples, key = 0.0027, 400, 2_000, jax.random.key(0)
    p = pm.default_params()
    report = dict(
        accelerator=accelerator.device_kind,
        planetary=dict(dt_s=dt, n_steps=n_steps, n_samples=n_samples),
    )

    def planetary(device, mass_scale=1.0):
        with jax.default_device(device):
            system, kw, mc_every, _ = study._setup(p, dt, n_steps * dt / study.carrier_period(p), n_saves=80)
            system = eqx.tree_at(lambda s: s.mass, system, system.mass * mass_scale)
            kw = dict(kw, n_steps=n_steps)
            sl = pg.solve_moments(system, save_every=mc_every, **kw)
            mc = pg.monte_carlo(
                system,
                n_samples=n_samples,
                key=key,
                chunk_size=n_samples // 2,  # two chunks: the running statistics' merge is in the comparison
                save_every=mc_every,
                progress=False,
                devices=[device],
                **kw,
            )
            where = [str(next(iter(r.std_u.devices()))) for r in (sl, mc)]
            return jax.device_get((sl, mc)), mc.propagation, where

    (sl_gpu, mc_gpu), route_gpu, where_gpu = planetary(accelerator)
    (sl_cpu, mc_cpu), route_cpu, where_cpu = planetary(cpu)
    print(f"planetary SL and MC results on {where_gpu} and on {where_cpu}")
    report["planetary"].update(
        results_on=dict(accelerator=where_gpu, cpu=where_cpu),
        mc_route=dict(accelerator=route_gpu, cpu=route_cpu),
        sl=_relative_differences(sl_gpu, sl_cpu),
        mc=_relative_differences(mc_gpu, mc_cpu),
    )

    def gear(device, mass_scale=1.0):
        with jax.default_device(device):
            system = gp.build()
            r = pg.monte_carlo(
                eqx.tree_at(lambda s: s.mass, system, system.mass * mass_scale),
                n_samples=4_000,
                key=key,
                dt=1e-5,
                n_steps=1_000,
                save_every=10,
                chunk_size=2_000,
                progress=False,
                devices=[device],
            )
            return jax.device_get(r)

    report["gear_pair"] = dict(
        n_samples=4_000, n_steps=1_000, mc=_relative_differences(gear(accelerator), gear_cpu := gear(cpu))
    )

    # the CPU against itself with the mass matrix changed at its last digit: how far rounding alone moves each
    # statistic in these computations
    (sl_nudged, mc_nudged), _, _ = planetary(cpu, NUDGE)
    report["cpu_with_mass_times_1_plus_1e-15"] = dict(
        planetary=dict(
            sl=_relative_differences(sl_nudged, sl_cpu), mc=_relative_differences(mc_nudged, mc_cpu)
        ),
        gear_pair=dict(mc=_relative_differences(gear(cpu, NUDGE), gear_cpu)),
    )

    worst = 0.0
    nudged = report["cpu_with_mass_times_1_plus_1e-15"]
    print("largest difference / largest value: GPU vs CPU, and CPU vs CPU with the mass x (1 + 1e-15)")
    for model in ("planetary", "gear_pair"):
        for method in ("sl", "mc"):
            for stat, value in report[model].get(method, {}).items():
                print(f"{model:10s} {method}  {stat:11s} {value:9.2e}  {nudged[model][method][stat]:9.2e}")
                worst = max(worst, value)
    report["largest_relative_difference"] = worst
    name = "gpu_agrees_with_cpu" if accelerator.platform == "gpu" else "cpu_agrees_check"
    print("wrote", write(name, report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
