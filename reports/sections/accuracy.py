"""The accuracy section: the paper's square path (§7), its Fig. 11 (paths in the YZ plane) and
Fig. 12 (error over time), armbench's two styles against the paper's figure.

Names come from the suite's contract
(:data:`armbench.bench.suites.accuracy_contract.ACCURACY`); every figure
in the tables is the one the record holds. The error series drawn in Fig. 12 are computed from the
samples (the record keeps only their summaries), one lap at a time: each lap's samples are read,
reduced to what its plots draw (at most :data:`PLOT_POINTS` points per figure over all laps, at
least :data:`MIN_LAP_POINTS` per lap) and let go, so the section's memory does not grow with the
samples of a long run.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from armbench.bench.suites.accuracy_contract import ACCURACY
from armbench.metrics import MetricsInputError, path_errors, square_yz
from armbench.record import RunRecord, SuiteRecord, Trial
from armbench.record.suite_contract import SAMPLE
from armbench.reports.render import plots
from armbench.reports.render.format import format_duration, format_value
from armbench.reports.render.plotting import MAX_LINE_POINTS
from armbench.reports.render.views import (
    Figures,
    FigureView,
    FloatArray,
    SectionView,
    SuiteView,
    num,
    text,
    vec3,
)

__all__ = ["SUITE", "AccuracyView", "LapRow", "PaperRow", "build"]

SUITE = ACCURACY.suite
#: Points one figure draws over all its laps; a run of few laps draws each as before, a run of
#: many draws each with fewer points (so memory and report size stay bounded) ...
PLOT_POINTS = 24_000
#: ... but never fewer than this per lap (ten per side of the square: its corners still read
#: as corners; runs of up to 300 laps stay within PLOT_POINTS).
MIN_LAP_POINTS = 40
#: How each style is called on the page.
STYLE_TITLES: Mapping[str, str] = {
    ACCURACY.paper: "paper-style (corners only, joint-interpolated)",
    ACCURACY.coordinated: "coordinated (Cartesian streaming)",
}


@dataclass(frozen=True, slots=True)
class LapRow:
    """One lap (trial), with the figures the record holds for it."""

    index: int
    style: str
    lap: str
    samples: int
    lap_time: str
    mean: str
    rms: str
    maximum: str
    belief: str
    true_mean: str
    status: str


@dataclass(frozen=True, slots=True)
class PaperRow:
    """A line of the comparison with the paper's figure."""

    label: str
    value: str
    note: str


@dataclass(frozen=True, slots=True)
class AccuracyView:
    laps: list[LapRow]
    paper: list[PaperRow]
    paper_mm: str


@dataclass(slots=True)
class _Lap:
    """One lap reduced to what the section shows: its sample count and its plots' points."""

    trial: Trial
    style: str
    samples: int
    path_mm: FloatArray  # the reported path, decimated
    errors: tuple[FloatArray, FloatArray] | None = None  # (t_s, mm), a min/max envelope
    belief: tuple[FloatArray, FloatArray] | None = None  # (t_s, mm), a min/max envelope


