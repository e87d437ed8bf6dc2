"""The report's plots, one function each: the paper's Figs. 11 and 12, the ISO 9283 cube and
scatter, the start-up recovery outcomes, the traffic, the joints' bars (the index's trends and
the comparison page's pairs are in :mod:`armbench.reports.render.plots_over_runs`).

Every function here takes numbers (numpy arrays, in the units its name says) and labels the report
code chose itself; no text from a record reaches a plot, and :func:`safe_label` filters the labels
anyway (matplotlib escapes SVG text too; math text is switched off). The style, the SVG export
(:func:`to_svg`) and the downsampling of long series live in
:mod:`armbench.reports.render.plotting`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle
from matplotlib.ticker import FuncFormatter, MaxNLocator, NullFormatter

from armbench.reports.render.plotting import (
    COLOURS,
    LINESTYLES,
    MARKERS,
    FloatArray,
    decimate,
    envelope,
    legend,
    new_figure,
    plot_style,
    safe_label,
    to_svg,
)

__all__ = [
    "AttainedPath",
    "ErrorPanel",
    "ErrorRun",
    "PathPanel",
    "PoseScatter",
    "ScatterGroup",
    "StartupPoint",
    "cube_projections",
    "decimate",
    "envelope",
    "error_over_time",
    "outcomes_by_condition",
    "paths_yz",
    "pose_scatter",
    "safe_label",
    "startup_plots",
    "to_svg",
    "traffic_plot",
]


# --------------------------------------------------------------------------------------------
# Accuracy (paper §7, Figs. 11 and 12)
# --------------------------------------------------------------------------------------------


#: Runs of a panel named in its legend; the others are drawn and counted in one more entry (a
#: legend of hundreds of laps reads as nothing and costs most of a long run's report).
LEGEND_RUNS = 8


def _more_runs(ax: Axes, runs: int) -> None:
    """One legend entry for the runs beyond :data:`LEGEND_RUNS`, if any."""
    if runs > LEGEND_RUNS:
        ax.plot([], [], " ", label=f"and {runs - LEGEND_RUNS} more")


@dataclass(frozen=True, slots=True)
class _Stroke:
    """How a family of run lines is drawn: a fixed line style (or each run's own), width, alpha."""

    linewidth: float
    linestyle: str | None = None
    alpha: float = 1.0


def _draw_runs(ax: Axes, lines: Sequence[tuple[str, FloatArray, FloatArray] | None],
               stroke: _Stroke) -> None:
    """Draw line ``i`` of ``lines`` (label, x, y; ``None`` draws nothing) in run ``i``'s colour
    and line style. The first :data:`LEGEND_RUNS` are lines of their own with their labels; the
    rest share one ``LineCollection`` per colour and style: a long run's hundreds of laps look the
    same, without a Line2D each (most of such a report's memory)."""
    grouped: dict[tuple[int, int], list[FloatArray]] = {}
    for i, line in enumerate(lines):
        if line is None or not len(line[1]):
            continue
        label, x, y = line
        style = LINESTYLES[i % 4] if stroke.linestyle is None else stroke.linestyle
        if i < LEGEND_RUNS:
            ax.plot(x, y, color=COLOURS[i % len(COLOURS)], linestyle=style,
                    linewidth=stroke.linewidth, alpha=stroke.alpha, label=safe_label(label))
        else:
            grouped.setdefault((i % len(COLOURS), i % 4), []).append(np.column_stack([x, y]))
    for (colour, style_index), segments in grouped.items():
        style = LINESTYLES[style_index] if stroke.linestyle is None else stroke.linestyle
        ax.add_collection(LineCollection(segments, colors=COLOURS[colour], linestyles=style,
                                         linewidths=stroke.linewidth, alpha=stroke.alpha))
    if grouped:
        ax.autoscale_view()


@dataclass(frozen=True, slots=True)
class AttainedPath:
    """One run's attained path: reported (forward kinematics of the reported joints) and, when the
    samples carry it, the true path (external measurement or emulator truth), ``(N, 3)`` in mm."""

    label: str
    reported_mm: FloatArray
    true_mm: FloatArray | None = None


@dataclass(frozen=True, slots=True)
class PathPanel:
    """One subplot of :func:`paths_yz`: a mode and its runs."""

    title: str
    runs: Sequence[AttainedPath]


def paths_yz(panels: Sequence[PathPanel], square_mm: FloatArray | None) -> Figure:
    """Fig. 11: the attained paths in the YZ plane against the reference square (corners
    ``(4, 3)`` mm, drawn closed and dashed), one subplot per panel."""
    with plot_style():
        # narrow enough to be drawn near its own size beside the scorecard (the page's lead
        # plot), its legend shared below the panels at the text's size
        fig = new_figure(5.6, 3.7 if len(panels) > 1 else 4.3, left=0.11, bottom=0.25, top=0.92)
        axes = fig.subplots(1, max(1, len(panels)), squeeze=False)[0]
        for ax, panel in zip(axes, panels, strict=False):
            if square_mm is not None:
                closed = np.vstack([square_mm, square_mm[:1]])
                ax.plot(closed[:, 1], closed[:, 2], color="black", linestyle="--",
                        linewidth=1.2, label="reference square")
            reported = [decimate(run.reported_mm) for run in panel.runs]
            _draw_runs(ax, [(f"{run.label} reported", rep[:, 1], rep[:, 2])
                            for run, rep in zip(panel.runs, reported, strict=True)],
                       _Stroke(linewidth=1.0))
            true = [None if run.true_mm is None else decimate(run.true_mm) for run in panel.runs]
            _draw_runs(ax, [None if tru is None else (f"{run.label} true", tru[:, 1], tru[:, 2])
                            for run, tru in zip(panel.runs, true, strict=True)],
                       _Stroke(linewidth=0.8, linestyle=":", alpha=0.8))
            _more_runs(ax, len(panel.runs))
            ax.set_title(safe_label(panel.title))
            ax.set_xlabel("y (mm)")
            ax.set_ylabel("z (mm)")
            ax.set_aspect("equal", adjustable="datalim")
        seen: dict[str, Artist] = {}
        for ax in axes:
            for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
                seen.setdefault(label, handle)
        if seen:
            fig.legend(list(seen.values()), list(seen), loc="lower center",
                       ncols=min(3, len(seen)), fontsize=8.5)
    return fig


@dataclass(frozen=True, slots=True)
class ErrorRun:
    """One run's error series: ``error_mm`` at ``t_s`` (s from the trial's start)."""

    label: str
    t_s: FloatArray
    error_mm: FloatArray


@dataclass(frozen=True, slots=True)
class ErrorPanel:
    """One subplot of :func:`error_over_time`; ``mean_mm`` is drawn as a dotted line."""

    title: str
    runs: Sequence[ErrorRun]
    mean_mm: float | None = None


def error_over_time(panels: Sequence[ErrorPanel], paper_mm: float | None,
                    ylabel: str = "path error (mm)") -> Figure:
    """Fig. 12: error over time per run, with armbench's mean (dotted) and the paper's mean
    (``paper_mm``, dashed) drawn across each subplot; shared y axis so the panels compare."""
    with plot_style():
        fig = new_figure(7.2, 2.9, bottom=0.16, top=0.9, wspace=0.08)
        axes = fig.subplots(1, max(1, len(panels)), squeeze=False, sharey=True)[0]
        top = 0.0
        for ax, panel in zip(axes, panels, strict=False):
            drawn = [(run.label, *envelope(run.t_s, run.error_mm)) for run in panel.runs]
            top = max([top, *(float(np.nanmax(y)) for _, _, y in drawn if len(y))])
            _draw_runs(ax, drawn, _Stroke(linewidth=0.8))
            _more_runs(ax, len(panel.runs))
            if paper_mm is not None:
                ax.axhline(paper_mm, color="#D55E00", linestyle="--", linewidth=1.3,
                           label=safe_label(f"paper §7 mean {paper_mm:.1f} mm"))
            if panel.mean_mm is not None:
                ax.axhline(panel.mean_mm, color="black", linestyle=":", linewidth=1.3,
                           label=safe_label(f"armbench mean {panel.mean_mm:.2f} mm"))
            ax.set_title(safe_label(panel.title))
            ax.set_xlabel("time in trial (s)")
            legend(ax, loc="upper right", fontsize=6.5, ncols=2)
        # head room above the data for the legend
        top = max(top, paper_mm or 0.0, *(p.mean_mm or 0.0 for p in panels))
        axes[0].set_ylim(0, 1.45 * top if top > 0 else 1.0)
        axes[0].set_ylabel(safe_label(ylabel))
    return fig


# --------------------------------------------------------------------------------------------
# Repeatability (ISO 9283)
# --------------------------------------------------------------------------------------------

_CUBE_EDGES = ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4),
               (0, 4), (1, 5), (2, 6), (3, 7))


