"""The startup-recovery section: the outcomes of the power cuts by condition (paper §5.2), the
recovery times and position errors, the failures with their conditions, and the EEPROM wear.

Names come from the suite's contract
(:data:`armbench.bench.suites.startup_contract.STARTUP`); every figure
shown is one the record holds (a trial's measurements, its ``outcome`` event, the suite's
measurements).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from armbench.bench.suites.startup_contract import STARTUP
from armbench.record import Measurement, RunRecord, SuiteRecord, Trial
from armbench.record.suite_contract import SAMPLE
from armbench.reports.render import plots
from armbench.reports.render.format import format_value
from armbench.reports.render.views import Figures, FigureView, SectionView, SuiteView, num, text

__all__ = ["SUITE", "FailureView", "StartupRow", "StartupView", "build"]

SUITE = STARTUP.suite
S = STARTUP
#: A condition name drawn in a plot as it is (``cw-away-near``); record text of any other shape
#: never reaches a plot.
_SAFE_CONDITION = re.compile(r"[a-z]{1,8}(-[a-z]{1,8}){0,3}")


@dataclass(frozen=True, slots=True)
class StartupRow:
    index: int
    condition: str
    joints: str
    status: str
    outcome: str
    recovered: bool
    recovery: str
    first_reply: str
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
    rows: list[StartupRow]
    summary: list[tuple[str, str]]
    failures: list[FailureView]
    eeprom: list[tuple[str, str]]


def _measure(trial: Trial, name: str) -> Measurement | None:
    return next((m for m in trial.measurements if m.name == name), None)


def _events(trial: Trial) -> list[Mapping[str, Any]]:
    return [s for s in trial.samples if isinstance(s.get(SAMPLE.event), str)]


def _event_text(sample: Mapping[str, Any]) -> str:
    t = num(sample.get(SAMPLE.t))
    extra = ", ".join(f"{k}={text(v, 60)}" for k, v in sample.items()
                      if k not in (SAMPLE.t, SAMPLE.event) and v is not None)
    when = "?" if t is None else f"{t:.3f} s"
    return f"{when}  {text(sample.get(SAMPLE.event), 40)}" + (f" ({extra})" if extra else "")


def _value(m: Measurement | None) -> str:
    return "-" if m is None else format_value(m.value, m.unit)


def _outcome(trial: Trial) -> tuple[str, bool]:
    """The trial's outcome in words and whether the arm recovered, from its ``outcome`` event
    (or its ``recovered`` measurement)."""
    if trial.status == "error":
        return "error", False
    event = next((e for e in reversed(_events(trial)) if e.get(SAMPLE.event) == S.ev_outcome),
                 None)
    if event is not None:
        if event.get(S.f_recovered) is True:
            return "recovered", True
        failure = event.get(S.f_failure)
        return (f"not recovered ({text(failure, 30)})" if failure else "not recovered"), False
    rec = _measure(trial, S.recovered)
    if rec is not None:
        return ("recovered", True) if rec.value >= 1 else ("not recovered", False)
    skipped = next((e for e in _events(trial) if e.get(SAMPLE.event) == S.ev_skipped), None)
    return ("skipped" if skipped is not None else "no outcome"), False


def _cut_trials(suite: SuiteRecord) -> list[Trial]:
    return [t for t in suite.trials if t.params.get(S.kind, S.cut_kind) == S.cut_kind]


def build(record: RunRecord, suite: SuiteRecord, view: SuiteView, figs: Figures) -> SectionView:
    """The startup-recovery section of ``record``."""
    rows: list[StartupRow] = []
    points: list[plots.StartupPoint] = []
    failures: list[FailureView] = []
    by_condition: dict[str, list[bool]] = {}
    error_unit = "mrad"
    time_limit = error_limit = None
    for trial in _cut_trials(suite):
        outcome, recovered = _outcome(trial)
        condition = text(trial.params.get(S.condition, "-"), 40)
        time_m = _measure(trial, S.recovery_time)
        err_m = _measure(trial, S.position_error_mrad) or _measure(trial, S.position_error_mm)
        if err_m is not None:
            error_unit = err_m.unit
            if err_m.limit is not None and err_m.limit.high is not None:
                error_limit = err_m.limit.high
        if time_m is not None and time_m.limit is not None and time_m.limit.high is not None:
            time_limit = time_m.limit.high
        failed = [m for m in trial.measurements if m.outcome == "fail"]
        rows.append(StartupRow(
            index=trial.index, condition=condition,
            joints=text(trial.params.get(S.joints, "-"), 20), status=trial.status,
            outcome=outcome, recovered=recovered, recovery=_value(time_m),
            first_reply=_value(_measure(trial, S.first_reply)), position_error=_value(err_m),
            eeprom=_value(_measure(trial, S.eeprom_writes)),
            failed=", ".join(m.name for m in failed) or "-", error=trial.error))
        if trial.status == "done" and outcome != "skipped":
            by_condition.setdefault(condition, []).append(recovered)
            points.append(plots.StartupPoint(
                f"#{trial.index}", None if time_m is None else time_m.value,
                None if err_m is None else err_m.value, recovered))
        if not recovered or failed:
            fault = next((e for e in _events(trial) if e.get(SAMPLE.event) == S.ev_fault), None)
            at = None if fault is None else num(fault.get(SAMPLE.t))
            failures.append(FailureView(
                index=trial.index,
                conditions=f"condition {condition}, joints {text(trial.params.get(S.joints))}"
                           + ("" if at is None else f", power cut at {at:.3f} s into the trial"),
                failed=[f"{m.name} = {format_value(m.value, m.unit)} (limit "
                        f"{'-' if m.limit is None else m.limit.describe()})" for m in failed],
                error=trial.error, events=[_event_text(e) for e in _events(trial)[:30]]))
    recorded = {m.name: m for m in suite.measurements}

    def kv(label: str, name: str) -> tuple[str, str] | None:
        m = recorded.get(name)
        return None if m is None else (label, format_value(m.value, m.unit))

    summary = [p for p in (
        kv("power cuts measured", S.trials_measured),
        kv("recovered", S.success_rate),
        kv("recovered where §5.2 can (not towards the Hall sensor)", S.expected_success_rate),
        kv("slowest recovery", S.recovery_time_max),
        kv("mean recovery time", S.recovery_time_mean),
        kv("largest joint error after a cut", S.position_error_max),
        kv("largest joint error after a recovery", S.recovered_position_error_max),
        kv("EEPROM record writes per cut", S.eeprom_writes_per_cut)) if p is not None]
    wear = [p for p in (
        kv("EEPROM writes per hour of typical use (busiest joint)", S.eeprom_writes_per_hour),
        kv("… of point-to-point motion", S.phase_writes("ptp")),
        kv("… of coordinated streaming", S.phase_writes("streaming")),
        kv("wear of the most-worn cell", S.eeprom_cell_wear_per_hour),
        kv("projected life (ATmega328P: 100,000 cycles a cell)", S.eeprom_life_years),
        kv("… in hours of use", S.eeprom_life_hours)) if p is not None]
    figures: list[FigureView] = []
    if by_condition:
        names = [c if _SAFE_CONDITION.fullmatch(c) else f"condition {k + 1}"
                 for k, c in enumerate(by_condition)]
        ok = [sum(v) for v in by_condition.values()]
        bad = [len(v) - sum(v) for v in by_condition.values()]
        figures.append(figs.make(
            plots.outcomes_by_condition, (names, ok, bad),
            "Start-up recovery: outcomes by condition",
            "Power cuts per condition (motion at the cut, relation to the Hall sensor, band of "
            "angles): recovered (solid) and not recovered (hatched). §5.2's procedure cannot "
            "recover a joint that moved towards its Hall sensor.",
            "; ".join(f"{n}: {o} recovered, {b} not" for n, o, b in zip(names, ok, bad,
                                                                         strict=True))))
    if points:
        figures.append(figs.make(
            plots.startup_plots, (points, time_limit, error_limit, error_unit),
            "Start-up recovery: times and position errors",
            "Left: share of the cuts whose arm was back within a given time after power-on "
            "(crosses: cuts that did not recover). Right: position error after each cut (hatched: "
            "not recovered).", _value(recorded.get(S.recovery_time_max)) + " slowest recovery"))
    return SectionView(
        key=SUITE, template="startup_recovery", title="Start-up recovery after power cuts",
        suite=view, figures=figures,
        body=StartupView(rows=rows, summary=summary, failures=failures, eeprom=wear))
