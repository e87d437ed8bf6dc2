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
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from armbench.bench.record import (
    RESULTS_FILE,
    RunRecord,
    atomic_write_bytes,
    load_record,
)
from armbench.reports.capture import CAPTURE_FILE
from armbench.reports.format import (
    format_duration,
    jinja_environment,
)
from armbench.reports.sections.accuracy import accuracy_section
from armbench.reports.sections.repeatability import repeatability_section
from armbench.reports.sections.startup_recovery import startup_section
from armbench.reports.sections.traffic import traffic_section
from armbench.reports.summary import (
    missing_row,
    not_started_view,
    suite_view,
    verdict_reasons,
)
from armbench.reports.views import (
    FaultRow,
    Figures,
    MeasurementRow,
    SuiteView,
    num,
    text,
)

__all__ = ["KNOWN_SUITES", "REPORT_FILE", "build_report_html", "render_report"]

#: The report's file name inside a run directory.
REPORT_FILE = "report.html"
#: Suites with a section of their own; any other suite gets a generic one.
KNOWN_SUITES = ("accuracy", "repeatability", "startup")

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
                n = num(v)
                if n is not None and k.endswith("_m"):
                    parts.append(f"{k[:-2]} {n * 1000:g} mm")
                else:
                    parts.append(f"{k} {text(v, 30)}")
            out.append(("geometry", ", ".join(parts)))
        elif key == "serial" and isinstance(value, Mapping):
            baud, bits = value.get("baudrate"), value.get("bytesize")
            parity, stop = value.get("parity"), value.get("stopbits")
            out.append(("serial", f"{text(baud)} baud, {text(bits)}{text(parity)}"
                                  f"{text(stop)}"))
        elif key == "joints" and isinstance(value, Mapping):
            for jname, j in value.items():
                if not isinstance(j, Mapping):
                    out.append((f"joint {jname}", text(j)))
                    continue
                lo, hi = num(j.get("lower_deg")), num(j.get("upper_deg"))
                gear, micro = num(j.get("gear_ratio")), num(j.get("microsteps"))
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
            out.append((str(key), text(value, 120)))
    return out


def _faults(record: RunRecord) -> list[FaultRow]:
    rows = []
    for f in record.environment.faults:
        details = ", ".join(f"{k}={text(v, 80)}" for k, v in f.items()
                            if k != "kind" and v is not None)
        rows.append(FaultRow(kind=text(f.get("kind", "?"), 80), details=details or "-"))
    return rows


# --------------------------------------------------------------------------------------------
# The page
# --------------------------------------------------------------------------------------------


def build_report_html(record: RunRecord, *, capture: Path | None = None,
                      out_dir: Path | None = None, source: str = RESULTS_FILE) -> str:
    """The report page of ``record`` as HTML text. ``capture`` is a traffic capture to summarise
    (linked relative to ``out_dir``, where the page will be written)."""
    figs = Figures()
    cmp_rows = {} if record.baseline is None else {r.name: r for r in record.baseline.rows}
    views: dict[str, SuiteView] = {}
    order = list(dict.fromkeys([*record.planned_suites, *record.suites]))
    for i, name in enumerate(order):
        key = f"suite-{i + 1}"
        suite = record.suites.get(name)
        views[name] = (not_started_view(record, name, key) if suite is None
                       else suite_view(record, suite, key, cmp_rows))
    orphans: list[MeasurementRow] = []
    if record.baseline is not None:
        for r in record.baseline.rows:
            if r.status != "missing":
                continue
            owner = views.get(r.name.split(".", 1)[0])
            if owner is not None:
                owner.rows.append(missing_row(r))
            else:
                orphans.append(missing_row(r))

    accuracy = repeatability = startup = None
    if "accuracy" in record.suites:
        accuracy = accuracy_section(record, record.suites["accuracy"], views["accuracy"], figs)
    if "repeatability" in record.suites:
        repeatability = repeatability_section(record.suites["repeatability"],
                                              views["repeatability"], figs)
    if "startup" in record.suites:
        startup = startup_section(record.suites["startup"], views["startup"], figs)
    traffic = None
    if capture is not None and capture.is_file():
        traffic = traffic_section(capture, out_dir or capture.parent, figs)
    others = [v for name, v in views.items()
              if name not in KNOWN_SUITES and name in record.suites]
    robot_s = sum(t.duration_s for s in record.suites.values() for t in s.trials)
    baseline = record.baseline
    template = jinja_environment().get_template("report.html.j2")
    return template.render(
        record=record,
        verdict=record.verdict,
        reasons=verdict_reasons(record),
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