def cube_projections(corners_mm: FloatArray | None, poses: Sequence[tuple[str, FloatArray]],
                     barycentres_mm: Sequence[FloatArray]) -> Figure:
    """The ISO test cube (corners C1..C8, ``(8, 3)`` mm) and the commanded poses (label, xyz mm)
    in three projections (top XY, side XZ, front YZ), with the attained barycentres."""
    views = (("top (x-y)", 0, 1), ("side (x-z)", 0, 2), ("front (y-z)", 1, 2))
    names = "xyz"
    with plot_style():
        fig = new_figure(7.2, 2.8, bottom=0.27, top=0.9, wspace=0.4)
        axes = fig.subplots(1, 3, squeeze=False)[0]
        for ax, (title, a, b) in zip(axes, views, strict=True):
            if corners_mm is not None:
                segs = [[(corners_mm[i, a], corners_mm[i, b]), (corners_mm[j, a], corners_mm[j, b])]
                        for i, j in _CUBE_EDGES]
                ax.add_collection(LineCollection(segs, colors="#999999", linewidths=0.8,
                                                 label="test cube"))
                ax.autoscale_view()
            if poses:
                pts = np.array([p for _, p in poses], dtype=np.float64)
                ax.plot(pts[:, a], pts[:, b], linestyle="none", marker="o", markersize=5,
                        markerfacecolor="white", markeredgecolor=COLOURS[0],
                        label="commanded pose")
                span = float(np.ptp(pts[:, [a, b]])) or 1.0
                groups: dict[tuple[int, int], list[str]] = {}
                for label, p in poses:  # poses that coincide in this view share one label
                    key = (round(p[a] / span * 50), round(p[b] / span * 50))
                    groups.setdefault(key, []).append(safe_label(label, 12))
                for _, p in poses:
                    key = (round(p[a] / span * 50), round(p[b] / span * 50))
                    shared = groups.pop(key, None)
                    if shared:
                        ax.annotate("/".join(shared), (p[a], p[b]), textcoords="offset points",
                                    xytext=(4, 3), fontsize=7)
            if barycentres_mm:
                bc = np.array(barycentres_mm)
                ax.plot(bc[:, a], bc[:, b], linestyle="none", marker="x", markersize=5,
                        color=COLOURS[1], label="attained barycentre")
            ax.set_title(title)
            ax.set_xlabel(f"{names[a]} (mm)")
            ax.set_ylabel(f"{names[b]} (mm)")
            ax.set_aspect("equal", adjustable="datalim")
        handles, labels = axes[0].get_legend_handles_labels()
        if handles:
            fig.legend(handles, labels, loc="lower center", ncols=3)
    return fig


