"""The JUnit shape the docs describe is the shape ``junit.xml`` has: each sentence of
``docs/record.md`` and ``docs/ci.md`` quoted here must still be in its page, and the file written
for the example records must do what it says. No page may call an unjudged measurement a
skipped test (they once disagreed: ``<skipped>`` in one page, ``<property>`` in the other and in
the output)."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

from armbench.record import RunRecord, load_record
from armbench.reports.files.junit import to_junit

ROOT = Path(__file__).resolve().parents[1]
RECORDS = ROOT / "tests" / "fixtures" / "records"


def _page(name: str) -> str:
    """A docs page with its line breaks and indentation folded into single spaces."""
    return " ".join((ROOT / "docs" / name).read_text(encoding="utf-8").split())


def _junit(name: str) -> tuple[RunRecord, ET.Element]:
    record = load_record(RECORDS / f"{name}.json")
    return record, to_junit(record)


def _cases(root: ET.Element) -> list[ET.Element]:
    return list(root.iter("testcase"))


def test_unjudged_measurements_are_properties_never_skipped_tests() -> None:
    assert ("An unjudged measurement (no limit) is no test: it is a `<property>` of its "
            "testsuite (`name` the metric, or `trial<index>.<metric>`)") in _page("record.md")
    assert ("unjudged measurements are `<property>` entries of their testsuite, never skipped "
            "tests") in _page("ci.md")
    record, root = _junit("passing")
    unjudged = [(s.name, t, m) for s, t, m in record.iter_measurements()
                if m.outcome == "unjudged"]
    assert unjudged
    for suite, trial, m in unjudged:
        element = root.find(f"testsuite[@name='{suite}']")
        assert element is not None
        name = m.name if trial is None else f"trial{trial.index}.{m.name}"
        (prop,) = [p for p in element.iter("property") if p.get("name") == name]
        assert prop.get("value") == f"{m.value:g} {m.unit}".rstrip()
    judged = {m.name for _, _, m in record.iter_measurements() if m.outcome != "unjudged"}
    assert {c.get("name") for c in _cases(root)} <= judged | {"trial", "suite"}
    assert not any(c.find("skipped") is not None for c in _cases(root))


def test_no_page_calls_an_unjudged_measurement_skipped() -> None:
    for page in sorted((ROOT / "docs").glob("*.md")):
        for sentence in re.split(r"(?<=[.;])\s", _page(page.name)):
            if "unjudged" in sentence and "<skipped" in sentence:
                assert "never skipped" in sentence or "no test" in sentence, (page.name,
                                                                              sentence)


def test_judged_measurements_are_testcases_a_failure_carries_value_and_limit() -> None:
    page = _page("record.md")
    assert ('one `<testcase>` per judged measurement: `classname="armbench.<suite>"` for '
            'suite-level, `"armbench.<suite>.trial<index>"` for trial-level, `name` = the '
            'metric; failed measurements carry `<failure type="limit" message="<name> = '
            '<value> <unit> outside limit <= 5 mm">`') in page
    record, root = _junit("failing")
    for suite, trial, m in record.iter_measurements():
        if m.outcome == "unjudged":
            continue
        classname = f"armbench.{suite.name}" + ("" if trial is None else f".trial{trial.index}")
        (case,) = [c for c in _cases(root)
                   if c.get("classname") == classname and c.get("name") == m.name]
        failure = case.find("failure")
        assert (failure is not None) == (m.outcome == "fail"), m.name
        if failure is not None:
            assert m.limit is not None and failure.get("type") == "limit"
            assert failure.get("message", "").startswith(
                f"{m.name} = {m.value:g} {m.unit} outside limit {m.limit.describe()}")


def test_suite_properties_errors_and_the_baseline_testsuite() -> None:
    page = _page("record.md")
    assert ("writes one `<testsuite>` per suite with properties `run_id`, `suite_version`, "
            "`status`, `robot_time_s`") in page
    assert '`<testcase name="trial">` with `<error type="trial_error">` per errored trial' in page
    assert ('a `baseline` testsuite with one testcase per comparison row, `<failure '
            'type="regression">` on regressed ones') in page
    record, root = _junit("interrupted")
    for suite in record.suites.values():
        element = root.find(f"testsuite[@name='{suite.name}']")
        assert element is not None
        names = {p.get("name") for p in element.iter("property")}
        assert {"run_id", "suite_version", "status", "robot_time_s"} <= names
        errored = [t.index for t in suite.trials if t.status == "error"]
        cases = [c for c in element.findall("testcase") if c.get("name") == "trial"
                 and (e := c.find("error")) is not None and e.get("type") == "trial_error"]
        assert len(cases) == len(errored)
    record, root = _junit("regressed")
    assert record.baseline is not None
    baseline = root.find("testsuite[@name='baseline']")
    assert baseline is not None
    assert len(baseline.findall("testcase")) == len(record.baseline.rows)
    regressed = {c.get("name") for c in baseline.findall("testcase")
                 if (f := c.find("failure")) is not None and f.get("type") == "regression"}
    assert regressed == {r.name for r in record.baseline.regressions} != set()
