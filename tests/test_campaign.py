"""``armbench campaign``: draws from a calibration's uncertainties, the Wilson interval, a
campaign's record (one trial per sample, distributions as ``campaign.*`` figures), its page, and
the same record whatever the number of workers or shards. Real emulator, real CLI."""

from __future__ import annotations

import dataclasses
import html
import io
import json
import math
import random
import re
from pathlib import Path

import pytest
from campaign_records import record_differences
from chromium import CHROMIUM, Chromium
from test_report import cells, parse

from armbench.bench.campaign import (
    CampaignOptions,
    merge_shards,
    read_uncertainties,
    run_campaign,
    wilson_interval,
)
from armbench.bench.campaign.draws import draw_arm
from armbench.cli.main import main
from armbench.drivers.model.settings import RobotSettings, SettingsError, load_settings
from armbench.drivers.model.twin_parameters import GEOMETRY_ERRORS, JOINT_PARAMETERS
from armbench.record import load_record
from armbench.record.verdict import DEFAULT_CONFIG, EXIT_FAIL, EXIT_PASS
from armbench.reports.pages.campaign_page import build_campaign_html
from armbench.reports.render.format import CSP, format_value

ARTIFACTS = Path(__file__).resolve().parents[1] / "test-artifacts"

def _play_only() -> str:
    """The ``[emulator.physics]`` tables of an arm whose every effect is off (the declared ideal
    values: no mass, stick-slip, friction, kinematic error or noise) but the gear play of joint
    2: the drawn play alone moves the true path."""
    joints = "".join(
        f"\n[emulator.physics.j{j + 1}]\n" + "".join(
            f"{p.key} = {p.ideal_value()!r}\n" for p in JOINT_PARAMETERS
            if not p.choices and math.isfinite(float(p.ideal_value())) and p.key != "backlash_deg")
        + f"backlash_deg = {0.06 if j == 1 else 0.0}\n" for j in range(4))
    geometry = "".join(f"{p.key} = 0.0\n" for p in GEOMETRY_ERRORS)
    return (f"[emulator.physics]\nnoise_per_count = 0.0\n\n[emulator.physics.geometry_error]\n"
            f"{geometry}{joints}")


# As armbench calibrate writes it: the standard errors in the [uncertainty] table (the comments
# beside the values are for the reader).
FITTED = f"""# Robot settings fitted by armbench calibrate from fake://.
[joints.j2]
offset_deg = 90.0  # fitted: ± 0.3 deg (1 σ); Hall approaches
hall_deg = 0.0  # kept: not identified

[emulator]
profile = "physical"

{_play_only()}
[uncertainty]
"joints.j2.offset_deg" = 0.3
"emulator.physics.j2.backlash_deg" = 0.11
"""

ACCURACY = """spec_version = "armbench-limits/1"
[limits."accuracy.coordinated.true_mean_mm"]
high = 0.5
unit = "mm"
[suites.accuracy]
laps = 1
styles = ["coordinated"]
"""


@pytest.fixture()
def fitted(tmp_path: Path) -> Path:
    path = tmp_path / "fitted.toml"
    path.write_text(FITTED, encoding="utf-8")
    return path


def test_uncertainties_read_from_the_settings_table(fitted: Path) -> None:
    got = read_uncertainties(fitted)
    assert [(u.key, u.value, u.sigma, u.unit) for u in got] == [
        ("joints.j2.offset_deg", 90.0, 0.3, "deg"),
        ("emulator.physics.j2.backlash_deg", 0.06, 0.11, "deg")]
    assert load_settings(fitted).uncertainty == {"joints.j2.offset_deg": 0.3,
                                                 "emulator.physics.j2.backlash_deg": 0.11}


PLAY = "[emulator.physics.j2]\nbacklash_deg = 0.1\n"


@pytest.mark.parametrize(("text", "sigma", "problem"), [
    (PLAY, "-0.1", "-0.1 must be in [0, 1e+12] (a standard error)"),
    (PLAY, '"wide"', "must be a number in [0, 1e+12]"),
    (PLAY, "nan", "nan must be in [0, 1e+12]"),
    ('[emulator.physics.j2]\nbacklash_deg = "x"\n', "0.1", "does not set to a number"),
    ("", "0.1", "does not set to a number")])
def test_a_bad_uncertainty_is_named(tmp_path: Path, text: str, sigma: str, problem: str) -> None:
    """The settings loader refuses a standard error that is not a number >= 0, or one of a
    setting the file does not give a number, naming the table's key."""
    path = tmp_path / "bad.toml"
    table = '[uncertainty]\n"emulator.physics.j2.backlash_deg" = '
    path.write_text(f"{PLAY}{table}0.1\n", encoding="utf-8")
    assert read_uncertainties(path)[0].sigma == 0.1
    path.write_text(f"{text}{table}{sigma}\n", encoding="utf-8")
    with pytest.raises(SettingsError, match=r'uncertainty\."emulator\.physics\.j2\.backlash_deg"'
                       ) as info:
        load_settings(path)
    assert problem in str(info.value)


