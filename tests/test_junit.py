"""armbench.reports.files.junit: the XML parses back, failures/errors/skips land where CI expects
them."""

from __future__ import annotations

import asyncio
import time
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest
from test_runner import CONFIG, TinySuite

from armbench.bench.runner import RunOptions, run_bench
from armbench.bench.suites import SUITES, SuiteContext
from armbench.fakes.clock.vclock import run_virtual
from armbench.record import (
    Environment,
    RecordWriter,
    RunRecord,
    Trial,
    judge,
    load_record,
)
from armbench.record.limits import SPEC_VERSION, parse_limits
from armbench.reports.files.junit import to_junit, write_junit

RECORDS = Path(__file__).parent / "fixtures" / "records"


def _write(tmp_path: Path, name: str) -> ET.Element:
    path = write_junit(load_record(RECORDS / f"{name}.json"), tmp_path / "junit.xml")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["junit.xml"]   # atomic, no leftovers
    assert path.read_bytes().startswith(b"<?xml version='1.0' encoding='utf-8'?>")
    return ET.parse(path).getroot()


def _suite(root: ET.Element, name: str) -> ET.Element:
    found = root.find(f"testsuite[@name='{name}']")
    assert found is not None, name
    return found


def _check_counts(root: ET.Element) -> None:
    totals = dict.fromkeys(("tests", "failures", "errors", "skipped"), 0)
    for suite in root.findall("testsuite"):
        cases = suite.findall("testcase")
        counts = {"tests": len(cases),
                  "failures": sum(c.find("failure") is not None for c in cases),
                  "errors": sum(c.find("error") is not None for c in cases),
                  "skipped": sum(c.find("skipped") is not None for c in cases)}
        for key, value in counts.items():
            assert suite.get(key) == str(value), (suite.get("name"), key)
            totals[key] += value
    for key, value in totals.items():
        assert root.get(key) == str(value)


def test_passing_record(tmp_path: Path) -> None:
    root = _write(tmp_path, "passing")
    record = load_record(RECORDS / "passing.json")
    assert root.tag == "testsuites"
    assert [s.get("name") for s in root.findall("testsuite")] == list(record.suites)
    _check_counts(root)
    assert root.get("failures") == "0" and root.get("errors") == "0"
    judged = sum(m.outcome != "unjudged" for _, _, m in record.iter_measurements())
    assert root.get("tests") == str(judged)
    # a figure without a limit is recorded, not tested: a property, never a skipped test
    assert root.get("skipped") == "0"
    acc = _suite(root, "accuracy")
    # a record written before wall time was kept: no time to give, and never the robot's
    suite = record.suites["accuracy"]
    assert suite.wall_s is None and acc.get("time") == "0.000"
    assert suite.ended_s is not None
    robot_s = f"{suite.ended_s - suite.started_s:.3f}"
    props = {p.get("name"): p.get("value") for p in acc.iter("property")}
    unjudged = {(f"trial{t.index}." if t is not None else "") + m.name: f"{m.value:g} {m.unit}"
                for s, t, m in record.iter_measurements()
                if s.name == "accuracy" and m.outcome == "unjudged"}
    assert unjudged
    assert props == {"run_id": record.run_id, "suite_version": "1", "status": "done",
                     "robot_time_s": robot_s, "target_kind": "serial",
                     **{k: v.rstrip() for k, v in unjudged.items()}}
    suite_level = acc.find("testcase[@classname='armbench.accuracy']"
                           "[@name='accuracy.coordinated.mean_mm']")
    assert suite_level is not None
    out = suite_level.findtext("system-out") or ""
    assert "pass" in out and "<= 5 mm" in out
    assert acc.find("testcase[@classname='armbench.accuracy.trial3']") is not None


def test_failed_measurements_carry_value_and_limit(tmp_path: Path) -> None:
    root = _write(tmp_path, "failing")
    _check_counts(root)
    failures = {(c.get("classname"), c.get("name")): c.find("failure")
                for c in root.iter("testcase") if c.find("failure") is not None}
    coord = failures[("armbench.accuracy", "accuracy.coordinated.mean_mm")]
    assert coord is not None and coord.get("type") == "limit"
    message = coord.get("message", "")
    assert "outside limit <= 5 mm" in message and " mm" in message
    record = load_record(RECORDS / "failing.json")
    value = record.suite_measurements()["accuracy.coordinated.mean_mm"].value
    assert f"{value:g} mm" in message
    assert ("armbench.startup-recovery.trial3", "startup.recovered") in failures
    assert ("armbench.startup-recovery.trial3", "startup.position_error_mrad") in failures
    limit_failures = {k for k, f in failures.items() if f is not None and f.get("type") == "limit"}
    expected = {(f"armbench.{s.name}" + ("" if t is None else f".trial{t.index}"), m.name)
                for s, t, m in record.iter_measurements() if m.outcome == "fail"}
    assert limit_failures == expected
    # The baseline testsuite flags the regressions of the comparison.
    base = _suite(root, "baseline")
    regressed = {c.get("name") for c in base.findall("testcase") if c.find("failure") is not None}
    assert record.baseline is not None
    assert regressed == {r.name for r in record.baseline.regressions}


