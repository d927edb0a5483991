"""Progress output: a tqdm bar on a terminal, plain lines at each tenth on any other stream (a log file)."""

import io
import re

import pytest

from pgtjax import _progress
from pgtjax._progress import LogLines, progress_bar

LINE = re.compile(
    r"^run: ([\d,]+) / ([\d,]+) samples \((\d+) %\) after [\d.]+ s(, [\d.,e+]+ samples/s)?(, .*)?$"
)


def _counts(stream):
    lines = stream.getvalue().splitlines()
    assert lines and all(LINE.match(line) for line in lines), lines
    assert "\r" not in stream.getvalue()
    return [int(LINE.match(line)[1].replace(",", "")) for line in lines]


def test_log_lines_at_each_tenth_and_the_end():
    out = io.StringIO()
    bar = LogLines(20, "run", "samples", stream=out)
    for _ in range(6):
        bar.update(3)  # 3, 6, ..., 18: tenths 1, 3, 4, 6, 7, 9
    bar.update(2)  # 20: the tenth 10
    bar.close()  # the end was shown: no second final line
    assert _counts(out) == [3, 6, 9, 12, 15, 18, 20]
    assert out.getvalue().splitlines()[-1].startswith("run: 20 / 20 samples (100 %)")


def test_log_lines_of_a_resumed_run_and_an_interrupted_one():
    out = io.StringIO()
    bar = LogLines(20, "run", "samples", initial=10, stream=out)  # half done before the resume: no line yet
    assert out.getvalue() == ""
    bar.update(1)  # 11 of 20: still the fifth tenth
    bar.update(9)
    bar.close()
    assert _counts(out) == [20]
    out = io.StringIO()
    bar = LogLines(1000, "run", "samples", stream=out)
    bar.update(5)
    bar.set_postfix(J="1.5")
    bar.close()  # stopped early: the count reached is shown once
    assert _counts(out) == [5]
    assert out.getvalue().rstrip().endswith(", J=1.5")
    out = io.StringIO()
    LogLines(0, "run", "samples", stream=out).close()  # nothing to do: nothing written
    assert out.getvalue() == ""


class _Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.mark.parametrize("stream, bar", [(io.StringIO(), "lines"), (_Terminal(), "tqdm")])
def test_a_bar_only_on_a_terminal(monkeypatch, stream, bar):
    monkeypatch.setattr(_progress.sys, "stderr", stream)
    got = progress_bar(10, "run", "samples")
    got.update(10)
    got.close()
    assert isinstance(got, LogLines) == (bar == "lines")
    assert ("\r" in stream.getvalue()) == (bar == "tqdm")  # tqdm rewrites its line
