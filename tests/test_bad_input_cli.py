"""The command line's counterpart of ``test_bad_input.py``: every bad option or file is refused with exit
status 2 and one line that names the option or file, before any study computes."""

from __future__ import annotations

import time

import pytest

from pgtjax import params as embedded
from pgtjax.cli import main


def _planetary_file(tmp_path, change):
    import tomllib

    with open(embedded.path("planetary.toml"), "rb") as fh:
        data = tomllib.load(fh)
    change(data)
    path = tmp_path / "params.toml"
    path.write_text(embedded.dumps_toml(data))
    return str(path)


def _design_file(tmp_path, text):
    path = tmp_path / "design.toml"
    path.write_text(embedded.path("design.toml").read_text().replace(*text))
    return str(path)


# (id, argv (a function of tmp_path), text the one-line error must contain)
CASES = [
    ("cpu devices zero", lambda d: ["--cpu-devices", "0", "run"], "--cpu-devices"),
    ("cpu devices a word", lambda d: ["--cpu-devices", "two", "run"], "--cpu-devices"),
    ("huge seed", lambda d: ["gear-pair", "--seed", "99999999999999999999999"], "--seed"),
    ("planetary huge seed", lambda d: ["planetary", "--seed", "1e3"], "--seed"),
    ("dts zero", lambda d: ["gear-pair-step", "--dts", "0"], "--dts"),
    ("dts NaN", lambda d: ["gear-pair-step", "--dts", "nan"], "--dts"),
    ("dts empty", lambda d: ["gear-pair-step", "--dts", ""], "--dts"),
    ("dts a word", lambda d: ["gear-pair-step", "--dts", "abc"], "--dts"),
    ("dts not dividing t_end", lambda d: ["gear-pair-step", "--dts", "3e-4", "--t-end", "1e-3"], "`t_end`"),
    ("t_end below the step", lambda d: ["gear-pair-step", "--t-end", "1e-9"], "`t_end`"),
    ("criteria empty", lambda d: ["gear-pair", "--criteria", ","], "--criteria"),
    ("criteria unknown", lambda d: ["gear-pair", "--criteria", "bogus"], "--criteria"),
    ("criteria energy_origin", lambda d: ["planetary", "--criteria", "energy_origin"], "--criteria"),
    ("t_end inf", lambda d: ["gear-pair", "--t-end", "inf"], "--t-end"),
    ("dt NaN", lambda d: ["gear-pair", "--dt", "nan"], "--dt"),
    ("dt negative", lambda d: ["planetary", "--dt", "-1"], "--dt"),
    ("pdf time a word", lambda d: ["gear-pair", "--pdf-times", "abc"], "--pdf-times"),
    (
        "pdf time after the end",
        lambda d: ["gear-pair", "--pdf-times", "99", "--out", str(d / "o")],
        "`pdf_times`",
    ),
    (
        "t_end below dt",
        lambda d: ["gear-pair", "--dt", "1e-3", "--t-end", "1e-4", "--out", str(d / "o")],
        "`t_end`",
    ),
    ("samples negative", lambda d: ["gear-pair", "--samples", "-1"], "--samples"),
    ("samples one", lambda d: ["gear-pair", "--samples", "1"], "--samples: must be 0 (no Monte Carlo) or an"),
    (
        "planetary samples one",
        lambda d: ["run", "--samples", "1"],
        "--samples: must be 0 (no Monte Carlo) or an",
    ),
    (
        "planetary dt beyond half a mesh period",
        lambda d: ["run", "--dt", "5", "--periods", "0.02", "--out", str(d / "o")],
        "`--dt` must be > 0 and below half the period of the mesh stiffness's highest harmonic (harmonic 5",
    ),  # fmt: skip
    (
        "planetary periods shorter than a step",
        lambda d: ["planetary", "--periods", "1e-6", "--out", str(d / "o")],
        "`--periods` (1e-06 carrier periods, 2.706e-05 s) must span at least one time step",
    ),  # fmt: skip
    ("chunk size zero", lambda d: ["planetary", "--chunk-size", "0", "--out", str(d / "o")], "--chunk-size"),
    ("gear-pair chunk size zero", lambda d: ["gear-pair", "--chunk-size", "0"], "--chunk-size"),
    ("dt negative with an exponent", lambda d: ["gear-pair", "--dt", "-1e-5"], "--dt: must be a number > 0"),
    ("planetary elements zero", lambda d: ["planetary-modal", "--elements", "0"], "--elements"),
    (
        "planetary elements not a multiple",
        lambda d: ["planetary-modal", "--elements", "5"],
        "`ring.n_supports`",
    ),
    ("ring elements zero", lambda d: ["ring-modal", "--n-elements", "0"], "--n-elements"),
    ("ring free vibration elements", lambda d: ["ring-free-vibration", "--n-elements", "2"], "--n-elements"),
    ("ring support case", lambda d: ["ring-modal", "--support", "4"], "--support"),
    (
        "ring moving-load supports",
        lambda d: ["ring-moving-load", "--supports", "4", "--out", str(d / "o")],
        "--supports",
    ),  # fmt: skip
    ("support counts not dividing", lambda d: ["run", "--support-counts", "4,6"], "--support-counts"),
    ("support counts zero", lambda d: ["run", "--support-counts", "0"], "--support-counts"),
    ("rim thicknesses negative", lambda d: ["run", "--rim-thicknesses", "-0.1"], "--rim-thicknesses"),
    ("ring revolutions negative", lambda d: ["ring-moving-load", "--revolutions", "-1"], "--revolutions"),
    ("params missing", lambda d: ["gear-pair", "--params", str(d / "nope.toml")], "nope.toml"),
    ("params a folder", lambda d: ["gear-pair-modal", "--params", str(d)], "is a folder"),
    (
        "params not TOML",
        lambda d: ["gear-pair-modal", "--params", str(_text(d, "x = = 1"))],
        "not valid TOML",
    ),
    (
        "params misspelt key",
        lambda d: ["planetary-modal", "--params", _planetary_file(d, lambda p: p.update(n_planet=3))],
        "`n_planet`",
    ),  # fmt: skip
    (
        "params 2.7 planets",
        lambda d: ["planetary-modal", "--params", _planetary_file(d, lambda p: p.update(n_planets=2.7))],
        "`n_planets` = 2.7",
    ),  # fmt: skip
    ("out a regular file", lambda d: ["gear-pair", "--out", str(_text(d, "x"))], "--out"),
    ("out not creatable", lambda d: ["gear-pair", "--out", "/proc/pgtjax-cannot-exist"], "--out"),
    (
        "coordinator alone",
        lambda d: ["planetary", "--coordinator", "127.0.0.1:1", "--out", str(d / "o")],
        "--coordinator",
    ),  # fmt: skip
    (
        "process id out of range",
        lambda d: [
            "planetary",
            "--coordinator",
            "127.0.0.1:1",
            "--processes",
            "2",
            "--process-id",
            "5",
            "--out",
            str(d / "o"),
        ],
        "--process-id",
    ),  # fmt: skip
    (
        "resume without samples",
        lambda d: ["planetary", "--resume", "--samples", "0", "--out", str(d / "o")],
        "--resume",
    ),  # fmt: skip
    (
        "peak forces without samples",
        lambda d: ["planetary", "--peak-forces", "20", "--samples", "0", "--out", str(d / "o")],
        "--peak-forces",
    ),  # fmt: skip
    (
        "peak start without peak forces",
        lambda d: ["planetary", "--peak-start", "0.5", "--out", str(d / "o")],
        "--peak-start",
    ),  # fmt: skip
    (
        "peak start negative",
        lambda d: ["planetary", "--peak-forces", "20", "--peak-start", "-1", "--out", str(d / "o")],
        "--peak-start",
    ),  # fmt: skip
    (
        "peak forces negative",
        lambda d: ["planetary", "--peak-forces", "-3", "--out", str(d / "o")],
        "--peak-forces",
    ),  # fmt: skip
    (
        "resume without checkpoint",
        lambda d: ["planetary", "--resume", "--out", str(d / "o")],
        "run without --resume",
    ),
    (
        "resume another seed",
        lambda d: [
            "planetary",
            "--resume",
            "--seed",
            "4",
            "--samples",
            "300",
            "--checkpoint",
            _checkpoint(d),
        ],
        "(key, from --seed: checkpoint [0, 3], this run [0, 4])",
    ),  # fmt: skip
    (
        "coordinator without a port",
        lambda d: ["planetary", "--coordinator", "localhost", "--processes", "2", "--process-id", "0"],
        "`--coordinator` must be HOST:PORT",
    ),  # fmt: skip
    (
        "coordinator port a word",
        lambda d: [
            "planetary",
            "--coordinator",
            "127.0.0.1:notaport",
            "--processes",
            "2",
            "--process-id",
            "0",
        ],
        "`--coordinator` must be HOST:PORT",
    ),  # fmt: skip
    (
        "checkpoint in a file",
        lambda d: ["planetary", "--checkpoint", str(_text(d, "x") / "ck.npz"), "--out", str(d / "o")],
        "is a file, not a folder",
    ),  # fmt: skip
    (
        "coordinator IPv6 without brackets",
        lambda d: ["planetary", "--coordinator", "fe80::1", "--processes", "2", "--process-id", "0"],
        "an IPv6 host in brackets",
    ),  # fmt: skip
    (
        "optimize periods negative",
        lambda d: ["optimize", "--periods", "-1", "--out", str(d / "o")],
        "periods",
    ),
    ("optimize design missing", lambda d: ["optimize", "--design", str(d / "none.toml")], "none.toml"),
    (
        "optimize bad transform",
        lambda d: [
            "optimize",
            "--design",
            _design_file(d, ('transform = "log"', 'transform = "sqrt"')),
            "--out",
            str(d / "o"),
        ],
        "`transform`",
    ),  # fmt: skip
    (
        "back-to-back window",
        lambda d: ["back-to-back", "--stft-window", "0", "--out", str(d / "o")],
        "--stft-window",
    ),
]


