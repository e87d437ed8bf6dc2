"""The report of real runs: every registered suite run on ``fake://`` through the real runner
(``armbench run``'s own code path: the runner, then the reports the run command writes), then
read as a user would: each suite in its own section, every column the suite fills filled,
figures at the measurement's resolution; and in headless Chromium at 1 280 × 800 the verdict,
the scorecard and a plot on the first screen, no sideways scroll, no console message; the same
for the run index and the comparison page. Nothing here is mocked: the emulator stands in for
the arm (that is what ``fake://`` is)."""

from __future__ import annotations

import io
import os
import re
from pathlib import Path
from typing import Any

import pytest
from chromium import CHROMIUM, Chromium
from test_report import Node, cells, parse

from armbench.bench.runner import RunOptions, run_sync
from armbench.bench.suites import suite_names
from armbench.bench.suites.accuracy_contract import ACCURACY
from armbench.bench.suites.repeatability_contract import REPEATABILITY
from armbench.bench.suites.startup_contract import STARTUP
from armbench.cli import main as cli
from armbench.cli.commands.run_files import write_reports
from armbench.record import RunRecord, load_record
from armbench.reports import render_index

ARTIFACTS = Path(__file__).resolve().parents[1] / "test-artifacts"
#: The default run's page must stay below this (bytes).
MAX_REPORT_BYTES = 1_500_000
#: Text that only a renderer reading other names than the suites write would print.
WRONG_NAMES = ("other modes", "0 run(s)", "mode=", "startup.recovery_rate_pct")

