"""The view objects the report templates render (strings are escaped there), the plot
numbering of a page and the readers of loosely typed sample data (samples are any JSON objects)."""

from __future__ import annotations

import contextlib
import gc
import json
import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from markupsafe import Markup
from matplotlib.figure import Figure

from armbench.reports.render import svg_cache

FloatArray = npt.NDArray[np.float64]

# --------------------------------------------------------------------------------------------
# Reading loosely typed sample data (samples are any JSON objects)
# --------------------------------------------------------------------------------------------


def num(value: object) -> float | None:
    """A finite number (not a boolean), else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def vec3(value: object) -> tuple[float, float, float] | None:
    """An ``[x, y, z]`` of finite numbers, else None."""
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        return None
    x, y, z = (num(v) for v in value)
    if x is None or y is None or z is None:
        return None
    return (x, y, z)


def text(value: object, limit: int = 200) -> str:
    """Any JSON value as short text for a table cell (escaped by the template)."""
    if isinstance(value, str):
        text = value
    else:
        try:
            text = json.dumps(value, ensure_ascii=False, allow_nan=False, sort_keys=False)
        except (TypeError, ValueError):
            text = repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def params_text(params: Mapping[str, Any]) -> str:
    return ", ".join(f"{k}={text(v, 60)}" for k, v in params.items()) or "-"


# --------------------------------------------------------------------------------------------
# View objects handed to the templates (strings are escaped there)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class FigureView:
    """An inline SVG plot (trusted markup from :mod:`armbench.reports.render.plots`) and its
    caption."""

    svg: Markup
    caption: str
    title: str = ""


@dataclass(frozen=True, slots=True)
class MeasurementRow:
    """One measurement as a table row; the baseline fields are ``""`` without a comparison."""

    name: str
    description: str
    trial: str
    value: str
    unit: str
    limit: str
    margin: str
    outcome: str
    baseline: str = ""
    change: str = ""
    change_pct: str = ""
    tolerance: str = ""
    result: str = ""


@dataclass(frozen=True, slots=True)
class TrialMetricRow:
    """A trial-level metric summarised over a suite's trials."""

    name: str
    unit: str
    limit: str
    n: int
    minimum: str
    mean: str
    maximum: str
    worst_margin: str
    failed: int
    failed_trials: str
    outcome: str


@dataclass(frozen=True, slots=True)
class TrialView:
    """One trial in a generic trial table."""

    index: int
    status: str
    params: str
    started: str
    duration: str
    samples: int
    measurements: str
    error: str | None


@dataclass(slots=True)
class SuiteView:
    """A suite in the summary, the measurements section and (unknown suites) its own section."""

    key: str
    name: str
    status: str
    verdict: str
    version: str
    started: str
    duration: str
    robot_time: str
    trials_done: int
    trials_error: int
    superseded: int
    measured: int
    failed: int
    regressed: int
    error: str | None
    params: str
    rows: list[MeasurementRow] = field(default_factory=list)
    disturbed: int = 0
    """Trials the link to the arm was lost during (measured, kept, flagged)."""
    trial_metrics: list[TrialMetricRow] = field(default_factory=list)
    trial_rows: list[MeasurementRow] = field(default_factory=list)
    trials: list[TrialView] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class FaultRow:
    """An injected fault: its kind and its other non-null fields."""

    kind: str
    details: str


@contextlib.contextmanager
def figures_collected_alone() -> Iterator[None]:
    """While a page is drawn, the collection after each figure (:meth:`Figures.make`) looks at
    the objects made since the page began, not at every object of the process (the modules,
    the record: a full collection each time, a large part of a report's time): what exists
    when the page begins is set aside (``gc.freeze``) until it ends. Nothing is lost: frozen
    garbage is collected after ``gc.unfreeze``. A caller that froze objects itself keeps its
    freeze."""
    if gc.get_freeze_count():
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


class Figures:
    """Numbers the plots of one page so their SVG ids never clash. ``collect``: run the
    collector after each plot drawn (:func:`~armbench.reports.render.svg_cache.drawn`); a page
    does, under :func:`figures_collected_alone`."""

    def __init__(self, *, collect: bool = True) -> None:
        self.count = 0
        self.collect = collect

    def make(self, plot: Callable[..., Figure], args: tuple[object, ...], title: str,
             caption: str, alt: str = "") -> FigureView:
        """The inline SVG of ``plot(*args)`` (drawn now, or kept from an earlier draw of the
        same inputs); its text alternative (``aria-label``) is ``title`` and, when given,
        ``alt``: the figures the plot shows, in words."""
        self.count += 1
        label = f"{title}. {alt}" if alt else title
        svg = svg_cache.drawn(plot, args, label, collect=self.collect)
        return FigureView(Markup(svg_cache.renamed(svg, self.count)), caption, title)

    def copy(self, figure: FigureView) -> FigureView:
        """The same plot once more on the page (the lead plot), its ids renamed."""
        self.count += 1
        svg = svg_cache.renamed(str(figure.svg), self.count)
        return FigureView(Markup(svg), figure.caption, figure.title)


@dataclass(frozen=True, slots=True)
class ScoreRow:
    """A headline figure in the scorecard: value, limit, margin and outcome as recorded, the
    change against the baseline and its direction in a word (``worse``, ``better``, ``same``),
    and the paper's figure."""

    label: str
    metric: str
    value: str
    limit: str
    margin: str
    outcome: str
    change: str = ""
    direction: str = ""
    paper: str = ""
    reported: str = ""
    """The firmware's (encoders') figure beside a true ``value``; empty when ``value`` is it."""
    view: str = ""
    """``true`` (``value`` is the true figure), ``encoders`` (the encoders' view, no truth in the
    run) or empty (not a position figure)."""
    warning: str = ""
    """A warning beside the value (a short lifetime)."""
    judges: str = ""
    """Which figures the limit column judges: ``true``, ``firmware``, ``true+firmware``, or
    empty (a figure that is neither, or no limit)."""


@dataclass(slots=True)
class SectionView:
    """One suite's section: its template (``sections/<name>.html.j2``), its html id and title,
    the plots it leads with, and the suite-specific view its template reads (``body``)."""

    key: str
    template: str
    title: str
    suite: SuiteView
    figures: list[FigureView]
    body: Any = None
    notes: list[str] = field(default_factory=list)
    scorecard: list[ScoreRow] = field(default_factory=list)
