"""Nothing in a config judges nothing (``docs/record.md``): every suite declares the metric names
it records (``Suite.metric_names``, checked here against a real ``fake://`` run), and a config
whose limit or tolerance pattern matches none of them, or whose ``[suites.NAME]`` table names no
suite, is refused before anything moves: exit status 2, the dotted field and the closest right
names on one line."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import cli, one_line_error

from armbench.bench.campaign.stats import CAMPAIGN, campaign_measurements
from armbench.bench.runner import RunOptions, prepare, run_sync
from armbench.bench.runner.config_check import check_config
from armbench.bench.suites import load_suite, suite_names
from armbench.bench.suites.startup_contract import STARTUP
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.record import RunRecord, Trial, judge
from armbench.record.limits import load_limits, parse_limits
from armbench.record.suite_contract import contract
from armbench.record.verdict import DEFAULT_CONFIG, load_config

ROOT = Path(__file__).resolve().parents[1]
RECORDS = ROOT / "tests" / "fixtures" / "records"
SPEC = 'spec_version = "armbench-limits/1"\n'

#: Every parameter that names a metric (styles, speeds, poses, conditions, joints) at its
#: default; only the counts cut short, so the run takes seconds.
SHORT = SPEC + """
[suites.accuracy]
laps = 1

[suites.repeatability]
cycles = 2
vap_cycles = 2
path_cycles = 2

[suites.startup-recovery]
trials = 10
wear_duration_s = 10.0

[suites.joints]
cycles = 2
"""

#: Declared figures a fake:// run cannot record: a tracker's TCP error after a power cut (the
#: emulator's truth gives joint angles, so the error is in mrad).
NEEDS_A_TRACKER = {"startup-recovery": {STARTUP.position_error_mm}}


def _config(tmp_path: Path, text: str, name: str = "bench.toml") -> Path:
    path = tmp_path / name
    path.write_text(SPEC + text, encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def default_run(tmp_path_factory: pytest.TempPathFactory) -> RunRecord:
    tmp = tmp_path_factory.mktemp("default-run")
    config = tmp / "short.toml"
    config.write_text(SHORT, encoding="utf-8")
    outcome = run_sync(RunOptions(config=config, out=tmp / "run"), progress=None)
    return outcome.record


@pytest.mark.parametrize("name", suite_names())
def test_each_suite_declares_exactly_what_it_records(default_run: RunRecord, name: str) -> None:
    """Every measurement of the suite, trial-level and suite-level, true figures included, is
    among its declared names; and every declared name is recorded but for a tracker's."""
    record = default_run.suites[name]
    assert record.status == "done", record.error
    recorded = {m.name for m in record.measurements}
    recorded |= {m.name for t in record.trials for m in t.measurements}
    if contract(name).has_true_figures:  # the emulator's truth was there
        assert any(n.split(".")[-1].startswith("true_") for n in recorded)
    declared = load_suite(name).metric_names(record.params)
    assert recorded - declared == set()
    assert declared - recorded == NEEDS_A_TRACKER.get(name, set())


def test_a_campaign_declares_its_figures() -> None:
    """The campaign's figures over samples with a judged yes/no figure and a measured one (every
    statistic, the rate and the pass probability among them) are its declared names."""
    limits = parse_limits({"spec_version": "armbench-limits/1",
                           "limits": {"x.ok": {"low": 1, "unit": "bool"}}})
    trials = [Trial(i, 0.0, 1.0, params={}, measurements=[
        judge("x.ok", float(i % 2), "bool", limits), judge("x.t_s", 0.1 * i, "s", limits)])
        for i in range(4)]
    trials.append(Trial(4, 0.0, 1.0, params={}, status="error", error="lost"))
    names = {m.name for m in campaign_measurements(trials, limits)}
    assert {"campaign.x.ok.rate_pct", "campaign.x.ok.pass_ci_low_pct",
            "campaign.all_limits.pass_pct", "campaign.x.t_s.p95"} <= names
    assert names <= CAMPAIGN.metric_names({"x.ok", "x.t_s"})


def test_the_packaged_configs_pass_the_check() -> None:
    """The packaged bench config (limits of ros2-square, which runs only when named, included)
    and twin-check's (a ``[suites."twin-check"]`` table, ``twin.*`` limits)."""
    check_config(load_config(None), RobotSettings())
    check_config(load_limits(ROOT / "bench" / "twin_check" / "twin_check.toml"), RobotSettings())


