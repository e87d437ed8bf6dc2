"""The fleet page (``fleet.html``) of a run over several arms: the fleet's verdict, the headline
figures of every arm side by side with their spread across the fleet (min, max, mean, standard
deviation), and which arm is outside its limits or drifted from its own baseline.

It reads ``fleet.json`` (``armbench.record.fleet_index``) and each arm's ``results.json``, nothing
else; the page is self-contained, with the run report's Content-Security-Policy and escaping.
"""

from __future__ import annotations

import math
import os
import statistics
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import quote

from armbench.record import RESULTS_FILE, RecordError, RunRecord, atomic_write_bytes
from armbench.record.baseline import read_record
from armbench.record.fleet_index import FleetArm, read_fleet_index
from armbench.record.suite_contract import Headline
from armbench.reports.pages.page import REPORT_FILE
from armbench.reports.render.format import format_value, jinja_environment
from armbench.reports.render.scorecard import HEADLINES, change_text, headline_figure

__all__ = ["FLEET_PAGE", "ArmRow", "Cell", "HeadlineRow", "build_fleet_html", "render_fleet"]

#: The fleet page's file name inside the fleet's run directory.
FLEET_PAGE = "fleet.html"
#: Verdicts from the worst: the fleet's verdict is its worst arm's.
_ORDER = ("error", "incomplete", "fail", "untested", "regression", "pass")


@dataclass(frozen=True, slots=True)
class Cell:
    """One arm's value of a headline: text, outside its limit, its change against the arm's own
    baseline (``worse``, ``better``, ``same``; empty without one)."""

    text: str
    failed: bool = False
    change: str = ""
    direction: str = ""


@dataclass(slots=True)
class HeadlineRow:
    """A headline figure across the fleet: one cell per arm and the spread of the values."""

    suite: str
    label: str
    metric: str
    cells: list[Cell]
    n: int = 0
    minimum: str = "-"
    maximum: str = "-"
    mean: str = "-"
    std: str = "-"


@dataclass(slots=True)
class ArmRow:
    """An arm: where it is, its verdict and exit status, what failed or drifted, its report."""

    name: str
    port: str
    verdict: str
    exit_status: str
    href: str | None
    outside: list[str] = field(default_factory=list)
    drifted: list[str] = field(default_factory=list)
    error: str | None = None


def _load(directory: Path, arm: FleetArm) -> tuple[RunRecord | None, str | None]:
    path = directory / arm.name / RESULTS_FILE
    if not path.is_file():
        return None, arm.error or "no record (the arm's run never began)"
    try:
        return read_record(path), None
    except RecordError as exc:
        return None, str(exc)


def _arm_verdict(arm: FleetArm, record: RunRecord | None) -> str:
    if record is None:
        return "error"
    if arm.error and record.verdict == "pass":
        return "error"
    return record.verdict


def _spread(row: HeadlineRow, values: list[float], unit: str) -> None:
    finite = [v for v in values if math.isfinite(v)]
    row.n = len(finite)
    if not finite:
        return
    row.minimum = format_value(min(finite), unit)
    row.maximum = format_value(max(finite), unit)
    row.mean = format_value(statistics.fmean(finite), unit)
    row.std = format_value(statistics.stdev(finite), unit) if len(finite) > 1 else "-"


def headline_rows(records: list[RunRecord | None]) -> list[HeadlineRow]:
    """Every contract headline some arm recorded, one cell per arm, with the fleet's spread."""
    rows: list[HeadlineRow] = []
    for suite_name, headlines in HEADLINES.items():
        for h in headlines:
            row = _headline_row(suite_name, h, records)
            if row is not None:
                rows.append(row)
    return rows


