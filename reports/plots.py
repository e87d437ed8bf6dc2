"""The report's plots: matplotlib figures turned into small, self-contained inline SVG.

Every function here takes numbers (numpy arrays, in the units its name says) and labels the report
code chose itself; no text from a record reaches a plot, and :func:`safe_label` filters the labels
anyway (matplotlib escapes SVG text too; math text is switched off). :func:`to_svg` strips what an
inline SVG in an HTML page must not carry: the XML prolog and DOCTYPE (with its URL), the
namespace URLs, the fixed width/height (CSS sizes the plot: ``width: 100%``), the global ``<style>``
block, and element ids that could clash between plots (the ids a plot refers to are prefixed, the
others dropped).

No pyplot: figures are plain :class:`matplotlib.figure.Figure` objects rendered by the SVG backend,
so no GUI backend is ever chosen and the global pyplot state is never touched. Long series are
downsampled for drawing (:func:`decimate`, :func:`envelope`); the raw data stays in the JSON.
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, cast

import matplotlib
import numpy as np
import numpy.typing as npt
from markupsafe import Markup, escape
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Circle
from matplotlib.ticker import FuncFormatter, MaxNLocator, NullFormatter

__all__ = [
    "AttainedPath",
    "ErrorPanel",
    "ErrorRun",
    "PathPanel",
    "PoseScatter",
    "ScatterGroup",
    "StartupPoint",
    "TrendPanel",
    "cube_projections",
    "decimate",
    "envelope",
    "error_over_time",
    "paths_yz",
    "pose_scatter",
    "safe_label",
    "startup_plots",
    "to_svg",
    "traffic_plot",
    "trend_plots",
]

FloatArray = npt.NDArray[np.float64]

#: Points drawn per line at most; longer series are downsampled.
MAX_LINE_POINTS = 1200
#: Buckets of the min/max envelope of a time series (two points each).
ENVELOPE_BUCKETS = 600

#: Colour-blind-safe palette (Okabe & Ito); lines also differ in style and markers in shape.
COLOURS = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000",
           "#999999")
LINESTYLES = ("-", "--", "-.", ":")
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")

_RC: dict[str, Any] = {
    "svg.fonttype": "none",          # text stays text: small, selectable, escaped by matplotlib
    "svg.hashsalt": "armbench-report",  # deterministic ids (prefixed per plot by to_svg)
    "font.family": "sans-serif",
    "font.sans-serif": ["DejaVu Sans"],
    "font.size": 8.5,
    "axes.titlesize": 9.5,
    "axes.labelsize": 8.5,
    "legend.fontsize": 7.5,
    "legend.frameon": False,
    "text.usetex": False,
    "text.parse_math": False,        # a '$' is a dollar, never math text
    "axes.grid": True,
    "grid.alpha": 0.35,
    "grid.linewidth": 0.5,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "path.simplify": True,
    "lines.linewidth": 1.0,
    "axes.titley": 1.02,             # fixed title position: no costly automatic placement
    "axes.titlepad": 3.0,
    "axes.formatter.use_mathtext": False,
}

_LABEL_BAD = re.compile(r"[^A-Za-z0-9 _.,:;%#()+=§/×·–|-]")


def safe_label(text: str, limit: int = 48) -> str:
    """``text`` with anything but letters, digits and plain punctuation replaced by ``?``,
    shortened to ``limit`` characters: for plot labels (defence in depth; labels are the
    report's own words)."""
    cleaned = _LABEL_BAD.sub("?", text)
    return cleaned if len(cleaned) <= limit else cleaned[: limit - 1] + "…"


@contextmanager
def _style() -> Iterator[None]:
    with matplotlib.rc_context(cast(Any, _RC)):
        yield


class _LeanFigure(Figure):
    """A figure whose axes get at most five ticks a side: each tick is five artists, and
    creating and drawing them is most of matplotlib's time here."""

    def add_subplot(self, *args: Any, **kwargs: Any) -> Any:
        ax = super().add_subplot(*args, **kwargs)
        ax.locator_params(nbins=5)
        return ax


def _legend(ax: Any, **kwargs: Any) -> None:
    """A legend when the axes have labelled artists (matplotlib warns otherwise)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(**kwargs)


def _figure(width_in: float, height_in: float, *, left: float = 0.08, right: float = 0.98,
            bottom: float = 0.15, top: float = 0.9, wspace: float = 0.25,
            hspace: float = 0.3) -> Figure:
    """A figure with fixed margins (fractions of the figure). A layout engine would fit them
    automatically but costs most of the rendering time; the plots here are few and known."""
    fig = _LeanFigure(figsize=(width_in, height_in))
    fig.subplots_adjust(left=left, right=right, bottom=bottom, top=top, wspace=wspace,
                        hspace=hspace)
    return fig


# --------------------------------------------------------------------------------------------
# SVG
# --------------------------------------------------------------------------------------------

_PROLOG_END = re.compile(r"<svg\b")
_ROOT = re.compile(r"<svg\b[^>]*>")
_VIEWBOX = re.compile(r'viewBox="([^"]*)"')
_STYLE_DEFS = re.compile(r"<defs>\s*<style[^>]*>.*?</style>\s*</defs>", re.DOTALL)
_REF = re.compile(r'(?:href="#|url\(#)([^")]+)')
_ID = re.compile(r' id="([^"]*)"')
_PATH_D = re.compile(r' d="([^"]*)"')
_LONG_NUMBER = re.compile(r"(-?\d+\.\d{2})\d+")
_COORD_ATTR = re.compile(r' (x|y|width|height)="(-?\d+\.\d{2})\d*"')


def _short_path(match: re.Match[str]) -> str:
    d = _LONG_NUMBER.sub(r"\1", " ".join(match.group(1).split()))
    return f' d="{d}"'


def to_svg(fig: Figure, fid: str, title: str) -> Markup:
    """``fig`` as an inline ``<svg>`` element: scalable (``viewBox``, no fixed size), labelled for
    screen readers with ``title`` (escaped), ids prefixed with ``fid`` so several plots can share a
    page, coordinates to 0.01 pt, no URL and no script."""
    buf = io.StringIO()
    with _style():
        fig.savefig(buf, format="svg",
                    metadata={"Date": None, "Creator": None, "Format": None, "Type": None})
    text = buf.getvalue()
    start = _PROLOG_END.search(text)
    if start is None:  # pragma: no cover - matplotlib always writes an <svg> root
        raise RuntimeError("matplotlib wrote no <svg> element")
    text = text[start.start():]
    root = _ROOT.match(text)
    assert root is not None
    box = _VIEWBOX.search(root.group(0))
    view_box = box.group(1) if box else "0 0 100 100"
    new_root = (f'<svg class="plot" viewBox="{view_box}" role="img" '
                f'aria-label="{escape(title)}" preserveAspectRatio="xMidYMid meet">')
    text = new_root + text[root.end():]
    text = _STYLE_DEFS.sub("", text, count=1)
    text = text.replace("xlink:href=", "href=")
    referenced = set(_REF.findall(text))

    def rename(match: re.Match[str]) -> str:
        name = match.group(1)
        return f' id="{fid}-{name}"' if name in referenced else ""

    text = _ID.sub(rename, text)
    text = re.sub(r'(href="#|url\(#)([^")]+)', lambda m: f"{m.group(1)}{fid}-{m.group(2)}", text)
    text = _PATH_D.sub(_short_path, text)
    text = _COORD_ATTR.sub(r' \1="\2"', text)
    text = re.sub(r">\s+<", "><", text).strip()
    lowered = text.lower()
    if "<script" in lowered or "http:" in lowered or "https:" in lowered or " on" in _attr_names(
            text):
        raise RuntimeError("refusing an SVG with a script or a URL")  # pragma: no cover
    return Markup(text)


def _attr_names(text: str) -> str:
    """Every attribute name (with a leading space) of the SVG's tags, for the on* check."""
    return " ".join(" " + name.lower() for name in re.findall(r"\s([A-Za-z_:][-\w:.]*)=", text))


# --------------------------------------------------------------------------------------------
# Downsampling
# --------------------------------------------------------------------------------------------


def decimate(points: FloatArray, max_points: int = MAX_LINE_POINTS) -> FloatArray:
    """Evenly spaced rows of ``points`` (first and last kept), at most ``max_points``."""
    n = len(points)
    if n <= max_points:
        return points
    idx = np.unique(np.linspace(0, n - 1, max_points).round().astype(np.int64))
    return points[idx]


def envelope(t: FloatArray, y: FloatArray,
             buckets: int = ENVELOPE_BUCKETS) -> tuple[FloatArray, FloatArray]:
    """A min/max envelope of the series ``y(t)``: per bucket of consecutive samples its lowest and
    highest point, in time order. Peaks survive, unlike with plain decimation."""
    n = len(y)
    if n <= 2 * buckets:
        return t, y
    size = math.ceil(n / buckets)
    pad = size * buckets - n
    yp = np.concatenate([y, np.full(pad, np.nan)]).reshape(buckets, size)
    valid = ~np.all(np.isnan(yp), axis=1)
    lo = np.nanargmin(np.where(np.isnan(yp), np.inf, yp), axis=1)
    hi = np.nanargmax(np.where(np.isnan(yp), -np.inf, yp), axis=1)
    base = np.arange(buckets) * size
    idx = np.concatenate([(base + lo)[valid], (base + hi)[valid]])
    idx = np.unique(np.clip(idx, 0, n - 1))
    return t[idx], y[idx]


# --------------------------------------------------------------------------------------------
# Accuracy (paper §7, Figs. 11 and 12)
# --------------------------------------------------------------------------------------------


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
    with _style():
        fig = _figure(7.2, 3.6 if len(panels) > 1 else 4.2, bottom=0.13, top=0.92)
        axes = fig.subplots(1, max(1, len(panels)), squeeze=False)[0]
        for ax, panel in zip(axes, panels, strict=False):
            if square_mm is not None:
                closed = np.vstack([square_mm, square_mm[:1]])
                ax.plot(closed[:, 1], closed[:, 2], color="black", linestyle="--",
                        linewidth=1.2, label="reference square")
            for i, run in enumerate(panel.runs):
                colour = COLOURS[i % len(COLOURS)]
                rep = decimate(run.reported_mm)
                ax.plot(rep[:, 1], rep[:, 2], color=colour, linestyle=LINESTYLES[i % 4],
                        linewidth=1.0, label=safe_label(f"{run.label} reported"))
                if run.true_mm is not None and len(run.true_mm):
                    tru = decimate(run.true_mm)
                    ax.plot(tru[:, 1], tru[:, 2], color=colour, linestyle=":", linewidth=0.8,
                            alpha=0.8, label=safe_label(f"{run.label} true"))
            ax.set_title(safe_label(panel.title))
            ax.set_xlabel("y (mm)")
            ax.set_ylabel("z (mm)")
            ax.set_aspect("equal", adjustable="datalim")
            _legend(ax, loc="center", fontsize=6.5)
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
    with _style():
        fig = _figure(7.2, 2.9, bottom=0.16, top=0.9, wspace=0.08)
        axes = fig.subplots(1, max(1, len(panels)), squeeze=False, sharey=True)[0]
        top = 0.0
        for ax, panel in zip(axes, panels, strict=False):
            for i, run in enumerate(panel.runs):
                t, y = envelope(run.t_s, run.error_mm)
                if len(y):
                    top = max(top, float(np.nanmax(y)))
                ax.plot(t, y, color=COLOURS[i % len(COLOURS)], linestyle=LINESTYLES[i % 4],
                        linewidth=0.8, label=safe_label(run.label))
            if paper_mm is not None:
                ax.axhline(paper_mm, color="#D55E00", linestyle="--", linewidth=1.3,
                           label=safe_label(f"paper §7 mean {paper_mm:.1f} mm"))
            if panel.mean_mm is not None:
                ax.axhline(panel.mean_mm, color="black", linestyle=":", linewidth=1.3,
                           label=safe_label(f"armbench mean {panel.mean_mm:.2f} mm"))
            ax.set_title(safe_label(panel.title))
            ax.set_xlabel("time in trial (s)")
            _legend(ax, loc="upper right", fontsize=6.5, ncols=2)
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
    with _style():
        fig = _figure(7.2, 2.8, bottom=0.27, top=0.9, wspace=0.4)
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


def pose_scatter(poses: Sequence[PoseScatter], plane: str = "y-z") -> Figure:
    """Per pose, the attained positions around their barycentre (origin) with the RP circle of
    each speed: the outline of the RP sphere, inside which every projected point of the sphere
    lies. Speeds differ by marker shape and line style as well as colour."""
    cols = min(5, max(1, len(poses)))
    rows = max(1, math.ceil(len(poses) / cols))
    a, b = plane.split("-")
    with _style():
        height = 1.75 * rows + 0.6
        fig = _figure(7.2, height, bottom=0.75 / height, top=1 - 0.28 / height, left=0.07,
                      wspace=0.45, hspace=0.55)
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
            reach = 1.12 * (reach or 1.0)
            ax.set_xlim(-reach, reach)
            ax.set_ylim(-reach, reach)
            ax.set_aspect("equal")
            ax.xaxis.set_major_locator(MaxNLocator(3, symmetric=True))
            ax.yaxis.set_major_locator(MaxNLocator(3, symmetric=True))
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
                  error_limit_mm: float | None) -> Figure:
    """Left: the recovery-time distribution as an empirical CDF (share of trials ready within t;
    trials that did not recover are crosses at their time-out). Right: the position error after
    recovery per trial (failed trials hatched), with the limits dashed."""
    with _style():
        fig = _figure(7.2, 2.7, bottom=0.17, top=0.9, wspace=0.3)
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
        _legend(left, loc="best")

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
                          label=f"limit {error_limit_mm:g} mm")
            _legend(right, loc="best")
        right.set_xlabel("trial (hatched: failed)")
        right.xaxis.grid(False)
        right.set_ylabel("position error (mm)")
        right.set_title("position error after recovery")
    return fig


