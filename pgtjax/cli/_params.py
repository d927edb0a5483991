"""The parameter options of every study command: ``--params FILE`` and ``--set TABLE.KEY=VALUE``, read into
one checked parameter dict, and the ``parameters.toml`` a run writes beside its results."""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import __version__
from .. import params as _params
from .._files import write_text

_HELP_FILE = {
    "planetary": "planetary parameter file (TOML, layout of pgtjax/params/planetary.toml); default: the embedded "
    "thesis ch. 3 set",
    "gear_pair": "gear-pair parameter file (TOML, layout of pgtjax/params/gear_pair.toml); default: the embedded "
    "thesis Table 4.1 set",
    "ring_ch6": "ring/moving-load parameter file (TOML, layout of pgtjax/params/ring_ch6.toml); default: the "
    "embedded thesis ch. 6 ring",
    "back_to_back": "bench parameter file (TOML, layout of pgtjax/params/back_to_back.toml); default: the "
    "embedded bench data",
}


def _assignment(text: str):
    try:
        return _params.parse_assignment(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


#: an entry of each kind of parameter file, for the --set help
_SET_EXAMPLE = {
    "planetary": "wind.mean_wind_speed=12 (the load: the banner prints the mean rotor torque)",
    "gear_pair": "damping.damping_ratio=0.05",
    "ring_ch6": "ring.face_width=0.2",
    "back_to_back": "operating.sun_torque_Nm=800",
}


def add_parameter_options(p: argparse.ArgumentParser, kind: str) -> None:
    """``--params`` and ``--set`` for a command on the parameter files of schema ``kind``."""
    p.add_argument("--params", type=Path, default=None, help=_HELP_FILE[kind])
    p.add_argument(
        "--set",
        dest="sets",
        action="append",
        type=_assignment,
        default=[],
        metavar="TABLE.KEY=VALUE",
        help=f"override one entry of the parameter file (repeatable), e.g. --set {_SET_EXAMPLE[kind]}; VALUE is "
        "read as TOML (0.1, [1e9, 2e9], true) or else as a string; docs/parameters.md lists every key",
    )


def parameters(args, kind: str, extra: dict | None = None) -> dict:
    """The checked parameter dict of ``--params`` (default: the embedded file) with ``--set`` and the
    command's own model options (``extra``: dotted name -> value) applied."""
    overrides = dict(args.sets)
    overrides.update({k: v for k, v in (extra or {}).items() if v is not None})
    return _params.read_params(args.params, kind, overrides)


def write_parameters(folder, data: dict, kind: str, command: str, options_outside: str = "") -> Path:
    """``parameters.toml``: every entry of the run's parameters (defaults filled in, overrides applied), so that
    ``pgtjax <command> --params parameters.toml`` with the same other options reproduces the run.
    ``options_outside``: the command's options that act on the model without being file entries (named in the
    header, so that nobody takes the file for the whole story)."""
    outside = f"\nNot in this file: {options_outside}." if options_outside else ""
    header = (
        f"Parameters of this run (pgtjax {__version__}, layout of pgtjax/params/{_params.EMBEDDED[kind]}), with "
        f"every --set applied:\n`pgtjax {command} --params parameters.toml` and the run's other options "
        f"(manifest.json has its command line) reproduce it. Units and sources: docs/parameters.md.{outside}"
    )
    return write_text(Path(folder) / "parameters.toml", _params.dumps_toml(data, header))
