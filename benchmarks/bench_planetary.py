"""Benchmark of the ch. 3 planetary model (70 DOF, 6 backlash meshes, moving ring contacts):
SL + recursion over one carrier period at the thesis's step (10,022 steps of 0.0027 s), its gradient
(reverse mode w.r.t. rim thickness and bolt stiffness), and Monte Carlo throughput, extrapolated to the
thesis's 100,000 samples, with the peak resident memory of the process. Monte Carlo is timed in
eigen-coordinates (the default) and, calls alternating, in physical coordinates as the baseline.

The gradient is timed at each save interval of ``--grad-save-every`` (forward and gradient calls alternating,
so that their ratio sees the same machine load). Reverse mode keeps the state once per saved block and
rematerializes the block's steps: with one step per block the recomputed step and its transpose form one
loop body, while longer blocks also stack each step's residuals for the block's reverse loop.

Usage: python benchmarks/bench_planetary.py [--mc-samples 2000] [--mc-periods 0.25] [--repeats 3]
       [--grad-save-every 1,2]
Writes benchmarks/results/planetary.json. Correctness first: MC vs SL on a short run.
"""

from __future__ import annotations

import argparse
import resource

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _common import timed, timed_interleaved, write

import pgtjax as pg
from pgtjax.models import planetary as pm
from pgtjax.studies import planetary as study

