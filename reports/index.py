"""The run index (``index.html``): one row per run directory, with trend plots of key metrics.

``render_index(runs_dir)`` reads every ``<runs_dir>/<run>/results.json`` (one level down), orders
the runs by creation time, and writes a self-contained page (same CSP and escaping as the run
report) linking each run's ``report.html``. A directory whose record cannot be read is listed with
the reason, never silently skipped.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from urllib.parse import quote

from armbench.bench.record import (
    REPORT_FILE,
    RESULTS_FILE,
    Measurement,
    RecordError,
    RunRecord,
    atomic_write_bytes,
    load_record,
)
from armbench.reports import plots
from armbench.reports.format import format_value, jinja_environment

__all__ = ["INDEX_FILE", "KEY_METRICS", "IndexRow", "KeyMetric", "key_metrics", "render_index"]

#: The index's file name inside the runs directory.
INDEX_FILE = "index.html"
#: The key metrics of the index, in column order: (key, column title, unit).
KEY_METRICS = (
    ("coordinated_mean", "coordinated mean path error", "mm"),
    ("paper_mean", "paper-style mean path error", "mm"),
    ("worst_rp", "worst RP", "mm"),
    ("recovery_rate", "start-up recovery rate", "%"),
)
#: Short column titles of the key metrics in the table.
_COLUMNS = ("coordinated mean error", "paper-style mean error", "worst RP", "recovery rate")
_RP = re.compile(r"repeatability\..*\.rp_mm")


@dataclass(frozen=True, slots=True)
class KeyMetric:
    """A key metric of one run: value in ``unit`` (None when the run lacks it), whether it failed
    its limit, the limit's bound for the trend plot, and where it came from."""

    value: float | None
    unit: str
    failed: bool = False
    limit: float | None = None
    source: str = ""

    @property
    def text(self) -> str:
        return format_value(self.value, self.unit) if self.value is not None else "-"


@dataclass(frozen=True, slots=True)
class IndexRow:
    """One run directory in the index."""

    number: int
    directory: str
    run_id: str
    created: str
    verdict: str
    port: str
    suites: str
    metrics: list[KeyMetric]
    href: str
    has_report: bool
    error: str | None = None


def _bound(m: Measurement) -> float | None:
    if m.limit is None:
        return None
    return m.limit.high if m.limit.high is not None else m.limit.low


def key_metrics(record: RunRecord) -> dict[str, KeyMetric]:
    """The index's key metrics of ``record`` (see :data:`KEY_METRICS`): suite-level figures when
    the suite finished, else what its trials allow (a partial run still shows a trend point)."""
    suite = record.suite_measurements()
    out: dict[str, KeyMetric] = {}
    for key, name in (("coordinated_mean", "accuracy.coordinated.mean_mm"),
                      ("paper_mean", "accuracy.paper.mean_mm")):
        m = suite.get(name)
        if m is not None:
            out[key] = KeyMetric(m.value, m.unit, m.outcome == "fail", _bound(m), name)
        else:
            acc = record.suites.get("accuracy")
            vals = [] if acc is None else [x.value for t in acc.trials for x in t.measurements
                                           if x.name == name]
            out[key] = KeyMetric(sum(vals) / len(vals) if vals else None, "mm",
                                 source="mean of the trials" if vals else "")
    rps = [m for n, m in suite.items() if _RP.fullmatch(n)]
    if rps:
        worst = max(rps, key=lambda m: m.value)
        out["worst_rp"] = KeyMetric(worst.value, worst.unit,
                                    any(m.outcome == "fail" for m in rps), _bound(worst),
                                    worst.name)
    else:
        out["worst_rp"] = KeyMetric(None, "mm")
    rate = suite.get("startup.recovery_rate_pct")
    if rate is not None:
        out["recovery_rate"] = KeyMetric(rate.value, rate.unit, rate.outcome == "fail",
                                         _bound(rate), rate.name)
    else:
        st = record.suites.get("startup")
        flags = [] if st is None else [m.value for t in st.trials for m in t.measurements
                                       if m.name == "startup.recovered"]
        out["recovery_rate"] = KeyMetric(100.0 * sum(flags) / len(flags) if flags else None,
                                         "%", failed=bool(flags) and min(flags) < 1,
                                         source="from the trials" if flags else "")
    return out