@dataclass(frozen=True, slots=True)
class ScatterGroup:
    """Attained positions of one pose at one speed: deviations from their own barycentre
    projected on a plane, ``(n, 2)`` mm, and the group's RP (mm) drawn as a circle."""

    label: str
    deviation_mm: FloatArray
    rp_mm: float | None


@dataclass(frozen=True, slots=True)
class PoseScatter:
    """One subplot of :func:`pose_scatter`: a pose and its groups (one per speed)."""

    label: str
    groups: Sequence[ScatterGroup]


def pose_scatter(poses: Sequence[PoseScatter], plane: str = "y-z",
                 min_reach_mm: float = 0.01) -> Figure:
    """Per pose, the attained positions around their barycentre (origin) with the RP circle of
    each speed: the outline of the RP sphere, inside which every projected point of the sphere
    lies. Speeds differ by marker shape and line style as well as colour. The axes span at least
    ``±min_reach_mm``: a spread below the measurement's resolution is a point at the origin,
    not a zoom into rounding noise."""
    cols = min(5, max(1, len(poses)))
    rows = max(1, math.ceil(len(poses) / cols))
    a, b = plane.split("-")
    with plot_style():
        height = 1.75 * rows + 0.6
        # room left of each panel for tick labels such as "-0.025" and, on the first, the label
        fig = new_figure(7.2, height, bottom=0.75 / height, top=1 - 0.28 / height, left=0.11,
                         wspace=0.75, hspace=0.55)
        axes = fig.subplots(rows, cols, squeeze=False)
        for k, ax in enumerate(axes.flat):
            if k >= len(poses):
                ax.set_visible(False)
                continue
            pose = poses[k]
            reach = 0.0
            for i, g in enumerate(pose.groups):
                colour = COLOURS[i % len(COLOURS)]
                d = g.deviation_mm
                if len(d):
                    ax.plot(d[:, 0], d[:, 1], linestyle="none", marker=MARKERS[i % len(MARKERS)],
                            markersize=3, markerfacecolor="none", markeredgewidth=0.7,
                            color=colour, label=safe_label(g.label) if k == 0 else None)
                    reach = max(reach, float(np.max(np.abs(d))))
                if g.rp_mm is not None and math.isfinite(g.rp_mm):
                    ax.add_patch(Circle((0.0, 0.0), g.rp_mm, fill=False, edgecolor=colour,
                                        linestyle=LINESTYLES[i % 4], linewidth=0.9))
                    reach = max(reach, g.rp_mm)
            reach = 1.12 * max(reach, min_reach_mm)
            ax.set_xlim(-reach, reach)
            ax.set_ylim(-reach, reach)
            ax.set_aspect("equal")
            for axis in (ax.xaxis, ax.yaxis):
                axis.set_major_locator(MaxNLocator(3, symmetric=True))
                axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.3g}"))
            ax.set_title(safe_label(pose.label, 16))
            ax.set_xlabel(f"Δ{a} (mm)")
            if k % cols == 0:
                ax.set_ylabel(f"Δ{b} (mm)")
        handles, labels = axes.flat[0].get_legend_handles_labels()
        if handles:
            fig.legend(handles, labels, loc="lower center", ncols=min(6, len(handles)))
    return fig