def test_standard_errors_in_comments_only_are_refused_by_a_campaign(tmp_path: Path) -> None:
    """A file an older ``armbench calibrate`` wrote, its standard errors in comments, still
    loads as settings (a comment is a comment); a campaign, which would draw nothing from it,
    says so and how to add the table."""
    path = tmp_path / "old.toml"
    path.write_text("[emulator.physics.j2]\nbacklash_deg = 0.2  # fitted: ± 0.03 deg (1 σ); a\n",
                    encoding="utf-8")
    assert load_settings(path).uncertainty == {}
    with pytest.raises(SettingsError, match=r"uncertainty.*comments.*\[uncertainty\] table"):
        read_uncertainties(path)


def test_draws_follow_the_law_within_valid_settings(fitted: Path) -> None:
    uncertain = read_uncertainties(fitted)
    rng = random.Random(1)
    arms = [draw_arm(RobotSettings(), uncertain, rng) for _ in range(800)]
    offsets = [a["joints.j2.offset_deg"] for a in arms]
    mean = sum(offsets) / len(offsets)
    sd = (sum((x - mean) ** 2 for x in offsets) / (len(offsets) - 1)) ** 0.5
    assert abs(mean - 90.0) < 0.04 and abs(sd - 0.3) < 0.04  # 3.8 and 2.7 standard errors
    # a play cannot be negative: N(0.06, 0.11) restricted to >= 0, every draw valid
    play = [a["emulator.physics.j2.backlash_deg"] for a in arms]
    assert min(play) >= 0.0 and max(play) > 0.3
    assert draw_arm(RobotSettings(), uncertain, random.Random(7)) == draw_arm(
        RobotSettings(), uncertain, random.Random(7))


def test_wilson_interval_known_values() -> None:
    # Wilson (1927); e.g. Brown, Cai & DasGupta (2001): 0/10 -> [0, 0.2775], 5/10 -> [0.2366,
    # 0.7634], 10/10 -> [0.7225, 1]
    for passed, n, low, high in ((0, 10, 0.0, 0.2775), (5, 10, 0.2366, 0.7634),
                                 (10, 10, 0.7225, 1.0), (95, 100, 0.8883, 0.9785)):
        lo, hi = wilson_interval(passed, n)
        assert lo == pytest.approx(low, abs=1e-4) and hi == pytest.approx(high, abs=1e-4)
    assert wilson_interval(0, 0) == (0.0, 1.0)


def _figures(run: Path) -> dict[str, float]:
    record = json.loads((run / "results.json").read_text())
    (suite,) = record["suites"].values()
    return {m["name"]: m["value"] for m in suite["measurements"]}


def test_accuracy_campaign_draws_arms_and_reports_pass_probability(
        tmp_path: Path, fitted: Path) -> None:
    config = tmp_path / "bench.toml"
    config.write_text(ACCURACY, encoding="utf-8")
    outcome = run_campaign(CampaignOptions("accuracy", 5, settings=fitted, config=config,
                                           out=tmp_path / "c", seed=4, workers=1),
                           progress=None)
    suite = outcome.record.suites["accuracy"]
    assert [t.index for t in suite.trials] == list(range(5))
    arms = [t.params["arm"] for t in suite.trials]
    assert len({a["emulator.physics.j2.backlash_deg"] for a in arms}) == 5
    # the emulator played the drawn arm: its play shows in the true path
    true_mean = [next(m.value for m in t.measurements
                      if m.name == "accuracy.coordinated.true_mean_mm") for t in suite.trials]
    assert len(set(true_mean)) == 5
    by_play = sorted(zip((a["emulator.physics.j2.backlash_deg"] for a in arms), true_mean,
                         strict=True))
    assert by_play[-1][1] > by_play[0][1]  # more play, larger true error
    figures = _figures(tmp_path / "c")
    passed = sum(v <= 0.5 for v in true_mean)
    assert figures["campaign.accuracy.coordinated.true_mean_mm.pass_pct"] == pytest.approx(
        100.0 * passed / 5)
    low, high = wilson_interval(passed, 5)
    assert figures["campaign.accuracy.coordinated.true_mean_mm.pass_ci_low_pct"] == \
        pytest.approx(100 * low)
    assert figures["campaign.accuracy.coordinated.true_mean_mm.pass_ci_high_pct"] == \
        pytest.approx(100 * high)
    assert figures["campaign.accuracy.coordinated.true_mean_mm.n"] == 5
    # the 100 Hz state samples are left out of the record; the figures stay
    assert all(s.get("event") == "samples_left_out" for t in suite.trials for s in t.samples)
    assert not (tmp_path / "c" / "capture.mcap").exists()


