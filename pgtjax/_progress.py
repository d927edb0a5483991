"""Progress of long runs (Monte Carlo over samples, design optimization over iterations).

On a terminal or in a Jupyter kernel: a tqdm bar. On any other stream (a file, a pipe, a batch job's log under
SLURM) a bar rewrites one line with carriage returns, thousands of times in a long run; there the progress is
a plain line at each tenth of the total and at the end instead.
"""

import sys
import time


def _in_jupyter(stream) -> bool:
    return type(stream).__module__.startswith("ipykernel")


class LogLines:
    """A tqdm-like counter (``update``, ``set_postfix``, ``close``) that writes a line to ``stream`` each time
    the count passes a tenth of ``total``, and one at ``close`` if the last line did not show the end."""

    def __init__(self, total: int, desc: str, unit: str, initial: int = 0, stream=None):
        self.total, self.desc, self.unit, self.n = int(total), desc, unit, int(initial)
        self.stream = sys.stderr if stream is None else stream
        self.start, self.start_n, self.postfix = time.perf_counter(), self.n, ""
        self._shown_n = self.n  # the count of the last line (a resumed run's start counts as shown)

    def _tenth(self, n: int) -> int:
        return 10 * n // self.total if self.total > 0 else 10

    def _write(self) -> None:
        elapsed = time.perf_counter() - self.start
        done = self.n - self.start_n
        rate = ""
        if done > 0 and elapsed > 0:
            per_s = done / elapsed
            rate = f", {per_s:,.0f} {self.unit}/s" if per_s >= 100 else f", {per_s:.3g} {self.unit}/s"
        share = f" ({100 * self.n / self.total:.0f} %)" if self.total > 0 else ""
        postfix = f", {self.postfix}" if self.postfix else ""
        line = f"{self.desc}: {self.n:,} / {self.total:,} {self.unit}{share} after {elapsed:.1f} s{rate}{postfix}"
        print(line, file=self.stream, flush=True)
        self._shown_n = self.n

    def update(self, n: int = 1) -> None:
        self.n += int(n)
        if self._tenth(self.n) > self._tenth(self._shown_n):
            self._write()

    def set_postfix(self, **values) -> None:
        self.postfix = ", ".join(f"{k}={v}" for k, v in values.items())

    def close(self) -> None:
        if self._shown_n != self.n:
            self._write()


def progress_bar(total: int, desc: str, unit: str, initial: int = 0):
    """A tqdm bar on a terminal or in a Jupyter kernel, else ``LogLines`` on ``sys.stderr``. tqdm is
    imported only here: ``tqdm.auto`` warns at import time in a Jupyter kernel without ipywidgets."""
    stream = sys.stderr
    if not (_in_jupyter(stream) or getattr(stream, "isatty", lambda: False)()):
        return LogLines(total, desc, unit, initial, stream)
    try:
        from tqdm.auto import tqdm
    except ImportError:  # pragma: no cover - a bar is a convenience, not a requirement
        return LogLines(total, desc, unit, initial, stream)
    return tqdm(total=total, desc=desc, unit=unit, initial=initial, leave=True)