def _series(samples: Sequence[Mapping[str, Any]]) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Times, reported and true positions (m) of the well-formed samples."""
    nan3 = (math.nan, math.nan, math.nan)
    t: list[float] = []
    rep: list[tuple[float, float, float]] = []
    tru: list[tuple[float, float, float]] = []
    for s in samples:
        ts, r = num(s.get(SAMPLE.t)), vec3(s.get(SAMPLE.reported))
        if ts is None or r is None:
            continue
        t.append(ts)
        rep.append(r)
        tru.append(vec3(s.get(SAMPLE.true)) or nan3)
    return (np.array(t, dtype=np.float64), np.array(rep, dtype=np.float64).reshape(-1, 3),
            np.array(tru, dtype=np.float64).reshape(-1, 3))


def _laps(suite: SuiteRecord, corners: FloatArray | None, notes: list[str]) -> list[_Lap]:
    """Every drawable lap, each read from its samples and reduced before the next is read."""
    points = max(MIN_LAP_POINTS, PLOT_POINTS // max(1, len(suite.trials)))
    points = min(points, MAX_LINE_POINTS)
    laps = []
    for trial in suite.trials:
        style = trial.params.get(ACCURACY.style)
        if not trial.samples or style not in STYLE_TITLES:
            continue
        t, rep, tru = _series(trial.samples)
        if not len(rep):
            continue
        lap = _Lap(trial, str(style), len(rep), plots.decimate(rep * 1000.0, points))
        has = ~np.isnan(tru[:, 0])
        if has.any():
            lap.belief = plots.envelope(t[has], np.linalg.norm(rep[has] - tru[has], axis=1)
                                        * 1000.0, points // 2)
        if corners is not None:
            try:
                lap.errors = plots.envelope(
                    t, path_errors(rep, corners, closed=True).euclidean_mm, points // 2)
            except MetricsInputError as exc:  # pragma: no cover - inputs are checked above
                notes.append(f"trial {trial.index}: {exc}")
        laps.append(lap)
    return laps


def _lap_label(lap: _Lap) -> str:
    """``lap 2`` (record text never reaches a plot: a lap that is not a number is named by its
    trial)."""
    n = num(lap.trial.params.get(ACCURACY.lap))
    return f"lap {n:g}" if n is not None else f"trial {lap.trial.index}"


def _recorded(ms: Sequence[Any], name: str) -> float | None:
    return next((m.value for m in ms if m.name == name), None)


def _figures(laps: list[_Lap], corners: FloatArray | None, suite: SuiteRecord,
             paper_mm: float | None, figs: Figures) -> list[FigureView]:
    styles = [s for s in STYLE_TITLES if any(lap.style == s for lap in laps)]
    if not laps:
        return []
    recorded = suite.measurements
    out = [figs.make(
        plots.paths_yz, ([plots.PathPanel(STYLE_TITLES[s], [
            plots.AttainedPath(_lap_label(lap), lap.path_mm)
            for lap in laps if lap.style == s])
            for s in styles], None if corners is None else corners * 1000.0),
        "Fig. 11: paths in the YZ plane against the reference square",
        "The reference square dashed, the reported path of each lap (forward kinematics of the "
        "reported joints, as the paper measured) solid; one panel per style, like the paper's "
        "Fig. 11.",
        "; ".join(f"{STYLE_TITLES[s]}: mean distance to the square "
                  f"{format_value(_recorded(recorded, ACCURACY.metric(s, ACCURACY.mean)), 'mm')}"
                  for s in styles))]
    if corners is not None and any(lap.errors is not None for lap in laps):
        out.append(figs.make(
            plots.error_over_time, ([plots.ErrorPanel(STYLE_TITLES[s], [
                plots.ErrorRun(_lap_label(lap), *lap.errors)
                for lap in laps if lap.style == s and lap.errors is not None],
                _recorded(recorded, ACCURACY.metric(s, ACCURACY.mean))) for s in styles],
                paper_mm),
            "Fig. 12: path error over time",
            "Distance of the reported position to the reference square over each lap, like the "
            "paper's Fig. 12; the paper's mean dashed, armbench's recorded mean of each style "
            "dotted. Long laps are drawn as a min/max envelope.",
            f"paper's mean {format_value(paper_mm, 'mm')}"))
    if any(lap.belief is not None for lap in laps):
        out.append(figs.make(
            plots.error_over_time, ([plots.ErrorPanel(STYLE_TITLES[s], [
                plots.ErrorRun(_lap_label(lap), *lap.belief)
                for lap in laps if lap.style == s and lap.belief is not None],
                _recorded(recorded, ACCURACY.metric(s, ACCURACY.belief_mean)))
                for s in styles], None, "reported - true (mm)"),
            "Reported against true position (twin check)",
            "Distance between the position the firmware reports and the true one (reference "
            "instrument, or the emulator's truth) over each lap; the recorded mean dotted.",
            "; ".join(f"{STYLE_TITLES[s]}: mean "
                      + format_value(_recorded(recorded, ACCURACY.metric(s, ACCURACY.belief_mean)),
                                     "mm") for s in styles)))
    return out


def build(record: RunRecord, suite: SuiteRecord, view: SuiteView, figs: Figures) -> SectionView:
    """The accuracy section of ``record``."""
    paper_mm = record.reference.get(ACCURACY.paper_mean)
    centre, side = vec3(suite.params.get(ACCURACY.centre)), num(suite.params.get(ACCURACY.side))
    corners = None if centre is None or side is None or side <= 0 else square_yz(centre, side)
    notes: list[str] = []
    if corners is None:
        notes.append(f"The suite parameters give no reference square ({ACCURACY.centre}, "
                     f"{ACCURACY.side}): the paths are drawn without it.")
    laps = _laps(suite, corners, notes)
    rows = []
    for lap in laps:
        ms = lap.trial.measurements

        def fig(figure: str, ms: Sequence[Any] = ms, style: str = lap.style) -> str:
            return format_value(_recorded(ms, ACCURACY.metric(style, figure)), "mm")

        rows.append(LapRow(
            index=lap.trial.index, style=STYLE_TITLES[lap.style],
            lap=text(lap.trial.params.get(ACCURACY.lap, "-"), 20), samples=lap.samples,
            lap_time=format_duration(_recorded(ms, ACCURACY.metric(lap.style,
                                                                   ACCURACY.lap_time))),
            mean=fig(ACCURACY.mean), rms=fig(ACCURACY.rms), maximum=fig(ACCURACY.max),
            belief=fig(ACCURACY.belief_mean), true_mean=fig(ACCURACY.true_mean),
            status=lap.trial.status))
    paper = [PaperRow("paper §7 (Fig. 12)", format_value(paper_mm, "mm"),
                      "mean Euclidean error of the position from direct kinematics to the "
                      "square; joint moves at maximum speed, no path planning")]
    for style in STYLE_TITLES:
        mean = _recorded(suite.measurements, ACCURACY.metric(style, ACCURACY.mean))
        if mean is None:
            continue
        laps_n = _recorded(suite.measurements, ACCURACY.metric(style, ACCURACY.laps))
        ratio = f"; {mean / paper_mm:.2f} × the paper's" if paper_mm else ""
        paper.append(PaperRow(f"armbench {STYLE_TITLES[style]}", format_value(mean, "mm"),
                              f"over {format_value(laps_n, '')} laps, reported position"
                              f"{ratio}"))
        true = _recorded(suite.measurements, ACCURACY.metric(style, ACCURACY.true_mean))
        if true is not None:
            paper.append(PaperRow(f"armbench {STYLE_TITLES[style]}, true position",
                                  format_value(true, "mm"),
                                  "the same error measured on the true path"))
    return SectionView(
        key=SUITE, template="accuracy", title="Accuracy: the paper's square path", suite=view,
        figures=_figures(laps, corners, suite, paper_mm, figs),
        body=AccuracyView(laps=rows, paper=paper, paper_mm=format_value(paper_mm, "mm")),
        notes=notes)