def _created_key(created: str) -> tuple[int, float, str]:
    try:
        when = datetime.fromisoformat(created)
    except ValueError:
        return (1, 0.0, created)
    if when.tzinfo is None:  # records are labelled in UTC; a bare label is taken as UTC too
        when = when.replace(tzinfo=UTC)
    return (0, when.timestamp(), created)


def _when(created: str) -> str:
    """``2024-05-03 09:15`` from an ISO 8601 label (UTC), the label itself if it is not one."""
    try:
        when = datetime.fromisoformat(created)
    except ValueError:
        return created
    if when.tzinfo is not None:
        when = when.astimezone(UTC)
    return f"{when:%Y-%m-%d %H:%M}"


def _href(target: Path, out_dir: Path) -> str:
    rel = os.path.relpath(target.resolve(), out_dir.resolve())
    return quote(Path(rel).as_posix(), safe="/")


def render_index(runs_dir: str | os.PathLike[str],
                 out_path: str | os.PathLike[str] | None = None) -> Path:
    """Write the index of the runs in ``runs_dir`` (each a directory holding ``results.json``) to
    ``out_path`` (default ``runs_dir/index.html``, written atomically); returns the path."""
    root = Path(runs_dir)
    if not root.is_dir():
        raise RecordError(str(root), "is not a directory of runs")
    out = Path(out_path) if out_path is not None else root / INDEX_FILE
    loaded: list[tuple[tuple[int, float, str], str, Path, RunRecord | None, str | None]] = []
    for d in sorted(p for p in root.iterdir() if p.is_dir()):
        results = d / RESULTS_FILE
        if not results.is_file():
            continue
        try:
            record = load_record(results)
        except RecordError as exc:
            loaded.append(((2, 0.0, d.name), d.name, d, None, str(exc)))
            continue
        loaded.append((_created_key(record.created), record.run_id, d, record, None))
    loaded.sort(key=lambda item: (item[0], item[1]))

    rows: list[IndexRow] = []
    for number, (_, _, d, rec, error) in enumerate(loaded, start=1):
        report = d / REPORT_FILE
        if rec is None:
            rows.append(IndexRow(number, d.name, "-", "-", "unreadable", "-", "-",
                                 [KeyMetric(None, unit) for _, _, unit in KEY_METRICS],
                                 _href(report, out.parent), report.is_file(), error))
            continue
        km = key_metrics(rec)
        rows.append(IndexRow(
            number=number, directory=d.name, run_id=rec.run_id, created=_when(rec.created),
            verdict=rec.verdict, port=rec.environment.port or "-",
            suites=", ".join(rec.suites) or "-",
            metrics=[km[key] for key, _, _ in KEY_METRICS],
            href=_href(report, out.parent), has_report=report.is_file()))

    panels = []
    for k, (key, title, unit) in enumerate(KEY_METRICS):
        if key == "paper_mean":
            continue  # in the table; the trend of the coordinated run is the one tracked
        values = [r.metrics[k] for r in rows]
        limits = [m.limit for m in values if m.limit is not None]
        panels.append(plots.TrendPanel(
            title=title, unit=unit, runs=[r.number for r in rows],
            values=[m.value if m.value is not None and math.isfinite(m.value) else None
                    for m in values],
            failed=[m.failed for m in values], limit=limits[-1] if limits else None))
    figure = None
    if rows:
        figure = plots.to_svg(plots.trend_plots(panels), "t1", "Key metrics across runs")
    html = jinja_environment().get_template("index.html.j2").render(
        rows=rows, columns=_COLUMNS, figure=figure,
        runs_dir=root.name or str(root))
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, html.encode("utf-8"))
    return out