# --------------------------------------------------------------------------------------------
# Traffic
# --------------------------------------------------------------------------------------------


def traffic_plot(t_s: FloatArray, rate_in: FloatArray, rate_out: FloatArray,
                 errors: FloatArray, resyncs: FloatArray, bin_s: float) -> Figure:
    """Frames per second in each direction over the capture (bins of ``bin_s`` starting at
    ``t_s``), and below the framing errors and resynchronisations per bin."""
    with _style():
        fig = _figure(7.2, 3.3, bottom=0.14, top=0.91, hspace=0.15)
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
        _legend(top, loc="lower right", ncols=2)
        top.set_title(safe_label(f"frame rate (bins of {bin_s:g} s)"))
        bottom.set_ylabel("per bin")
        bottom.set_xlabel("capture time (s)")
        bottom.set_ylim(bottom=0)
        bottom.yaxis.set_major_locator(MaxNLocator(3, integer=True))
        _legend(bottom, loc="upper right", ncols=2)
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


def trend_plots(panels: Sequence[TrendPanel]) -> Figure:
    """Key metrics across runs in creation order, one subplot each; values outside their limits
    are drawn as crosses (not colour alone)."""
    with _style():
        fig = _figure(7.2, 2.5, bottom=0.18, top=0.88, wspace=0.35)
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
                        color=COLOURS[0], label="within limit")
                if (~good).any():
                    ax.plot(xs[~good], ys[~good], linestyle="none", marker="X", markersize=7,
                            color=COLOURS[1], label="outside limit")
            if p.limit is not None:
                ax.axhline(p.limit, color="black", linestyle="--", linewidth=1.0,
                           label=safe_label(f"limit {p.limit:g} {p.unit}"))
            ax.set_title(safe_label(p.title))
            ax.set_xlabel("run #")
            ax.set_ylabel(safe_label(p.unit))
            ax.xaxis.set_major_locator(MaxNLocator(6, integer=True))
            if pts or p.limit is not None:
                _legend(ax, loc="best", fontsize=6.5)
            else:
                ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center",
                        va="center")
    return fig
