"""A verdict is a claim (issue 37): the true figure is judged where the run knows it, what was not
measured is ``untested`` and never a pass, and the junit, the summary and the terminal say so.

Runs on ``fake://`` (virtual time) and against an emulator served over a real TCP socket
(``armbench emulate --tcp``, real time: only suites that move nothing there)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from conftest import cli
from far_end import emulator_maker

from armbench.record import load_record
from armbench.record.verdict import EXIT_FAIL, EXIT_PASS, EXIT_UNTESTED, load_config
from armbench.reports.render.scorecard import score_rows, suite_headlines

#: One coordinated lap: the accuracy suite's true and believed path figures, in seconds.
ONE_LAP = """spec_version = "armbench-limits/1"
[suites.accuracy]
laps = 1
styles = ["coordinated"]
"""


def _config(tmp_path: Path, extra: str = "") -> Path:
    """The packaged limits plus ``extra`` tables (replacing those of the same name), with the
    one-lap accuracy suite."""
    packaged = load_config(None)
    lines = [ONE_LAP]
    for name, lim in packaged.limits.items():
        if f'"{name}"' in extra or "paper" in name or "improvement" in name:
            continue  # a limit on a style the lap does not run would judge nothing: refused
        bounds = "".join(f"{k} = {v!r}\n" for k, v in (("low", lim.low), ("high", lim.high))
                         if v is not None)
        lines.append(f'[limits."{name}"]\n{bounds}unit = "{lim.unit}"\n')
    path = tmp_path / "bench.toml"
    path.write_text("\n".join(lines) + extra, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def lap(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One coordinated lap of the default emulated arm, judged by the packaged limits."""
    tmp = tmp_path_factory.mktemp("lap")
    status = _run(tmp, "accuracy", "--config", str(_config(tmp)), "--out", str(tmp / "run"))
    assert status == EXIT_PASS
    return tmp / "run"


def _run(tmp: Path, *args: str) -> int:
    import armbench.cli.main

    return armbench.cli.main.main(["run", *args, "--no-capture", "--workers", "1"])


def test_the_true_figure_is_judged_where_the_emulator_knows_it(lap: Path) -> None:
    """Seen: PASS with the true coordinated mean 3.3 mm against a 2 mm limit that only judged
    the firmware's 0.09 mm. The packaged limits judge the true figure too."""
    record = load_record(lap / "results.json")
    by_name = {m.name: m for m in record.suite_measurements().values()}
    true = by_name["accuracy.coordinated.true_mean_mm"]
    believed = by_name["accuracy.coordinated.mean_mm"]
    assert true.limit is not None and true.outcome == "pass"
    assert believed.limit is not None and believed.outcome == "pass"
    assert true.value > 10 * believed.value  # play and geometry no encoder sees
    assert record.environment.truth_source == "the emulator's ground truth"


