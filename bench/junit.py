"""JUnit XML of a run record, for CI systems that show test results (Jenkins, GitLab, GitHub).

Layout (the common "Jenkins" dialect, as pytest's ``--junitxml`` writes it):

- one ``<testsuite>`` per bench suite, with the suite's version and the run's id as properties;
- one ``<testcase>`` per measurement: suite-level ones have ``classname="armbench.<suite>"``,
  trial-level ones ``"armbench.<suite>.trial<index>"``; a failed measurement carries a
  ``<failure type="limit">`` with value and limit, an unjudged one a ``<skipped type="unjudged">``
  and its value in ``<system-out>``, a passed one its value in ``<system-out>``;
- one ``<testcase name="trial">`` with an ``<error>`` per errored trial, and one per suite that
  errored or never finished (``name="suite"``), and per planned suite that never started;
- a ``baseline`` testsuite with one testcase per compared metric when the record has a baseline
  comparison; regressed metrics carry a ``<failure type="regression">``.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

from armbench.bench.record import (
    ComparisonRow,
    Measurement,
    RunRecord,
    SuiteRecord,
    atomic_write_bytes,
)

__all__ = ["to_junit", "write_junit"]

#: Characters XML 1.0 cannot carry at all (control characters other than tab, LF, CR).
_ILLEGAL_XML = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff]")


def _text(value: str) -> str:
    """``value`` with characters XML cannot hold shown as ``\\xNN`` (serial garbage in errors)."""
    return _ILLEGAL_XML.sub(lambda m: f"\\x{ord(m.group(0)):02x}", value)


def _seconds(value: float) -> str:
    return f"{max(value, 0.0):.3f}"


def _value(m: Measurement) -> str:
    return f"{m.value:g} {m.unit}".rstrip()


def _measurement_case(parent: ET.Element, classname: str, m: Measurement) -> None:
    case = ET.SubElement(parent, "testcase", classname=classname, name=_text(m.name), time="0")
    limit = "no limit" if m.limit is None else f"limit {m.limit.describe()}"
    if m.outcome == "fail":
        failure = ET.SubElement(case, "failure", type="limit",
                                message=_text(f"{m.name} = {_value(m)} outside {limit}"))
        failure.text = _text(f"value: {_value(m)}\n{limit} (pattern {m.limit.metric!r})"
                             if m.limit is not None else f"value: {_value(m)}")
    elif m.outcome == "unjudged":
        ET.SubElement(case, "skipped", type="unjudged",
                      message=_text(f"unjudged: {_value(m)} (no limit)"))
    out = ET.SubElement(case, "system-out")
    out.text = _text(f"{m.name} = {_value(m)} ({m.outcome}; {limit})"
                     + (f"\n{m.description}" if m.description else ""))


def _error_case(parent: ET.Element, classname: str, name: str, kind: str, message: str) -> None:
    case = ET.SubElement(parent, "testcase", classname=classname, name=name, time="0")
    err = ET.SubElement(case, "error", type=kind, message=_text(message))
    err.text = _text(message)


def _suite_element(record: RunRecord, suite: SuiteRecord) -> ET.Element:
    el = ET.Element("testsuite", name=_text(suite.name))
    props = ET.SubElement(el, "properties")
    for key, value in (("run_id", record.run_id), ("suite_version", suite.version),
                       ("status", suite.status)):
        ET.SubElement(props, "property", name=key, value=_text(value))
    disturbed = [str(t.index) for t in suite.trials if t.disturbed]
    if disturbed:  # measured while the link to the arm was lost at least once: kept, flagged
        ET.SubElement(props, "property", name="disturbed_trials", value=", ".join(disturbed))
    base = f"armbench.{suite.name}"
    for trial in suite.trials:
        cls = f"{base}.trial{trial.index}"
        if trial.status == "error":
            _error_case(el, cls, "trial", "trial_error",
                        f"trial {trial.index} could not be carried out: {trial.error}")
        for m in trial.measurements:
            _measurement_case(el, cls, m)
    for m in suite.measurements:
        _measurement_case(el, base, m)
    if suite.status == "error":
        _error_case(el, base, "suite", "suite_error", f"suite {suite.name} stopped: {suite.error}")
    elif suite.status == "running":
        _error_case(el, base, "suite", "incomplete",
                    f"suite {suite.name} did not finish (the run was interrupted)")
    duration = 0.0 if suite.ended_s is None else suite.ended_s - suite.started_s
    el.set("time", _seconds(duration))
    return el


def _row_case(parent: ET.Element, row: ComparisonRow) -> None:
    case = ET.SubElement(parent, "testcase", classname="armbench.baseline", name=_text(row.name),
                         time="0")
    unit = f" {row.unit}" if row.unit else ""
    if row.status == "compared":
        summary = (f"{row.name}: {row.value:g}{unit}, baseline {row.baseline:g}{unit}, change "
                   f"{row.change_abs:+g}{unit}, tolerance {row.tolerance:g}{unit}")
    elif row.status == "new":
        summary = f"{row.name}: new metric, {row.value:g}{unit}"
    else:
        summary = f"{row.name}: missing from this run (baseline {row.baseline:g}{unit})"
    if row.regressed:
        failure = ET.SubElement(case, "failure", type="regression", message=_text(summary))
        failure.text = _text(summary)
    out = ET.SubElement(case, "system-out")
    out.text = _text(summary)


def _count(el: ET.Element) -> None:
    """Set the ``tests``/``failures``/``errors``/``skipped`` attributes of a testsuite."""
    cases = el.findall("testcase")
    el.set("tests", str(len(cases)))
    for tag, attr in (("failure", "failures"), ("error", "errors"), ("skipped", "skipped")):
        el.set(attr, str(sum(1 for c in cases if c.find(tag) is not None)))


def to_junit(record: RunRecord) -> ET.Element:
    """The ``<testsuites>`` element of ``record`` (see the module docstring for the layout)."""
    root = ET.Element("testsuites", name=_text(f"armbench {record.run_id}"))
    suites = [_suite_element(record, s) for s in record.suites.values()]
    for name in record.planned_suites:
        if name not in record.suites:
            el = ET.Element("testsuite", name=_text(name), time=_seconds(0.0))
            _error_case(el, f"armbench.{name}", "suite", "incomplete",
                        f"suite {name} was planned but never started")
            suites.append(el)
    if record.baseline is not None:
        el = ET.Element("testsuite", name="baseline", time=_seconds(0.0))
        props = ET.SubElement(el, "properties")
        ET.SubElement(props, "property", name="baseline_run_id",
                      value=_text(record.baseline.baseline_run_id))
        for row in record.baseline.rows:
            _row_case(el, row)
        suites.append(el)
    total = 0.0
    for el in suites:
        _count(el)
        total += float(el.get("time", "0"))
        root.append(el)
    for attr in ("tests", "failures", "errors", "skipped"):
        root.set(attr, str(sum(int(el.get(attr, "0")) for el in suites)))
    root.set("time", _seconds(total))
    return root


def write_junit(record: RunRecord, path: str | Path) -> Path:
    """Write the JUnit XML of ``record`` to ``path`` atomically (UTF-8, with XML declaration);
    returns the path."""
    root = to_junit(record)
    ET.indent(root)
    data = ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n"
    atomic_write_bytes(path, data)
    return Path(path)
