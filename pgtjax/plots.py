"""Publication-style figures shared by the studies and the notebooks.

This module never selects a matplotlib backend: that is the application's choice (ipykernel's inline backend
in Jupyter, ``MPLBACKEND``, or matplotlib's own default, which is Agg on a machine without a display).

The figure builders here (:func:`mean_std_figure`, :func:`pdf_figure`) return
:class:`matplotlib.figure.Figure` objects made without pyplot: they need no display and no particular
backend, so a headless study or CLI run writes its PNGs whatever backend is configured, and no figure is left
open in pyplot's registry. Save one with :func:`save` (or ``fig.savefig``); in a notebook show it with
``display(fig)`` or as a cell's value (after ``%matplotlib inline``), not with ``plt.show()``, which only
knows pyplot's figures.

``plt`` (pyplot) stays exported for the studies that draw their own figures with it; :func:`save` closes
those.
"""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib as mpl
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

STYLE = {
    "font.size": 9,
    "axes.labelsize": 9,
    "axes.titlesize": 9,
    "legend.fontsize": 8,
    "lines.linewidth": 1.2,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "figure.dpi": 100,
    "savefig.dpi": 200,
    "savefig.bbox": "tight",
}
LINESTYLES = {
    "MC": dict(color="k", lw=1.6),
    "SL force": dict(color="tab:blue", ls="--"),
    "SL energy": dict(color="tab:red", ls=":"),
}

_SCALE = {"m": (1e6, "µm"), "rad": (1.0, "rad"), "N": (1e-3, "kN"), "m/s": (1e3, "mm/s")}


def scaled(unit: str):
    """(factor, display unit) for plotting SI quantities at a readable scale."""
    return _SCALE.get(unit, (1.0, unit))


def _time_axis(times):
    """(factor, unit) for a time axis: ms when every time is below 2 s, else s."""
    t = np.asarray(times)
    return (1e3, "ms") if t.size and float(np.max(np.abs(t))) < 2.0 else (1.0, "s")


def readable_ylim(ax, min_relative_span: float = 1e-2) -> None:
    """Keep a nearly constant curve flat on the page: no offset notation, and a y-range of at least
    ``min_relative_span`` of the values' magnitude (otherwise a 1e-6 relative wobble fills the axes)."""
    ax.ticklabel_format(axis="y", useOffset=False)
    values = [np.asarray(line.get_ydata(), float) for line in ax.get_lines()]
    values = np.concatenate([v[np.isfinite(v)] for v in values]) if values else np.zeros(0)
    if values.size == 0:
        return
    lo, hi = float(values.min()), float(values.max())
    magnitude = max(abs(lo), abs(hi))
    if magnitude > 0.0 and hi - lo < min_relative_span * magnitude:
        centre, half = 0.5 * (lo + hi), 0.5 * min_relative_span * magnitude
        ax.set_ylim(centre - half, centre + half)


def mean_std_figure(
    times,
    curves: dict,
    quantities: list[tuple[str, str]],
    title: str = "",
    second: str = "std",
    styles: dict | None = None,
    subtitle: str = "",
):
    """One column per quantity, rows = mean and standard deviation (or mean square, ``second="mean square"``).

    ``curves[label][quantity] = (mean array, second array)``; ``quantities`` = [(name, unit)]; ``times`` (s)
    is one array for every curve or ``{label: array}`` (e.g. SL saved more densely than MC); ``styles``
    overrides :data:`LINESTYLES` per label (e.g. markers for a sparser curve); ``subtitle`` is a line of small
    print under the title. Returns a :class:`~matplotlib.figure.Figure` outside pyplot (see the module's
    note).
    """
    styles = {**LINESTYLES, **(styles or {})}
    times_of = times if isinstance(times, dict) else {label: times for label in curves}
    t_scale, t_unit = _time_axis(next(iter(times_of.values())))
    with mpl.rc_context(STYLE):
        fig = Figure(figsize=(2.6 * len(quantities) + 0.6, 4.4))
        axes = fig.subplots(2, len(quantities), squeeze=False, sharex=True)
        for j, (name, unit) in enumerate(quantities):
            factor, shown = scaled(unit)
            f2 = factor**2 if second == "mean square" else factor
            for label, data in curves.items():
                mean, std = data[name]
                t = np.asarray(times_of[label]) * t_scale
                axes[0, j].plot(t, np.asarray(mean) * factor, label=label, **styles.get(label, {}))
                axes[1, j].plot(t, np.asarray(std) * f2, label=label, **styles.get(label, {}))
            axes[0, j].set_title(name)
            axes[0, j].set_ylabel(f"mean ({shown})")
            axes[1, j].set_ylabel(f"{second} ({shown}²)" if second == "mean square" else f"std ({shown})")
            axes[1, j].set_xlabel(f"time ({t_unit})")
            for ax in axes[:, j]:
                readable_ylim(ax)
        axes[0, 0].legend(loc="best")
        if title:
            fig.suptitle(title + (f"\n{subtitle}" if subtitle else ""), fontsize=9 if subtitle else None)
        fig.tight_layout()
    return fig


def pdf_figure(edges, counts, n_samples, gaussians: dict, clearance=None, unit="m", title=""):
    """MC histogram as a density against Gaussian densities ``{label: (mean, std)}``; shaded backlash zone.
    Returns a :class:`~matplotlib.figure.Figure` outside pyplot (see the module's note)."""
    factor, shown = scaled(unit)
    edges = np.asarray(edges) * factor
    width = np.diff(edges)
    density = np.asarray(counts) / (n_samples * width)
    x = np.linspace(edges[0], edges[-1], 600)
    with mpl.rc_context(STYLE):
        fig = Figure(figsize=(4.2, 3.0))
        ax = fig.subplots()
        ax.stairs(density, edges, fill=True, color="0.8", label="MC histogram")
        ax.stairs(density, edges, color="k", lw=0.8)
        for label, (mu, sd) in gaussians.items():
            mu, sd = mu * factor, max(sd * factor, 1e-300)
            ax.plot(
                x,
                np.exp(-0.5 * ((x - mu) / sd) ** 2) / (sd * np.sqrt(2 * np.pi)),
                label=label,
                **{k: v for k, v in LINESTYLES.get(label, {}).items() if k != "lw"},
            )
        if clearance is not None:
            b = clearance * factor
            ax.axvspan(-b, b, color="tab:orange", alpha=0.15, label="backlash zone")
        ax.set_xlabel(f"mesh deflection ({shown})")
        ax.set_ylabel(f"probability density (1/{shown})")
        ax.legend(loc="best")
        if title:
            ax.set_title(title)
        fig.tight_layout()
    return fig


def save(fig, path) -> Path:
    """Write ``fig`` to ``path`` (format from the suffix) and close it if pyplot manages it (the studies' own
    figures; the builders' figures are not in pyplot and need no closing); returns ``path`` as a Path."""
    path = Path(path)
    # written under a temporary name and renamed into place: an interrupted run leaves no truncated image
    # under the final name. dpi and bbox given here: figures are often saved after the style's rc_context.
    partial = path.with_name(f".{path.stem}.partial-{os.getpid()}{path.suffix}")
    try:
        fig.savefig(partial, dpi=STYLE["savefig.dpi"], bbox_inches=STYLE["savefig.bbox"])
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
        plt.close(fig)  # a no-op for a figure that pyplot does not manage
    return path
