"""Plots across runs: the run index's trends (:func:`trend_plots`) and the comparison page's
pairs of headline figures (:func:`compare_bars`). Numbers in, figures out, as in
:mod:`armbench.reports.plots`; labels pass :func:`safe_label`.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from armbench.reports.plotting import (
    COLOURS,
    legend,
    new_figure,
    plot_style,
    safe_label,
    to_svg,
)

__all__ = ["PairPanel", "TrendPanel", "compare_bars", "to_svg", "trend_plots"]


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
class TrendPanel:
    """One metric across runs: ``values[i]`` of run number ``runs[i]`` (None where the run lacks
    it), ``failed[i]`` when that value was outside its limit; ``limit`` drawn dashed."""

    title: str
    unit: str
    runs: Sequence[int]
    values: Sequence[float | None]
    failed: Sequence[bool]
    limit: float | None = None
    regressed: Sequence[bool] = ()
    """``regressed[i]`` when run ``runs[i]`` found this metric regressed against its baseline
    (empty: none did)."""


def trend_plots(panels: Sequence[TrendPanel], width_in: float = 7.2,
                height_in: float = 2.5) -> Figure:
    """Key metrics across runs in creation order, one subplot each; values outside their limits
    are drawn as crosses (not colour alone)."""
    with plot_style():
        fig = new_figure(width_in, height_in, left=0.08 * 7.2 / width_in, bottom=0.2,
                         top=0.86, wspace=0.35)
        axes = fig.subplots(1, max(1, len(panels)), squeeze=False)[0]
        for ax, p in zip(axes, panels, strict=False):
            pts = [(r, v, f) for r, v, f in zip(p.runs, p.values, p.failed, strict=True)
                   if v is not None]
            if pts:
                xs = np.array([r for r, _, _ in pts], dtype=np.float64)
                ys = np.array([v for _, v, _ in pts], dtype=np.float64)
                ax.plot(xs, ys, color=COLOURS[0], linewidth=1.0)
                good = np.array([not f for _, _, f in pts])
                ax.plot(xs[good], ys[good], linestyle="none", marker="o", markersize=4,
                        color=COLOURS[0],
                        label="within limit" if p.limit is not None else "value")
                if (~good).any():
                    ax.plot(xs[~good], ys[~good], linestyle="none", marker="X", markersize=7,
                            color=COLOURS[1], label="outside limit")
                worse = [(r, v) for r, v, k in zip(p.runs, p.values, p.regressed or
                                                   [False] * len(p.runs), strict=True)
                         if k and v is not None]
                if worse:  # a ring around the point, so it reads without colour too
                    ax.plot([r for r, _ in worse], [v for _, v in worse], linestyle="none",
                            marker="o", markersize=10, markerfacecolor="none",
                            markeredgewidth=1.4, color="black",
                            label="regressed vs baseline")
            if p.limit is not None:
                ax.axhline(p.limit, color="black", linestyle="--", linewidth=1.0,
                           label=safe_label(f"limit {p.limit:g} {p.unit}"))
            ax.set_title(safe_label(p.title))
            ax.set_xlabel("run #")
            ax.set_ylabel(safe_label(p.unit))
            ax.xaxis.set_major_locator(MaxNLocator(6, integer=True))
            if p.runs:
                ax.set_xlim(min(p.runs) - 0.5, max(p.runs) + 0.5)
            if pts or p.limit is not None:
                legend(ax, loc="best", fontsize=7.5)
            else:
                ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center",
                        va="center")
    return fig