needs_chromium = pytest.mark.skipif(
    CHROMIUM is None or not hasattr(os, "posix_spawn"),
    reason="headless Chromium not installed (apt-get install chromium)")


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The default run (every suite, default limits, seed 0) in ``a`` and an accuracy run
    against it as baseline in ``b``."""
    root = tmp_path_factory.mktemp("runs")
    a = run_sync(RunOptions(out=root / "a", seed=0), progress=io.StringIO())
    assert a.record.suites and set(a.record.suites) == set(suite_names())
    write_reports(a.record, a.out_dir)  # as the run command does once the runner returned
    b = run_sync(RunOptions(suites=[ACCURACY.suite], out=root / "b", seed=1,
                            baseline=root / "a" / "results.json"), progress=io.StringIO())
    write_reports(b.record, b.out_dir)
    return root


def _table(section: Node, header: str) -> list[list[str]]:
    """The rows of the first table in ``section`` whose header row starts with ``header``."""
    for table in section.iter("table"):
        rows = [cells(r) for r in table.iter("tr")]
        if rows and rows[0] and rows[0][0] == header:
            return rows
    raise AssertionError(f"no table headed {header!r}")


def _filled(rows: list[list[str]], columns: list[str], where: str) -> None:
    header, body = rows[0], rows[1:]
    assert body, where
    for name in columns:
        k = header.index(name)
        empty = [r for r in body if r[k] in ("", "-")]
        assert not empty, (where, name, empty[:3])


def test_each_suite_gets_its_own_section(runs: Path) -> None:
    record: RunRecord = load_record(runs / "a" / "results.json")
    page = runs / "a" / "report.html"
    html = page.read_text(encoding="utf-8")
    assert len(html.encode()) <= MAX_REPORT_BYTES
    doc = parse(html)
    text = doc.text()
    for wrong in WRONG_NAMES:
        assert wrong not in text
    assert not re.search(r"\d\.?\d*e[-+]\d", " ".join(
        c for t in doc.iter("table") for r in t.iter("tr") for c in cells(r)))
    for name in record.suites:
        section = doc.by_id(name)
        assert section is not None and section.tag == "section", name
        assert list(section.iter("svg")), f"{name}: its section leads with its plots"
        assert "Suite " not in next(section.iter("h2")).text()  # not the generic section

    acc = doc.by_id(ACCURACY.suite)
    assert acc is not None
    _filled(_table(acc, "trial"), ["style", "lap", "samples", "lap time", "mean", "RMS", "max",
                                   "reported − true", "true path mean"], "accuracy laps")
    paper = _table(acc, "source")
    assert paper[1][:2] == ["paper §7 (Fig. 12)", "12.4 mm"]
    assert [r for r in paper if "paper-style" in r[0] and "true position" in r[0]]
    rep = doc.by_id(REPEATABILITY.suite)
    assert rep is not None
    _filled(_table(rep, "speed"), ["pose cycles", "mean cycle time", "worst AP", "worst RP",
                                   "worst RP, true", "RD (P2-P4)", "path AT"],
            "repeatability per speed")
    assert "the true RP is the arm's repeatability" in rep.text()
    per_pose = _table(rep, "pose")
    assert per_pose[1][:3] == ["AP", "RP", "RP, true"]
    poses = [r for r in per_pose[2:] if r and r[0].startswith("P")]
    assert len(poses) == 5
    for row in poses:  # pose, commanded, then AP / RP / RP true per speed
        true_rp = row[4::3]
        assert len(true_rp) == 3 and all(float(v) > 0.0 for v in true_rp), row
    st = doc.by_id(STARTUP.suite)
    assert st is not None
    cuts = _table(st, "trial")
    _filled(cuts, ["condition", "joints", "outcome", "EEPROM writes"], "startup-recovery cuts")
    # a cut the arm came back from has every figure; one it never replied after has none
    recovered = [cuts[0], *(r for r in cuts[1:] if "✔ recovered" in r)]
    assert len(recovered) > 1
    _filled(recovered, ["recovery time", "first reply", "position error"], "recovered cuts")
    assert "recovered where §5.2 can" in st.text() and "projected life" in st.text()

    card = doc.by_id("scorecard")
    assert card is not None
    for name in record.suites:
        assert name in card.text()
    values = [c[1] for c in (cells(r) for r in card.iter("tr")) if len(c) > 2 and c[0] != "figure"]
    assert len(values) >= 3 * len(record.suites) and "-" not in values
    assert "12.4 mm" in card.text()  # the paper's figure beside the square's


def _first_screen(browser: Chromium, page: Path, shot: str, *,
                  answer: bool = True) -> dict[str, Any]:
    browser.load(page.as_uri(), 1280, 800)
    facts = browser.probe()
    assert facts["innerHeight"] == 800
    if answer:
        verdict, scorecard = facts["first"]
        assert verdict is not None and verdict[1] <= 800, facts["first"]
        assert scorecard is not None and scorecard[0] < 800 and scorecard[1] <= 800, facts
    assert facts["firstSvg"] is not None and facts["firstSvg"][1] <= 800, facts["firstSvg"]
    assert facts["scrollWidth"] <= facts["innerWidth"]
    assert facts["scripts"] == 0
    ARTIFACTS.mkdir(exist_ok=True)
    browser.screenshot(ARTIFACTS / shot, max_height=800)
    assert browser.problems() == []
    assert browser.requests() == [page.as_uri()]
    return facts


@needs_chromium
def test_answers_first_in_chromium(runs: Path, tmp_path: Path,
                                   monkeypatch: pytest.MonkeyPatch) -> None:
    chrome = Chromium(tmp_path)
    try:
        chrome.open_page()
        _first_screen(chrome, runs / "a" / "report.html", "real-report-first-screen.png")
        _first_screen(chrome, runs / "b" / "report.html", "real-report-baseline.png")
        index = render_index(runs)
        _first_screen(chrome, index, "real-index-first-screen.png", answer=False)
        out = tmp_path / "compare.html"
        assert cli.main(["compare", str(runs / "a"), str(runs / "b"), "--html", str(out)]) in (0, 3)
        facts = _first_screen(chrome, out, "real-compare-first-screen.png")
        assert len(facts["svgs"]) >= 2  # the overlaid paths and the headline bars
        html = out.read_text(encoding="utf-8")
        assert "accuracy.coordinated.mean_mm" in html and "Both runs" in html
    finally:
        chrome.close()