# --------------------------------------------------------------------------------------------
# Start-up recovery
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class StartupPoint:
    """One start-up trial: recovery time (s), position error after it (mm), recovered or not."""

    label: str
    recovery_s: float | None
    error_mm: float | None
    recovered: bool


def startup_plots(points: Sequence[StartupPoint], time_limit_s: float | None,
                  error_limit_mm: float | None, error_unit: str = "mm") -> Figure:
    """Left: the recovery-time distribution as an empirical CDF (share of trials ready within t;
    trials that did not recover are crosses at their time-out). Right: the position error after
    recovery per trial (failed trials hatched), with the limits dashed."""
    with plot_style():
        fig = new_figure(7.2, 2.7, bottom=0.17, top=0.9, wspace=0.3)
        left, right = fig.subplots(1, 2, squeeze=False)[0]
        times = [(p.recovery_s, p.recovered) for p in points if p.recovery_s is not None]
        if times:
            ok = np.sort(np.array([t for t, r in times if r], dtype=np.float64))
            n = len(points)
            if len(ok):
                xs = np.concatenate([[0.0], ok])
                ys = np.concatenate([[0.0], np.arange(1, len(ok) + 1) / n]) * 100.0
                left.step(xs, ys, where="post", color=COLOURS[0], label="recovered trials")
                left.plot(xs[1:], ys[1:], linestyle="none", marker="o", markersize=3.5,
                          color=COLOURS[0])
            bad = [t for t, r in times if not r]
            if bad:
                left.plot(bad, [0.0] * len(bad), linestyle="none", marker="X", markersize=7,
                          color=COLOURS[1], label="not recovered")
        if time_limit_s is not None:
            left.axvline(time_limit_s, color="black", linestyle="--", linewidth=1.0,
                         label=f"limit {time_limit_s:g} s")
        left.set_xlim(left=0)
        left.set_ylim(-5, 105)
        left.set_xlabel("recovery time (s)")
        left.set_ylabel("trials ready within t (%)")
        left.set_title("recovery-time distribution")
        legend(left, loc="best")

        errs = [(p.label, p.error_mm, p.recovered) for p in points if p.error_mm is not None]
        if errs:
            x = np.arange(len(errs))
            values = np.array([max(e, 1e-3) for _, e, _ in errs], dtype=np.float64)
            bars = right.bar(x, values, color=[COLOURS[0] if r else COLOURS[1]
                                               for _, _, r in errs], width=0.7)
            for bar, (_, _, r) in zip(bars, errs, strict=True):
                if not r:
                    bar.set_hatch("///")
                    bar.set_edgecolor("black")
            step = max(1, math.ceil(len(errs) / 10))  # at most ~10 tick labels
            right.set_xticks(x[::step], [safe_label(lab, 8) for lab, _, _ in errs][::step])
            if values.max() / max(values.min(), 1e-3) > 60:
                right.set_yscale("log")
                # plain "10", "0.1": the default log labels are math text, which is off here
                right.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
                right.yaxis.set_minor_formatter(NullFormatter())
        if error_limit_mm is not None:
            right.axhline(error_limit_mm, color="black", linestyle="--", linewidth=1.0,
                          label=safe_label(f"limit {error_limit_mm:g} {error_unit}"))
            legend(right, loc="best")
        right.set_xlabel("trial (hatched: failed)")
        right.xaxis.grid(False)
        right.set_ylabel(safe_label(f"position error ({error_unit})"))
        right.set_title("position error after recovery")
    return fig


