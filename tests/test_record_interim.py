"""An interrupted suite's figures come from the record layer, not from the report: the interim
AP and RP of every pose are those the suite itself records at its end, and the report shows
them marked as interim."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from armbench.bench.suites.repeatability_contract import REPEATABILITY as R
from armbench.record import SuiteRecord, validate_record
from armbench.record.interim import interim_pose_figures, pose_samples
from armbench.reports import render_report  # type: ignore[attr-defined, unused-ignore]

RECORDS = Path(__file__).parent / "fixtures" / "records"


def _pose_names(suite: SuiteRecord) -> dict[str, tuple[float, str, str]]:
    """Every AP and RP measurement name of the suite's poses: (speed, pose, figure)."""
    return {R.pose_metric(speed, pose, figure): (speed, pose, figure)
            for speed, pose in pose_samples(suite).attained for figure in (R.ap, R.rp)}


def _cut_summary(data: dict[str, Any], names: set[str]) -> dict[str, Any]:
    """The record as a run interrupted before the suite's summary: its pose figures gone."""
    suite = data["suites"][R.suite]
    suite["measurements"] = [m for m in suite["measurements"] if m["name"] not in names]
    return data


def test_interim_figures_are_the_suites_own() -> None:
    data = json.loads((RECORDS / "passing.json").read_text(encoding="utf-8"))
    whole = validate_record(data).suites[R.suite]
    names = _pose_names(whole)
    recorded = {m.name: m.value for m in whole.measurements if m.name in names}
    assert recorded and interim_pose_figures(whole) == {}  # a finished suite: nothing interim
    cut = validate_record(_cut_summary(data, set(names))).suites[R.suite]
    interim = interim_pose_figures(cut)
    got = {}
    for name, (speed, pose, figure) in names.items():
        late = interim[(speed, pose)]
        got[name] = late.ap_mm if figure == R.ap else late.rp_mm
    assert got == pytest.approx(recorded, rel=1e-9, abs=1e-9)


def test_the_report_shows_interim_figures_marked(tmp_path: Path) -> None:
    data = json.loads((RECORDS / "passing.json").read_text(encoding="utf-8"))
    names = set(_pose_names(validate_record(data).suites[R.suite]))
    out = render_report(validate_record(_cut_summary(data, names)), tmp_path / "report.html")
    text = out.read_text(encoding="utf-8")
    assert "interim: the suite was interrupted before its summary" in text
    assert "†" in text
