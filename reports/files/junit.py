"""JUnit XML of a run record, for CI systems that show test results (Jenkins, GitLab, GitHub).

Layout (the common "Jenkins" dialect, as pytest's ``--junitxml`` writes it):

- one ``<testsuite>`` per bench suite, with the suite's version, the run's id, the robot time
  (``robot_time_s``: the run clock's seconds, simulated ones on a virtual-time target), the
  target's kind, the unit under test (``dut.name``, ``dut.serial``, ``dut.firmware_commit``,
  ``dut.host_commit``, ``dut.meta.<key>``) and the CI job (``ci.system``, ``ci.url``, ...) as
  properties; every testsuite (the baseline's and a never started suite's too) carries the
  run's properties;
- ``time`` attributes are wall-clock seconds: a testsuite's is the suite's wall time, a trial's
  wall time is on the trial's first testcase (the others measured in the same trial have 0, so
  the testcases add up to the trials' time); 0 where the record holds none (a record written
  before wall time was kept);
- one ``<testcase>`` per judged measurement (one a limit applies to): suite-level ones have
  ``classname="armbench.<suite>"``, trial-level ones ``"armbench.<suite>.trial<index>"``; a
  failed measurement carries a ``<failure type="limit">`` with value and limit, a passed one its
  value in ``<system-out>``;
- a campaign's samples (``armbench campaign``: trials of a suite whose parameters hold
  ``campaign``) are summarised by its ``campaign.*`` figures, which are its testcases; their own
  figures are left out (a sample outside a limit is a finding, not a failed test), a sample in
  error is an ``<error>`` testcase;
- an unjudged measurement (no limit) is no test: it is a ``<property>`` of its testsuite,
  ``name="<metric>"`` (suite level) or ``"trial<index>.<metric>"``, ``value="<value> <unit>"``,
  so test reporters list no skipped tests for figures that are only recorded;
- one ``<testcase name="trial">`` with an ``<error>`` per errored trial, and one per suite that
  errored or never finished (``name="suite"``), and per planned suite that never started;
- untested is never passed: one ``<testcase name="trial">`` with ``<skipped>`` and its reason per
  trial that measured nothing, one ``name="suite"`` per suite that measured nothing, and a
  ``required`` testsuite with one skipped testcase per required figure no suite measured;
- a ``baseline`` testsuite with one testcase per compared metric when the record has a baseline
  comparison; regressed metrics carry a ``<failure type="regression">``.
"""

from __future__ import annotations

import functools
import itertools
import re
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import BinaryIO

from armbench.record import (
    ComparisonRow,
    Measurement,
    RunRecord,
    SuiteRecord,
    Trial,
)
from armbench.record.files import atomic_write

#: The key of a campaign suite's parameters (``armbench.bench.campaign.CAMPAIGN_KEY``; the
#: campaign package imports the runner, which this module must not).
CAMPAIGN_KEY = "campaign"

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


def _measurement_case(classname: str, m: Measurement) -> ET.Element:
    case = ET.Element("testcase", classname=classname, name=_text(m.name), time="0")
    limit = "no limit" if m.limit is None else f"limit {m.limit.describe()}"
    if m.outcome == "fail":
        failure = ET.SubElement(case, "failure", type="limit",
                                message=_text(f"{m.name} = {_value(m)} outside {limit}"))
        failure.text = _text(f"value: {_value(m)}\n{limit} (pattern {m.limit.metric!r})"
                             if m.limit is not None else f"value: {_value(m)}")
    out = ET.SubElement(case, "system-out")
    out.text = _text(f"{m.name} = {_value(m)} ({m.outcome}; {limit})"
                     + (f"\n{m.description}" if m.description else ""))
    return case


def _error_case(classname: str, name: str, kind: str, message: str) -> ET.Element:
    case = ET.Element("testcase", classname=classname, name=name, time="0")
    err = ET.SubElement(case, "error", type=kind, message=_text(message))
    err.text = _text(message)
    return case


def _skipped_case(classname: str, name: str, message: str) -> ET.Element:
    """A testcase the bench could not measure: untested, never passed."""
    case = ET.Element("testcase", classname=classname, name=name, time="0")
    ET.SubElement(case, "skipped", message=_text(message)).text = _text(message)
    return case


def _run_properties(record: RunRecord, props: ET.Element) -> None:
    """Add the run's properties to ``props``: what was tested (the target's kind, the unit under
    test) and the CI job."""
    env = record.environment
    pairs = [("target_kind", env.kind), *((f"dut.{k}", v) for k, v in env.dut.items()),
             *((f"ci.{k}", v) for k, v in (env.ci.items() if env.ci is not None else ()))]
    for key, value in pairs:
        ET.SubElement(props, "property", name=_text(key), value=_text(value))


