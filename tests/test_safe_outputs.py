"""Nothing half-written is left behind: output sets published with a manifest written last, stale files of an
earlier run moved aside, result files that survive a kill, and Ctrl-C that exits 130 with one line."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

import pgtjax as pg
from pgtjax._files import MANIFEST, PREVIOUS, publish


def _writer(contents: dict[str, str]):
    def write(folder):
        paths = []
        for name, text in contents.items():
            path = folder / name
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
            paths.append(path)
        return paths

    return write


def test_publish_lists_every_file_and_moves_the_previous_run_aside(tmp_path):
    out = tmp_path / "out"
    first = publish(
        out, _writer({"summary.json": "{}", "mc.npz": "mc", "figs/a.png": "a"}), command=["first"]
    )
    assert sorted(p.name for p in first) == ["a.png", "mc.npz", "summary.json"]
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest["status"] == "complete" and manifest["command"] == ["first"]
    assert {f["name"] for f in manifest["files"]} == {"summary.json", "mc.npz", "figs/a.png"}
    # a second run without Monte Carlo: the first run's mc.npz must not sit beside the new summary
    publish(out, _writer({"summary.json": '{"samples": 0}'}), command=["second"])
    assert not (out / "mc.npz").exists() and not (out / "figs" / "a.png").exists()
    assert (out / PREVIOUS / "mc.npz").read_text() == "mc"
    assert (out / PREVIOUS / "summary.json").read_text() == "{}"
    manifest = json.loads((out / MANIFEST).read_text())
    assert [f["name"] for f in manifest["files"]] == ["summary.json"]
    import hashlib

    assert manifest["files"][0]["sha256"] == hashlib.sha256(b'{"samples": 0}').hexdigest()
    assert not [p for p in out.iterdir() if p.name.startswith(".partial")]


def test_a_failed_write_leaves_the_previous_outputs_and_manifest_untouched(tmp_path):
    out = tmp_path / "out"
    publish(out, _writer({"summary.json": "old"}))
    before = (out / MANIFEST).read_text()

    def failing(folder):
        (folder / "summary.json").write_text("new, half")
        raise RuntimeError("figure failed")

    with pytest.raises(RuntimeError):
        publish(out, failing)
    assert (out / "summary.json").read_text() == "old" and (out / MANIFEST).read_text() == before
    assert not [p for p in out.iterdir() if p.name.startswith(".partial")]


def test_files_written_during_the_run_are_listed_but_not_moved(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    checkpoint = out / "monte_carlo.checkpoint.npz"
    checkpoint.write_text("state")
    publish(out, lambda folder: _writer({"s.json": "1"})(folder) + [checkpoint])
    publish(out, lambda folder: _writer({"s.json": "2"})(folder) + [checkpoint])
    assert checkpoint.read_text() == "state"  # a resumable state stays where the next run reads it
    files = json.loads((out / MANIFEST).read_text())["files"]
    assert {f["name"]: f.get("written_during_the_run", False) for f in files} == {
        "s.json": False,
        "monte_carlo.checkpoint.npz": True,
    }


@pytest.mark.slow
def test_a_process_killed_while_overwriting_a_result_file_leaves_it_loadable(tmp_path):
    """save_results rewrites a large result in a loop; SIGKILL at varied moments; the file must load each
    time (the old or the new content, never a stub)."""
    script = tmp_path / "writer.py"
    script.write_text(
        textwrap.dedent(
            f"""
            import sys
            import numpy as np, jax.numpy as jnp
            import pgtjax as pg
            n = 4000
            rng = np.random.default_rng(0)
            def result(k):
                a = lambda: jnp.asarray(rng.standard_normal((n, 40)))
                return pg.Trajectory(times=jnp.arange(n, dtype=float), dof_names=tuple(f"q{{i}}" for i in range(40)),
                    dof_units=("m",) * 40, contact_names=(), u=a(), v=a(),
                    delta=jnp.zeros((n, 0)), force=jnp.zeros((n, 0)), unconverged=jnp.asarray(float(k)))
            pg.save_results({str(tmp_path / "r.npz")!r}, result(0))
            print("ready", flush=True)
            k = 0
            while True:
                k += 1
                pg.save_results({str(tmp_path / "r.npz")!r}, result(k))
            """
        )
    )
    rng = np.random.default_rng(1)
    for attempt in range(5):
        proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
        assert proc.stdout.readline().strip() == "ready"
        time.sleep(float(rng.uniform(0.2, 1.5)))
        proc.kill()
        proc.wait()
        loaded, _ = pg.load_results(tmp_path / "r.npz")
        assert loaded.u.shape == (4000, 40), attempt


def _start_study(tmp_path, index: int):
    out = tmp_path / f"out{index}"
    argv = [
        sys.executable,
        "-m",
        "pgtjax.cli",
        "gear-pair",
        "--samples",
        "200000",
        "--quiet",
        "--out",
        str(out),
    ]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True), out


def _wait_until_running(proc, out):
    """main() creates the output folder once its Ctrl-C handler is in place, just before the study starts."""
    deadline = time.monotonic() + 120.0
    while not out.exists() and time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.02)


@pytest.mark.slow
def test_ctrl_c_exits_130_with_one_line_in_20_of_20_tries(tmp_path):
    """SIGINT to a running study at 20 moments, from its first instant to seconds into the computation (four
    processes at a time): exit status 130 every time, one line on stderr, no traceback or crash, no staging
    folder left and no output set that claims to be complete."""
    delays = np.linspace(0.0, 3.0, 20)
    results = []
    for start in range(0, 20, 4):
        batch = [(*_start_study(tmp_path, i), delays[i]) for i in range(start, start + 4)]
        for proc, out, delay in batch:
            _wait_until_running(proc, out)
        began = time.monotonic()
        for proc, out, delay in sorted(batch, key=lambda b: b[2]):
            time.sleep(max(0.0, began + delay - time.monotonic()))
            proc.send_signal(signal.SIGINT)
        for proc, out, delay in batch:
            _, err = proc.communicate(timeout=120)
            results.append((proc.returncode, err, out, delay))
    for code, err, out, delay in results:
        lines = [line for line in err.splitlines() if line.strip()]
        assert code == 130, f"SIGINT {delay:.2f} s into the study: exit {code}, stderr {err!r}"
        assert len(lines) == 1 and lines[0].startswith("pgtjax: interrupted"), err
        assert not [p for p in out.iterdir() if p.name.startswith(".partial")]
        manifest = out / MANIFEST
        assert not manifest.exists() or json.loads(manifest.read_text())["status"] != "complete"


@pytest.mark.skipif(os.name != "posix", reason="signals")
def test_ctrl_c_before_any_output_says_nothing_was_written(tmp_path):
    proc, out = _start_study(tmp_path, 0)
    _wait_until_running(proc, out)
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert err.strip() == "pgtjax: interrupted: no output files written (earlier outputs unchanged)"