def test_startup_campaign_draws_states_and_shards_merge_to_the_same_record(
        tmp_path: Path) -> None:
    def campaign(out: str, **kw: object) -> None:
        run_campaign(CampaignOptions("startup-recovery", 15, seed=11, out=tmp_path / out,
                                     **kw),  # type: ignore[arg-type]
                     progress=None)

    campaign("w1", workers=1)
    campaign("w2", workers=2)
    for i in (1, 2, 3):
        campaign(f"s{i}", workers=1, shard=(i, 3))
    merge_shards([tmp_path / f"s{i}" for i in (1, 2, 3)], tmp_path / "merged")
    # one worker measures in turn on the run's loop: trial durations agree to rounding
    assert record_differences(tmp_path / "w1", tmp_path / "w2", tol=1e-9) == []
    assert record_differences(tmp_path / "w1", tmp_path / "merged", tol=1e-9) == []
    record = json.loads((tmp_path / "w1" / "results.json").read_text())
    trials = record["suites"]["startup-recovery"]["trials"]
    conditions = {t["params"]["trials"][0]["condition"] for t in trials}
    assert len(conditions) >= 5  # drawn, not cycled: 15 draws of 10 states
    recovered = [m["value"] for t in trials for m in t["measurements"]
                 if m["name"] == "startup.recovered"]
    figures = _figures(tmp_path / "w1")
    assert figures["campaign.startup.recovered.rate_pct"] == pytest.approx(
        100 * sum(recovered) / len(recovered))
    assert figures["campaign.samples"] == 15
    # every sample is in the denominator: a cut the arm did not recover from has no recovery
    # time to judge, and does not pass (it once dropped out: 100 % of 27 with 23 of 50 lost)
    clean = sum(all(m["outcome"] != "fail" for m in t["measurements"])
                and any(m["name"] == "startup.recovery_time_s" for m in t["measurements"])
                for t in trials)
    assert 0 < sum(recovered) < 15
    assert figures["campaign.all_limits.pass_pct"] == pytest.approx(100 * clean / 15)
    assert figures["campaign.all_limits.pass_pct"] <= figures["campaign.startup.recovered.rate_pct"]
    low, high = wilson_interval(clean, 15)
    assert figures["campaign.all_limits.pass_ci_low_pct"] == pytest.approx(100 * low)
    assert figures["campaign.all_limits.pass_ci_high_pct"] == pytest.approx(100 * high)


