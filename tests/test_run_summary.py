"""``armbench run --summary``: the Markdown summary says what the record says, briefly."""

from __future__ import annotations

from pathlib import Path

from armbench.record import load_record
from armbench.reports.files.run_summary import MAX_LINES, append_summary, markdown_summary

RECORDS = Path(__file__).parent / "fixtures" / "records"


def test_each_verdict_with_its_reasons(tmp_path: Path) -> None:
    passing = markdown_summary(load_record(RECORDS / "passing.json"))
    assert "PASS (exit 0)" in passing and "outside its limit" not in passing
    failing = load_record(RECORDS / "failing.json")
    text = markdown_summary(failing, report="runs/x/report.html")
    failed = [m for _, _, m in failing.iter_measurements() if m.outcome == "fail"]
    assert "FAIL (exit 1)" in text and failed and failed[0].name in text
    assert "Full report: `runs/x/report.html`" in text
    regressed = markdown_summary(load_record(RECORDS / "regressed.json"))
    assert "| regressed | baseline | value | tolerance |" in regressed
    interrupted = markdown_summary(load_record(RECORDS / "interrupted.json"))
    assert "(exit 4)" in interrupted


def test_long_lists_are_cut_and_the_file_is_appended_to(tmp_path: Path) -> None:
    record = load_record(RECORDS / "failing.json")
    suite, _, bad = next(x for x in record.iter_measurements() if x[2].outcome == "fail")
    trial = suite.trials[0]
    for _ in range(MAX_LINES + 5):  # many failed trials: the table stays short
        suite.trials.append(type(trial)(len(suite.trials), 0.0, 0.0, measurements=[bad]))
    text = markdown_summary(record)
    assert "more measurements" in text
    rows = [x for x in text.splitlines() if x.startswith("| ") and bad.name in x
            and "(trial" in x]
    assert len(rows) == MAX_LINES
    path = tmp_path / "step.md"
    path.write_text("earlier step\n")
    append_summary(path, text)
    assert path.read_text().startswith("earlier step\n") and path.read_text().endswith(text)
