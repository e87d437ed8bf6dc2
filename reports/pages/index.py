"""The run index (``index.html``): one row per run directory, with trend plots of key metrics.

``render_index(runs_dir)`` reads every ``<runs_dir>/<run>/results.json`` (one level down), orders
the runs by creation time, and writes a self-contained page (same CSP and escaping as the run
report) linking each run's ``report.html``. A directory whose record cannot be read is listed with
the reason, never silently skipped.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from urllib.parse import quote

from armbench.record import (
    REPORT_FILE,
    RESULTS_FILE,
    RecordError,
    RunRecord,
    atomic_write_bytes,
)
from armbench.record.baseline import read_record
from armbench.record.limits import Limit
from armbench.record.suite_contract import Headline
from armbench.reports.render import plots, plots_over_runs
from armbench.reports.render.format import format_value, jinja_environment
from armbench.reports.render.scorecard import HEADLINES, headline_figure
from armbench.reports.render.trends import TrendPoint, TrendSeries, trend_series
from armbench.reports.render.views import FigureView

__all__ = ["INDEX_FILE", "KEY_METRICS", "IndexRow", "KeyMetric", "key_metrics", "render_index",
           "trend_figures"]

#: The index's file name inside the runs directory.
INDEX_FILE = "index.html"
#: The index's key metrics: every suite's headline figures from the suite contract, in order:
#: (suite, headline).
KEY_METRICS: tuple[tuple[str, Headline], ...] = tuple(
    (suite, h) for suite, headlines in HEADLINES.items() for h in headlines)
#: Headlines per suite shown as table columns (all of them get a trend plot).
TABLE_HEADLINES = 2


@dataclass(frozen=True, slots=True)
class KeyMetric:
    """A key metric of one run: value in ``unit`` (None when the run lacks it), whether it failed
    its limit, and where it came from (the measurement's name)."""

    value: float | None
    unit: str
    failed: bool = False
    source: str = ""
    regressed: bool = False
    """Whether the run found this metric regressed against its baseline."""

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
    unit_under_test: str
    kind: str
    href: str
    has_report: bool
    error: str | None = None
    regressions: int = 0
    """Metrics the run found regressed against its baseline."""


def key_metrics(record: RunRecord) -> list[KeyMetric]:
    """The index's key metrics of ``record``, in :data:`KEY_METRICS` order: the recorded
    suite-level figure of each headline, the true one where the record holds it (as the
    scorecard shows, its limit then judging the firmware's figure), None when the run lacks
    it. The trends do not mix the two: :mod:`armbench.reports.render.trends`."""
    out = []
    worse = set() if record.baseline is None else {r.name for r in record.baseline.regressions}
    for suite_name, h in KEY_METRICS:
        suite = record.suites.get(suite_name)
        shown = None if suite is None else headline_figure(suite, h)
        if shown is None:
            out.append(KeyMetric(None, ""))
            continue
        m, reported = shown  # the true figure where the run has one, as the scorecard shows
        judged = m if reported is None or m.limit is not None else reported
        out.append(KeyMetric(m.value, m.unit, judged.outcome == "fail", m.name,
                             m.name in worse))
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


def _listing(s: TrendSeries) -> str:
    """The points of a series in words: ``"arm-3 · fake: run 1 0.8 mm, run 3 2.5 mm (outside
    <= 2 mm)"``."""
    def point(p: TrendPoint) -> str:
        text = f"run {p.run} {format_value(p.value, s.unit)}"
        if not p.outside:
            return text
        limit = Limit(p.metric, s.unit, p.low, p.high).describe()
        return f"{text} (outside limit {limit})"

    return f"{s.label}: " + ", ".join(point(p) for p in s.points)


def trend_figures(series: Sequence[TrendSeries], runs: Sequence[int]) -> list[FigureView]:
    """A trend plot per headline figure and view (believed, true), one line per unit under
    test and kind of target; the caption lists the points outside their limits, the plot's
    description every point."""
    groups: dict[tuple[str, str, str, str], list[TrendSeries]] = {}
    for s in series:
        groups.setdefault((s.suite, s.headline, s.view, s.unit), []).append(s)
    figures = []
    for k, ((suite_name, label, view, unit), members) in enumerate(groups.items()):
        lines = [plots_over_runs.TrendLine(
            s.label, [p.run for p in s.points], [p.value for p in s.points],
            [p.outside for p in s.points], [p.low for p in s.points],
            [p.high for p in s.points], [p.regressed for p in s.points]) for s in members]
        panel = plots_over_runs.TrendPanel(f"{label} ({view})", unit, runs, lines)
        title = f"{suite_name}: {label} ({view}) across runs"
        outside = [f"run {p.run} ({s.label})" for s in members for p in s.outside]
        caption = f"{suite_name}: {label} ({view})" + (
            f"; outside the limit: {', '.join(outside)}" if outside else "")
        figures.append(FigureView(
            plots.to_svg(plots_over_runs.trend_plots([panel], 3.6, 2.3), f"t{k + 1}",
                         f"{title}. " + "; ".join(_listing(s) for s in members)),
            caption, label))
    return figures


def render_index(runs_dir: str | os.PathLike[str],
                 out_path: str | os.PathLike[str] | None = None,
                 warn: Callable[[str], object] | None = None) -> Path:
    """Write the index of the runs in ``runs_dir`` (each a directory holding ``results.json``) to
    ``out_path`` (default ``runs_dir/index.html``, written atomically); returns the path. A record
    that cannot be read is listed as unreadable with the reason, and ``warn`` (if given) is told
    the reason."""
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
            record = read_record(results)
        except RecordError as exc:
            loaded.append(((2, 0.0, d.name), d.name, d, None, str(exc)))
            if warn is not None:
                warn(f"{exc} (listed as unreadable)")
            continue
        loaded.append((_created_key(record.created), record.run_id, d, record, None))
    loaded.sort(key=lambda item: (item[0], item[1]))

    rows: list[IndexRow] = []
    measured: list[tuple[int, RunRecord]] = []
    for number, (_, _, d, rec, error) in enumerate(loaded, start=1):
        report = d / REPORT_FILE
        if rec is None:
            rows.append(IndexRow(number, d.name, "-", "-", "unreadable", "-", "-",
                                 [KeyMetric(None, "") for _ in KEY_METRICS], "-", "-",
                                 _href(report, out.parent), report.is_file(), error))
            continue
        measured.append((number, rec))
        rows.append(IndexRow(
            number=number, directory=d.name, run_id=rec.run_id, created=_when(rec.created),
            verdict=rec.verdict, port=rec.environment.port or "-",
            suites=", ".join(rec.suites) or "-",
            metrics=key_metrics(rec), unit_under_test=rec.environment.dut.label(),
            kind=rec.environment.kind,
            regressions=0 if rec.baseline is None else len(rec.baseline.regressions),
            href=_href(report, out.parent), has_report=report.is_file()))

    figures = trend_figures(trend_series(measured), [r.number for r in rows])
    columns = [(s, h.label) for s, hs in HEADLINES.items() for h in hs[:TABLE_HEADLINES]]
    shown_k = [k for k, (s, h) in enumerate(KEY_METRICS)
               if (s, h.label) in columns]
    for row in rows:
        row.metrics[:] = [row.metrics[k] for k in shown_k]
    html = jinja_environment().get_template("index.html.j2").render(
        rows=rows, columns=[label for _, label in columns], figures=figures,
        runs_dir=root.name or str(root))
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, html.encode("utf-8"))
    return out
