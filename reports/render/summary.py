"""Verdicts, reasons and the measurement tables of each suite: what every report shows whatever
the suite."""

from __future__ import annotations

import statistics
from collections.abc import Iterable, Mapping

from armbench.record import (
    ComparisonRow,
    Measurement,
    RunRecord,
    SuiteRecord,
    Trial,
)
from armbench.record.claims import truth_line, uncovered_lines
from armbench.reports.render.format import (
    OUTCOME_MARKS,
    format_duration,
    format_number,
    format_value,
    margin,
)
from armbench.reports.render.views import (
    MeasurementRow,
    SuiteView,
    TrialMetricRow,
    TrialView,
    params_text,
)

# --------------------------------------------------------------------------------------------
# Verdicts and the baseline
# --------------------------------------------------------------------------------------------


def suite_verdict(record: RunRecord, name: str) -> str:
    """A suite's own verdict as the record judges it (:meth:`RunRecord.suite_verdict`)."""
    return record.suite_verdict(name)


def all_measurements(suite: SuiteRecord) -> Iterable[Measurement]:
    for t in suite.trials:
        yield from t.measurements
    yield from suite.measurements


def verdict_reasons(record: RunRecord) -> list[str]:
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
    reasons.extend(uncovered_lines(record))
    if record.baseline is not None:
        regressed = [r.name for r in record.baseline.regressions]
        if regressed:
            reasons.append(f"{len(regressed)} metric(s) regressed against baseline "
                           f"{record.baseline.baseline_run_id}: each is marked ▲ regressed "
                           "in the scorecard")
    disturbed = record.disturbance_note()
    if not reasons:
        reasons.append("every judged measurement within its limits" +
                       ("" if record.baseline is None else
                        f", no regression against baseline {record.baseline.baseline_run_id}"))
    reasons.append(truth_line(record))
    if disturbed is not None:
        reasons.append(disturbed)
    return reasons


# --------------------------------------------------------------------------------------------
# Suites and measurements
# --------------------------------------------------------------------------------------------


def measurement_row(m: Measurement, trial: Trial | None,
                     cmp: ComparisonRow | None) -> MeasurementRow:
    row = MeasurementRow(
        name=m.name, description=m.description,
        trial="" if trial is None else f"trial {trial.index}",
        value=format_number(m.value, unit=m.unit), unit=m.unit,
        limit="-" if m.limit is None else m.limit.describe(),
        margin=format_number(margin(m), signed=True, unit=m.unit), outcome=m.outcome,
    )
    if cmp is None:
        return row
    return with_comparison(row, cmp)


def with_comparison(row: MeasurementRow, cmp: ComparisonRow) -> MeasurementRow:
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


def missing_row(cmp: ComparisonRow) -> MeasurementRow:
    row = MeasurementRow(name=cmp.name, description="in the baseline, not in this run",
                         trial="", value="-", unit=cmp.unit, limit="-", margin="-",
                         outcome="unjudged")
    return with_comparison(row, cmp)


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
        unit = items[0][1].unit
        rows.append(TrialMetricRow(
            name=name, unit=unit, limit=limits[0] if limits else "-",
            n=len(items), minimum=format_number(min(values), unit=unit),
            mean=format_number(statistics.fmean(values), unit=unit),
            maximum=format_number(max(values), unit=unit),
            worst_margin=(format_number(min(margins), signed=True, unit=unit) if margins
                          else "-"),
            failed=len(failed), failed_trials=shown, outcome=outcome,
        ))
    return rows


def suite_view(record: RunRecord, suite: SuiteRecord, key: str,
                cmp_rows: Mapping[str, ComparisonRow]) -> SuiteView:
    ends = [t.ended_s for t in suite.trials]
    if suite.ended_s is not None:
        duration = format_duration(suite.ended_s - suite.started_s)
    elif ends:
        duration = format_duration(max(ends) - suite.started_s) + " so far"
    else:
        duration = "-"
    failed = sum(m.outcome == "fail" for m in all_measurements(suite))
    names = {m.name for m in suite.measurements}
    regressed = sum(1 for r in cmp_rows.values() if r.regressed and r.name in names)
    view = SuiteView(
        key=key, name=suite.name, status=suite.status, verdict=suite_verdict(record, suite.name),
        version=suite.version, started=format_duration(suite.started_s), duration=duration,
        robot_time=format_duration(sum(t.duration_s for t in suite.trials)),
        trials_done=sum(t.status == "done" for t in suite.trials),
        trials_error=sum(t.status == "error" for t in suite.trials),
        superseded=len(suite.superseded_trials),
        measured=sum(1 for _ in all_measurements(suite)), failed=failed, regressed=regressed,
        error=suite.error, params=params_text(suite.params),
        disturbed=sum(t.disturbed for t in suite.trials),
    )
    view.rows = [measurement_row(m, None, cmp_rows.get(m.name)) for m in suite.measurements]
    view.trial_metrics = _trial_metrics(suite)
    view.trial_rows = [measurement_row(m, t, None) for t in suite.trials for m in t.measurements]
    for t in suite.trials:
        counts = {o: sum(m.outcome == o for m in t.measurements) for o in OUTCOME_MARKS}
        summary = ", ".join(f"{n} {OUTCOME_MARKS[o][1]}" for o, n in counts.items() if n) or "-"
        view.trials.append(TrialView(
            index=t.index, status=t.status, params=params_text(t.params),
            started=format_duration(t.started_s), duration=format_duration(t.duration_s),
            samples=len(t.samples), measurements=summary, error=t.error))
    return view


def not_started_view(record: RunRecord, name: str, key: str) -> SuiteView:
    return SuiteView(key=key, name=name, status="not started", verdict="incomplete",
                     version="-", started="-", duration="-", robot_time="-", trials_done=0,
                     trials_error=0, superseded=0, measured=0, failed=0, regressed=0,
                     error=None, params="-")


