"""``pgtjax optimize`` end to end at a tiny size, resume from its history, and the design specification's
errors (each a ValueError naming the entry, before any simulation)."""

import copy
import json
import tomllib

import numpy as np
import pytest
from _outputs import assert_readme_lists_every_file

from pgtjax import params as embedded
from pgtjax._summary import missing_units
from pgtjax.cli import main
from pgtjax.models import planetary as pm
from pgtjax.studies import design as study

with open(embedded.path("design.toml"), "rb") as fh:
    SPEC = tomllib.load(fh)


def tiny_spec(**changes):
    d = copy.deepcopy(SPEC)
    d["horizon"]["periods"] = 0.005  # 50 steps
    d["optimizer"]["max_iter"] = 3
    d["verification"].update(n_samples=40, batches=2, save_every=10)
    d["pareto"]["weights"] = [0.4]
    for section, values in changes.items():
        d[section].update(values)
    return d


def write_spec(path, data):
    path.write_text(embedded.dumps_toml(data))
    return path


@pytest.mark.slow
def test_optimize_writes_its_outputs_and_resumes(tmp_path, capsys, monkeypatch):
    spec = write_spec(tmp_path / "design.toml", tiny_spec())
    params = embedded.read_toml(embedded.path("planetary.toml"))
    params["ring"]["n_elements"] = 6  # a bolt at every node: a small, fast model
    params_file = tmp_path / "params.toml"
    params_file.write_text(embedded.dumps_toml(params))
    out = tmp_path / "pgtjax-output" / "design"  # the default --out, relative to the working folder
    monkeypatch.chdir(tmp_path)
    args = ["optimize", "--params", str(params_file), "--design", str(spec)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "standard errors" in printed and "symmetric" in printed
    for name in (
        "history.json",
        "optimized_params.toml",
        "summary.json",
        "convergence.png",
        "variables.png",
        "response.png",
        "pareto.png",
    ):
        assert (out / name).is_file(), name
    summary = json.loads((out / "summary.json").read_text())
    assert missing_units(summary) == []  # every number carries its unit
    assert_readme_lists_every_file(out)
    assert summary["objective"]["unit"] == "m" and summary["units"]["cost_units"] == ["N/m"]
    check = summary["monte_carlo"]["designs"]["optimum"]
    assert np.isfinite(check["improvement_in_se"])
    np.testing.assert_allclose(check["improvement_in_se"], check["improvement"] / check["improvement_se"])
    assert len(summary["pareto_front"]) == 2
    # the optimized file is a parameter file that pgtjax run --params reads, with the optimum's values
    optimum = pm.load_params(out / "optimized_params.toml")
    variables = summary["variables"]
    np.testing.assert_allclose(
        np.asarray(optimum.ring.k_support_tangential),
        [variables[f"k_tangential[{i}]"]["optimum"] for i in range(6)],
        rtol=1e-14,
    )
    assert all(not name.startswith(".") for name in (p.name for p in out.iterdir()))  # no partial files
    # resume: a higher iteration limit continues the same history
    history = json.loads((out / "history.json").read_text())["iterations"]
    capsys.readouterr()
    assert main(args + ["--resume", "--max-iter", "5", "--no-pareto"]) == 0
    assert f"history.json: {len(history) - 1} iterations done" in capsys.readouterr().out
    resumed = json.loads((out / "history.json").read_text())["iterations"]
    assert resumed[: len(history)] == history
    assert [e["iteration"] for e in resumed] == list(range(len(resumed)))
    # it went on from the saved iterate (or stopped at once, converged there)
    assert (
        len(resumed) > len(history)
        or "below" in json.loads((out / "history.json").read_text())["status"]["reason"]
    )


@pytest.mark.slow
@pytest.mark.parametrize(
    "change, message",
    [
        ({"objective": {"kind": "peak"}}, r"\[objective\]: unknown kind 'peak'"),
        ({"objective": {"quantities": ["ring_mesh7"]}}, "unknown quantity 'ring_mesh7'"),
        ({"costs": {"kind": "price"}}, r"\[\[costs\]\] #1: unknown kind 'price'"),
        ({"variables": {"path": "ring.no_such"}}, r"\[\[variables\]\] #1: unknown or unsupported path"),
        ({"variables": {"lower": 2e11}}, r"\[\[variables\]\] #1: .*lower.*below"),
        ({"variables": {"lower": 0.0}}, r"\[\[variables\]\] #1: .*lower. > 0"),
        ({"variables": {"transform": "cube"}}, r"\[\[variables\]\] #1: .*transform"),
        ({"variables": {"colour": "red"}}, r"\[\[variables\]\] #1: unknown key"),
        ({"optimizer": {"name": "sgd"}}, r"\[optimizer\]: unknown name 'sgd'"),
        ({"horizon": {"periods": "one"}}, r"\[horizon\]: `periods` has the wrong type"),
    ],
)
def test_bad_design_specs_name_the_entry(change, message):
    data = tiny_spec()
    for section, values in change.items():
        target = data[section][0] if isinstance(data[section], list) else data[section]
        target.update(values)
    with pytest.raises(ValueError, match=message):
        study.build_problem(pm.default_params(), study.load_spec(data))


def test_bad_spec_on_the_command_line_is_one_line(tmp_path, capsys):
    data = tiny_spec(objective={"kind": "peak"})
    code = main(["optimize", "--design", str(write_spec(tmp_path / "d.toml", data)), "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "[objective]" in err
    assert main(["optimize", "--out", str(tmp_path / "new"), "--resume"]) == 2
    assert "no history to resume" in capsys.readouterr().err
