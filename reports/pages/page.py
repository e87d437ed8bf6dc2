"""The run report: one self-contained HTML page (``report.html``) from a run record.

Data flows one way: the report reads ``results.json`` (and ``capture.mcap`` beside it, when the
run captured its traffic) and nothing else; it never talks to a robot, a driver or the emulator.
What each section shows is described in ``docs/reports.md``.

The answer comes first: the verdict, the scorecard (each suite's headline figures, from the suite
contract) and the first plot fit the first screen of a laptop; then one section per suite, chosen
by the suite's name (:data:`SECTIONS`; a generic one for any other suite), each leading with its
plots, then a short table, its per-metric tables folded.

The page is one file with no network access: CSS inline, plots inline as SVG, a
Content-Security-Policy that forbids fetching anything and running any script, every piece of
record text HTML-escaped by the templates (Jinja2 autoescaping; record text never reaches an SVG).
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import BinaryIO

from jinja2 import meta

from armbench.record import (
    CAPTURE_FILE,
    LEGACY_CAPTURE_FILE,
    REPORT_FILE,
    RESULTS_FILE,
    RunRecord,
    load_record,
)
from armbench.record.files import atomic_write
from armbench.record.suite_contract import contracts
from armbench.reports.render.environment_view import environment_rows, fault_rows, settings_summary
from armbench.reports.render.format import format_duration, jinja_environment
from armbench.reports.render.scorecard import score_rows, suite_headlines
from armbench.reports.render.summary import (
    missing_row,
    not_started_view,
    suite_view,
    verdict_reasons,
)
from armbench.reports.render.views import (
    Figures,
    FigureView,
    MeasurementRow,
    SectionView,
    SuiteView,
    figures_collected_alone,
)
from armbench.reports.sections import SectionBuilder, generic, registered_sections
from armbench.reports.sections.traffic import traffic_section

__all__ = ["REPORT_FILE", "SECTIONS", "build_report_html", "draw_ahead", "load_templates",
           "render_report", "report_chunks", "suite_sections"]

_FIG_NUMBER = re.compile(r"^Fig\. \d+: ")
#: The section of each suite the report knows, by the suite's name (registered as entry points,
#: :mod:`armbench.reports.sections`); any other suite gets
#: :func:`armbench.reports.sections.generic.build`.
SECTIONS: Mapping[str, SectionBuilder] = registered_sections()


def suite_sections(record: RunRecord, figs: Figures) -> tuple[list[SuiteView],
                                                              list[SectionView],
                                                              list[MeasurementRow]]:
    """The summary view of every planned or recorded suite, the section of every recorded one
    (scorecard included) and the baseline's rows of suites not in this run."""
    cmp_rows = {} if record.baseline is None else {r.name: r for r in record.baseline.rows}
    views: dict[str, SuiteView] = {}
    order = list(dict.fromkeys([*record.planned_suites, *record.suites]))
    for i, name in enumerate(order):
        suite = record.suites.get(name)
        key = f"suite-{i + 1}"
        views[name] = (not_started_view(record, name, key) if suite is None
                       else suite_view(record, suite, key, cmp_rows))
    orphans: list[MeasurementRow] = []
    if record.baseline is not None:
        prefixes = {getattr(c, "prefix", c.suite): c.suite for c in contracts()}
        for r in record.baseline.rows:
            if r.status != "missing":
                continue
            head = r.name.split(".", 1)[0]
            owner = views.get(prefixes.get(head, head))
            (owner.rows if owner is not None else orphans).append(missing_row(r))
    sections = []
    for name, suite in record.suites.items():
        builder = registered_sections().get(name, generic.build)
        section = builder(record, suite, views[name], figs)
        section.scorecard = score_rows(record, suite, suite_headlines(name), cmp_rows)
        sections.append(section)
    return list(views.values()), sections, orphans


def draw_ahead(record: RunRecord, name: str) -> None:
    """Draw the plots of suite ``name``'s section of ``record`` now, to be found drawn
    (:mod:`armbench.reports.render.svg_cache`) by the report written later: the run calls it
    in a thread of its own once the suite's summary is in the record, while the next suite's
    trials go on. Nothing is written; the collector is left alone (a full collection of the
    run's process would hold up its event loop)."""
    suite = record.suites.get(name)
    if suite is None:
        return
    builder = registered_sections().get(name, generic.build)
    builder(record, suite, suite_view(record, suite, "suite-0", {}), Figures(collect=False))