THESIS_SL_S = 48.0
THESIS_MC_S = 223 * 3600.0


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--mc-samples", type=int, default=2000)
    ap.add_argument(
        "--mc-periods", type=float, default=0.25, help="fraction of a carrier period for MC timing"
    )
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument(
        "--grad-save-every",
        type=lambda s: [int(v) for v in s.split(",")],
        default=[1, 2],
        help="save intervals at which to time the gradient, comma-separated",
    )
    args = ap.parse_args()
    p = pm.default_params()
    lay = pm.layout(p)
    system = pm.build(p)
    u_eq = pg.static_equilibrium(system)
    p0 = pm.wind_filter_stationary_covariance(p, lay)
    dt = 0.0027
    n_period = int(round(study.carrier_period(p) / dt))

    # --- correctness: MC vs SL on a short run
    kw = dict(dt=dt, n_steps=200, save_every=50, initial_displacement=u_eq, initial_covariance=p0)
    sl = pg.solve_moments(system, **kw)
    mc = pg.monte_carlo(system, n_samples=1000, key=jax.random.key(5), progress=False, **kw)
    se_m, se_s = mc.standard_error("u")
    dofs = [lay.sun(2), lay.carrier(2), lay.planet(0, 1), lay.ring_start + 7]
    z = float(np.max(np.abs(np.asarray(sl.std_u - mc.std_u))[1:, dofs] / np.asarray(se_s)[1:, dofs]))
    print(f"correctness: max |SL - MC| std over 4 DOFs = {z:.2f} s.e.")

    # --- SL over one carrier period
    sl_fn = lambda: (  # noqa: E731
        pg.solve_moments(
            system,
            dt=dt,
            n_steps=n_period,
            save_every=2,
            initial_displacement=u_eq,
            initial_covariance=p0,
        ).std_u
    )
    sl_first, sl_med, sl_all, _ = timed(sl_fn, repeats=args.repeats)
    print(f"SL one carrier period ({n_period} steps): first {sl_first:.1f} s, median {sl_med:.2f} s {sl_all}")

    # --- gradient of a scalar of the full-period SL run, for each save interval asked for: reverse mode
    # rematerializes each saved block, so the interval changes the gradient's cost (module docstring)
    node = lay.ring_start + 6
    x = jnp.array([float(p.ring.thickness), 1.362e10])
    gradients = []
    for save_every in args.grad_save_every:

        def loss(x, save_every=save_every):
            ring = eqx.tree_at(
                lambda r: (r.thickness, r.radius, r.k_support_radial),
                p.ring,
                (x[0], p.ring_pitch_radius + x[0] / 2, x[1]),
            )
            q = eqx.tree_at(lambda z: z.ring, p, ring)
            r = pg.solve_moments(
                pm.build(q),
                dt=dt,
                n_steps=n_period,
                save_every=save_every,
                initial_displacement=u_eq,
                initial_covariance=p0,
            )
            return jnp.max(r.std_u[:, node])

        t = timed_interleaved(
            {"forward": jax.jit(loss), "gradient": jax.jit(jax.grad(loss))}, x, repeats=args.repeats
        )
        fwd, grd = t["forward"], t["gradient"]
        ratio = grd["median_s"] / fwd["median_s"]
        print(
            f"scalar of the SL run (save_every={save_every}): forward {fwd['median_s']:.2f} s, gradient "
            f"{grd['median_s']:.2f} s ({ratio:.2f}x)"
        )
        gradients.append(
            dict(
                save_every=save_every,
                forward_median_s=fwd["median_s"],
                gradient_median_s=grd["median_s"],
                ratio=ratio,
                forward_runs_s=fwd["runs_s"],
                gradient_runs_s=grd["runs_s"],
                forward_first_call_s=fwd["first_call_s"],
                gradient_first_call_s=grd["first_call_s"],
            )
        )

    # --- Monte Carlo throughput
    n_mc = int(round(args.mc_periods * n_period))
    n_mc -= n_mc % 10

    def mc_run(propagation):
        return pg.monte_carlo(
            system,
            n_samples=args.mc_samples,
            key=jax.random.key(1),
            dt=dt,
            n_steps=n_mc,
            save_every=10,
            chunk_size=args.mc_samples,
            initial_displacement=u_eq,
            initial_covariance=p0,
            progress=False,
            propagation=propagation,
        )

    # the default (eigen-coordinates) against the physical-coordinate step as the baseline, calls alternating
    runs = timed_interleaved(
        {name: (lambda name=name: mc_run(name).std_u) for name in ("eigen", "physical")}, repeats=args.repeats
    )
    mc_first, mc_med, mc_all = (runs["eigen"][k] for k in ("first_call_s", "median_s", "runs_s"))
    per_sample_step = mc_med / (args.mc_samples * n_mc)
    physical_per_sample_step = runs["physical"]["median_s"] / (args.mc_samples * n_mc)
    extrapolated = per_sample_step * 100_000 * n_period
    rss_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2
    print(
        f"MC {args.mc_samples} x {n_mc} steps: median {mc_med:.2f} s -> {per_sample_step * 1e9:.0f} ns per "
        f"sample-step; 100,000 samples x one period extrapolated {extrapolated / 60:.1f} min; peak RSS {rss_gb:.2f} GB"
    )
    print(
        f"  physical-coordinate baseline {physical_per_sample_step * 1e9:.0f} ns per sample-step: "
        f"eigen-coordinates {physical_per_sample_step / per_sample_step:.2f}x faster"
    )
    path = write(
        "planetary",
        dict(
            command="python benchmarks/bench_planetary.py "
            + " ".join(
                f"--{k.replace('_', '-')} {','.join(map(str, v)) if isinstance(v, list) else v}"
                for k, v in vars(args).items()
            ),
            n_dof=lay.n_dof,
            n_contacts=system.n_contacts,
            dt_s=dt,
            steps_per_carrier_period=n_period,
            correctness=dict(max_std_deviation_in_se=z),
            sl_one_period=dict(
                first_call_s=sl_first,
                median_s=sl_med,
                runs_s=sl_all,
                ratio_vs_thesis_48s=THESIS_SL_S / sl_med,
            ),
            gradient=gradients,
            monte_carlo=dict(
                samples=args.mc_samples,
                steps=n_mc,
                first_call_s=mc_first,
                median_s=mc_med,
                runs_s=mc_all,
                per_sample_step_ns=per_sample_step * 1e9,
                extrapolated_100k_one_period_s=extrapolated,
                ratio_vs_thesis_223_cpu_hours=THESIS_MC_S / extrapolated,
                peak_rss_gb=rss_gb,
                chunk_size=args.mc_samples,
                save_every=10,
                propagation="eigen",
                physical_baseline=dict(
                    median_s=runs["physical"]["median_s"],
                    runs_s=runs["physical"]["runs_s"],
                    per_sample_step_ns=physical_per_sample_step * 1e9,
                    speedup_of_eigen=physical_per_sample_step / per_sample_step,
                ),
            ),
        ),
    )
    print("wrote", path)


if __name__ == "__main__":
    main()
