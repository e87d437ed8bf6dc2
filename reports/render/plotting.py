"""The plots' common ground: the matplotlib style, a figure with fixed margins, inline SVG export
(:func:`to_svg`) and downsampling of long series (:func:`decimate`, :func:`envelope`).

:func:`to_svg` strips what an inline SVG in an HTML page must not carry: the XML prolog and DOCTYPE
(with its URL), the namespace URLs, the fixed width/height (CSS sizes the plot: ``width: 100%``),
the global ``<style>`` block, and element ids that could clash between plots (the ids a plot refers
to are prefixed, the others dropped). No pyplot: figures are plain
:class:`matplotlib.figure.Figure` objects rendered by the SVG backend.
"""

from __future__ import annotations

import io
import re
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, cast

import matplotlib
import numpy as np
import numpy.typing as npt
from markupsafe import Markup, escape
from matplotlib.figure import Figure

from armbench.metrics.series import envelope_indices

__all__ = [
    "COLOURS",
    "LINESTYLES",
    "MARKERS",
    "FloatArray",
    "decimate",
    "envelope",
    "legend",
    "new_figure",
    "plot_style",
    "safe_label",
    "to_svg",
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
    "axes.formatter.useoffset": False,  # no "1e-13" offset label over the title
    "axes.formatter.limits": (-99, 99),  # plain numbers on the axes, never scientific
}

_LABEL_BAD = re.compile(r"[^A-Za-z0-9 _.,:;%#()+=§/×·–|-]")


def safe_label(text: str, limit: int = 48) -> str:
    """``text`` with anything but letters, digits and plain punctuation replaced by ``?``,
    shortened to ``limit`` characters: for plot labels (defence in depth; labels are the
    report's own words)."""
    cleaned = _LABEL_BAD.sub("?", text)
    return cleaned if len(cleaned) <= limit else cleaned[: limit - 1] + "…"


@contextmanager
def plot_style() -> Iterator[None]:
    with matplotlib.rc_context(cast(Any, _RC)):
        yield


class _LeanFigure(Figure):
    """A figure whose axes get at most five ticks a side: each tick is five artists, and
    creating and drawing them is most of matplotlib's time here."""

    def add_subplot(self, *args: Any, **kwargs: Any) -> Any:
        ax = super().add_subplot(*args, **kwargs)
        ax.locator_params(nbins=5)
        return ax


def legend(ax: Any, **kwargs: Any) -> None:
    """A legend when the axes have labelled artists (matplotlib warns otherwise)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(**kwargs)


def new_figure(width_in: float, height_in: float, *, left: float = 0.08, right: float = 0.98,
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
    with plot_style():
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
    idx = envelope_indices(y, buckets)
    return t[idx], y[idx]
