"""Memory and time of the planetary SL gradient against ``checkpoint_blocks`` (docs/gradients.md, "Long runs of
large models"): the gradient of a scalar of the 70-DOF run (ring thickness and bolt radial stiffness), saved every
step, with the state kept once per saved block (k = 1) and once per group of k blocks.

Memory is XLA's temporary allocation of each compiled gradient (``memory_analysis()``), which holds the states
kept for the reverse pass. The gradients and the forward run are timed with their calls alternating (serpentine
order), so that their ratios see the same machine load; compilation is timed apart (first call).

Usage: python benchmarks/bench_gradient_memory.py [--steps 10022] [--blocks 1,100] [--repeats 3]
Writes benchmarks/results/gradient_memory.json. Takes about 3 minutes at the default size on 2 cores.
"""

from __future__ import annotations

import argparse
import math
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _common import timed_interleaved, write

import pgtjax as pg
from pgtjax.models import planetary as pm


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--steps", type=int, default=10022, help="SL steps (10,022: one carrier period at 2.7 ms)"
    )
    ap.add_argument(
        "--blocks",
        type=lambda s: [int(v) for v in s.split(",")],
        default=[1, 100],
        help="values of checkpoint_blocks, comma-separated (1: the default, state kept once per saved block)",
    )
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    if 1 not in args.blocks:
        ap.error("--blocks must include 1 (the reference the others are compared with)")
    p = pm.default_params()
    lay = pm.layout(p)
    u_eq = pg.static_equilibrium(pm.build(p))
    p0 = pm.wind_filter_stationary_covariance(p, lay)
    node = lay.ring_start + 6
    x = jnp.array([float(p.ring.thickness), float(p.ring.k_support_radial)])

    def scalar(x, k):
        q = eqx.tree_at(lambda z: (z.ring.thickness, z.ring.k_support_radial), p, (x[0], x[1]))
        r = pg.solve_moments(
            pm.build(q),
            dt=0.0027,
            n_steps=args.steps,
            save_every=1,
            initial_displacement=u_eq,
            initial_covariance=p0,
            checkpoint_blocks=k,
        )
        return jnp.max(r.std_u[:, node]) + 1e-6 * r.force_std[-1, 0]

    programs, compile_s, temporaries = {}, {}, {}
    for k in args.blocks:
        start = time.perf_counter()
        compiled = jax.jit(jax.grad(scalar), static_argnums=1).lower(x, k).compile()
        compile_s[k] = time.perf_counter() - start
        temporaries[k] = compiled.memory_analysis().temp_size_in_bytes
        programs[f"gradient, checkpoint_blocks={k}"] = compiled
        print(
            f"checkpoint_blocks={k}: compiled in {compile_s[k]:.1f} s, temporaries {temporaries[k] / 1e6:.0f} MB"
        )
    programs["forward"] = jax.jit(scalar, static_argnums=1).lower(x, 1).compile()
    reference = np.asarray(programs["gradient, checkpoint_blocks=1"](x))
    times = timed_interleaved(programs, x, repeats=args.repeats, serpentine=True)
    forward_s = times["forward"]["median_s"]
    rows = []
    for k in args.blocks:
        name = f"gradient, checkpoint_blocks={k}"
        gradient = np.asarray(programs[name](x))
        difference = float(np.max(np.abs(gradient - reference) / np.abs(reference)))
        row = dict(
            checkpoint_blocks=k,
            temporary_mb=temporaries[k] / 1e6,
            compile_s=compile_s[k],
            gradient_median_s=times[name]["median_s"],
            gradient_runs_s=times[name]["runs_s"],
            ratio_to_forward=times[name]["median_s"] / forward_s,
            max_relative_difference_from_k1=difference,
        )
        rows.append(row)
        print(
            f"checkpoint_blocks={k}: gradient {row['gradient_median_s']:.2f} s ({row['ratio_to_forward']:.2f}x the "
            f"forward run's {forward_s:.2f} s), {row['temporary_mb']:.0f} MB, gradient differs from k=1 by "
            f"{difference:.1e} relative"
        )
    path = write(
        "gradient_memory",
        dict(
            command="python benchmarks/bench_gradient_memory.py "
            f"--steps {args.steps} --blocks {','.join(map(str, args.blocks))} --repeats {args.repeats}",
            n_dof=lay.n_dof,
            steps=args.steps,
            save_every=1,
            suggested_blocks=round(math.sqrt(args.steps)),
            forward_median_s=forward_s,
            forward_runs_s=times["forward"]["runs_s"],
            runs=rows,
        ),
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