def test_cli_campaign_writes_record_and_page(tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["campaign", "startup-recovery", "--samples", "6", "--seed", "3", "--workers",
                 "1", "--out", str(tmp_path / "c")]) == 0
    out = capsys.readouterr().out
    assert "6 sample(s) measured" in out and "campaign.startup.recovered.rate_pct" in out
    page = (tmp_path / "c" / "campaign.html").read_text(encoding="utf-8")
    assert CSP in html.unescape(page) and "<svg" in page and "<script" not in page
    assert "Recovery by state at the cut" in page
    assert re.search(r"http[s]?://", page.replace("http://www.w3.org", "")) is None
    assert main(["campaign", "startup-recovery", "--samples", "0",
                 "--out", str(tmp_path / "d")]) == 2
    assert "--samples" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def test_campaign_verdict_and_exit_status_from_its_limits(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A campaign is judged by the limits of its figures in the config: the pass probability
    of every limit together, at 95 % confidence, below 99 % fails it (exit 1); without such a
    limit the samples' failures are findings and the campaign passes."""
    strict = tmp_path / "strict.toml"
    strict.write_text(DEFAULT_CONFIG.read_text(encoding="utf-8")
                      + '\n[limits."campaign.all_limits.pass_ci_low_pct"]\nlow = 99.0\n'
                        'unit = "%"\n', encoding="utf-8")
    args = ["campaign", "startup-recovery", "--samples", "6", "--seed", "3", "--workers", "1"]
    assert main([*args, "--config", str(strict), "--out", str(tmp_path / "s")]) == EXIT_FAIL
    out = capsys.readouterr().out
    assert "campaign verdict: fail" in out and "FAIL   campaign.all_limits.pass_ci_low_pct" in out
    record = load_record(tmp_path / "s" / "results.json")
    assert record.verdict == "fail"
    # in junit.xml the campaign's figures are the tests, not the samples' own limits
    from armbench.reports.files.junit import to_junit

    cases = list(to_junit(record).iter("testcase"))
    failed = [c.get("name") for c in cases if c.find("failure") is not None]
    assert failed == ["campaign.all_limits.pass_ci_low_pct"]
    assert all(".trial" not in (c.get("classname") or "") for c in cases)
    assert main([*args, "--out", str(tmp_path / "d")]) == EXIT_PASS
    assert "no campaign.* limit" in capsys.readouterr().out


def test_campaign_page_leads_with_the_records_verdict(tmp_path: Path) -> None:
    """The page opens with the record's verdict and the judged ``campaign.*`` figures behind it,
    read from the record: FAIL and the failed figure for a strict limit; PASS and "no limit"
    without one. In headless Chromium at 1 280 × 800 the verdict is on the first screen."""
    strict = tmp_path / "strict.toml"
    strict.write_text(DEFAULT_CONFIG.read_text(encoding="utf-8")
                      + '\n[limits."campaign.all_limits.pass_ci_low_pct"]\nlow = 99.0\n'
                        'unit = "%"\n', encoding="utf-8")
    args = ["campaign", "startup-recovery", "--samples", "4", "--seed", "3", "--workers", "1"]
    assert main([*args, "--config", str(strict), "--out", str(tmp_path / "s")]) == EXIT_FAIL
    record = load_record(tmp_path / "s" / "results.json")
    (low,) = (m for m in record.suites["startup-recovery"].measurements
              if m.name == "campaign.all_limits.pass_ci_low_pct")
    assert record.verdict == "fail" and low.outcome == "fail"
    page = tmp_path / "s" / "campaign.html"
    doc = parse(page.read_text(encoding="utf-8"))
    banner, limits = doc.by_id("verdict"), doc.by_id("campaign-limits")
    assert banner is not None and limits is not None
    assert "Verdict: FAIL" in banner.text()
    assert f"campaign.all_limits.pass_ci_low_pct = {format_value(low.value, '%')}" in \
        banner.text()
    rows = [cells(tr) for tr in limits.iter("tr") if list(tr.iter("td"))]
    assert rows[0][0] == "campaign.all_limits.pass_ci_low_pct" and "FAIL" in rows[0][3]
    # the page reads the verdict from the record: a record judged otherwise shows that
    record.suites["startup-recovery"].measurements = [
        dataclasses.replace(m, limit=None, outcome="unjudged")
        for m in record.suites["startup-recovery"].measurements]
    other = parse(build_campaign_html(record))
    shown = other.by_id("verdict")
    assert shown is not None and "Verdict: PASS" in shown.text()
    assert "no campaign.* limit" in shown.text() and other.by_id("campaign-limits") is None
    if CHROMIUM is None:
        pytest.skip("no chromium: the first-screen check needs it")
    chrome = Chromium(tmp_path)
    try:
        chrome.open_page()
        chrome.load(page.as_uri(), 1280, 800)
        facts = chrome.probe()
        top, bottom = facts["first"][0]
        assert top >= 0 and bottom <= 800, facts["first"]
        assert "FAIL" in facts["verdict"]
        assert facts["scrollWidth"] <= facts["innerWidth"]
        ARTIFACTS.mkdir(exist_ok=True)
        chrome.screenshot(ARTIFACTS / "campaign-first-screen.png", max_height=800)
        assert chrome.problems() == []
    finally:
        chrome.close()


class _CtrlC(io.StringIO):
    """A progress stream whose ``after``-th finished trial line is met by Ctrl-C."""

    def __init__(self, after: int) -> None:
        super().__init__()
        self.after = after
        self.done = 0

    def write(self, text: str) -> int:
        if " done " in text:
            self.done += 1
            if self.done == self.after:
                raise KeyboardInterrupt
        return super().write(text)


def test_interrupted_campaign_keeps_its_samples_and_resumes(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    stopped = run_campaign(CampaignOptions("startup-recovery", 8, seed=3, out=tmp_path / "a",
                                           workers=1), progress=_CtrlC(4))
    assert stopped.interrupted and stopped.exit_status == 130
    on_disk = json.loads((tmp_path / "a" / "results.json").read_text())
    assert len(on_disk["suites"]["startup-recovery"]["trials"]) == 4  # batching lost none
    assert main(["campaign", "--resume", str(tmp_path / "a"), "--workers", "1"]) == 0
    assert "8 sample(s) measured" in capsys.readouterr().out
    run_campaign(CampaignOptions("startup-recovery", 8, seed=3, out=tmp_path / "b", workers=1),
                 progress=None)
    assert record_differences(tmp_path / "a", tmp_path / "b", tol=1e-9) == []
    assert main(["campaign", "--resume", str(tmp_path / "a"), "--seed", "2"]) == 2
    assert "--seed comes from the campaign" in capsys.readouterr().err