def _head(name: str, record: RunRecord, wall_s: float | None,
          own: tuple[tuple[str, str], ...] = ()) -> ET.Element:
    """A ``<testsuite>`` head: ``wall_s`` as its time, its ``own`` properties, the run's."""
    el = ET.Element("testsuite", name=_text(name), time=_seconds(wall_s or 0.0))
    props = ET.SubElement(el, "properties")
    for key, value in own:
        ET.SubElement(props, "property", name=key, value=_text(value))
    _run_properties(record, props)
    return el


def _suite_head(record: RunRecord, suite: SuiteRecord) -> ET.Element:
    """The ``<testsuite>`` element of ``suite`` with its properties and time, no testcases."""
    robot_s = 0.0 if suite.ended_s is None else suite.ended_s - suite.started_s
    own = [("run_id", record.run_id), ("suite_version", suite.version),
           ("status", suite.status), ("robot_time_s", _seconds(robot_s))]
    disturbed = [str(t.index) for t in suite.trials if t.disturbed]
    if disturbed:  # measured while the link to the arm was lost at least once: kept, flagged
        own.append(("disturbed_trials", ", ".join(disturbed)))
    return _head(suite.name, record, suite.wall_s, tuple(own))


def _campaign(suite: SuiteRecord) -> bool:
    return CAMPAIGN_KEY in suite.params


def _unjudged_properties(suite: SuiteRecord) -> Iterator[ET.Element]:
    """A ``<property>`` per unjudged measurement of ``suite``, one at a time."""
    for trial in () if _campaign(suite) else suite.trials:
        for m in trial.measurements:
            if m.outcome == "unjudged":
                yield ET.Element("property", name=_text(f"trial{trial.index}.{m.name}"),
                                 value=_text(_value(m)))
    for m in suite.measurements:
        if m.outcome == "unjudged":
            yield ET.Element("property", name=_text(m.name), value=_text(_value(m)))


def _trial_cases(suite: SuiteRecord, trial: Trial) -> Iterator[ET.Element]:
    """The testcases of one trial: its error or why it measured nothing, its judged
    measurements."""
    cls = f"armbench.{suite.name}.trial{trial.index}"
    if trial.status == "error":
        yield _error_case(cls, "trial", "trial_error",
                          f"trial {trial.index} could not be carried out: {trial.error}")
    elif trial.skipped is not None:
        yield _skipped_case(cls, "trial", f"untested: {trial.skipped}")
    for m in () if _campaign(suite) else trial.measurements:
        if m.outcome != "unjudged":
            yield _measurement_case(cls, m)


def _suite_cases(suite: SuiteRecord) -> Iterator[ET.Element]:
    """The testcases of ``suite``, one at a time (a long run has hundreds of thousands); the
    first of each trial's carries the trial's wall-clock time."""
    base = f"armbench.{suite.name}"
    for trial in suite.trials:
        cases = _trial_cases(suite, trial)
        first = next(cases, None)
        if first is None:
            continue
        first.set("time", _seconds(trial.wall_s or 0.0))
        yield first
        yield from cases
    for m in suite.measurements:
        if m.outcome != "unjudged":
            yield _measurement_case(base, m)
    if suite.status == "error":
        yield _error_case(base, "suite", "suite_error",
                          f"suite {suite.name} stopped: {suite.error}")
    elif suite.status == "running":
        yield _error_case(base, "suite", "incomplete",
                          f"suite {suite.name} did not finish (the run was interrupted)")
    elif (reason := suite.untested_reason()) is not None:
        yield _skipped_case(base, "suite", f"suite {suite.name} untested: {reason}")


def _row_case(row: ComparisonRow) -> ET.Element:
    case = ET.Element("testcase", classname="armbench.baseline", name=_text(row.name), time="0")
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
    return case


def _baseline_head(record: RunRecord) -> ET.Element:
    assert record.baseline is not None
    return _head("baseline", record, None,
                 (("baseline_run_id", record.baseline.baseline_run_id),))


#: A testsuite head, a function that yields its testcases and one that yields the properties it
#: has besides those of the head (the unjudged measurements).
_Suite = tuple[ET.Element, Callable[[], Iterator[ET.Element]],
               Callable[[], Iterator[ET.Element]]]


def _none() -> Iterator[ET.Element]:
    return iter(())