def _text(folder, text):
    path = folder / "file.txt"
    path.write_text(text)
    return path


def _checkpoint(folder) -> str:
    """A checkpoint of the planetary Monte Carlo of `--seed 3 --samples 300` on this machine's devices (its
    statistics are not read: a resume of another seed must be refused before any work)."""
    import jax

    from pgtjax._checkpoint import save_checkpoint
    from pgtjax._montecarlo import _samples_per_device

    path = folder / "ck.npz"
    devices = jax.local_devices()
    description = dict(
        n_samples=300,
        key=[0, 3],
        samples_per_device=_samples_per_device(300, None, devices, 1),
        devices=len(devices),
        processes=1,
        process=0,
    )
    save_checkpoint(path, {"count": 0.0}, description, what="monte_carlo")
    return str(path)


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_bad_option_exits_2_with_one_line_naming_it(case, tmp_path, capsys, monkeypatch):
    _, argv, needle = case
    monkeypatch.chdir(tmp_path)  # a default --out is created in the working folder
    start = time.perf_counter()
    try:
        code = main(argv(tmp_path))
    except SystemExit as stop:  # argparse's own refusal of an option
        code = stop.code
    err = capsys.readouterr().err
    assert code == 2, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("pgtjax") and "error" in last, err
    assert needle in last, err
    assert "Traceback" not in err
    assert time.perf_counter() - start < 30.0  # refused before a study runs
    # the --out write check creates the folder; a refused run must not leave it behind, empty, as if it had run
    empty = [str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*") if p.is_dir() and not any(p.iterdir())]
    assert not empty, f"refused run left empty folders {empty}"


def test_unknown_subcommand(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["bogus"])
    assert stop.value.code == 2 and "invalid choice: 'bogus'" in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["planetary-modal", "--set", "ring.rim_thicknes=0.1"], "did you mean `ring.rim_thickness`"),
        (["gear-pair-modal", "--set", "gears.teeth_1=21.5"], "`gears.teeth_1` = 21.5"),
        (["gear-pair-modal", "--set", "gearsteeth_1"], "--set"),
        (["ring-modal", "--set", "supports.n_bolts=5"], "`supports.n_bolts`"),
        (["back-to-back-modal", "--set", "gears.n_planets=4"], "`gears.n_planets`"),
        (["planetary-modal", "--set", "ring.teeth.x=1"], "`ring.teeth` is a value"),
    ],
    ids=["misspelt", "teeth", "no value", "bolts", "bench planets", "through a value"],
)
def test_set_overrides_are_checked_like_the_file(argv, needle, capsys):
    try:
        code = main(argv)
    except SystemExit as stop:
        code = stop.code
    err = capsys.readouterr().err
    assert code == 2 and needle in err.strip().splitlines()[-1], err


def test_refused_run_removes_only_the_folders_it_created(tmp_path, capsys):
    """The write check's clean-up removes what the check made, never a folder that was there before, even
    through ``..`` in ``--out``."""
    (tmp_path / "existing_empty").mkdir()
    out = tmp_path / "new" / ".." / "existing_empty" / "run"
    code = main(["gear-pair", "--pdf-times", "99", "--out", str(out)])
    assert code == 2 and "pdf_times" in capsys.readouterr().err
    assert (tmp_path / "existing_empty").is_dir()
    assert not (tmp_path / "existing_empty" / "run").exists()
    assert not (tmp_path / "new").exists()