def outcomes_by_condition(conditions: Sequence[str], recovered: Sequence[int],
                          failed: Sequence[int]) -> Figure:
    """Horizontal stacked bars, one per condition: trials recovered (solid) and not recovered
    (hatched, so the outcome never rests on colour alone)."""
    with plot_style():
        height = 0.8 + 0.22 * max(1, len(conditions))
        fig = new_figure(7.2, height, left=0.2, bottom=0.5 / height, top=1 - 0.35 / height)
        ax = fig.add_subplot(1, 1, 1)
        y = np.arange(len(conditions))
        ax.barh(y, recovered, color=COLOURS[0], label="recovered")
        ax.barh(y, failed, left=recovered, color=COLOURS[1], hatch="///", edgecolor="black",
                linewidth=0.4, label="not recovered")
        ax.set_yticks(y, [safe_label(c, 24) for c in conditions])
        ax.invert_yaxis()
        ax.yaxis.grid(False)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.set_xlabel("power cuts")
        legend(ax, loc="lower center", bbox_to_anchor=(0.5, 1.0), ncols=2)
    return fig


# --------------------------------------------------------------------------------------------
# Traffic
# --------------------------------------------------------------------------------------------


def traffic_plot(t_s: FloatArray, rate_in: FloatArray, rate_out: FloatArray,
                 errors: FloatArray, resyncs: FloatArray, bin_s: float) -> Figure:
    """Frames per second in each direction over the capture (bins of ``bin_s`` starting at
    ``t_s``), and below the framing errors and resynchronisations per bin."""
    if not np.any(errors) and not np.any(resyncs):
        return _rate_only(t_s, rate_in, rate_out, bin_s)
    with plot_style():
        fig = new_figure(7.2, 3.3, bottom=0.14, top=0.91, hspace=0.15)
        top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=(2, 1), squeeze=False)[:, 0]
        edges = np.append(t_s, t_s[-1] + bin_s) if len(t_s) else t_s
        if len(t_s):
            top.stairs(rate_out, edges, color=COLOURS[0], linewidth=1.0,
                       label="out (host → arm)")
            top.stairs(rate_in, edges, color=COLOURS[1], linestyle="--", linewidth=1.0,
                       label="in (arm → host)")
            bottom.bar(t_s, errors, width=bin_s, align="edge", color=COLOURS[1],
                       label="framing errors")
            some = resyncs > 0
            bottom.plot((t_s + bin_s / 2)[some], resyncs[some], linestyle="none", marker="^",
                        markersize=3.5, color="black", label="resyncs")
        top.set_ylabel("frames/s")
        top.set_ylim(bottom=0)
        legend(top, loc="lower right", ncols=2)
        top.set_title(safe_label(f"frame rate (bins of {bin_s:g} s)"))
        bottom.set_ylabel("per bin")
        bottom.set_xlabel("capture time (s)")
        bottom.set_ylim(bottom=0)
        bottom.yaxis.set_major_locator(MaxNLocator(3, integer=True))
        legend(bottom, loc="upper right", ncols=2)
    return fig


