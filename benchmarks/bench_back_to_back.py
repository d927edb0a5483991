"""Benchmark: 1 s of run-up of the back-to-back bench at dt = 1e-4 s (10,000 Newmark-Newton steps, 12 DOF,
12 Hertzian mesh contacts), as in the paper (Hammami et al., section 4: dt = 1e-4 s).

Correctness is checked before timing (every contact solve converged, finite states, the STFT ridge of a
transmission error within 2 % of Z_r f_c). Compilation is timed separately from the run (first call minus the
median of the timed calls); every timed call ends with ``jax.block_until_ready``. Writes
``benchmarks/results/back_to_back.json``.

    python benchmarks/bench_back_to_back.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import jax
import numpy as np
from _common import machine

import pgtjax as pg
from pgtjax.models import back_to_back as bb
from pgtjax.studies import back_to_back as study

DT = 1e-4
T_END = 1.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5, help="timed runs (median reported, >= 3)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "back_to_back.json")
    args = ap.parse_args(argv)
    repeats = max(args.repeats, 3)

    params = bb.default_params(ramp_start=0.0, ramp_duration=T_END)
    t0 = time.perf_counter()
    model = bb.build_model(params)
    u0, v0 = bb.initial_state(model, 0.5 * DT)
    jax.block_until_ready(u0)
    build_s = time.perf_counter() - t0
    n_steps = int(round(T_END / DT))

    def run():
        tr = pg.simulate(
            model.system, t0=0.5 * DT, dt=DT, n_steps=n_steps, initial_displacement=u0, initial_velocity=v0
        )
        return jax.block_until_ready(tr)

    t0 = time.perf_counter()
    traj = run()
    first_s = time.perf_counter() - t0

    # correctness before timing
    assert int(traj.unconverged) == 0, "contact solves did not converge"
    assert np.all(np.isfinite(np.asarray(traj.u))), "non-finite states"
    reg = study.RegimeResult(
        "run_up",
        model,
        traj,
        bb.mesh_history(model, traj.times, traj.delta),
        np.asarray(bb.accelerations(model, traj.times, traj.u, traj.v, traj.force)),
        np.asarray(traj.v[:, 6] / model.radii[6]) / (2 * np.pi),
        np.asarray(model.profile.speed(traj.times)),
        np.zeros(n_steps + 1),
        np.asarray(model.profile.torque(traj.times)),
        DT,
        first_s,
    )
    ridge = study.ridge_check(reg, 0.1)
    ridge_err = ridge["transmission_error_ring-planet1_T"]["max_relative_error"]
    assert ridge_err < 0.02, f"STFT ridge off by {ridge_err:.3%}"

    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        run()
        times.append(time.perf_counter() - t0)
    median = statistics.median(times)
    result = dict(
        what="pgtjax.simulate of the back-to-back bench: 1 s run-up 900 -> 1500 rpm, torque 100 -> 300 N m, "
        "dt = 1e-4 s (10,000 steps), 12 DOF, 12 nonlinear Hertzian mesh contacts (Newton in contact space)",
        n_steps=n_steps,
        dt_s=DT,
        repeats=repeats,
        build_and_static_s=build_s,
        compile_s=first_s - median,
        first_call_s=first_s,
        run_median_s=median,
        run_all_s=times,
        per_step_us=1e6 * median / n_steps,
        correctness=dict(
            unconverged=int(traj.unconverged),
            stft_ridge_max_relative_error=ridge_err,
            stft_ridge_ring_acceleration_3fm=ridge["ring_T_acceleration"]["max_relative_error"],
        ),
        machine=machine(),
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2))
    print(json.dumps({k: v for k, v in result.items() if k != "run_all_s"}, indent=2))
    print(f"written to {args.out.resolve()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