def test_a_misspelt_limit_stops_the_run_before_anything_moves(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = DEFAULT_CONFIG.read_text(encoding="utf-8").replace(
        '[limits."accuracy.coordinated.mean_mm"]', '[limits."accuracy.cordinated.mean_mm"]')
    config = tmp_path / "bench.toml"
    config.write_text(text, encoding="utf-8")
    status, _, err = cli(capsys, "run", "--config", str(config), "--out", str(tmp_path / "r"))
    one_line_error(status, err, 'limits."accuracy.cordinated.mean_mm"', "judge nothing",
                   "closest: accuracy.coordinated.mean_mm")
    assert not (tmp_path / "r").exists()


def test_a_misspelt_tolerance_stops_compare(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    config = _config(tmp_path, '[regression.metrics."startup.recovery_tme_s"]\n'
                               "tolerance_pct = 5.0\n")
    status, _, err = cli(capsys, "compare", str(RECORDS / "passing.json"),
                         str(RECORDS / "passing.json"), "--config", str(config))
    one_line_error(status, err, 'regression.metrics."startup.recovery_tme_s"',
                   "closest: startup.recovery_time_s")
    status, _, err = cli(capsys, "config", "show", "--config", str(config))
    one_line_error(status, err, 'regression.metrics."startup.recovery_tme_s"')


def test_a_misspelt_suite_table_stops_the_run(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """``[suites.acuracy] laps = 50`` would leave the accuracy suite at its 3 laps."""
    config = _config(tmp_path, "[suites.acuracy]\nlaps = 50\n")
    status, _, err = cli(capsys, "run", "accuracy", "--config", str(config),
                         "--out", str(tmp_path / "r"))
    one_line_error(status, err, "suites.acuracy", "is not a suite", "closest: accuracy")
    assert not (tmp_path / "r").exists()


def test_a_misspelt_bench_key_names_the_closest(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    config = _config(tmp_path, "[bench]\nretrys = 2\n")
    status, _, err = cli(capsys, "run", "--config", str(config), "--out", str(tmp_path / "r"))
    one_line_error(status, err, "bench.retrys", "closest: retries")


def test_a_wildcard_passes_when_it_matches_and_a_near_miss_is_named(tmp_path: Path) -> None:
    good = _config(tmp_path, '[limits."repeatability.*.ap_mm"]\nhigh = 2.0\nunit = "mm"\n'
                             '[limits."joints.j*.true_accuracy_mrad"]\nhigh = 5.0\n'
                             'unit = "mrad"\n', "good.toml")
    prepare(RunOptions(suites=["joints"], config=good, runs_root=tmp_path))
    bad = _config(tmp_path, '[limits."repeatability.*.ap_nm"]\nhigh = 2.0\nunit = "mm"\n',
                  "bad.toml")
    with pytest.raises(SettingsError) as info:
        prepare(RunOptions(suites=["joints"], config=bad, runs_root=tmp_path))
    assert info.value.field == 'limits."repeatability.*.ap_nm"'
    assert "closest: repeatability.*.ap_mm" in str(info.value)


def test_the_suite_parameters_of_the_config_decide_the_names(tmp_path: Path) -> None:
    """A limit at a speed the config's repeatability suite does not run judges nothing, run or
    not; a campaign's figure and a limit of a suite not run are fine."""
    fine = _config(tmp_path, "[suites.repeatability]\nspeeds_pct = [100, 50]\n"
                             '[limits."repeatability.v50.p1.ap_mm"]\nhigh = 2.0\nunit = "mm"\n'
                             '[limits."campaign.all_limits.pass_ci_low_pct"]\nlow = 95.0\n'
                             'unit = "%"\n'
                             '[limits."ros2.trajectory.true_mean_mm"]\nhigh = 2.0\n'
                             'unit = "mm"\n', "fine.toml")
    prepare(RunOptions(suites=["joints"], config=fine, runs_root=tmp_path))
    slow = _config(tmp_path, "[suites.repeatability]\nspeeds_pct = [100, 50]\n"
                             '[limits."repeatability.v10.p1.ap_mm"]\nhigh = 2.0\nunit = "mm"\n',
                   "slow.toml")
    with pytest.raises(ArmbenchError, match=r'limits\."repeatability\.v10\.p1\.ap_mm"'):
        prepare(RunOptions(suites=["joints"], config=slow, runs_root=tmp_path))


def test_a_suite_table_of_a_suite_not_run_is_checked_too(tmp_path: Path) -> None:
    config = _config(tmp_path, "[suites.repeatability]\nspeed_pct = [100]\n")
    with pytest.raises(SettingsError) as info:
        prepare(RunOptions(suites=["joints"], config=config, runs_root=tmp_path))
    assert info.value.field == "suites.repeatability.speed_pct"