def _rate_only(t_s: FloatArray, rate_in: FloatArray, rate_out: FloatArray,
               bin_s: float) -> Figure:
    """The frame rate alone: a capture without framing errors or resyncs gets no empty panel
    for them (the title says there were none)."""
    with plot_style():
        fig = new_figure(7.2, 2.5, bottom=0.19, top=0.88)
        ax = fig.subplots(1, 1)
        if len(t_s):
            edges = np.append(t_s, t_s[-1] + bin_s)
            ax.stairs(rate_out, edges, color=COLOURS[0], linewidth=1.0, label="out (host → arm)")
            ax.stairs(rate_in, edges, color=COLOURS[1], linestyle="--", linewidth=1.0,
                      label="in (arm → host)")
        ax.set_ylabel("frames/s")
        ax.set_xlabel("capture time (s)")
        ax.set_ylim(bottom=0)
        legend(ax, loc="center right", ncols=2)
        ax.set_title(safe_label(f"frame rate (bins of {bin_s:g} s); no framing errors, "
                                "no resyncs", 80))
    return fig


@dataclass(frozen=True, slots=True)
class JointBars:
    """One figure of every joint for :func:`joint_bars`: reported and, where known, true."""

    title: str
    reported: Sequence[float | None]
    true: Sequence[float | None]


def joint_bars(joints: Sequence[str], panels: Sequence[JointBars], unit: str) -> Figure:
    """One small panel per figure: a bar per joint for the reported angle (solid) and the true
    one (hatched, so the two never rest on colour alone)."""
    with plot_style():
        cols = max(1, len(panels))
        fig = new_figure(7.2, 2.3, left=0.08, bottom=0.2, top=0.8, wspace=0.45)
        x = np.arange(len(joints))
        for k, panel in enumerate(panels):
            ax = fig.add_subplot(1, cols, k + 1)
            rep = [np.nan if v is None else v for v in panel.reported]
            tru = [np.nan if v is None else v for v in panel.true]
            ax.bar(x - 0.2, rep, 0.4, color=COLOURS[0], label="reported")
            ax.bar(x + 0.2, tru, 0.4, color=COLOURS[1], hatch="///", edgecolor="black",
                   linewidth=0.4, label="true")
            ax.set_xticks(x, [safe_label(j, 6) for j in joints])
            ax.set_title(safe_label(panel.title, 30), fontsize=8)
            ax.xaxis.grid(False)
            if k == 0:
                ax.set_ylabel(unit)
        legend(fig.axes[0], loc="lower left", bbox_to_anchor=(0.0, 1.12), ncols=2)
    return fig
