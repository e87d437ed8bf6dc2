"""``armbench twin-check --out DIR``: the check as a run record (results.json read back by the
record package, report.html with the overlay, junit.xml), the CI gate's exit statuses, bad input
writing nothing; and the min/max envelope that keeps the record's series bounded. The emulator
stands in for the arm (its capture is the arm's traffic); everything else is the real command,
run in this process (its status is the one ``python -m armbench`` exits with)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import cli
from hypothesis import given, settings
from hypothesis import strategies as st
from test_report import cells, check_safe, parse
from test_twin_check import _lap

from armbench.bench.suites.twin_check_contract import TWIN_CHECK
from armbench.bench.twin_check.twin_record import SERIES_BUCKETS, file_sha256
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.clock.vclock import run_virtual
from armbench.metrics.series import envelope_indices
from armbench.record import load_record
from armbench.record.suite_contract import SAMPLE

N = TWIN_CHECK


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("twin-record") / "capture.jsonl"
    run_virtual(_lap("fake://", path))
    return path


def _series(samples: list[Mapping[str, Any]], joint: int) -> list[Mapping[str, Any]]:
    return [s for s in samples if s[SAMPLE.kind] == N.series_kind and s[N.joint] == joint]


def test_same_arm_record_and_rerender(capture: Path, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    """The arm's capture against its own twin: a record with RMS 0 and verdict pass, junit.xml
    without failures, and ``armbench report DIR`` renders it again."""
    out = tmp_path / "check"
    status, _, err = cli(capsys, "twin-check", str(capture), "--out", str(out))
    assert status == 0, err
    record = load_record(out / "results.json")
    assert record.verdict == "pass"
    assert list(record.suites) == [N.suite] and record.planned_suites == [N.suite]
    suite = record.suites[N.suite]
    ms = {m.name: m for m in suite.measurements}
    assert {*ms, *(m.name for t in suite.trials for m in t.measurements)} <= N.metric_names()
    for j in range(1, 5):
        assert ms[N.joint_metric(j, N.rms_counts)].value == 0.0
        assert ms[N.joint_metric(j, N.per_allowed)].outcome == "pass"
        assert ms[N.joint_metric(j, N.max_counts)].value == 0.0
    assert suite.params[N.capture_sha256] == file_sha256(capture)
    assert suite.params[N.settings] is None
    assert record.environment.port == "fake://"
    samples = list(suite.trials[0].samples)
    assert all(s[N.divergence] == 0.0 for s in samples if s[SAMPLE.kind] == N.series_kind)
    junit = ET.parse(out / "junit.xml").getroot()
    assert sum(int(s.get("failures", "0")) for s in junit.iter("testsuite")) == 0
    assert (out / "report.html").is_file()
    (out / "report.html").unlink()
    status, _, err = cli(capsys, "report", str(out))
    assert status == 0, err
    html = (out / "report.html").read_text(encoding="utf-8")
    doc = parse(html)
    check_safe(html, doc)
    section = doc.by_id(N.suite)
    assert section is not None
    assert "pass" in section.text().lower()


def test_other_twin_fails_with_the_overlay(capture: Path, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """A twin with a weaker joint 2 (pull-out torque 1.0 instead of 1.5 N·m): exit 1, a fail
    record whose numbers are the ones --json prints, whose kept series show the divergence (its
    peak kept exactly), and a report with the overlay figure and the per-joint table."""
    weak = tmp_path / "weak.toml"
    weak.write_text("[emulator.physics.j2]\npullout_nm = 1.0\n")
    out = tmp_path / "check"
    status, stdout, err = cli(capsys, "twin-check", str(capture), "--settings", str(weak),
                              "--out", str(out), "--json")
    assert status == 1, err
    body = json.loads(stdout)
    assert body["verdict"] == "fail"
    record = load_record(out / "results.json")
    assert record.verdict == "fail"
    suite = record.suites[N.suite]
    ms = {m.name: m for m in suite.measurements}
    assert {m["name"]: m["value"] for m in body["measurements"]} == {
        name: m.value for name, m in ms.items()}
    for j in range(4):
        assert ms[N.joint_metric(j + 1, N.rms_counts)].value == body["rms_counts"][j]
        assert ms[N.joint_metric(j + 1, N.max_rad)].value == body["max_rad"][j]
    assert ms[N.metric(N.replies)].value == body["replies_compared"]
    assert ms[N.metric(N.compared)].value == body["arrival"]["compared"]
    assert ms[N.joint_metric(2, N.per_allowed)].outcome == "fail"
    assert body["rms_counts"][1] > body["allowed_counts"][1]
    assert suite.params[N.settings] == str(weak)
    assert suite.params[N.settings_sha256] == file_sha256(weak)

    samples = list(suite.trials[0].samples)
    counts = RobotSettings().joints[1].counts_per_rad
    j2 = _series(samples, 2)
    assert len(j2) < body["replies_compared"]  # kept, not all
    assert len(j2) <= 6 * SERIES_BUCKETS + 2
    peak = max(abs(float(s[N.divergence])) for s in j2)
    assert peak == pytest.approx(body["max_counts"][1], abs=1e-3)
    for s in j2:
        arm, twin = float(s[N.arm]), float(s[N.twin])
        # both angles kept to 1 µrad (half of it each way), the twin's read off its trajectory
        assert float(s[N.divergence]) == pytest.approx((arm - twin) * counts,
                                                       abs=counts * 1e-6 + 1e-3)
    times = [float(s[SAMPLE.t]) for s in j2]
    assert times == sorted(times)
    assert all(s[N.divergence] == 0.0 for s in _series(samples, 1))

    junit = ET.parse(out / "junit.xml").getroot()
    failed = [c.get("name") for c in junit.iter("testcase") if c.find("failure") is not None]
    # joint 2 diverges while moving and where its moves settle; the others stay within
    assert failed == [N.joint_metric(2, N.per_allowed), N.joint_metric(2, N.settled_per_allowed),
                      N.joint_metric(2, N.worst_part_per_allowed)]

    html = (out / "report.html").read_text(encoding="utf-8")
    doc = parse(html)
    check_safe(html, doc)
    section = doc.by_id(N.suite)
    assert section is not None
    labels = [svg.attrs.get("aria-label") or "" for svg in section.iter("svg")]
    assert any(label.startswith("Arm against twin") for label in labels), labels
    assert f"{body['max_counts'][1]:.3g} counts on j2" in labels[0]
    table = next(t for t in section.iter("table") if "twin-joints" in t.classes())
    rows = {cells(r)[0]: cells(r) for r in table.iter("tr") if cells(r)[0] != "joint"}
    assert sorted(rows) == ["j1", "j2", "j3", "j4"]
    assert rows["j2"][1] == f"{body['rms_counts'][1]:.4g} counts"
    assert "FAIL" in rows["j2"][-1] and "pass" in rows["j1"][-1]
    arrivals = next(t for t in section.iter("table") if "twin-arrivals" in t.classes())
    assert ["commands replayed", str(body["arrival"]["moves"])] in [cells(r) for r in
                                                                   arrivals.iter("tr")]
    scorecard = doc.by_id("scorecard")
    assert scorecard is not None and "worst joint RMS divergence" in scorecard.text()


def test_bad_input_writes_nothing(capture: Path, tmp_path: Path,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    """A truncated capture exits 2 with --out and leaves no record; an --out that already holds
    a record exits 2 before the replay and leaves that record as it was."""
    lines = capture.read_text().splitlines()
    cut = tmp_path / "cut.jsonl"
    cut.write_text("\n".join(lines[:300]) + "\n" + lines[300][:20])
    out = tmp_path / "check"
    status, _, err = cli(capsys, "twin-check", str(cut), "--out", str(out))
    assert status == 2 and "truncated" in err
    assert not (out / "results.json").exists() and not (out / "junit.xml").exists()
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "results.json").write_text("{}")
    status, _, err = cli(capsys, "twin-check", str(capture), "--out", str(taken))
    assert status == 2 and "already holds a run record" in err
    assert (taken / "results.json").read_text() == "{}"


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=1, max_size=3000),
       st.integers(1, 50), st.integers(0, 2999))
def test_envelope_keeps_extremes(values: list[float], buckets: int, spike_at: int) -> None:
    """The kept rows are at most two per bucket and series plus the ends, ascending, and hold
    every series' extremes (a spike anywhere survives)."""
    y = np.asarray(values)
    y[spike_at % len(y)] = 1e4
    both = np.column_stack([y, -y[::-1]])
    idx = envelope_indices(both, buckets)
    assert list(idx) == sorted(set(idx.tolist()))
    assert idx[0] == 0 and idx[-1] == len(y) - 1
    assert len(idx) <= max(len(y) if len(y) <= 2 * buckets else 0, 4 * buckets + 2)
    for col in both.T:
        assert col[idx].max() == col.max() and col[idx].min() == col.min()
