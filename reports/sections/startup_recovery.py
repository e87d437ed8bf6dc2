"""The start-up recovery section: outcomes of the power cuts and the EEPROM wear."""

from __future__ import annotations

import statistics
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from armbench.bench.record import (
    Measurement,
    SuiteRecord,
    Trial,
)
from armbench.reports import plots
from armbench.reports.format import (
    format_number,
    format_value,
)
from armbench.reports.views import (
    Figures,
    FigureView,
    SuiteView,
    num,
    text,
    vec3,
)

#: Rated write/erase cycles of an EEPROM cell of the joint boards' ATmega328P (datasheet:
#: 100 000); a startup suite parameter ``eeprom_endurance_cycles`` overrides it.
EEPROM_ENDURANCE_CYCLES = 100_000
#: Power-ups and resets per day assumed for the projected EEPROM life (suite parameter
#: ``eeprom_events_per_day`` overrides it).
EEPROM_EVENTS_PER_DAY = 10.0


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



# --------------------------------------------------------------------------------------------
# Start-up recovery
# --------------------------------------------------------------------------------------------


def _measure(trial: Trial, name: str) -> Measurement | None:
    return next((m for m in trial.measurements if m.name == name), None)


def _events(trial: Trial) -> list[Mapping[str, Any]]:
    return [s for s in trial.samples if isinstance(s.get("event"), str)]


def _event_text(sample: Mapping[str, Any]) -> str:
    t = num(sample.get("t_s"))
    extra = ", ".join(f"{k}={text(v, 60)}" for k, v in sample.items()
                      if k not in ("t_s", "event") and v is not None)
    when = "?" if t is None else f"{t:.3f} s"
    return f"{when}  {text(sample.get('event'), 40)}" + (f" ({extra})" if extra else "")


def startup_section(suite: SuiteRecord, view: SuiteView, figs: Figures) -> StartupView:
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
            starts = [num(e.get("t_s")) for e in events
                      if e.get("event") in ("power_restore", "fault")]
            ready = [num(e.get("t_s")) for e in events if e.get("event") in ("ready", "timeout")]
            if starts and ready and starts[-1] is not None and ready[0] is not None:
                recovery = ready[0] - starts[-1]
        pos_err = None if err_m is None else err_m.value
        if pos_err is None:
            check = next((e for e in events if e.get("event") == "position_check"), None)
            if check is not None:
                c, r = vec3(check.get("commanded_m")), vec3(check.get("reported_m"))
                if c is not None and r is not None:
                    pos_err = float(np.linalg.norm(np.subtract(r, c))) * 1000.0
        eeprom = None if eep_m is None else eep_m.value
        if eeprom is None and outcome_ev is not None:
            eeprom = num(outcome_ev.get("eeprom_writes"))
        if eeprom is not None and trial.status == "done":
            writes.append(eeprom)
        failed = [m for m in trial.measurements if m.outcome == "fail"]
        joint = trial.params.get("joint")
        rows.append(StartupRow(
            index=trial.index, fault=text(trial.params.get("fault", "-"), 60),
            phase=text(trial.params.get("phase", "-"), 40),
            joint="-" if joint is None else text(joint, 20), status=trial.status,
            outcome=outcome, recovered=recovered,
            recovery=format_value(recovery, "s"), position_error=format_value(pos_err, "mm"),
            eeprom=format_number(eeprom), failed=", ".join(m.name for m in failed) or "-",
            error=trial.error))
        if trial.status == "done":
            points.append(plots.StartupPoint(f"#{trial.index}", recovery, pos_err, recovered))
        if failed or trial.status == "error":
            fault_at = next((num(e.get("t_s")) for e in events if e.get("event") == "fault"),
                            None)
            conditions = (f"fault {text(trial.params.get('fault', '?'), 60)} while "
                          f"{text(trial.params.get('phase', '?'), 40)}"
                          + ("" if joint is None else f", joint {text(joint, 20)}")
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
    endurance = num(suite.params.get("eeprom_endurance_cycles")) or EEPROM_ENDURANCE_CYCLES
    per_day = num(suite.params.get("eeprom_events_per_day")) or EEPROM_EVENTS_PER_DAY
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


