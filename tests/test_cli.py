"""The command line's handling of unusable output folders and of Ctrl-C."""

import os
import signal
import subprocess
import sys
import time

import pytest

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


def test_ctrl_c_exits_130_with_one_line(tmp_path):
    """SIGINT while a study computes: exit status 130 and one line on stderr, no traceback."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    argv = [sys.executable, "-m", "pgtjax.cli", "gear-pair", "--samples", "200000", "--quiet"]
    proc = subprocess.Popen(
        [*argv, "--out", str(tmp_path / "out")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    out = tmp_path / "out"
    deadline = time.monotonic() + 120.0
    while not out.exists() and time.monotonic() < deadline:  # main() creates it just before the study
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.1)
    time.sleep(1.0)  # inside the study
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("pgtjax: interrupted"), err
