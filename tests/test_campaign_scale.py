"""Campaigns at scale (``slow``, and run only when asked for: ``pytest -m slow``; minutes to an
hour on a busy 2-core machine): the same campaign on 1, 2 and 4 Dask workers and merged from 3
shards gives one record; a 10 000-cut start-up recovery campaign completes with every cut
exactly once. Their small variants are in the default run (``test_dask.py``,
``test_campaign.py``). Throughput is measured by ``scripts/dask_throughput.py``
(``docs/campaigns.md``), not asserted here."""

from __future__ import annotations

from pathlib import Path

import pytest
from campaign_records import record_differences

from armbench.bench.campaign import CampaignOptions, merge_shards, run_campaign

distributed = pytest.importorskip("distributed")

pytestmark = pytest.mark.slow


@pytest.fixture(autouse=True)
def _asked_for(request: pytest.FixtureRequest) -> None:
    expression = str(request.config.getoption("markexpr") or "")
    if "slow" not in expression or "not slow" in expression:
        pytest.skip("campaign at scale: run with -m slow")


def test_one_two_four_workers_and_three_shards_give_one_record(tmp_path: Path) -> None:
    samples, seed = 40, 21
    for workers in (1, 2, 4):
        with distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                      host="127.0.0.1", dashboard_address=":0") as cluster:
            run_campaign(CampaignOptions("startup-recovery", samples, seed=seed,
                                         out=tmp_path / f"w{workers}",
                                         scheduler=cluster.scheduler_address), progress=None)
    for i in (1, 2, 3):
        run_campaign(CampaignOptions("startup-recovery", samples, seed=seed,
                                     out=tmp_path / f"s{i}", shard=(i, 3), workers=2),
                     progress=None)
    merge_shards([tmp_path / f"s{i}" for i in (1, 2, 3)], tmp_path / "merged")
    for other in ("w2", "w4", "merged"):
        assert record_differences(tmp_path / "w1", tmp_path / other) == [], other


@pytest.mark.long(wall_s=210)
def test_ten_thousand_cuts(tmp_path: Path) -> None:
    outcome = run_campaign(CampaignOptions("startup-recovery", 10_000, seed=0,
                                           out=tmp_path / "c", workers=2), progress=None)
    suite = outcome.record.suites["startup-recovery"]
    assert suite.status == "done"
    assert [t.index for t in suite.trials] == list(range(10_000))
    assert all(t.status == "done" for t in suite.trials)
    figures = {m.name: m.value for m in suite.measurements}
    assert figures["campaign.samples"] == 10_000
