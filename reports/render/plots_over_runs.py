"""Plots across runs: the run index's trends (:func:`trend_plots`) and the comparison page's
pairs of headline figures (:func:`compare_bars`). Numbers in, figures out, as in
:mod:`armbench.reports.render.plots`; labels pass :func:`safe_label`.
"""

from __future__ import annotations

import math
import textwrap
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from armbench.reports.render.plotting import (
    COLOURS,
    LINESTYLES,
    MARKERS,
    new_figure,
    plot_style,
    safe_label,
    to_svg,
)

__all__ = ["PairPanel", "TrendLine", "TrendPanel", "compare_bars", "to_svg", "trend_plots"]


@dataclass(frozen=True, slots=True)
class PairPanel:
    """One metric in two runs for :func:`compare_bars`: ``a`` (baseline) and ``b``, in
    ``unit``; ``limit`` dashed."""

    title: str
    unit: str
    a: float | None
    b: float | None
    limit: float | None = None


def compare_bars(panels: Sequence[PairPanel], labels: tuple[str, str]) -> Figure:
    """Each metric as a pair of bars, run A (hatched) beside run B, one small panel each."""
    cols = min(4, max(1, len(panels)))
    rows = max(1, math.ceil(len(panels) / cols))
    with plot_style():
        height = 2.1 * rows + 0.3
        fig = new_figure(7.2, height, left=0.07, bottom=0.35 / height, top=1 - 0.5 / height,
                         wspace=0.6, hspace=1.0)
        axes = fig.subplots(rows, cols, squeeze=False)
        for k, ax in enumerate(axes.flat):
            if k >= len(panels):
                ax.set_visible(False)
                continue
            p = panels[k]
            values = [0.0 if v is None else v for v in (p.a, p.b)]
            bars = ax.bar([0, 1], values, color=[COLOURS[7], COLOURS[0]], width=0.6)
            bars[0].set_hatch("///")
            ax.set_xticks([0, 1], [safe_label(labels[0], 10), safe_label(labels[1], 10)])
            if p.limit is not None:
                ax.axhline(p.limit, color="black", linestyle="--", linewidth=1.0)
            ax.xaxis.grid(False)
            # wrapped on two lines, never cut: "improvement (paper-style / coordinated)"
            ax.set_title(textwrap.fill(safe_label(p.title, 60), 26, max_lines=2,
                                       placeholder="…"), fontsize=7.5)
            ax.set_ylabel(safe_label(p.unit or "value", 12))
    return fig


# --------------------------------------------------------------------------------------------
# Trends across runs (the run index)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class TrendLine:
    """One series of a trend panel: ``values[i]`` of run number ``runs[i]``, ``outside[i]``
    when it lies outside its own run's limit, whose bounds are ``lows[i]`` and ``highs[i]``
    (None: no bound on that side); ``regressed[i]`` when that run found it regressed against its
    baseline (empty: none did)."""

    label: str
    runs: Sequence[int]
    values: Sequence[float]
    outside: Sequence[bool]
    lows: Sequence[float | None]
    highs: Sequence[float | None]
    regressed: Sequence[bool] = ()


@dataclass(frozen=True, slots=True)
class TrendPanel:
    """One metric across runs: its series (one line each, never joined), in ``unit``, on the
    run numbers ``runs`` (the x axis)."""

    title: str
    unit: str
    runs: Sequence[int]
    lines: Sequence[TrendLine]


def _constant_bounds(line: TrendLine) -> list[float]:
    """The bounds every run of ``line`` shared (a low, a high), each drawn across the panel."""
    out = []
    for bounds in (line.lows, line.highs):
        values = set(bounds)
        if len(values) == 1 and None not in values:
            out.append(float(bounds[0]))  # type: ignore[arg-type]
    return out


def _limit_lines(ax: Any, line: TrendLine, colour: str, unit: str,
                 shared: set[float]) -> None:
    """Each bound of ``line``'s limits dashed in its colour: one line across the panel when
    every run of the series had the same bound (left to the caller when another series shares
    it), else a dash at each run's own."""
    for bounds in (line.lows, line.highs):
        pairs = [(r, b) for r, b in zip(line.runs, bounds, strict=True) if b is not None]
        if not pairs:
            continue
        if len(pairs) == len(line.runs) and len({b for _, b in pairs}) == 1:
            bound = pairs[0][1]
            if bound not in shared:
                ax.axhline(bound, color=colour, linestyle="--", linewidth=1.0,
                           label=safe_label(f"limit {bound:g} {unit}"))
        else:
            ax.hlines([b for _, b in pairs], [r - 0.4 for r, _ in pairs],
                      [r + 0.4 for r, _ in pairs], colors=colour, linestyles="--",
                      linewidth=1.0, label="limit of each run")


def trend_plots(panels: Sequence[TrendPanel], width_in: float = 7.2,
                height_in: float = 2.5) -> Figure:
    """Key metrics across runs in creation order, one subplot each, one line per series with
    its own limits dashed in its colour; values outside their limits are drawn as crosses (not
    colour alone), a ring marks a regression."""
    with plot_style():
        fig = new_figure(width_in, height_in, left=0.08 * 7.2 / width_in, bottom=0.2,
                         top=0.86, wspace=0.35)
        axes = fig.subplots(1, max(1, len(panels)), squeeze=False)[0]
        for ax, p in zip(axes, panels, strict=False):
            counts = Counter(b for line in p.lines for b in _constant_bounds(line))
            shared = {b for b, n in counts.items() if n > 1}
            for bound in sorted(shared):  # one limit of several series: black, once
                ax.axhline(bound, color="black", linestyle="--", linewidth=1.0,
                           label=safe_label(f"limit {bound:g} {p.unit}"))
            for k, line in enumerate(p.lines):
                colour = COLOURS[k % len(COLOURS)]
                xs = np.array(line.runs, dtype=np.float64)
                ys = np.array(line.values, dtype=np.float64)
                bad = np.array(line.outside, dtype=bool)
                ax.plot(xs, ys, color=colour, linestyle=LINESTYLES[k % len(LINESTYLES)],
                        marker=MARKERS[k % len(MARKERS)], markersize=4,
                        label=safe_label(line.label))
                if bad.any():
                    ax.plot(xs[bad], ys[bad], linestyle="none", marker="X", markersize=8,
                            color=colour, markeredgecolor="black", label="outside limit")
                ringed = np.array(line.regressed or [False] * len(line.runs), dtype=bool)
                if ringed.any():  # a ring around the point, so it reads without colour too
                    ax.plot(xs[ringed], ys[ringed], linestyle="none", marker="o",
                            markersize=10, markerfacecolor="none", markeredgewidth=1.4,
                            color="black", label="regressed vs baseline")
                _limit_lines(ax, line, colour, p.unit, shared)
            ax.set_title(safe_label(p.title))
            ax.set_xlabel("run #")
            ax.set_ylabel(safe_label(p.unit))
            ax.xaxis.set_major_locator(MaxNLocator(6, integer=True))
            if p.runs:
                ax.set_xlim(min(p.runs) - 0.5, max(p.runs) + 0.5)
            if p.lines:
                handles, labels = ax.get_legend_handles_labels()
                unique = dict(zip(labels, handles, strict=True))  # one entry per label
                ax.legend(list(unique.values()), list(unique), loc="best", fontsize=7.5)
            else:
                ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center",
                        va="center")
    return fig
