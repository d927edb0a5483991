"""Command-line interface: ``pgtjax <study> [options]``; ``pgtjax run`` is the main job on embedded defaults."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


def _positive_int(text):
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def _positive_float(text):
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value}")
    return value


def _add_gear_pair_options(p: argparse.ArgumentParser, quick: bool) -> None:
    p.add_argument("--params", type=Path, default=None,
                   help="gear-pair parameter file (TOML, layout of pgtjax/params/gear_pair.toml); "
                        "default: the embedded thesis Table 4.1 set")
    p.add_argument("--samples", type=_positive_int, default=2000 if quick else 20_000,
                   help="Monte Carlo samples per regime (0 skips MC; default %(default)s)")
    p.add_argument("--dt", type=_positive_float, default=1e-5, help="time step in s (default %(default)s)")
    p.add_argument("--t-end", type=_positive_float, default=0.04, help="simulated time in s (default %(default)s)")
    p.add_argument("--saves", type=_positive_int, default=80, help="number of saved times (default %(default)s)")
    p.add_argument("--criteria", default="force,energy",
                   help="comma-separated SL criteria among force, energy, energy_origin (default %(default)s)")
    p.add_argument("--pdf-times", default="0.03",
                   help="comma-separated times in s for the PDF of the mesh deflection (default %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed of the Monte Carlo (default %(default)s)")
    p.add_argument("--chunk-size", type=_positive_int, default=10_000,
                   help="MC samples per compiled batch; bounds memory (default %(default)s)")
    p.add_argument("--out", type=Path, default=None,
                   help="output folder (default: pgtjax-output/gear_pair)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _csv_floats(text: str) -> tuple[float, ...]:
    return tuple(float(x) for x in text.split(",") if x.strip())


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
        n_saves=args.saves, pdf_times=_csv_floats(args.pdf_times), key=jax.random.key(args.seed),
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
    rows = study.step_convergence(params, dts=_csv_floats(args.dts), t_end=args.t_end)
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pgtjax",
        description="Differentiable stochastic dynamics of planetary gear trains: statistical linearization, "
                    "stochastic Newmark moments and Monte Carlo on JAX.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    run = sub.add_parser("run", help="the main job on the embedded default parameters (currently the ch. 4 "
                                     "gear-pair study at a quick size; --full for the thesis size)")
    _add_gear_pair_options(run, quick=True)
    run.add_argument("--full", action="store_true", help="thesis size: 20,000 MC samples per regime")
    run.set_defaults(func=lambda a: _run_gear_pair(_full(a)))

    gear = sub.add_parser("gear-pair", help="thesis ch. 4: gear pair with backlash, SL vs MC in three regimes")
    _add_gear_pair_options(gear, quick=False)
    gear.set_defaults(func=_run_gear_pair)

    step = sub.add_parser("gear-pair-step", help="time-step convergence study of the gear-pair SL moments")
    step.add_argument("--params", type=Path, default=None, help="gear-pair parameter file (TOML)")
    step.add_argument("--dts", default="4e-5,2e-5,1e-5,5e-6,2.5e-6", help="comma-separated steps in s")
    step.add_argument("--t-end", type=_positive_float, default=0.04, help="simulated time in s")
    step.add_argument("--json", action="store_true", help="print JSON instead of a table")
    step.set_defaults(func=_run_step_study)

    modal = sub.add_parser("gear-pair-modal", help="natural frequencies and mode shapes of the gear pair "
                                                   "(mesh closed at its mean stiffness)")
    modal.add_argument("--params", type=Path, default=None, help="gear-pair parameter file (TOML)")
    modal.add_argument("--json", action="store_true", help="print JSON instead of a table")
    modal.set_defaults(func=_run_modal)
    return parser


def _full(args):
    if args.full:
        args.samples = 20_000
    return args


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    try:
        return args.func(args)
    except ValueError as err:  # bad input: a clear message, no traceback
        print(f"pgtjax: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
