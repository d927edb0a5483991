"""The command line's handling of unusable output folders (Ctrl-C: ``test_safe_outputs.py``)."""

import os
import time

import pytest
from _outputs import assert_readme_lists_every_file

from pgtjax.cli import main


def test_out_that_is_a_regular_file_is_refused_before_computing(tmp_path, capsys):
    target = tmp_path / "taken"
    target.write_text("not a folder")
    start = time.perf_counter()
    code = main(["gear-pair", "--out", str(target)])
    err = capsys.readouterr().err
    assert code == 2
    assert "--out" in err and str(target) in err
    assert err.count("\n") == 1
    assert time.perf_counter() - start < 5.0  # refused at once, not after the study
    assert target.read_text() == "not a folder"


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write into read-only folders")
def test_out_inside_a_read_only_folder_is_refused(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        assert main(["gear-pair", "--out", str(locked / "run")]) == 2
        assert "--out" in capsys.readouterr().err
    finally:
        locked.chmod(0o700)


@pytest.mark.slow
def test_parameters_toml_reproduces_the_run_and_set_overrides_name_their_key(tmp_path, monkeypatch, capsys):
    """A run with --set writes parameters.toml (every entry, the override applied); a second run from that file
    alone gives the same summary.json and results (tiny sizes, Monte Carlo and sweeps included); every number
    in summary.json carries a unit; README.txt lists every file; a misspelt --set key is named. The second run
    is `pgtjax run` as the README gives it, without --out, in a folder where no pgtjax-output exists yet (it
    failed when the Monte Carlo started: its checkpoint folder did not exist)."""
    import json

    import numpy as np

    import pgtjax as pg
    from pgtjax._summary import missing_units

    small = ["--samples", "20", "--periods", "0.01", "--no-sensitivities", "--quiet", "--peak-forces", "30"]
    first, fresh = tmp_path / "first", tmp_path / "fresh"
    second = fresh / "pgtjax-output" / "planetary"  # the default output folder
    assert main(["run", *small, "--set", "ring.rim_thickness=0.1", "--out", str(first)]) == 0
    written = (first / "parameters.toml").read_text()
    assert "rim_thickness = 0.1\n" in written
    fresh.mkdir()
    monkeypatch.chdir(fresh)
    assert main(["run", *small, "--params", str(first / "parameters.toml")]) == 0, capsys.readouterr().err
    manifest = json.loads((second / "manifest.json").read_text())
    assert manifest["status"] == "complete"
    names = {f["name"] for f in manifest["files"]}
    assert {"summary.json", "planetary_mc.npz", "planetary_sl_force.npz"} <= names
    assert (second / "parameters.toml").read_text() == written.replace(str(first), str(second))
    summary = [json.loads((d / "summary.json").read_text()) for d in (first, second)]
    assert summary[0] == summary[1]
    assert missing_units(summary[0]) == [], "every number in summary.json carries a unit"
    assert {"sl_vs_mc", "rim_thickness", "supports", "modes", "peak_meshing_forces"} <= set(summary[0])
    assert (first / "planetary_peak_forces.png").is_file()
    assert_readme_lists_every_file(first)
    a, _ = pg.load_results(first / "planetary_sl_force.npz")
    b, _ = pg.load_results(second / "planetary_sl_force.npz")
    np.testing.assert_array_equal(np.asarray(a.std_u), np.asarray(b.std_u))
    capsys.readouterr()
    assert main(["planetary-modal", "--set", "ring.rim_thicknes=0.1"]) == 2
    assert "did you mean `ring.rim_thickness`" in capsys.readouterr().err


_CACHED_PROGRAM = """
import sys
import jax, jax.numpy as jnp
import pgtjax as pg
hits = []
jax.monitoring.register_event_listener(lambda name, **kw: hits.append(name.endswith("/cache_hits")))
assert pg.use_compilation_cache(sys.argv[1]).is_dir()
y = jax.jit(lambda x: jnp.sin(x) @ x)(jnp.linspace(0.0, 1.0, 400).reshape(20, 20))
assert y.dtype == jnp.float64
print(repr(float(jnp.sum(y))), sum(hits))
"""


@pytest.mark.slow
def test_compilation_cache_gives_the_next_process_the_compiled_programs(tmp_path):
    """``pg.use_compilation_cache``: a program compiled in well under JAX's default threshold of a second is
    kept (the folder gains its entry), and a second process loads it (JAX's cache-hit event) and computes the
    same doubles."""
    import subprocess
    import sys

    cache = tmp_path / "cache"

    def run():
        out = subprocess.run(
            [sys.executable, "-c", _CACHED_PROGRAM, str(cache)], capture_output=True, text=True, timeout=300
        )
        assert out.returncode == 0, out.stderr
        value, hits = out.stdout.split()
        return value, int(hits), out.stderr

    first, hits, _ = run()
    assert hits == 0
    assert any(p.name.startswith("jit__lambda") for p in cache.iterdir())
    second, hits, err = run()
    assert second == first
    if "doesn't match the machine type" in err:  # pragma: no cover - some Intel CPUs with AVX-512
        pytest.skip("JAX rejects its own cached CPU programs on this CPU (jax-ml/jax issue 38445)")
    assert hits >= 1


_SWITCHED_FOLDER = """
import sys
import jax, jax.numpy as jnp
import pgtjax as pg
pg.use_compilation_cache(sys.argv[1])
jax.jit(lambda x: jnp.cos(x) + 1.0)(jnp.ones(3)).block_until_ready()
pg.use_compilation_cache(sys.argv[2])
jax.jit(lambda x: jnp.tan(x) * 2.0)(jnp.ones(3)).block_until_ready()
"""


def test_compilation_cache_called_again_writes_to_the_new_folder(tmp_path):
    """A second ``pg.use_compilation_cache`` takes effect in a process that already compiled into another
    folder (JAX keeps writing to the first one unless its cache is reset)."""
    import subprocess
    import sys

    first, second = tmp_path / "first", tmp_path / "second"
    out = subprocess.run(
        [sys.executable, "-c", _SWITCHED_FOLDER, str(first), str(second)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    assert len(list(first.glob("jit__lambda*"))) == 1
    assert len(list(second.glob("jit__lambda*"))) == 1
    assert not list(tmp_path.glob("*/.pgtjax-write-check-*"))


def test_compilation_cache_folder_that_cannot_be_made_is_refused_with_the_option_named(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["--compilation-cache", str(blocker / "cache"), "gear-pair-modal"]) == 2
    err = capsys.readouterr().err
    assert "--compilation-cache" in err and str(blocker / "cache") in err and err.count("\n") == 1
