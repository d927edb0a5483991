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
from matplotlib.patches import Patch, Polygon

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

#: Monte Carlo as markers with error bars (``ax.errorbar(t, y, yerr=1.96 * se, **MC_ERRORBARS)``), under SL lines
MC_ERRORBARS = dict(fmt="o", ms=2.2, color="0.25", ecolor="0.6", elinewidth=0.6, capsize=0, zorder=2)

#: the most Monte Carlo markers per panel when a long run is drawn per cycle
MAX_MARKERS = 50

#: more cycles of ``mean_std_figure``'s ``cycle`` than this in a panel are drawn per cycle (no aliasing)
MAX_DRAWN_CYCLES = 12

_SCALE = {"m": (1e6, "µm"), "rad": (1.0, "rad"), "N": (1e-3, "kN"), "m/s": (1e3, "mm/s")}
#: SI prefixes by which :func:`scaled` brings a magnitude into [1, 1000) when it is given one
_PREFIXES = ((1e-9, "n"), (1e-6, "µ"), (1e-3, "m"), (1.0, ""), (1e3, "k"), (1e6, "M"), (1e9, "G"))
_PREFIXED_UNITS = {"m", "rad", "N", "m/s", "N m", "Pa", "N/m"}


def scaled(unit: str, magnitude: float | None = None):
    """(factor, display unit) for plotting SI quantities at a readable scale: with ``magnitude`` (the
    largest |value| to be shown) the SI prefix that puts it in [1, 1000) (µm, mrad, kN...), else a fixed
    choice per unit; units without prefixes are returned as they are."""
    if magnitude is None or unit not in _PREFIXED_UNITS or not np.isfinite(magnitude) or magnitude <= 0:
        return _SCALE.get(unit, (1.0, unit))
    size, prefix = next(
        ((size, prefix) for size, prefix in reversed(_PREFIXES) if magnitude >= size), _PREFIXES[0]
    )
    return 1.0 / size, prefix + unit


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


def cycle_envelope(times, values, period: float):
    """Per window of length ``period`` (s) from ``times[0]``: (mid times, min, max, average) of ``values``.
    Windows with fewer than 80 % of the fullest window's points (a truncated last cycle) are dropped."""
    t, y = np.asarray(times, float), np.asarray(values, float)
    index = np.floor((t - t[0]) / period + 1e-9).astype(int)
    counts = np.bincount(index)
    keep = np.flatnonzero(counts >= max(2, 0.8 * counts.max()))
    rows = [(t[index == k], y[index == k]) for k in keep]
    return tuple(np.array(v) for v in zip(*[(tk.mean(), yk.min(), yk.max(), yk.mean()) for tk, yk in rows]))


def _second_error(mean, second, se_mean, se_second, kind):
    """Standard error of the plotted second moment: that of the std, or of the mean square m^2 + s^2 by the
    delta method (the estimates of m and s are uncorrelated for a Gaussian quantity)."""
    if kind != "mean square":
        return se_second
    std = np.sqrt(np.maximum(second - mean**2, 0.0))
    return np.hypot(2.0 * mean * se_mean, 2.0 * std * se_second)


def transient_free_ylim(ax, curves: list, skip: float = 0.03, zero_floor: bool = False) -> None:
    """y-range of the ``[(t, y)]`` curves after the first ``skip`` of the time (or angle) axis, so that a std
    growing from the deterministic start (0 at t = 0) does not squeeze the stationary detail to the top of
    the panel; 8 % margins. ``zero_floor``: start at 0 when the values reach down to 30 % of their top (a std
    panel). A nearly constant curve is drawn flat (as :func:`readable_ylim` does)."""
    t_all = np.concatenate([np.asarray(t, float) for t, _ in curves])
    if t_all.size < 10:
        return
    start = t_all.min() + skip * (t_all.max() - t_all.min())
    values = np.concatenate([np.asarray(y, float)[np.asarray(t) >= start] for t, y in curves])
    values = values[np.isfinite(values)]
    if values.size == 0:
        return
    lo, hi = float(values.min()), float(values.max())
    magnitude = max(abs(lo), abs(hi), 1e-300)
    if hi - lo < 1e-2 * magnitude:  # nearly constant: drawn flat
        centre = 0.5 * (lo + hi)
        ax.set_ylim(centre - 5e-3 * magnitude, centre + 5e-3 * magnitude)
        return
    if zero_floor and 0.0 <= lo < 0.3 * hi:
        ax.set_ylim(0.0, hi + 0.08 * hi)
        return
    pad = 0.08 * (hi - lo)
    ax.set_ylim(lo - pad, hi + pad)


