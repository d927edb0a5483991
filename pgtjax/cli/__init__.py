"""Command-line interface: ``pgtjax <study> [options]``; ``pgtjax run`` is the main job on embedded defaults."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from . import cli_back_to_back, cli_ring
from ._cli_types import csv_floats, nonneg_int, positive_float, positive_int


def _add_gear_pair_options(p: argparse.ArgumentParser, quick: bool) -> None:
    p.add_argument("--params", type=Path, default=None,
                   help="gear-pair parameter file (TOML, layout of pgtjax/params/gear_pair.toml); "
                        "default: the embedded thesis Table 4.1 set")
    p.add_argument("--samples", type=nonneg_int, default=2000 if quick else 20_000,
                   help="Monte Carlo samples per regime (0 skips MC; default %(default)s)")
    p.add_argument("--dt", type=positive_float, default=1e-5, help="time step in s (default %(default)s)")
    p.add_argument("--t-end", type=positive_float, default=0.04, help="simulated time in s (default %(default)s)")
    p.add_argument("--saves", type=positive_int, default=80,
                   help="number of saved times (default %(default)s)")
    p.add_argument("--criteria", default="force,energy",
                   help="comma-separated SL criteria among force, energy, energy_origin (default %(default)s)")
    p.add_argument("--pdf-times", default="0.03",
                   help="comma-separated times in s for the PDF of the mesh deflection (default %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed of the Monte Carlo (default %(default)s)")
    p.add_argument("--chunk-size", type=nonneg_int, default=10_000,
                   help="MC samples per compiled batch; bounds memory (default %(default)s)")
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default: pgtjax-output/gear_pair)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")




def _run_gear_pair(args) -> int:
    import jax

    from .models import gear_pair as gp
    from .studies import gear_pair as study

    params = gp.default_params() if args.params is None else gp.load_params(args.params)
    regimes = gp.load_regimes(args.params) if args.params is not None else gp.load_regimes()
    out = args.out or Path("pgtjax-output") / "gear_pair"
    criteria = tuple(c.strip() for c in args.criteria.split(",") if c.strip())
    print(f"pgtjax gear pair (thesis ch. 4): {len(regimes)} regimes, SL {', '.join(criteria)}, "
          f"MC {args.samples} samples, dt = {args.dt:g} s, t_end = {args.t_end:g} s")
    start = time.perf_counter()
    result = study.run_study(
        params, regimes=regimes, criteria=criteria, n_samples=args.samples, dt=args.dt, t_end=args.t_end,
        n_saves=args.saves, pdf_times=csv_floats(args.pdf_times), key=jax.random.key(args.seed),
        chunk_size=args.chunk_size, progress=not args.quiet,
    )
    written = study.write_outputs(result, out)
    if args.samples:
        print(study.format_error_table(study.error_table(result)))
    print(f"done in {time.perf_counter() - start:.1f} s; {len(written)} files written to {out.resolve()}")
    return 0


def _run_step_study(args) -> int:
    from .models import gear_pair as gp
    from .studies import gear_pair as study

    params = gp.default_params() if args.params is None else gp.load_params(args.params)
    rows = study.step_convergence(params, dts=csv_floats(args.dts), t_end=args.t_end)
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        print(f"{'dt (s)':>10s} {'w_max dt':>9s} {'mean delta (m)':>15s} {'std delta (m)':>14s} {'d mean':>9s} {'d std':>9s}")
        for r in rows:
            print(f"{r['dt']:10.2e} {r['omega_max_dt']:9.3f} {r['mean']:15.6e} {r['std']:14.6e} "
                  f"{r['mean_rel_error']:9.2e} {r['std_rel_error']:9.2e}")
    return 0


def _run_modal(args) -> int:
    from .modal import modal_analysis
    from .models import gear_pair as gp

    params = gp.default_params() if args.params is None else gp.load_params(args.params)
    modes = modal_analysis(gp.gear_pair(params))
    rows = [dict(mode=i + 1, frequency_hz=float(f), shape=dict(zip(modes.dof_names, map(float, modes.shapes[:, i]))))
            for i, f in enumerate(modes.frequencies_hz)]
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        print(f"{'mode':>4s} {'f (Hz)':>12s}  shape ({', '.join(modes.dof_names)})")
        for r in rows:
            print(f"{r['mode']:4d} {r['frequency_hz']:12.3f}  " + " ".join(f"{v:+.3e}" for v in r["shape"].values()))
    return 0


def _add_planetary_options(p: argparse.ArgumentParser, quick: bool) -> None:
    p.add_argument("--params", type=Path, default=None,
                   help="planetary parameter file (TOML, layout of pgtjax/params/planetary.toml); default: the "
                        "embedded thesis Tables 3.1-3.2 set")
    p.add_argument("--samples", type=nonneg_int, default=300 if quick else 100_000,
                   help="Monte Carlo samples (0 skips MC; default %(default)s; the thesis used 100,000)")
    p.add_argument("--periods", type=positive_float, default=1.0, help="carrier periods simulated (default 1)")
    p.add_argument("--dt", type=positive_float, default=0.0027, help="time step in s (thesis: 0.0027)")
    p.add_argument("--saves", type=positive_int, default=200,
                   help="Monte Carlo saved times (default %(default)s)")
    p.add_argument("--sl-refine", type=positive_int, default=10,
                   help="SL is saved this many times as often as MC (default %(default)s: resolves the "
                        "meshing frequency)")
    p.add_argument("--criteria", default="force", help="comma-separated SL criteria (force, energy, energy_origin)")
    p.add_argument("--ring-model", choices=("elastic", "rigid"), default=None,
                   help="override the parameter file's ring model")
    p.add_argument("--elements", type=nonneg_int, default=None, help="override the number of ring elements")
    p.add_argument("--no-sweeps", action="store_true", help="skip the rim-thickness and support studies")
    p.add_argument("--no-sensitivities", action="store_true", help="skip the autodiff sensitivities")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed of the Monte Carlo")
    p.add_argument("--chunk-size", type=nonneg_int, default=5000, help="MC samples per compiled batch")
    p.add_argument("--out", type=Path, default=None, help="output folder (default: pgtjax-output/planetary)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _planetary_params(args):
    from .models import planetary as pm

    overrides = {}
    if args.ring_model:
        overrides["ring_model"] = args.ring_model
    if args.elements:
        overrides["n_elements"] = args.elements
    source = args.params if args.params is not None else None
    return pm.load_params(source, **overrides) if source else pm.default_params(**overrides)


def _run_planetary(args) -> int:
    import jax

    from .studies import planetary as study

    params = _planetary_params(args)
    out = args.out or Path("pgtjax-output") / "planetary"
    criteria = tuple(c.strip() for c in args.criteria.split(",") if c.strip())
    print(f"pgtjax planetary gear train (thesis ch. 3): {params.ring_model} ring, {params.n_planets} planets, "
          f"{args.periods:g} carrier period(s) of {study.carrier_period(params):.2f} s at dt = {args.dt:g} s, "
          f"SL {', '.join(criteria)}, MC {args.samples} samples")
    start = time.perf_counter()
    step = lambda msg: print(f"[{time.perf_counter() - start:7.1f} s] {msg}", flush=True)  # noqa: E731
    step("SL + moment recursion" + (" and Monte Carlo" if args.samples else ""))
    result = study.run_study(params, n_samples=args.samples, dt=args.dt, periods=args.periods, n_saves=args.saves,
                             sl_refine=args.sl_refine, criteria=criteria, key=jax.random.key(args.seed),
                             chunk_size=args.chunk_size, progress=not args.quiet)
    sweeps = None
    if not args.no_sweeps and params.ring_model == "elastic":
        step("rim thickness 87 / 128 / 168 mm (SL)")
        kw = dict(dt=args.dt, periods=args.periods, n_saves=args.saves, sl_refine=args.sl_refine)
        sweeps = {"Rim thickness: thesis Figs. 3.12-3.15": study.parameter_sweep(
            params, study.rim_thickness_variants(params), **kw)}
        counts = tuple(c for c in (3, 6, 9) if params.ring.n_elements % c == 0)
        step(f"bolt supports {counts} (SL)")
        sweeps["Supports: number of bolts"] = study.parameter_sweep(params, study.support_variants(params, counts), **kw)
    step("modal analysis")
    modal = study.modal_table(params)
    sens = None
    if not args.no_sensitivities and params.ring_model == "elastic":
        step("sensitivities by autodiff (checked by extrapolated central differences)")
        sens = study.sensitivities(params, dt=args.dt)
    written = study.write_outputs(result, out, sweeps=sweeps, modal=modal, sens=sens)
    if result.mc is not None:
        e = study.error_summary(result)
        f = e["mesh_force"]
        quiet = ", ".join(e["roundoff_dofs_not_compared"]) or "none"
        print(f"SL ({e['criterion']}) vs MC ({e['n_samples']} samples), in MC standard errors (s.e.):\n"
              f"  {e['dofs_compared']} DOFs: {100 * e['fraction_of_dof_time_points_within_3_se']:.2f} % "
              f"of (DOF, time) points within 3 s.e.; largest deviation {e['max_mean_error_in_se']:.1f} "
              f"(mean), {e['max_std_error_in_se']:.1f} (std)\n"
              f"  meshing forces: {100 * f['fraction_of_mesh_time_points_within_3_se']:.2f} % within 3 s.e.; "
              f"largest deviation {f['max_mean_error_in_se']:.1f} (mean), "
              f"{f['max_std_error_in_se']:.1f} (std)\n"
              f"  max contact-loss probability {e['contact_loss_probability_max']:.3g}; "
              f"not compared (zero by symmetry): {quiet}")
    if sens is not None:
        for q, grad, fd, el in zip(sens["quantities"], sens["gradient"], sens["central_difference"],
                                   sens["elasticity"]):
            print(f"d {q} / d(rim thickness, bolt k_r): autodiff [{grad[0]:.8e}, {grad[1]:.8e}], "
                  f"extrapolated central differences [{fd[0]:.8e}, {fd[1]:.8e}]; "
                  f"elasticities [{el[0]:+.3f}, {el[1]:+.3f}]")
    step(f"done; {len(written)} files written to {out.resolve()}")
    return 0


def _run_planetary_modal(args) -> int:
    from .studies import planetary as study

    rows = study.modal_table(_planetary_params(args))
    if args.json:
        print(json.dumps(rows, indent=2))
    else:
        print(f"{'mode':>4s} {'f (Hz)':>12s}  type")
        for r in rows:
            print(f"{r['mode']:4d} {r['frequency_hz']:12.3f}  {r['type']}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pgtjax",
        description="Differentiable stochastic dynamics of planetary gear trains: statistical linearization, "
                    "stochastic Newmark moments and Monte Carlo on JAX.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    run = sub.add_parser("run", help="the main job on the embedded default parameters: the ch. 3 planetary "
                                     "study at a quick size (--full: the thesis's 100,000 MC samples)")
    _add_planetary_options(run, quick=True)
    run.add_argument("--full", action="store_true", help="thesis size: 100,000 MC samples")
    run.set_defaults(func=lambda a: _run_planetary(_full(a)))

    plan = sub.add_parser("planetary", help="thesis ch. 3: planetary gear train with elastic ring, SL vs MC, rim "
                                            "thickness, supports, modes, sensitivities")
    _add_planetary_options(plan, quick=False)
    plan.set_defaults(func=_run_planetary)

    pmodal = sub.add_parser("planetary-modal", help="natural frequencies and mode types of the planetary model")
    pmodal.add_argument("--params", type=Path, default=None, help="planetary parameter file (TOML)")
    pmodal.add_argument("--ring-model", choices=("elastic", "rigid"), default=None, help="override the ring model")
    pmodal.add_argument("--elements", type=nonneg_int, default=None, help="override the number of ring elements")
    pmodal.add_argument("--json", action="store_true", help="print JSON instead of a table")
    pmodal.set_defaults(func=_run_planetary_modal)

    gear = sub.add_parser("gear-pair", help="thesis ch. 4: gear pair with backlash, SL vs MC in three regimes")
    _add_gear_pair_options(gear, quick=False)
    gear.set_defaults(func=_run_gear_pair)

    step = sub.add_parser("gear-pair-step", help="time-step convergence study of the gear-pair SL moments")
    step.add_argument("--params", type=Path, default=None, help="gear-pair parameter file (TOML)")
    step.add_argument("--dts", default="4e-5,2e-5,1e-5,5e-6,2.5e-6", help="comma-separated steps in s")
    step.add_argument("--t-end", type=positive_float, default=0.04, help="simulated time in s")
    step.add_argument("--json", action="store_true", help="print JSON instead of a table")
    step.set_defaults(func=_run_step_study)

    modal = sub.add_parser("gear-pair-modal", help="natural frequencies and mode shapes of the gear pair "
                                                   "(mesh closed at its mean stiffness)")
    modal.add_argument("--params", type=Path, default=None, help="gear-pair parameter file (TOML)")
    modal.add_argument("--json", action="store_true", help="print JSON instead of a table")
    modal.set_defaults(func=_run_modal)

    cli_ring.register(sub)
    cli_back_to_back.register(sub)
    return parser


def _full(args):
    if args.full:
        args.samples = 100_000
    return args


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        return args.func(args)
    except (ValueError, argparse.ArgumentTypeError) as err:  # bad input: a clear message, no traceback
        print(f"pgtjax: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
