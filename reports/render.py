"""The run report: one self-contained HTML page (``report.html``) from a run record.

Data flows one way: the report reads ``results.json`` (and ``capture.jsonl`` beside it, when the
run captured its traffic) and nothing else; it never talks to a robot, a driver or the emulator.
What each section shows is described in ``docs/reports.md``.

The page is one file with no network access: CSS inline, plots inline as SVG
(``armbench.reports.plots``),
a Content-Security-Policy that forbids fetching anything and running any script, every piece of
record text HTML-escaped by the templates (Jinja2 autoescaping; record text never reaches an SVG).
Sections render from whatever the record holds: a suite absent from the record is left out, an
interrupted or errored run still renders, an unknown suite gets a generic section.
"""

from __future__ import annotations

import json
import math
import os
import re
import statistics
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np
import numpy.typing as npt
from markupsafe import Markup
from matplotlib.figure import Figure

from armbench.bench.metrics import (
    MetricsInputError,
    cube_corners,
    iso_cube_poses,
    path_errors,
    pose_accuracy,
    pose_repeatability,
    square_yz,
)
from armbench.bench.record import (
    CAPTURE_FILE,
    PAPER_REFERENCE,
    REPORT_FILE,
    RESULTS_FILE,
    ComparisonRow,
    Measurement,
    RunRecord,
    SuiteRecord,
    Trial,
    atomic_write_bytes,
    load_record,
)
from armbench.reports import plots
from armbench.reports.capture import CaptureLine, summarize_capture
from armbench.reports.format import (
    OUTCOME_MARKS,
    format_duration,
    format_number,
    format_value,
    jinja_environment,
    margin,
)

__all__ = [
    "EEPROM_ENDURANCE_CYCLES",
    "EEPROM_EVENTS_PER_DAY",
    "KNOWN_SUITES",
    "REPORT_FILE",
    "build_report_html",
    "render_report",
    "suite_verdict",
]

#: Suites with a section of their own; any other suite gets a generic one.
KNOWN_SUITES = ("accuracy", "repeatability", "startup")
#: Rated write/erase cycles of an EEPROM cell of the joint boards' ATmega328P (datasheet:
#: 100 000); a startup suite parameter ``eeprom_endurance_cycles`` overrides it.
EEPROM_ENDURANCE_CYCLES = 100_000
#: Power-ups and resets per day assumed for the projected EEPROM life (suite parameter
#: ``eeprom_events_per_day`` overrides it).
EEPROM_EVENTS_PER_DAY = 10.0

FloatArray = npt.NDArray[np.float64]
_MODE_TITLES = {"paper": "paper-style (joint-interpolated corners)",
                "coordinated": "coordinated (Cartesian interpolation)",
                "other": "other modes"}
_SAFE_POSE = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,11}")


# --------------------------------------------------------------------------------------------
# Reading loosely typed sample data (samples are any JSON objects)
# --------------------------------------------------------------------------------------------


