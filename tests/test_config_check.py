"""Every suite declares the metric names it records (``Suite.metric_names``), checked here
against a real ``fake://`` run."""

from __future__ import annotations

import pytest

from armbench.bench.campaign.stats import CAMPAIGN, campaign_measurements
from armbench.bench.runner import RunOptions, run_sync
from armbench.bench.suites import load_suite, suite_names
from armbench.bench.suites.startup_contract import STARTUP
from armbench.record import RunRecord, Trial, judge
from armbench.record.limits import parse_limits
from armbench.record.suite_contract import contract

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
