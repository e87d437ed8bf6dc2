"""The accuracy section: the paper's square path (§7, Figs. 11 and 12)."""

from __future__ import annotations

import math
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from armbench.bench.metrics import (
    MetricsInputError,
    path_errors,
    square_yz,
)
from armbench.bench.record import (
    PAPER_REFERENCE,
    RunRecord,
    SuiteRecord,
    Trial,
)
from armbench.reports import plots
from armbench.reports.format import (
    format_duration,
    format_number,
)
from armbench.reports.views import (
    Figures,
    FigureView,
    FloatArray,
    SuiteView,
    num,
    text,
    vec3,
)

_MODE_TITLES = {"paper": "paper-style (joint-interpolated corners)",
                "coordinated": "coordinated (Cartesian interpolation)",
                "other": "other modes"}


@dataclass(frozen=True, slots=True)
class AccuracyRunRow:
    """One accuracy trial, with the figures the report computed from its samples."""

    index: int
    mode: str
    run: str
    speed: str
    samples: int
    duration: str
    mean: str
    rms: str
    maximum: str
    report_error: str
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
    suite: SuiteView
    figures: list[FigureView]
    runs: list[AccuracyRunRow]
    paper: list[PaperRow]
    paper_mm: str
    has_true: bool
    notes: list[str]


# --------------------------------------------------------------------------------------------
# Accuracy
# --------------------------------------------------------------------------------------------


@dataclass(slots=True)
class _AccRun:
    trial: Trial
    mode: str
    t: FloatArray
    reported: FloatArray
    true: FloatArray  # NaN rows where a sample has no true position
    errors: FloatArray | None = None
    true_errors: FloatArray | None = None
    tracking: FloatArray | None = None