def test_a_true_figure_over_its_limit_fails_the_run(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """The same lap with the true limit at the firmware's 2 mm: the run fails (exit 1) though
    every firmware figure is within its limits, and the terminal says which figure."""
    extra = '\n[limits."accuracy.coordinated.true_mean_mm"]\nhigh = 2.0\nunit = "mm"\n'
    status, out, _ = cli(capsys, "run", "accuracy", "--config", str(_config(tmp_path, extra)),
                         "--out", str(tmp_path / "run"), "--no-capture", "--workers", "1")
    assert status == EXIT_FAIL, out
    record = load_record(tmp_path / "run" / "results.json")
    assert record.verdict == "fail"
    failed = {m.name for _, _, m in record.iter_measurements() if m.outcome == "fail"}
    assert failed == {"accuracy.coordinated.true_mean_mm"}
    assert "FAIL   accuracy.coordinated.true_mean_mm" in out
    assert "truth judged" in out and " 0 outside" not in out


def test_the_scorecard_margin_is_of_the_figure_its_limit_judges(lap: Path) -> None:
    """Seen: the margin column printed ``+1.909 mm`` (the firmware's margin) beside 3.303 mm.
    A true figure's row reads its limits ``true · firmware``, and its margin is the tighter of
    the two, computed for the figure it names."""
    record = load_record(lap / "results.json")
    suite = record.suites["accuracy"]
    rows = {r.metric: r for r in score_rows(record, suite, suite_headlines("accuracy"), {})}
    row = rows["accuracy.coordinated.true_mean_mm"]
    measured = record.suite_measurements()
    true = measured["accuracy.coordinated.true_mean_mm"]
    believed = measured["accuracy.coordinated.mean_mm"]
    assert row.judges == "true+firmware"
    assert true.limit is not None and believed.limit is not None
    assert true.limit.high is not None and believed.limit.high is not None
    assert row.limit == f"≤ {true.limit.high:g} · {believed.limit.high:g} mm"
    true_margin = true.limit.high - true.value
    firmware_margin = believed.limit.high - believed.value
    shown, which = row.margin.rsplit(" ", 1)
    tighter = min(true_margin, firmware_margin)
    assert which == ("(true)" if tighter == true_margin else "(fw)")
    assert float(shown) == pytest.approx(tighter, abs=0.01)


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """An emulated arm served over a real TCP socket: no power switch, no ground truth."""
    tmp = tmp_path_factory.mktemp("served")
    with emulator_maker(tmp) as make:
        yield make("tcp")


def test_power_cuts_that_cut_nothing_are_untested(served, tmp_path: Path,  # type: ignore[no-untyped-def]
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    """Seen: startup-recovery over TCP with no power switch passed (exit 0) with every trial
    skipped. Now: untested, exit 5, in the record, the terminal, the summary and junit."""
    summary = tmp_path / "summary.md"
    status, out, _ = cli(capsys, "run", "startup-recovery", "--port", served.port, "--out",
                         str(tmp_path / "run"), "--no-capture", "--summary", str(summary))
    assert status == EXIT_UNTESTED, out
    record = load_record(tmp_path / "run" / "results.json")
    assert record.verdict == "untested"
    assert record.suite_verdict("startup-recovery") == "untested"
    assert record.environment.truth_source is None
    [(name, reason, required)] = record.untested()
    assert name == "startup-recovery" and required and "no power switch" in reason
    assert "startup-recovery: untested, every trial skipped: no power switch" in out
    assert "no reference instrument" in out
    text = summary.read_text(encoding="utf-8")
    assert "UNTESTED" in text.upper() and "no power switch" in text
    suites = {s.get("name"): s for s in ET.parse(tmp_path / "run" / "junit.xml").getroot()}
    junit = suites["startup-recovery"]
    assert int(junit.get("skipped", "0")) == len(record.suites["startup-recovery"].trials) + 1
    assert int(junit.get("failures", "0")) == int(junit.get("errors", "0")) == 0
    messages = [skipped.get("message", "") for case in junit.iter("testcase")
                if (skipped := case.find("skipped")) is not None]
    assert all(m.startswith(("untested: ", "suite startup-recovery untested: ")) for m in messages)
    assert sum("no power switch" in m for m in messages) == len(messages) - 1
    assert sum("EEPROM writes are not observable" in m for m in messages) == 2  # wear, suite


def test_an_optional_suite_may_go_untested(served, tmp_path: Path,  # type: ignore[no-untyped-def]
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """``--optional`` keeps the untested line but not the verdict: a lab that has no relay."""
    status, out, _ = cli(capsys, "run", "startup-recovery", "--optional", "startup-recovery",
                         "--port", served.port, "--out", str(tmp_path / "run"), "--no-capture")
    assert status == EXIT_PASS, out
    assert "untested" in out and "optional" in out
    record = load_record(tmp_path / "run" / "results.json")
    assert record.required == []


def test_a_required_true_figure_without_a_reference_is_untested(  # type: ignore[no-untyped-def]
        served, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A lab that needs the truth says so: with no reference instrument the run is untested,
    naming the figure, and the junit lists it as a skipped required test."""
    status, out, _ = cli(capsys, "run", "startup-recovery", "--optional", "startup-recovery",
                         "--require", "accuracy.*.true_mean_mm", "--port", served.port,
                         "--out", str(tmp_path / "run"), "--no-capture")
    assert status == EXIT_UNTESTED, out
    assert "accuracy.*.true_mean_mm: untested, not measured" in out
    root = ET.parse(tmp_path / "run" / "junit.xml").getroot()
    required = next(s for s in root if s.get("name") == "required")
    assert required.get("skipped") == "1"


def test_optional_and_require_name_suites_of_the_run(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """A flag that names no suite of the run judges nothing: bad input, before anything runs."""
    status, _, err = cli(capsys, "run", "accuracy", "--optional", "acuracy", "--out",
                         str(tmp_path / "run"))
    assert status == 2 and "acuracy" in err and "did you mean accuracy" in err
    assert not (tmp_path / "run").exists()


def test_figures_no_limit_judges_are_said_zero_trials_untested(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A config that judges none of a suite's figures makes no claim about it: the verdict says
    so beside the pass; a suite of zero trials measured nothing: untested (exit 5)."""
    config = tmp_path / "bare.toml"
    config.write_text('spec_version = "armbench-limits/1"\n[suites.startup-recovery]\n'
                      "trials = 1\nwear_duration_s = 0\nconditions = [\"stopped-near\"]\n",
                      encoding="utf-8")
    status, out, _ = cli(capsys, "run", "startup-recovery", "--config", str(config), "--out",
                         str(tmp_path / "run"), "--no-capture", "--workers", "1")
    assert status == EXIT_PASS, out
    assert "none judged (no limit in the config): its pass claims nothing" in out
    config.write_text(config.read_text(encoding="utf-8").replace("trials = 1", "trials = 0"),
                      encoding="utf-8")
    status, out, _ = cli(capsys, "run", "startup-recovery", "--config", str(config), "--out",
                         str(tmp_path / "zero"), "--no-capture", "--workers", "1")
    assert status == EXIT_UNTESTED, out
    assert "no trial was measured (zero trials)" in out


def test_a_record_keeps_what_was_required(lap: Path) -> None:
    """The record says what the run had to measure: a later reader judges it the same."""
    raw = json.loads((lap / "results.json").read_text(encoding="utf-8"))
    assert raw["required"] == ["accuracy"]
    assert raw["verdict"] == "pass"