def _headline_row(suite_name: str, h: Headline,
                  records: list[RunRecord | None]) -> HeadlineRow | None:
    cells: list[Cell] = []
    values: list[float] = []
    unit = ""
    true = False
    for record in records:
        suite = None if record is None else record.suites.get(suite_name)
        shown = None if suite is None else headline_figure(suite, h)
        if record is None or shown is None:
            cells.append(Cell("-"))
            continue
        m, reported = shown  # the true figure where the arm's run has one, as its scorecard
        true = true or reported is not None
        judged = m if reported is None or m.limit is not None else reported
        unit = m.unit
        values.append(m.value)
        change = direction = ""
        if record.baseline is not None:
            cmp = next((r for r in record.baseline.rows if r.name == m.name), None)
            if cmp is not None:
                change, direction = change_text(cmp)
        cells.append(Cell(format_value(m.value, m.unit), judged.outcome == "fail", change,
                          direction))
    if not values:
        return None
    row = HeadlineRow(suite_name, h.label + (" (true)" if true else ""), h.metric, cells)
    _spread(row, values, unit)
    return row


def _groups(rows: list[HeadlineRow]) -> list[tuple[str, list[HeadlineRow]]]:
    """The rows by suite, in the contract's order."""
    groups: dict[str, list[HeadlineRow]] = {}
    for row in rows:
        groups.setdefault(row.suite, []).append(row)
    return list(groups.items())


def _href(target: Path, page_dir: Path) -> str:
    rel = os.path.relpath(target.resolve(), page_dir.resolve())
    return quote(Path(rel).as_posix(), safe="/")


def build_fleet_html(directory: str | os.PathLike[str], page_dir: Path | None = None) -> str:
    """The fleet page of the fleet run in ``directory`` as HTML text (links relative to
    ``page_dir``, where the page will be written; default the run directory)."""
    root = Path(directory)
    index = read_fleet_index(root)
    page_dir = page_dir or root
    arms: list[ArmRow] = []
    records: list[RunRecord | None] = []
    for arm in index.arms:
        record, problem = _load(root, arm)
        records.append(record)
        report = root / arm.name / REPORT_FILE
        row = ArmRow(arm.name, arm.port, _arm_verdict(arm, record),
                     "-" if arm.exit_status is None else str(arm.exit_status),
                     _href(report, page_dir) if report.is_file() else None,
                     error=arm.error or problem)
        if record is not None:
            row.outside = list(dict.fromkeys(m.name for _, _, m in record.iter_measurements()
                                             if m.outcome == "fail"))
            if record.baseline is not None:
                row.drifted = [r.name for r in record.baseline.regressions]
        arms.append(row)
    verdict = min((a.verdict for a in arms), key=_ORDER.index, default="incomplete")
    reasons = []
    for a in arms:
        if a.verdict == "pass":
            continue
        why = a.error or (f"{len(a.outside)} metric(s) outside their limits" if a.outside
                          else f"{len(a.drifted)} metric(s) drifted from its baseline"
                          if a.drifted else a.verdict)
        reasons.append(f"{a.name}: {a.verdict.upper()} (exit {a.exit_status}): {why}")
    if not reasons:
        reasons.append(f"all {len(arms)} arms within their limits"
                       + (", none drifted from its baseline"
                          if any(r is not None and r.baseline for r in records) else ""))
    return jinja_environment().get_template("fleet.html.j2").render(
        fleet_id=index.fleet_id, verdict=verdict, reasons=reasons, arms=arms,
        groups=_groups(headline_rows(records)),
        with_baseline=any(r is not None and r.baseline is not None for r in records),
        running=index.exit_status is None)


def render_fleet(directory: str | os.PathLike[str],
                 out_path: str | os.PathLike[str] | None = None) -> Path:
    """Write the fleet page of the fleet run in ``directory`` to ``out_path`` (default
    ``directory/fleet.html``, written atomically); returns the path written."""
    out = Path(out_path) if out_path is not None else Path(directory) / FLEET_PAGE
    html = build_fleet_html(directory, out.parent)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, html.encode("utf-8"))
    return out