def _fast_series(samples: Sequence[Mapping[str, Any]]) -> tuple[FloatArray, FloatArray,
                                                                  FloatArray] | None:
    """t, reported, true of well-formed samples in one numpy pass (the usual case), or None
    when any sample is irregular (then :func:`_slow_series` checks each one)."""
    try:
        t = np.array([s["t_s"] for s in samples], dtype=np.float64)
        rep = np.array([s["reported_m"] for s in samples], dtype=np.float64)
        trues = [s.get("true_m") for s in samples]
        if all(v is None for v in trues):
            tru = np.full_like(rep, np.nan)
        else:
            tru = np.array(trues, dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        return None
    if (t.shape != (len(samples),) or rep.shape != (len(samples), 3) or tru.shape != rep.shape
            or not np.isfinite(t).all() or not np.isfinite(rep).all()
            or not np.isfinite(tru).all()
            or any(isinstance(s["t_s"], bool) for s in samples)):
        return None
    return t, rep, tru


def _slow_series(samples: Sequence[Mapping[str, Any]]) -> tuple[FloatArray, FloatArray,
                                                                  FloatArray]:
    nan3 = (math.nan, math.nan, math.nan)
    t: list[float] = []
    rep: list[tuple[float, float, float]] = []
    tru: list[tuple[float, float, float]] = []
    for s in samples:
        ts, r = num(s.get("t_s")), vec3(s.get("reported_m"))
        if ts is None or r is None:
            continue
        t.append(ts)
        rep.append(r)
        tru.append(vec3(s.get("true_m")) or nan3)
    return (np.array(t, dtype=np.float64), np.array(rep, dtype=np.float64).reshape(-1, 3),
            np.array(tru, dtype=np.float64).reshape(-1, 3))


def _accuracy_runs(suite: SuiteRecord) -> list[_AccRun]:
    runs = []
    for trial in suite.trials:
        if not trial.samples:
            continue
        series = _fast_series(trial.samples) or _slow_series(trial.samples)
        t, rep, tru = series
        if not len(rep):
            continue
        mode = trial.params.get("mode")
        runs.append(_AccRun(trial, mode if mode in ("paper", "coordinated") else "other",
                            t, rep, tru))
    return runs


def _square(params: Mapping[str, Any]) -> FloatArray | None:
    centre, side = vec3(params.get("centre_m")), num(params.get("side_m"))
    if centre is None or side is None or side <= 0:
        return None
    return square_yz(centre, side)


def accuracy_section(record: RunRecord, suite: SuiteRecord, view: SuiteView,
              figs: Figures) -> AccuracyView:
    paper_mm = record.reference.get("paper_mean_error_mm",
                                    PAPER_REFERENCE["paper_mean_error_mm"])
    runs = _accuracy_runs(suite)
    corners = _square(suite.params)
    notes: list[str] = []
    if corners is None:
        notes.append("The suite parameters give no reference square (centre_m, side_m): the "
                     "paths are drawn without it and path errors are not recomputed.")
    for run in runs:
        has = ~np.isnan(run.true[:, 0])
        if has.any():
            run.tracking = np.linalg.norm(run.reported[has] - run.true[has], axis=1) * 1000.0
        if corners is None:
            continue
        try:
            run.errors = path_errors(run.reported, corners, closed=True).euclidean_mm
            if has.any():
                run.true_errors = path_errors(run.true[has], corners, closed=True).euclidean_mm
        except MetricsInputError as exc:  # pragma: no cover - inputs are checked above
            notes.append(f"trial {run.trial.index}: {exc}")
    has_true = any(r.tracking is not None for r in runs)
    modes = [m for m in ("paper", "coordinated", "other") if any(r.mode == m for r in runs)]
    recorded = {m.name: m for m in suite.measurements}

    def mode_mean(mode: str) -> tuple[float | None, str]:
        m = recorded.get(f"accuracy.{mode}.mean_mm")
        if m is not None:
            return m.value, "recorded"
        means = [float(r.errors.mean()) for r in runs if r.mode == mode and r.errors is not None]
        return (statistics.fmean(means), "computed from the samples") if means else (None, "")

    figures: list[FigureView] = []
    if runs:
        panels = [plots.PathPanel(_MODE_TITLES[mode], [
            plots.PathRun(f"trial {r.trial.index}", r.reported * 1000.0,
                          None if r.tracking is None
                          else r.true[~np.isnan(r.true[:, 0])] * 1000.0)
            for r in runs if r.mode == mode]) for mode in modes]
        figures.append(figs.make(
            plots.paths_yz(panels, None if corners is None else corners * 1000.0),
            "Path in the YZ plane against the reference square",
            "Path in the YZ plane (like the paper's Fig. 11): the reference square dashed, the "
            "reported path (forward kinematics of the reported joints) of each run solid"
            + (", the true path dotted" if has_true else "") + "."))
    if corners is not None and any(r.errors is not None for r in runs):
        panels_e = [plots.ErrorPanel(_MODE_TITLES[mode], [
            plots.ErrorRun(f"trial {r.trial.index}", r.t, r.errors)
            for r in runs if r.mode == mode and r.errors is not None], mode_mean(mode)[0])
            for mode in modes]
        figures.append(figs.make(
            plots.error_over_time(panels_e, paper_mm),
            "Path error over time",
            f"Euclidean distance of the reported position to the reference square over time "
            f"(like the paper's Fig. 12); the paper's mean of {paper_mm:g} mm dashed, "
            "armbench's mean of each mode dotted. Long runs are drawn as a min/max envelope."))
    if has_true:
        panels_t = []
        for mode in modes:
            rs = [r for r in runs if r.mode == mode and r.tracking is not None]
            if not rs:
                continue
            allv = np.concatenate([r.tracking for r in rs if r.tracking is not None])
            panels_t.append(plots.ErrorPanel(_MODE_TITLES[mode], [
                plots.ErrorRun(f"trial {r.trial.index}", r.t[~np.isnan(r.true[:, 0])],
                               r.tracking)
                for r in rs if r.tracking is not None], float(allv.mean())))
        figures.append(figs.make(
            plots.error_over_time(panels_t, None, "reported - true (mm)"),
            "Reported against true position",
            "Distance between the reported position (what the robot says) and the true one "
            "(external measurement, or the emulator's truth) over time; the mean dotted."))

    rows = []
    for r in runs:
        speed = num(r.trial.params.get("speed_pct"))
        err = r.errors
        rows.append(AccuracyRunRow(
            index=r.trial.index, mode=text(r.trial.params.get("mode", "-"), 40),
            run=text(r.trial.params.get("run", "-"), 20),
            speed="-" if speed is None else f"{speed:g} %",
            samples=len(r.reported), duration=format_duration(r.trial.duration_s),
            mean=format_number(None if err is None else float(err.mean())),
            rms=format_number(None if err is None else float(np.sqrt(np.mean(err * err)))),
            maximum=format_number(None if err is None else float(err.max())),
            report_error=format_number(None if r.tracking is None else float(r.tracking.mean())),
            true_mean=format_number(None if r.true_errors is None
                                    else float(r.true_errors.mean())),
            status=r.trial.status))

    paper = [PaperRow("paper §7 (Fig. 12)", f"{format_number(paper_mm)} mm",
                      "mean Euclidean error of the position from direct kinematics to the "
                      "square; joint moves at maximum speed, no path planning")]
    for mode in ("paper", "coordinated"):
        value, source = mode_mean(mode)
        if value is None:
            continue
        n = sum(r.mode == mode for r in runs)
        ratio = f"; {value / paper_mm:.2f} × the paper's" if paper_mm else ""
        paper.append(PaperRow(f"armbench {_MODE_TITLES[mode]}", f"{format_number(value)} mm",
                              f"mean over {n} run(s), {source}{ratio}"))
        trues = [float(r.true_errors.mean()) for r in runs
                 if r.mode == mode and r.true_errors is not None]
        if trues:
            style = "paper-style" if mode == "paper" else mode
            paper.append(PaperRow(f"armbench {style}, true position",
                                  f"{format_number(statistics.fmean(trues))} mm",
                                  "the same error measured on the true path"))
    return AccuracyView(suite=view, figures=figures, runs=rows, paper=paper,
                        paper_mm=format_number(paper_mm), has_true=has_true, notes=notes)