def _suites(record: RunRecord) -> Iterator[_Suite]:
    """Each ``<testsuite>`` head of ``record`` with a function that yields its testcases afresh
    (called once to count them, once to write them: nothing of a long run is held whole)."""
    for suite in record.suites.values():
        yield (_suite_head(record, suite), functools.partial(_suite_cases, suite),
               functools.partial(_unjudged_properties, suite))
    for name in record.planned_suites:
        if name not in record.suites:
            el = _head(name, record, None)
            case = _error_case(f"armbench.{name}", "suite", "incomplete",
                               f"suite {name} was planned but never started")
            yield el, functools.partial(iter, (case,)), _none
    missing = [(name, why) for name, why, _ in record.untested() if name not in record.suites]
    if missing:
        cases = [_skipped_case("armbench.required", name, f"required {name}: {why}")
                 for name, why in missing]
        yield (_head("required", record, None),
               functools.partial(iter, cases), _none)
    baseline = record.baseline
    if baseline is not None:
        yield (_baseline_head(record), lambda: (_row_case(row) for row in baseline.rows),
               _none)


def _count(head: ET.Element, cases: Iterator[ET.Element]) -> None:
    """Set the ``tests``/``failures``/``errors``/``skipped`` attributes of a testsuite head."""
    counts = dict.fromkeys(("tests", "failures", "errors", "skipped"), 0)
    for case in cases:
        counts["tests"] += 1
        for tag, attr in (("failure", "failures"), ("error", "errors"), ("skipped", "skipped")):
            counts[attr] += case.find(tag) is not None
    for attr, value in counts.items():
        head.set(attr, str(value))


def _counted(record: RunRecord) -> tuple[ET.Element, list[_Suite]]:
    """The ``<testsuites>`` root (attributes only) and the counted suite heads of ``record``."""
    root = ET.Element("testsuites", name=_text(f"armbench {record.run_id}"))
    suites = list(_suites(record))
    for head, cases, _ in suites:
        _count(head, cases())
    for attr in ("tests", "failures", "errors", "skipped"):
        root.set(attr, str(sum(int(head.get(attr, "0")) for head, _, _ in suites)))
    root.set("time", _seconds(sum(float(head.get("time", "0")) for head, _, _ in suites)))
    return root, suites


def to_junit(record: RunRecord) -> ET.Element:
    """The ``<testsuites>`` element of ``record`` as one tree (see the module docstring for the
    layout); :func:`write_junit` writes the same document without building it whole."""
    root, suites = _counted(record)
    for head, cases, properties in suites:
        props = head.find("properties")
        extra = list(properties())
        if extra:
            if props is None:
                props = ET.Element("properties")
                head.insert(0, props)
            props.extend(extra)
        head.extend(cases())
        root.append(head)
    return root


def _open_tag(el: ET.Element) -> bytes:
    """``<tag attr="...">`` of ``el``, without its children or end tag."""
    whole: bytes = ET.tostring(ET.Element(el.tag, el.attrib), encoding="utf-8",
                               short_empty_elements=False)
    return whole[: whole.rindex(b"</")]


def _indented(el: ET.Element, level: int) -> bytes:
    """``el`` serialised on its own lines, indented as ``ET.indent`` would at depth ``level``."""
    ET.indent(el, level=level)
    text: bytes = ET.tostring(el, encoding="utf-8")
    return b"  " * level + text + b"\n"


def _stream(record: RunRecord, fh: BinaryIO) -> None:
    root, suites = _counted(record)
    fh.write(b"<?xml version='1.0' encoding='utf-8'?>\n" + _open_tag(root) + b"\n")
    for head, cases, properties in suites:
        fh.write(b"  " + _open_tag(head) + b"\n")
        extra = properties()
        first = next(extra, None)
        if first is not None and head.find("properties") is None:
            head.insert(0, ET.Element("properties"))
        for child in head:
            if child.tag != "properties" or first is None:
                fh.write(_indented(child, 2))
                continue
            fh.write(b"    " + _open_tag(child) + b"\n")
            for prop in child:
                fh.write(_indented(prop, 3))
            for prop in itertools.chain((first,), extra):
                fh.write(_indented(prop, 3))
            fh.write(b"    </properties>\n")
        for case in cases():
            fh.write(_indented(case, 2))
        fh.write(b"  </testsuite>\n")
    fh.write(b"</testsuites>\n")


def write_junit(record: RunRecord, path: str | Path) -> Path:
    """Write the JUnit XML of ``record`` to ``path`` atomically (UTF-8, with XML declaration),
    testcase by testcase, so its memory is one testcase's whatever the run's length; returns the
    path."""
    atomic_write(path, functools.partial(_stream, record))
    return Path(path)