def closed_curve(ax, xs, ys, **line) -> None:
    """Draw the closed curve through ``(xs, ys)`` (the last point repeating the first) as one closed path, so
    that it joins where it closes; as a plotted line its two end caps leave a small kink there."""
    points = np.column_stack([xs, ys])
    if np.allclose(points[0], points[-1], rtol=0.0, atol=1e-12 * np.max(np.abs(points))):
        points = points[:-1]
    if "lw" in line:
        line["linewidth"] = line.pop("lw")
    line.setdefault("linewidth", mpl.rcParams["lines.linewidth"])  # as a plotted line would be
    line.setdefault("zorder", 2)  # a line's, above the reference curves drawn before it (a patch's is 1)
    ax.add_patch(Polygon(points, closed=True, fill=False, **line))
    ax.autoscale_view()


def panel_grid_figure(figsize) -> Figure:
    """An empty figure (outside pyplot) laid out by matplotlib's constrained layout, with 0.1 in around each
    panel instead of the default 3 pt: at 3 pt the y-label of a column with wide tick labels (such as
    ``197.5``) overlapped the panel to its left in the saved rim-thickness figure."""
    fig = Figure(figsize=figsize, layout="constrained")
    fig.get_layout_engine().set(w_pad=0.1)
    return fig


def mean_std_figure(
    times,
    curves: dict,
    quantities: list[tuple[str, str]],
    title: str = "",
    second: str = "std",
    styles: dict | None = None,
    subtitle: str = "",
    cycle: float | None = None,
    cycle_name: str = "mesh cycle",
):
    """One column per quantity, rows = mean and standard deviation (or mean square, ``second="mean square"``).

    ``curves[label][quantity] = (mean, second)`` arrays, or ``(mean, second, se_mean, se_second)`` with
    standard errors (Monte Carlo), drawn as 95 % error bars (1.96 s.e.) on the label's markers; lines are drawn
    above markers. ``quantities`` = [(name, SI unit)], shown with a readable prefix (:func:`scaled`);
    ``times`` (s) is one array for every curve or ``{label: array}``; ``styles`` overrides :data:`LINESTYLES`
    per label (e.g. markers, ``ls="none"``); ``subtitle`` is a line of small print under the title.

    ``cycle`` (s): the period of a fast oscillation (the meshing). When the curves span more than
    :data:`MAX_DRAWN_CYCLES` of them, each curve is drawn per cycle instead of point by point, which would
    alias: lines as a band (the range within each cycle) around the cycle average, markers at the cycle
    average with the mean of their standard errors (an upper bound of the average's). The legend sits below
    the panels. Returns a :class:`~matplotlib.figure.Figure` outside pyplot (see the module's note).
    """
    if not curves or not quantities:
        raise ValueError("mean_std_figure needs at least one curve and one quantity")
    styles = {**LINESTYLES, **(styles or {})}
    times_of = times if isinstance(times, dict) else {label: times for label in curves}
    t_all = np.concatenate([np.asarray(times_of[label], float) for label in curves])
    t_scale, t_unit = _time_axis(t_all)
    span = float(t_all.max() - t_all.min()) if t_all.size else 0.0
    # per cycle only where every curve is saved often enough to have a range within each cycle
    per_cycle = (
        cycle is not None
        and span > MAX_DRAWN_CYCLES * cycle
        and min(np.size(times_of[label]) for label in curves) >= 4 * span / cycle
    )
    handles = {}
    with mpl.rc_context(STYLE):
        fig = panel_grid_figure((2.6 * len(quantities) + 0.6, 4.8))
        axes = fig.subplots(2, len(quantities), squeeze=False, sharex=True)
        for j, (name, unit) in enumerate(quantities):

            def row_magnitude(k):  # of the mean (k = 0) or the std / root mean square (k = 1)
                values = [np.abs(np.asarray(d[name][k], float)) for d in curves.values()]
                finite = [v[np.isfinite(v)] for v in values]
                top = max((float(v.max()) for v in finite if v.size), default=0.0)
                return top**0.5 if k and second == "mean square" else top

            magnitudes = (row_magnitude(0), row_magnitude(1))
            factor, shown = scaled(unit, max(magnitudes))  # one prefix for both rows...
            factor2, shown2 = factor, shown
            if min(magnitudes) > 0 and max(magnitudes) > 1e3 * min(magnitudes):  # ...unless it hides one
                factor2, shown2 = scaled(unit, magnitudes[1])
            f2 = factor2**2 if second == "mean square" else factor2
            drawn = {0: [], 1: []}
            for label, data in curves.items():
                mean, moment2 = (np.asarray(a, float) for a in data[name][:2])
                t = np.asarray(times_of[label], float)
                errors = None
                if len(data[name]) == 4:
                    se_mean, se_second = (np.asarray(a, float) for a in data[name][2:])
                    errors = (se_mean, _second_error(mean, moment2, se_mean, se_second, second))
                style = {"color": f"C{list(curves).index(label)}", **styles.get(label, {})}
                markers = style.get("ls", style.get("linestyle")) == "none"
                for row, (y, f) in enumerate(((mean, factor), (moment2, f2))):
                    ax = axes[row, j]
                    err = None if errors is None else errors[row]
                    if per_cycle:
                        tc, lo, hi, avg = cycle_envelope(t, y, cycle)
                        err = None if err is None else cycle_envelope(t, err, cycle)[3]
                        if not markers:
                            ax.fill_between(
                                tc * t_scale, lo * f, hi * f, color=style["color"], alpha=0.25, lw=0
                            )
                            drawn[row] += [(tc, lo * f), (tc, hi * f)]
                        t_plot, y_plot = tc, avg
                        if markers:  # at most MAX_MARKERS cycle averages: the error bars stay apart
                            keep = slice(None, None, -(-len(tc) // MAX_MARKERS))
                            t_plot, y_plot = t_plot[keep], y_plot[keep]
                            err = None if err is None else err[keep]
                    else:
                        t_plot, y_plot = t, y
                    if markers and err is not None:
                        bar_style = {"elinewidth": 0.6, "capsize": 0, "zorder": 2, "ms": 2.0, **style}
                        artist = ax.errorbar(t_plot * t_scale, y_plot * f, yerr=1.96 * err * f, **bar_style)
                    else:
                        line_style = {"zorder": 2 if markers else 3, **style}
                        (artist,) = ax.plot(t_plot * t_scale, y_plot * f, **line_style)
                    drawn[row].append((t_plot, y_plot * f))
                    if markers and err is not None:  # the error bars stay inside the panel
                        drawn[row] += [
                            (t_plot, (y_plot - 1.96 * err) * f),
                            (t_plot, (y_plot + 1.96 * err) * f),
                        ]
                    suffix = ", 95 % error bars" if markers and err is not None else ""
                    handles.setdefault(f"{label}{suffix}", artist)
            axes[0, j].set_title(name)
            axes[0, j].set_ylabel(f"mean ({shown})")
            axes[1, j].set_ylabel(f"{second} ({shown2}²)" if second == "mean square" else f"std ({shown2})")
            axes[1, j].set_xlabel(f"time ({t_unit})")
            for ax in axes[:, j]:
                readable_ylim(ax)
            transient_free_ylim(axes[1, j], drawn[1])
            for row, ax in enumerate(axes[:, j]):  # the panel holds every error bar (readable_ylim may not)
                lo, hi = ax.get_ylim()
                finite = np.concatenate([np.ravel(y) for _, y in drawn[row]] or [np.zeros(0)])
                finite = finite[np.isfinite(finite)]
                if finite.size == 0:
                    continue
                top, bottom = float(finite.max()), float(finite.min())
                if row == 0 and (bottom < lo or top > hi):
                    pad = 0.05 * (max(hi, top) - min(lo, bottom))
                    ax.set_ylim(min(lo, bottom - pad), max(hi, top + pad))
        if title:
            fig.suptitle(title + (f"\n{subtitle}" if subtitle else ""), fontsize=9 if subtitle else None)
        if per_cycle:
            averaged = "lines and markers" if any(", 95 %" in k for k in handles) else "lines"
            shaded = f"shaded, in the colour of its line: range within each {cycle_name};"
            handles[f"{shaded}\n{averaged}: {cycle_name} averages"] = Patch(color="0.6", alpha=0.4, lw=0)
        # a figure of two columns takes the legend on two rows: in one row it would set the figure's width,
        # leaving the panels squeezed in the middle
        columns = min(len(handles), 4 if len(quantities) > 2 else 2)
        fig.legend(list(handles.values()), list(handles), loc="outside lower center", ncol=columns)
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