def test_errored_trials_and_unstarted_suites(tmp_path: Path) -> None:
    root = _write(tmp_path, "interrupted")
    _check_counts(root)
    startup = _suite(root, "startup-recovery")
    errors = {(c.get("classname"), c.get("name")): c.find("error")
              for c in startup.findall("testcase") if c.find("error") is not None}
    trial = errors[("armbench.startup-recovery.trial2", "trial")]
    assert trial is not None and "PortLostError" in trial.get("message", "")
    suite = errors[("armbench.startup-recovery", "suite")]
    assert suite is not None and suite.get("type") == "suite_error"
    never = _suite(root, "repeatability")
    case = never.find("testcase/error")
    assert case is not None and case.get("type") == "incomplete"
    assert "never started" in case.get("message", "")


def test_interrupted_suite_and_illegal_characters(tmp_path: Path) -> None:
    env = Environment(armbench_version="0", git_revision="x", python="3", platform="p",
                      port=None, settings={}, seed=None, faults=(), limits_spec_version=None,
                      config_path=None)
    cfg = parse_limits({"spec_version": SPEC_VERSION,
                        "limits": {"m_mm": {"high": 1.0, "unit": "mm"}}})
    w = RecordWriter(tmp_path / "run", RunRecord(run_id="r<&>", created="c", environment=env,
                                                 planned_suites=["s"]))
    w.begin_suite("s", "1")
    w.add_trial("s", Trial(0, 0.0, 1.0, {}, [], [judge("m_mm", 2.0, "mm", cfg,
                                                       description="bad \x00\x1b byte")]))
    w.add_trial("s", Trial(1, 1.0, 1.0, {}, [], status="error",
                           error="garbage from the port: \x02\x15\xff"))
    root = ET.fromstring(ET.tostring(to_junit(w.record)))
    _check_counts(root)
    assert root.get("name") == "armbench r<&>"
    suite = _suite(root, "s")
    incomplete = suite.find("testcase[@name='suite']/error")
    assert incomplete is not None and incomplete.get("type") == "incomplete"
    err = suite.find("testcase[@name='trial']/error")
    assert err is not None and "\\x02\\x15\xff" in err.get("message", "")
    out = suite.findtext("testcase[@name='m_mm']/system-out") or ""
    assert "bad \\x00\\x1b byte" in out
    path = write_junit(w.record, tmp_path / "junit.xml")
    assert ET.parse(path).getroot().get("errors") == "2"


def test_streamed_file_is_the_tree_serialised(tmp_path: Path) -> None:
    """write_junit writes testcase by testcase; the document is the one to_junit builds whole."""
    for name in ("passing", "failing", "interrupted", "regressed"):
        record = load_record(RECORDS / f"{name}.json")
        tree = to_junit(record)
        ET.indent(tree)
        whole = ET.tostring(tree, encoding="utf-8", xml_declaration=True) + b"\n"
        assert write_junit(record, tmp_path / f"{name}.xml").read_bytes() == whole, name


# --------------------------------------------------------------------------------------------
# Wall-clock times of a real run


class SleepySuite(TinySuite):
    """``sleepy``: each trial of the tiny suite after 40 s of robot time waiting (on the
    virtual clock: a fraction of a second of wall time)."""

    name = "sleepy"

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        await asyncio.sleep(40.0)
        return await super().run_trial(ctx, index, trial_params)


def test_times_are_wall_clock_and_robot_time_a_property(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(SUITES, "sleepy", f"{__name__}:SleepySuite")
    config = tmp_path / "bench.toml"
    config.write_text(CONFIG.format(trials=2, move_high=60.0).replace("[suites.tiny]",
                                                                     "[suites.sleepy]"))
    wall0 = time.perf_counter()
    outcome = run_virtual(run_bench(RunOptions(suites=["sleepy"], config=config,
                                               out=tmp_path / "run", workers=1)))
    wall_s = time.perf_counter() - wall0
    assert outcome.exit_status == 0
    record = load_record(tmp_path / "run" / "results.json")
    suite = record.suites["sleepy"]
    assert suite.ended_s is not None and suite.wall_s is not None
    robot_s = suite.ended_s - suite.started_s
    assert robot_s > 80.0 > wall_s  # 40 s of robot time per trial, fractions of it of wall time
    assert 0.0 < suite.wall_s <= wall_s
    assert all(t.wall_s is not None and 0.0 < t.wall_s <= suite.wall_s for t in suite.trials)
    root = ET.parse(write_junit(record, tmp_path / "junit.xml")).getroot()
    head = _suite(root, "sleepy")
    assert head.get("time") == f"{suite.wall_s:.3f}"
    props = {p.get("name"): p.get("value") for p in head.iter("property")}
    assert props["robot_time_s"] == f"{robot_s:.3f}"
    for trial in suite.trials:  # the trial's wall time on its first testcase, none on the rest
        cases = head.findall(f"testcase[@classname='armbench.sleepy.trial{trial.index}']")
        assert [c.get("time") for c in cases] == [f"{trial.wall_s:.3f}"] + ["0"] * (
            len(cases) - 1)
    assert float(root.get("time", "")) == pytest.approx(suite.wall_s, abs=2e-3)
