"""The ros2-square section: the accuracy square through ROS 2 against the driver's own
coordinated run, side by side (the figures the suite recorded, the paths in the YZ plane).

Names come from the suite contract
(:data:`armbench.bench.suites.ros2_square_contract.ROS2_SQUARE`); every figure in the tables is
one the record holds.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from armbench.bench.suites.ros2_square_contract import ROS2_SQUARE
from armbench.metrics import square_yz
from armbench.record import Measurement, RunRecord, SuiteRecord
from armbench.record.suite_contract import SAMPLE
from armbench.reports.render import plots
from armbench.reports.render.format import format_duration, format_value
from armbench.reports.render.plotting import MAX_LINE_POINTS
from armbench.reports.render.views import (
    Figures,
    FigureView,
    SectionView,
    SuiteView,
    num,
    text,
    vec3,
)

__all__ = ["SUITE", "LapRow", "Ros2SquareView", "StyleRow", "build"]

SUITE = ROS2_SQUARE.suite
N = ROS2_SQUARE
#: How each style is called on the page.
STYLE_TITLES: Mapping[str, str] = {
    N.coordinated: "the driver's own coordinated run",
    N.trajectory: "through ROS 2 (FollowJointTrajectory from a separate process)",
}
#: Points drawn per lap at most.
LAP_POINTS = 2000


@dataclass(frozen=True, slots=True)
class StyleRow:
    """One style's suite-level figures."""

    style: str
    laps: str
    mean: str
    rms: str
    maximum: str
    true_mean: str
    lap_time: str


@dataclass(frozen=True, slots=True)
class LapRow:
    """One lap (trial), with the figures the record holds for it."""

    index: int
    style: str
    lap: str
    samples: int
    lap_time: str
    mean: str
    maximum: str
    status: str


@dataclass(frozen=True, slots=True)
class Ros2SquareView:
    styles: list[StyleRow]
    laps: list[LapRow]
    ratio: str
    true_ratio: str


def _value(ms: Sequence[Measurement], name: str) -> float | None:
    return next((m.value for m in ms if m.name == name), None)


def _path_mm(samples: Sequence[Mapping[str, Any]]) -> np.ndarray[Any, np.dtype[np.float64]]:
    pts = [p for p in (vec3(s.get(SAMPLE.reported)) for s in samples) if p is not None]
    return np.array(pts, dtype=np.float64).reshape(-1, 3) * 1000.0


def _figures(suite: SuiteRecord, figs: Figures) -> list[FigureView]:
    centre, side = vec3(suite.params.get(N.centre)), num(suite.params.get(N.side))
    corners = None if centre is None or side is None or side <= 0 else square_yz(centre, side)
    points = min(LAP_POINTS, MAX_LINE_POINTS)
    panels = []
    for style, title in STYLE_TITLES.items():
        runs = []
        for t in suite.trials:
            if t.params.get(N.style) != style or not t.samples:
                continue
            path = _path_mm(t.samples)
            if len(path):
                lap = num(t.params.get(N.lap))
                runs.append(plots.AttainedPath(f"lap {lap:g}" if lap is not None
                                               else f"trial {t.index}",
                                               plots.decimate(path, points)))
        if runs:
            panels.append(plots.PathPanel(title, runs))
    if not panels:
        return []
    return [figs.make(
        plots.paths_yz, (panels, None if corners is None else corners * 1000.0),
        "The square in the YZ plane: the driver's own run and through ROS 2",
        "The reference square dashed, the reported path of each lap (forward kinematics of the "
        "reported joints) solid; one panel per style.",
        "; ".join(f"{STYLE_TITLES[s]}: mean distance to the square "
                  f"{format_value(_value(suite.measurements, N.metric(s, N.mean)), 'mm')}"
                  for s in STYLE_TITLES))]


def build(record: RunRecord, suite: SuiteRecord, view: SuiteView, figs: Figures) -> SectionView:
    """The ros2-square section of ``record``."""
    ms = suite.measurements
    styles = [StyleRow(
        style=STYLE_TITLES[s], laps=format_value(_value(ms, N.metric(s, N.laps)), ""),
        mean=format_value(_value(ms, N.metric(s, N.mean)), "mm"),
        rms=format_value(_value(ms, N.metric(s, N.rms)), "mm"),
        maximum=format_value(_value(ms, N.metric(s, N.max)), "mm"),
        true_mean=format_value(_value(ms, N.metric(s, N.true_mean)), "mm"),
        lap_time=format_duration(_value(ms, N.metric(s, N.lap_time))))
        for s in STYLE_TITLES if _value(ms, N.metric(s, N.laps)) is not None]
    laps = []
    for t in suite.trials:
        style = t.params.get(N.style)
        if style not in STYLE_TITLES:
            continue
        laps.append(LapRow(
            index=t.index, style=STYLE_TITLES[str(style)],
            lap=text(t.params.get(N.lap, "-"), 20), samples=len(t.samples),
            lap_time=format_duration(_value(t.measurements, N.metric(str(style), N.lap_time))),
            mean=format_value(_value(t.measurements, N.metric(str(style), N.mean)), "mm"),
            maximum=format_value(_value(t.measurements, N.metric(str(style), N.max)), "mm"),
            status=t.status))
    body = Ros2SquareView(styles=styles, laps=laps,
                          ratio=format_value(_value(ms, N.ratio), ""),
                          true_ratio=format_value(_value(ms, N.true_ratio), ""))
    return SectionView(key=SUITE, template="ros2_square",
                       title="ROS 2: the square through FollowJointTrajectory", suite=view,
                       figures=_figures(suite, figs), body=body)