def _num(value: object) -> float | None:
    """A finite number (not a boolean), else None."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def _vec3(value: object) -> tuple[float, float, float] | None:
    """An ``[x, y, z]`` of finite numbers, else None."""
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        return None
    x, y, z = (_num(v) for v in value)
    if x is None or y is None or z is None:
        return None
    return (x, y, z)


def _text(value: object, limit: int = 200) -> str:
    """Any JSON value as short text for a table cell (escaped by the template)."""
    if isinstance(value, str):
        text = value
    else:
        try:
            text = json.dumps(value, ensure_ascii=False, allow_nan=False, sort_keys=False)
        except (TypeError, ValueError):
            text = repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _params_text(params: Mapping[str, Any]) -> str:
    return ", ".join(f"{k}={_text(v, 60)}" for k, v in params.items()) or "-"


# --------------------------------------------------------------------------------------------
# View objects handed to the templates (strings are escaped there)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class FigureView:
    """An inline SVG plot (trusted markup from :mod:`armbench.reports.plots`) and its caption."""

    svg: Markup
    caption: str


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
    trial_metrics: list[TrialMetricRow] = field(default_factory=list)
    trial_rows: list[MeasurementRow] = field(default_factory=list)
    trials: list[TrialView] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class FaultRow:
    """An injected fault: its kind and its other non-null fields."""

    kind: str
    details: str


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


@dataclass(frozen=True, slots=True)
class RepCell:
    """AP and RP of one pose at one speed."""

    ap: str
    ap_outcome: str
    rp: str
    rp_outcome: str
    n: int
    computed: bool


@dataclass(frozen=True, slots=True)
class RepRow:
    pose: str
    commanded: str
    cells: list[RepCell]


@dataclass(frozen=True, slots=True)
class SpeedRow:
    speed: str
    cycles: int
    cycle_time: str
    worst_ap: str
    worst_rp: str


@dataclass(frozen=True, slots=True)
class RepeatabilityView:
    suite: SuiteView
    figures: list[FigureView]
    speeds: list[str]
    rows: list[RepRow]
    speed_rows: list[SpeedRow]
    cube: str
    notes: list[str]


@dataclass(frozen=True, slots=True)
class StartupRow:
    index: int
    fault: str
    phase: str
    joint: str
    status: str
    outcome: str
    recovered: bool
    recovery: str
    position_error: str
    eeprom: str
    failed: str
    error: str | None


@dataclass(frozen=True, slots=True)
class FailureView:
    index: int
    conditions: str
    failed: list[str]
    error: str | None
    events: list[str]


@dataclass(frozen=True, slots=True)
class StartupView:
    suite: SuiteView
    figures: list[FigureView]
    rows: list[StartupRow]
    summary: list[tuple[str, str]]
    failures: list[FailureView]
    eeprom: list[tuple[str, str]]


@dataclass(frozen=True, slots=True)
class TrafficView:
    figures: list[FigureView]
    href: str
    name: str
    size: str
    stats: list[tuple[str, str]]
    reasons: list[tuple[str, int]]
    head: list[CaptureLine]
    first_errors: list[CaptureLine]
    notes: list[str]


class _Figures:
    """Numbers the plots of one page so their SVG ids never clash."""

    def __init__(self) -> None:
        self.count = 0

    def make(self, fig: Figure, title: str, caption: str) -> FigureView:
        self.count += 1
        return FigureView(plots.to_svg(fig, f"f{self.count}", title), caption)


# --------------------------------------------------------------------------------------------
# Verdicts and the baseline
# --------------------------------------------------------------------------------------------


def suite_verdict(record: RunRecord, name: str) -> str:
    """A suite's own verdict, with the run's precedence: ``error``, ``incomplete`` (also a
    planned suite that never started), ``fail``, ``regression`` (one of its metrics regressed),
    ``pass``."""
    suite = record.suites.get(name)
    if suite is None:
        return "incomplete"
    if suite.status == "error" or any(t.status == "error" for t in suite.trials):
        return "error"
    if suite.status == "running":
        return "incomplete"
    if any(m.outcome == "fail" for m in _all_measurements(suite)):
        return "fail"
    if record.baseline is not None:
        names = {m.name for m in suite.measurements}
        if any(r.regressed and r.name in names for r in record.baseline.rows):
            return "regression"
    return "pass"


def _all_measurements(suite: SuiteRecord) -> Iterable[Measurement]:
    for t in suite.trials:
        yield from t.measurements
    yield from suite.measurements


def _verdict_reasons(record: RunRecord) -> list[str]:
    reasons: list[str] = []
    errored = 0
    for s in record.suites.values():
        if s.status == "error":
            reasons.append(f"suite {s.name} stopped on an error: {s.error or 'no reason given'}")
        elif s.status == "running":
            reasons.append(f"suite {s.name} did not finish (interrupted or still running)")
        for t in s.trials:
            if t.status == "error":
                errored += 1
                if errored <= 5:
                    reasons.append(f"{s.name} trial {t.index} could not be measured: {t.error}")
    if errored > 5:
        reasons.append(f"… and {errored - 5} more errored trials")
    for name in record.planned_suites:
        if name not in record.suites:
            reasons.append(f"planned suite {name} never started")
    failed = list(dict.fromkeys(m.name for _, _, m in record.iter_measurements()
                                if m.outcome == "fail"))
    if failed:
        shown = ", ".join(failed[:6]) + (f" and {len(failed) - 6} more" if len(failed) > 6 else "")
        reasons.append(f"{len(failed)} metric(s) outside their limits: {shown}")
    if record.baseline is not None:
        regressed = [r.name for r in record.baseline.regressions]
        if regressed:
            shown = ", ".join(regressed[:6])
            reasons.append(f"{len(regressed)} metric(s) regressed against baseline "
                           f"{record.baseline.baseline_run_id}: {shown}")
    if not reasons:
        reasons.append("every measurement within its limits" +
                       ("" if record.baseline is None else
                        f", no regression against baseline {record.baseline.baseline_run_id}"))
    return reasons


# --------------------------------------------------------------------------------------------
# Suites and measurements
# --------------------------------------------------------------------------------------------


def _measurement_row(m: Measurement, trial: Trial | None,
                     cmp: ComparisonRow | None) -> MeasurementRow:
    row = MeasurementRow(
        name=m.name, description=m.description,
        trial="" if trial is None else f"trial {trial.index}",
        value=format_number(m.value), unit=m.unit,
        limit="-" if m.limit is None else m.limit.describe(),
        margin=format_number(margin(m), signed=True), outcome=m.outcome,
    )
    if cmp is None:
        return row
    return _with_comparison(row, cmp)


def _with_comparison(row: MeasurementRow, cmp: ComparisonRow) -> MeasurementRow:
    unit = cmp.unit
    return MeasurementRow(
        name=row.name, description=row.description, trial=row.trial, value=row.value,
        unit=row.unit, limit=row.limit, margin=row.margin, outcome=row.outcome,
        baseline=format_value(cmp.baseline, unit),
        change=format_value(cmp.change_abs, unit, signed=True),
        change_pct=("-" if cmp.change_pct is None
                    else f"{format_number(cmp.change_pct, signed=True)} %"),
        tolerance=format_value(cmp.tolerance, unit),
        result=cmp.result,
    )


def _missing_row(cmp: ComparisonRow) -> MeasurementRow:
    row = MeasurementRow(name=cmp.name, description="in the baseline, not in this run",
                         trial="", value="-", unit=cmp.unit, limit="-", margin="-",
                         outcome="unjudged")
    return _with_comparison(row, cmp)


def _trial_metrics(suite: SuiteRecord) -> list[TrialMetricRow]:
    groups: dict[str, list[tuple[Trial, Measurement]]] = {}
    for t in suite.trials:
        for m in t.measurements:
            groups.setdefault(m.name, []).append((t, m))
    rows = []
    for name, items in groups.items():
        values = [m.value for _, m in items]
        margins = [g for g in (margin(m) for _, m in items) if g is not None]
        failed = [t.index for t, m in items if m.outcome == "fail"]
        limits = [m.limit.describe() for _, m in items if m.limit is not None]
        outcomes = {m.outcome for _, m in items}
        outcome = ("fail" if "fail" in outcomes else
                   "pass" if outcomes == {"pass"} else "unjudged")
        shown = ", ".join(f"#{i}" for i in failed[:12]) + (" …" if len(failed) > 12 else "")
        rows.append(TrialMetricRow(
            name=name, unit=items[0][1].unit, limit=limits[0] if limits else "-",
            n=len(items), minimum=format_number(min(values)),
            mean=format_number(statistics.fmean(values)), maximum=format_number(max(values)),
            worst_margin=format_number(min(margins), signed=True) if margins else "-",
            failed=len(failed), failed_trials=shown, outcome=outcome,
        ))
    return rows


def _suite_view(record: RunRecord, suite: SuiteRecord, key: str,
                cmp_rows: Mapping[str, ComparisonRow]) -> SuiteView:
    ends = [t.ended_s for t in suite.trials]
    if suite.ended_s is not None:
        duration = format_duration(suite.ended_s - suite.started_s)
    elif ends:
        duration = format_duration(max(ends) - suite.started_s) + " so far"
    else:
        duration = "-"
    failed = sum(m.outcome == "fail" for m in _all_measurements(suite))
    names = {m.name for m in suite.measurements}
    regressed = sum(1 for r in cmp_rows.values() if r.regressed and r.name in names)
    view = SuiteView(
        key=key, name=suite.name, status=suite.status, verdict=suite_verdict(record, suite.name),
        version=suite.version, started=format_duration(suite.started_s), duration=duration,
        robot_time=format_duration(sum(t.duration_s for t in suite.trials)),
        trials_done=sum(t.status == "done" for t in suite.trials),
        trials_error=sum(t.status == "error" for t in suite.trials),
        superseded=len(suite.superseded_trials),
        measured=sum(1 for _ in _all_measurements(suite)), failed=failed, regressed=regressed,
        error=suite.error, params=_params_text(suite.params),
    )
    view.rows = [_measurement_row(m, None, cmp_rows.get(m.name)) for m in suite.measurements]
    view.trial_metrics = _trial_metrics(suite)
    view.trial_rows = [_measurement_row(m, t, None) for t in suite.trials for m in t.measurements]
    for t in suite.trials:
        counts = {o: sum(m.outcome == o for m in t.measurements) for o in OUTCOME_MARKS}
        summary = ", ".join(f"{n} {OUTCOME_MARKS[o][1]}" for o, n in counts.items() if n) or "-"
        view.trials.append(TrialView(
            index=t.index, status=t.status, params=_params_text(t.params),
            started=format_duration(t.started_s), duration=format_duration(t.duration_s),
            samples=len(t.samples), measurements=summary, error=t.error))
    return view


def _not_started_view(record: RunRecord, name: str, key: str) -> SuiteView:
    return SuiteView(key=key, name=name, status="not started", verdict="incomplete",
                     version="-", started="-", duration="-", robot_time="-", trials_done=0,
                     trials_error=0, superseded=0, measured=0, failed=0, regressed=0,
                     error=None, params="-")


# --------------------------------------------------------------------------------------------
# Environment
# --------------------------------------------------------------------------------------------


def _environment(record: RunRecord) -> list[tuple[str, str]]:
    env = record.environment
    limits = "-" if env.config_path is None else env.config_path
    if env.limits_spec_version:
        limits += f" ({env.limits_spec_version})"
    return [
        ("run id", record.run_id),
        ("created (UTC)", record.created),
        ("resumed", ", ".join(record.resumed) or "never"),
        ("armbench version", env.armbench_version),
        ("git revision", env.git_revision),
        ("port", env.port or "-"),
        ("seed", "-" if env.seed is None else str(env.seed)),
        ("limits file", limits),
        ("Python", env.python),
        ("platform", env.platform),
    ]


def _settings_summary(settings: Mapping[str, Any]) -> list[tuple[str, str]]:
    out: list[tuple[str, str]] = []
    for key, value in settings.items():
        if key == "geometry" and isinstance(value, Mapping):
            parts = []
            for k, v in value.items():
                n = _num(v)
                if n is not None and k.endswith("_m"):
                    parts.append(f"{k[:-2]} {n * 1000:g} mm")
                else:
                    parts.append(f"{k} {_text(v, 30)}")
            out.append(("geometry", ", ".join(parts)))
        elif key == "serial" and isinstance(value, Mapping):
            baud, bits = value.get("baudrate"), value.get("bytesize")
            parity, stop = value.get("parity"), value.get("stopbits")
            out.append(("serial", f"{_text(baud)} baud, {_text(bits)}{_text(parity)}"
                                  f"{_text(stop)}"))
        elif key == "joints" and isinstance(value, Mapping):
            for jname, j in value.items():
                if not isinstance(j, Mapping):
                    out.append((f"joint {jname}", _text(j)))
                    continue
                lo, hi = _num(j.get("lower_deg")), _num(j.get("upper_deg"))
                gear, micro = _num(j.get("gear_ratio")), _num(j.get("microsteps"))
                addr = j.get("i2c_address")
                bits = []
                if lo is not None and hi is not None:
                    bits.append(f"{lo:.4g}° … {hi:.4g}°")
                if gear is not None:
                    bits.append(f"gear {gear:g}:1")
                if micro is not None:
                    bits.append(f"{micro:g} microsteps")
                if isinstance(addr, int) and not isinstance(addr, bool):
                    bits.append(f"I²C 0x{addr:02x}")
                else:
                    bits.append("I²C master")
                out.append((f"joint {jname}", ", ".join(bits)))
        else:
            out.append((str(key), _text(value, 120)))
    return out


def _faults(record: RunRecord) -> list[FaultRow]:
    rows = []
    for f in record.environment.faults:
        details = ", ".join(f"{k}={_text(v, 80)}" for k, v in f.items()
                            if k != "kind" and v is not None)
        rows.append(FaultRow(kind=_text(f.get("kind", "?"), 80), details=details or "-"))
    return rows


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
        ts, r = _num(s.get("t_s")), _vec3(s.get("reported_m"))
        if ts is None or r is None:
            continue
        t.append(ts)
        rep.append(r)
        tru.append(_vec3(s.get("true_m")) or nan3)
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
    centre, side = _vec3(params.get("centre_m")), _num(params.get("side_m"))
    if centre is None or side is None or side <= 0:
        return None
    return square_yz(centre, side)


def _accuracy(record: RunRecord, suite: SuiteRecord, view: SuiteView,
              figs: _Figures) -> AccuracyView:
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
            plots.AttainedPath(f"trial {r.trial.index}", r.reported * 1000.0,
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
        speed = _num(r.trial.params.get("speed_pct"))
        err = r.errors
        rows.append(AccuracyRunRow(
            index=r.trial.index, mode=_text(r.trial.params.get("mode", "-"), 40),
            run=_text(r.trial.params.get("run", "-"), 20),
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


# --------------------------------------------------------------------------------------------
# Repeatability
# --------------------------------------------------------------------------------------------


def _pose_key(name: str) -> tuple[int, str]:
    digits = re.sub(r"\D", "", name)
    return (int(digits) if digits and len(digits) < 6 else 10**6, name)


def _speed_token(speed: float | None) -> str:
    if speed is None:
        return "?"
    return str(int(speed)) if float(speed).is_integer() else format_number(speed)


def _repeatability(suite: SuiteRecord, view: SuiteView, figs: _Figures) -> RepeatabilityView:
    points: dict[tuple[float | None, str], list[tuple[float, float, float]]] = {}
    commanded: dict[str, tuple[float, float, float]] = {}
    cycles: dict[float | None, int] = {}
    cycle_times: dict[float | None, list[float]] = {}
    for trial in suite.trials:
        speed = _num(trial.params.get("speed_pct"))
        used = False
        for s in trial.samples:
            pose, r = s.get("pose"), _vec3(s.get("reported_m"))
            if not isinstance(pose, str) or r is None:
                continue
            points.setdefault((speed, pose), []).append(r)
            c = _vec3(s.get("commanded_m"))
            if c is not None:
                commanded.setdefault(pose, c)
            used = True
        if used:
            cycles[speed] = cycles.get(speed, 0) + 1
            ct = next((m.value for m in trial.measurements if m.name.endswith("cycle_time_s")),
                      trial.duration_s)
            cycle_times.setdefault(speed, []).append(ct)
    speeds = sorted({sp for sp, _ in points}, key=lambda v: (v is None, v or 0.0))
    poses = sorted({p for _, p in points}, key=_pose_key)
    recorded = {m.name: m for m in suite.measurements}
    notes: list[str] = []

    centre = _vec3(suite.params.get("cube_centre_m"))
    side = _num(suite.params.get("cube_side_m"))
    corners = None
    cube = "-"
    if centre is not None and side is not None and side > 0:
        corners = cube_corners(centre, side)
        cube = (f"centre ({', '.join(f'{v * 1000:g}' for v in centre)}) mm, "
                f"side {side * 1000:g} mm")
        if not commanded and len(poses) <= 5:
            for i, p in enumerate(iso_cube_poses(centre, side)):
                commanded[f"P{i + 1}"] = (float(p[0]), float(p[1]), float(p[2]))

    def plot_label(i: int, name: str) -> str:
        return name if _SAFE_POSE.fullmatch(name) else f"pose {i + 1}"

    rows: list[RepRow] = []
    scatter: list[plots.PoseScatter] = []
    worst: dict[float | None, tuple[float, float]] = {}
    computed_any = False
    for i, pose in enumerate(poses):
        cells = []
        groups = []
        for speed in speeds:
            pts = np.array(points.get((speed, pose), []), dtype=np.float64).reshape(-1, 3)
            base = f"repeatability.v{_speed_token(speed)}.{pose.lower()}"
            ap_m, rp_m = recorded.get(f"{base}.ap_mm"), recorded.get(f"{base}.rp_mm")
            ap = None if ap_m is None else ap_m.value
            rp = None if rp_m is None else rp_m.value
            computed = False
            if ap is None and len(pts) >= 1 and pose in commanded:
                ap, computed = pose_accuracy(pts, commanded[pose]).ap_p_mm, True
            if rp is None and len(pts) >= 2:
                rp, computed = pose_repeatability(pts).rp_mm, True
            computed_any |= computed
            cells.append(RepCell(
                ap=format_number(ap), ap_outcome="unjudged" if ap_m is None else ap_m.outcome,
                rp=format_number(rp), rp_outcome="unjudged" if rp_m is None else rp_m.outcome,
                n=len(pts), computed=computed))
            w_ap, w_rp = worst.get(speed, (-math.inf, -math.inf))
            worst[speed] = (max(w_ap, ap if ap is not None else -math.inf),
                            max(w_rp, rp if rp is not None else -math.inf))
            if len(pts):
                dev = (pts - pts.mean(axis=0))[:, 1:] * 1000.0
                groups.append(plots.ScatterGroup(f"{format_number(speed)} %", dev, rp))
        c = commanded.get(pose)
        rows.append(RepRow(pose=pose, cells=cells, commanded="-" if c is None else
                           "(" + ", ".join(f"{v * 1000:.1f}" for v in c) + ") mm"))
        scatter.append(plots.PoseScatter(plot_label(i, pose), groups))
    if computed_any:
        notes.append("† computed by the report from the samples (no recorded, judged "
                     "measurement of that name, e.g. an interrupted suite).")

    figures: list[FigureView] = []
    if poses:
        pose_pts = [(plot_label(i, p), np.array(commanded[p]) * 1000.0)
                    for i, p in enumerate(poses) if p in commanded]
        bary = []
        for p in poses:
            every = [x for sp in speeds for x in points.get((sp, p), [])]
            if every:
                bary.append(np.array(every, dtype=np.float64).mean(axis=0) * 1000.0)
        figures.append(figs.make(
            plots.cube_projections(None if corners is None else corners * 1000.0, pose_pts,
                                   bary),
            "ISO 9283 test cube and poses",
            "The ISO 9283 test cube and the five commanded poses in three projections, with the "
            "barycentre of every attained position of each pose (all speeds)."))
        figures.append(figs.make(
            plots.pose_scatter(scatter),
            "Attained positions around their barycentre",
            "Attained positions of each pose around their barycentre, projected on the YZ plane, "
            "one marker shape per speed; each circle is the outline of that speed's RP sphere "
            "(ISO 9283: mean distance to the barycentre + 3 standard deviations)."))
    speed_rows = []
    for speed in speeds:
        w_ap, w_rp = worst.get(speed, (-math.inf, -math.inf))
        times = cycle_times.get(speed, [])
        speed_rows.append(SpeedRow(
            speed=f"{format_number(speed)} %", cycles=cycles.get(speed, 0),
            cycle_time=format_duration(statistics.fmean(times)) if times else "-",
            worst_ap=format_number(w_ap if math.isfinite(w_ap) else None),
            worst_rp=format_number(w_rp if math.isfinite(w_rp) else None)))
    return RepeatabilityView(suite=view, figures=figures,
                             speeds=[f"{format_number(s)} %" for s in speeds], rows=rows,
                             speed_rows=speed_rows, cube=cube, notes=notes)


# --------------------------------------------------------------------------------------------
# Start-up recovery
# --------------------------------------------------------------------------------------------


def _measure(trial: Trial, name: str) -> Measurement | None:
    return next((m for m in trial.measurements if m.name == name), None)


def _events(trial: Trial) -> list[Mapping[str, Any]]:
    return [s for s in trial.samples if isinstance(s.get("event"), str)]


def _event_text(sample: Mapping[str, Any]) -> str:
    t = _num(sample.get("t_s"))
    extra = ", ".join(f"{k}={_text(v, 60)}" for k, v in sample.items()
                      if k not in ("t_s", "event") and v is not None)
    when = "?" if t is None else f"{t:.3f} s"
    return f"{when}  {_text(sample.get('event'), 40)}" + (f" ({extra})" if extra else "")


def _startup(suite: SuiteRecord, view: SuiteView, figs: _Figures) -> StartupView:
    rows: list[StartupRow] = []
    points: list[plots.StartupPoint] = []
    failures: list[FailureView] = []
    writes: list[float] = []
    time_limit = error_limit = None
    for trial in suite.trials:
        events = _events(trial)
        outcome_ev = next((e for e in reversed(events) if e.get("event") == "outcome"), None)
        rec_m = _measure(trial, "startup.recovered")
        time_m = _measure(trial, "startup.recovery_time_s")
        err_m = _measure(trial, "startup.position_error_mm")
        eep_m = _measure(trial, "startup.eeprom_writes")
        if time_m is not None and time_m.limit is not None and time_m.limit.high is not None:
            time_limit = time_m.limit.high
        if err_m is not None and err_m.limit is not None and err_m.limit.high is not None:
            error_limit = err_m.limit.high
        if trial.status == "error":
            outcome = "error"
        elif outcome_ev is not None and isinstance(outcome_ev.get("outcome"), str):
            outcome = str(outcome_ev["outcome"])
        elif rec_m is not None:
            outcome = "recovered" if rec_m.value >= 1 else "not recovered"
        else:
            outcome = "-"
        recovered = (trial.status == "done" and
                     (rec_m.value >= 1 if rec_m is not None else outcome == "recovered"))
        recovery = None if time_m is None else time_m.value
        if recovery is None:
            starts = [_num(e.get("t_s")) for e in events
                      if e.get("event") in ("power_restore", "fault")]
            ready = [_num(e.get("t_s")) for e in events if e.get("event") in ("ready", "timeout")]
            if starts and ready and starts[-1] is not None and ready[0] is not None:
                recovery = ready[0] - starts[-1]
        pos_err = None if err_m is None else err_m.value
        if pos_err is None:
            check = next((e for e in events if e.get("event") == "position_check"), None)
            if check is not None:
                c, r = _vec3(check.get("commanded_m")), _vec3(check.get("reported_m"))
                if c is not None and r is not None:
                    pos_err = float(np.linalg.norm(np.subtract(r, c))) * 1000.0
        eeprom = None if eep_m is None else eep_m.value
        if eeprom is None and outcome_ev is not None:
            eeprom = _num(outcome_ev.get("eeprom_writes"))
        if eeprom is not None and trial.status == "done":
            writes.append(eeprom)
        failed = [m for m in trial.measurements if m.outcome == "fail"]
        joint = trial.params.get("joint")
        rows.append(StartupRow(
            index=trial.index, fault=_text(trial.params.get("fault", "-"), 60),
            phase=_text(trial.params.get("phase", "-"), 40),
            joint="-" if joint is None else _text(joint, 20), status=trial.status,
            outcome=outcome, recovered=recovered,
            recovery=format_value(recovery, "s"), position_error=format_value(pos_err, "mm"),
            eeprom=format_number(eeprom), failed=", ".join(m.name for m in failed) or "-",
            error=trial.error))
        if trial.status == "done":
            points.append(plots.StartupPoint(f"#{trial.index}", recovery, pos_err, recovered))
        if failed or trial.status == "error":
            fault_at = next((_num(e.get("t_s")) for e in events if e.get("event") == "fault"),
                            None)
            conditions = (f"fault {_text(trial.params.get('fault', '?'), 60)} while "
                          f"{_text(trial.params.get('phase', '?'), 40)}"
                          + ("" if joint is None else f", joint {_text(joint, 20)}")
                          + ("" if fault_at is None else f", at {fault_at:.3f} s into the trial"))
            failures.append(FailureView(
                index=trial.index, conditions=conditions,
                failed=[f"{m.name} = {format_value(m.value, m.unit)} (limit "
                        f"{'-' if m.limit is None else m.limit.describe()})" for m in failed],
                error=trial.error, events=[_event_text(e) for e in events[:30]]))

    done = [r for r in rows if r.status == "done"]
    ok = sum(r.recovered for r in done)
    times = [p.recovery_s for p in points if p.recovery_s is not None and p.recovered]
    errs = [p.error_mm for p in points if p.error_mm is not None]
    summary = [
        ("trials", f"{len(rows)} ({len(done)} measured, {len(rows) - len(done)} errored)"),
        ("recovered", f"{ok} of {len(done)}" +
         (f" ({100.0 * ok / len(done):.4g} %)" if done else "")),
        ("recovery time (recovered trials)",
         "-" if not times else f"median {format_value(statistics.median(times), 's')}, "
                               f"max {format_value(max(times), 's')}"),
        ("position error after recovery",
         "-" if not errs else f"median {format_value(statistics.median(errs), 'mm')}, "
                              f"max {format_value(max(errs), 'mm')}"),
    ]
    endurance = _num(suite.params.get("eeprom_endurance_cycles")) or EEPROM_ENDURANCE_CYCLES
    per_day = _num(suite.params.get("eeprom_events_per_day")) or EEPROM_EVENTS_PER_DAY
    wear: list[tuple[str, str]] = []
    if writes:
        worst = max(writes)
        wear = [
            ("EEPROM writes", f"{format_number(sum(writes))} in {len(writes)} recoveries "
                              f"(mean {format_number(statistics.fmean(writes))}, "
                              f"max {format_number(worst)} per event)"),
            ("rated endurance", f"{endurance:,.0f} write/erase cycles per cell"),
        ]
        if worst > 0:
            events_left = endurance / worst
            years = events_left / per_day / 365.25
            wear.append(("projected life", f"{events_left:,.0f} power-ups/resets "
                           f"(≈ {years:,.0f} years at {per_day:g} a day), worst case: every "
                           "write of the worst trial hits the same cell"))
        else:
            wear.append(("projected life", "no EEPROM writes measured: no wear"))
    figures = []
    if points:
        figures.append(figs.make(
            plots.startup_plots(points, time_limit, error_limit),
            "Start-up recovery",
            "Left: share of the trials whose arm was ready within a given time after the fault "
            "cleared (crosses: trials that did not recover, at their time-out). Right: distance "
            "of the reported position from home after recovery, per trial (hatched: failed)."))
    return StartupView(suite=view, figures=figures, rows=rows, summary=summary,
                       failures=failures, eeprom=wear)


# --------------------------------------------------------------------------------------------
# Traffic
# --------------------------------------------------------------------------------------------


def _size(n: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n} B"


def _traffic(capture: Path, out_dir: Path, figs: _Figures) -> TrafficView | None:
    try:
        c = summarize_capture(capture)
    except OSError:
        return None
    rel = os.path.relpath(capture.resolve(), out_dir.resolve())
    href = quote(Path(rel).as_posix(), safe="/")
    frames = c.frames_in + c.frames_out
    errors = c.errors_in + c.errors_out
    rate = frames / c.duration_s if c.duration_s > 0 else None
    stats = [
        ("records", f"{c.records:,}" + (f" analysed, {c.skipped_records:,} more not read"
                                        if c.skipped_records else "")),
        ("duration", format_duration(c.duration_s)),
        ("frames", f"{c.frames_out:,} out (host → arm), {c.frames_in:,} in (arm → host)"),
        ("mean frame rate", "-" if rate is None else f"{rate:,.1f} frames/s"),
        ("framing errors", f"{errors:,} ({c.errors_out:,} out, {c.errors_in:,} in)"),
        ("resyncs", f"{c.resyncs:,} (a valid frame after an error)"),
    ]
    notes = []
    if c.bad_lines:
        notes.append(f"{c.bad_lines:,} line(s) of the file are not capture records and were "
                     "skipped.")
    figures = []
    if c.records:
        figures.append(figs.make(
            plots.traffic_plot(c.bin_start_s, c.rate_in, c.rate_out, c.errors_per_bin,
                               c.resyncs_per_bin, c.bin_s),
            "Traffic over time",
            "Frames per second in each direction over the capture; below, framing errors and "
            "resynchronisations per bin."))
    return TrafficView(figures=figures, href=href, name=capture.name, size=_size(c.size_bytes),
                       stats=stats, reasons=c.reasons, head=c.head,
                       first_errors=c.first_errors, notes=notes)


# --------------------------------------------------------------------------------------------
# The page
# --------------------------------------------------------------------------------------------


def build_report_html(record: RunRecord, *, capture: Path | None = None,
                      out_dir: Path | None = None, source: str = RESULTS_FILE) -> str:
    """The report page of ``record`` as HTML text. ``capture`` is a traffic capture to summarise
    (linked relative to ``out_dir``, where the page will be written)."""
    figs = _Figures()
    cmp_rows = {} if record.baseline is None else {r.name: r for r in record.baseline.rows}
    views: dict[str, SuiteView] = {}
    order = list(dict.fromkeys([*record.planned_suites, *record.suites]))
    for i, name in enumerate(order):
        key = f"suite-{i + 1}"
        suite = record.suites.get(name)
        views[name] = (_not_started_view(record, name, key) if suite is None
                       else _suite_view(record, suite, key, cmp_rows))
    orphans: list[MeasurementRow] = []
    if record.baseline is not None:
        for r in record.baseline.rows:
            if r.status != "missing":
                continue
            owner = views.get(r.name.split(".", 1)[0])
            if owner is not None:
                owner.rows.append(_missing_row(r))
            else:
                orphans.append(_missing_row(r))

    accuracy = repeatability = startup = None
    if "accuracy" in record.suites:
        accuracy = _accuracy(record, record.suites["accuracy"], views["accuracy"], figs)
    if "repeatability" in record.suites:
        repeatability = _repeatability(record.suites["repeatability"], views["repeatability"],
                                       figs)
    if "startup" in record.suites:
        startup = _startup(record.suites["startup"], views["startup"], figs)
    traffic = None
    if capture is not None and capture.is_file():
        traffic = _traffic(capture, out_dir or capture.parent, figs)
    others = [v for name, v in views.items()
              if name not in KNOWN_SUITES and name in record.suites]
    robot_s = sum(t.duration_s for s in record.suites.values() for t in s.trials)
    baseline = record.baseline
    template = jinja_environment().get_template("report.html.j2")
    return template.render(
        record=record,
        verdict=record.verdict,
        reasons=_verdict_reasons(record),
        environment=_environment(record),
        settings=_settings_summary(record.environment.settings),
        settings_json=json.dumps(dict(record.environment.settings), indent=1,
                                 ensure_ascii=False),
        faults=_faults(record),
        suites=list(views.values()),
        run_time=format_duration(record.end_s),
        robot_time=format_duration(robot_s),
        baseline=baseline,
        baseline_counts=None if baseline is None else {
            "compared": sum(r.status == "compared" for r in baseline.rows),
            "regressed": len(baseline.regressions),
            "new": sum(r.status == "new" for r in baseline.rows),
            "missing": sum(r.status == "missing" for r in baseline.rows)},
        orphans=orphans,
        accuracy=accuracy,
        repeatability=repeatability,
        startup=startup,
        traffic=traffic,
        others=others,
        source=source,
    )


def render_report(record: RunRecord | str | os.PathLike[str], out_path: str | os.PathLike[str],
                  *, capture: str | os.PathLike[str] | None = None) -> Path:
    """Render the report of ``record`` (a :class:`RunRecord`, a ``results.json`` path or a run
    directory) to ``out_path`` (written atomically); returns the path written.

    The traffic section reads ``capture`` when given, else ``capture.jsonl`` beside the record
    file if there is one. Raises ``RecordError`` for an unreadable or invalid record.
    """
    out = Path(out_path)
    capture_path = None if capture is None else Path(capture)
    source = "RunRecord"
    if isinstance(record, RunRecord):
        rec = record
    else:
        path = Path(record)
        if path.is_dir():
            path = path / RESULTS_FILE
        rec = load_record(path)
        source = path.name
        if capture_path is None and (path.parent / CAPTURE_FILE).is_file():
            capture_path = path.parent / CAPTURE_FILE
    html = build_report_html(rec, capture=capture_path, out_dir=out.parent, source=source)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, html.encode("utf-8"))
    return out

