"""Emulated trials on a real Dask cluster: a ``distributed.LocalCluster`` with its scheduler and
worker processes on loopback (``processes=True``), no mock. The record is the same whatever the
number or placement of workers; the capture comes back from the workers as data; a worker killed
mid-campaign loses no trial and counts none twice."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from campaign_records import record_differences

from armbench.bench.campaign import CampaignOptions, run_campaign
from armbench.bench.runner import RunOptions, run_sync
from armbench.drivers.capture.read import open_capture
from armbench.drivers.model.settings import SettingsError
from armbench.record import CAPTURE_FILE
from armbench.record.verdict import EXIT_INCOMPLETE

distributed = pytest.importorskip("distributed")

CONFIG = """spec_version = "armbench-limits/1"
[limits."startup.recovery_time_s"]
high = 10.0
unit = "s"
[suites.startup-recovery]
trials = 6
wear_duration_s = 0.0
"""


def _cluster(workers: int) -> Any:  # a distributed.LocalCluster
    return distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                    host="127.0.0.1", dashboard_address=":0")


@pytest.fixture(scope="module")
def two_workers() -> Iterator[Any]:
    with _cluster(2) as cluster:
        yield cluster


@pytest.fixture()
def config(tmp_path: Path) -> Path:
    path = tmp_path / "bench.toml"
    path.write_text(CONFIG, encoding="utf-8")
    return path


def test_run_on_dask_gives_the_local_pool_record_and_capture(
        tmp_path: Path, config: Path, two_workers: Any) -> None:
    local = run_sync(RunOptions(suites=["startup-recovery"], config=config, seed=5,
                                out=tmp_path / "local", workers=2), progress=None)
    on_dask = tmp_path / "dask.toml"  # the [bench] setting this time
    on_dask.write_text(CONFIG + f'[bench]\nscheduler = "{two_workers.scheduler_address}"\n',
                       encoding="utf-8")
    dask = run_sync(RunOptions(suites=["startup-recovery"], config=on_dask, seed=5,
                               out=tmp_path / "dask"), progress=None)
    assert local.exit_status == dask.exit_status == 0
    assert record_differences(tmp_path / "local", tmp_path / "dask", environment=False) == []
    # the capture parts travelled back as bytes and were merged on the run clock
    capture = list(open_capture(tmp_path / "dask" / CAPTURE_FILE))
    assert capture and capture == list(open_capture(tmp_path / "local" / CAPTURE_FILE))
    assert not list((tmp_path / "dask").glob(".capture.part*"))


def test_scheduler_address_is_checked_before_the_run(tmp_path: Path, config: Path) -> None:
    for bad in ("localhost:8786", "tcp://", "http://h:1"):
        with pytest.raises(SettingsError, match="scheduler address"):
            run_sync(RunOptions(suites=["startup-recovery"], config=config, scheduler=bad,
                                out=tmp_path / "x"), progress=None)
    assert not (tmp_path / "x").exists()


def test_campaign_same_record_on_one_and_two_workers(
        tmp_path: Path, two_workers: Any) -> None:
    with _cluster(1) as one:
        run_campaign(CampaignOptions("startup-recovery", 16, seed=2, out=tmp_path / "one",
                                     scheduler=one.scheduler_address), progress=None)
    run_campaign(CampaignOptions("startup-recovery", 16, seed=2, out=tmp_path / "two",
                                 scheduler=two_workers.scheduler_address), progress=None)
    run_campaign(CampaignOptions("startup-recovery", 16, seed=2, out=tmp_path / "local",
                                 workers=2), progress=None)
    assert record_differences(tmp_path / "one", tmp_path / "two") == []
    assert record_differences(tmp_path / "one", tmp_path / "local") == []


class _KillOnce:
    """A progress stream that, when the ``after``-th trial is committed, kills the process of a
    worker that is running a trial (SIGKILL, as a lost machine)."""

    def __init__(self, cluster: Any, after: int) -> None:
        self.cluster = cluster
        self.after = after
        self.lines = 0
        self.killed: int | None = None

    def isatty(self) -> bool:
        return False

    def flush(self) -> None:
        pass

    def write(self, text: str) -> None:
        if "trial " in text and " done " in text:
            self.lines += 1
        if self.killed is None and self.lines >= self.after:
            busy = {addr for addr, ws in self.cluster.scheduler.workers.items() if ws.processing}
            for nanny in self.cluster.workers.values():
                if nanny.worker_address in busy and nanny.process is not None:
                    self.killed = nanny.process.pid
                    assert self.killed is not None
                    os.kill(self.killed, signal.SIGKILL)
                    return


def test_worker_killed_mid_campaign_loses_and_repeats_nothing(
        tmp_path: Path, two_workers: Any) -> None:
    """The module's cluster, after the other tests that use it (its nanny starts a new worker
    in place of the one killed): a cluster of its own would start two more worker processes."""
    samples = 30
    stream = _KillOnce(two_workers, after=4)
    outcome = run_campaign(CampaignOptions("startup-recovery", samples, seed=9,
                                           out=tmp_path / "killed",
                                           scheduler=two_workers.scheduler_address),
                           progress=stream)  # type: ignore[arg-type]
    assert stream.killed is not None, "no worker was busy to kill"
    alive = {n.process.pid for n in two_workers.workers.values() if n.process is not None}
    assert stream.killed not in alive
    suite = outcome.record.suites["startup-recovery"]
    assert [t.index for t in suite.trials] == list(range(samples))  # each sample exactly once
    assert not suite.superseded_trials
    assert all(t.status == "done" for t in suite.trials)  # Dask ran the lost one elsewhere
    # and what it measured there is what an undisturbed campaign measures
    run_campaign(CampaignOptions("startup-recovery", samples, seed=9, out=tmp_path / "calm",
                                 workers=2), progress=None)
    assert record_differences(tmp_path / "killed", tmp_path / "calm") == []


def test_unreachable_scheduler_stops_the_run_with_its_address(
        tmp_path: Path, config: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from armbench.bench.runner import cluster

    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT_S", 1.0)  # nothing listens: no need to wait
    outcome = run_sync(RunOptions(suites=["startup-recovery"], config=config,
                                  out=tmp_path / "r", scheduler="tcp://127.0.0.1:1"),
                       progress=None)
    assert outcome.exit_status == EXIT_INCOMPLETE  # the run began, and stopped unfinished
    assert outcome.error is not None and "Dask scheduler tcp://127.0.0.1:1" in outcome.error