def load_templates() -> None:
    """Compile the report page's templates now, for the report written later to find them
    compiled (the environment keeps them): ``report.html.j2`` and every template it names,
    every section's for an include whose name is computed. The run calls it in a thread of its
    own while the trials go on."""
    env = jinja_environment()
    todo, done = ["report.html.j2"], set()
    while todo:
        name = todo.pop()
        if name in done:
            continue
        done.add(name)
        env.get_template(name)
        assert env.loader is not None  # the environment loads from the package's folder
        source = env.loader.get_source(env, name)[0]
        for ref in meta.find_referenced_templates(env.parse(source)):
            todo.extend([ref] if ref is not None else env.list_templates(
                filter_func=lambda n: n.startswith("sections/")))


def _lead(sections: Sequence[SectionView], figs: Figures) -> FigureView | None:
    """The first plot of the page, shown again beside the scorecard."""
    first = next((s.figures[0] for s in sections if s.figures), None)
    if first is None:
        return None
    lead = figs.copy(first)  # the paper's numbering means nothing beside the scorecard
    return dataclasses.replace(lead, title=_FIG_NUMBER.sub("", lead.title))


def build_report_html(record: RunRecord, *, capture: Path | None = None,
                      out_dir: Path | None = None, source: str = RESULTS_FILE) -> str:
    """The report page of ``record`` as HTML text. ``capture`` is a traffic capture to summarise
    (linked relative to ``out_dir``, where the page will be written)."""
    return "".join(report_chunks(record, capture=capture, out_dir=out_dir, source=source))


def report_chunks(record: RunRecord, *, capture: Path | None = None,
                  out_dir: Path | None = None, source: str = RESULTS_FILE) -> Iterator[str]:
    """The report page of ``record`` as pieces of HTML text in order (Jinja's ``generate``):
    written as they come, a long run's page is never in memory whole, as text or as bytes."""
    figs = Figures()
    suites, sections, orphans = suite_sections(record, figs)
    traffic = None
    if capture is not None and capture.is_file():
        traffic = traffic_section(capture, out_dir or capture.parent, figs)
    lead = _lead(sections, figs)
    if lead is None and traffic is not None and traffic.figures:
        lead = figs.copy(traffic.figures[0])
    robot_s = sum(t.duration_s for s in record.suites.values() for t in s.trials)
    baseline = record.baseline
    return jinja_environment().get_template("report.html.j2").generate(
        record=record,
        verdict=record.verdict,
        reasons=verdict_reasons(record),
        environment=environment_rows(record),
        settings=settings_summary(record.environment.settings),
        settings_json=json.dumps(dict(record.environment.settings), indent=1,
                                 ensure_ascii=False),
        faults=fault_rows(record),
        suites=suites,
        sections=sections,
        lead=lead,
        run_time=format_duration(record.end_s),
        robot_time=format_duration(robot_s),
        baseline=baseline,
        baseline_counts=None if baseline is None else {
            "compared": sum(r.status == "compared" for r in baseline.rows),
            "regressed": len(baseline.regressions),
            "new": sum(r.status == "new" for r in baseline.rows),
            "missing": sum(r.status == "missing" for r in baseline.rows)},
        orphans=orphans,
        traffic=traffic,
        source=source,
    )


def render_report(record: RunRecord | str | os.PathLike[str], out_path: str | os.PathLike[str],
                  *, capture: str | os.PathLike[str] | None = None) -> Path:
    """Render the report of ``record`` (a :class:`RunRecord`, a ``results.json`` path or a run
    directory) to ``out_path`` (written atomically); returns the path written.

    The traffic section reads ``capture`` when given, else ``capture.mcap`` (or an older run's
    ``capture.jsonl``) beside the record file if there is one. Raises ``RecordError`` for an
    unreadable or invalid record.
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
        for name in (CAPTURE_FILE, LEGACY_CAPTURE_FILE):  # capture.mcap, else an older run's
            if capture_path is None and (path.parent / name).is_file():
                capture_path = path.parent / name
    out.parent.mkdir(parents=True, exist_ok=True)
    with figures_collected_alone():
        chunks = report_chunks(rec, capture=capture_path, out_dir=out.parent, source=source)

        def write(fh: BinaryIO) -> None:
            for chunk in chunks:  # a template error leaves the earlier page as it was
                fh.write(chunk.encode("utf-8"))

        atomic_write(out, write)
    return out
