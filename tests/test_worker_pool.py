"""The worker processes of a run started as it begins (``bench/workers/worker_process.py``:
``prestart`` / ``take_pool``), real spawned processes."""

from __future__ import annotations

import concurrent.futures
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import pytest
from test_runner import TinySuite, write_config

from armbench.bench.runner import RunOptions
from armbench.bench.runner.options import PlannedSuite
from armbench.bench.runner.parallel import TRIAL_MODULES, prestart_workers
from armbench.bench.suites import SuiteContext
from armbench.bench.workers import worker_process
from armbench.drivers.model.errors import PortLostError
from armbench.record import Measurement, Trial


def loaded(names: tuple[str, ...]) -> tuple[int, list[bool]]:
    """In a worker: its pid, and which of ``names`` it has imported before its first job."""
    return os.getpid(), [name in sys.modules for name in names]


@pytest.fixture(autouse=True)
def no_pool_left() -> Iterator[None]:
    """Each test starts with no pool readied or parked (by a run of another test in this
    process) and leaves none."""
    worker_process.discard_prestarted()
    worker_process.discard_parked()
    yield
    worker_process.discard_prestarted()
    worker_process.discard_parked()


def test_a_prestarted_pool_is_taken_with_its_modules_already_imported() -> None:
    worker_process.prestart(1, ("armbench.drivers.model.protocol",))
    waiting = worker_process._prestarted
    assert waiting is not None
    pool = worker_process.take_pool(1)
    try:
        assert pool is waiting[2] and worker_process._prestarted is None
        pid, found = pool.submit(loaded, ("armbench.drivers.model.protocol", "armbench.reports"),
                                 ).result(timeout=120)
        assert pid != os.getpid() and found == [True, False]
    finally:
        pool.shutdown()


def test_a_pool_of_another_size_is_not_taken_but_let_go() -> None:
    worker_process.prestart(1)
    waiting = worker_process._prestarted
    assert waiting is not None
    pool = worker_process.take_pool(2)
    try:
        assert pool is not waiting[2] and worker_process._prestarted is None
        with pytest.raises(RuntimeError):  # shut down: it takes no job
            waiting[2].submit(loaded, ())
    finally:
        pool.shutdown()


@pytest.mark.parametrize(("options", "started"), [
    (RunOptions(workers=2), True),
    (RunOptions(workers=2, ports=["fake://?seed=4"], suites=["accuracy"]), True),
    (RunOptions(workers=1), False),
    (RunOptions(workers=2, scheduler="tcp://127.0.0.1:1"), False),
    (RunOptions(workers=2, ports=["a=fake://", "b=fake://"]), False),
    (RunOptions(workers=2, ports=["socket://127.0.0.1:1"]), False),
    (RunOptions(workers=2, resume="somewhere"), False),
])
def test_a_run_starts_its_workers_only_where_it_will_measure_in_them(
        options: RunOptions, started: bool) -> None:
    prestart_workers(options)
    waiting = worker_process._prestarted
    assert (waiting is not None) is started
    if waiting is not None:
        assert waiting[0] == 2 and waiting[1][:len(TRIAL_MODULES)] == TRIAL_MODULES
        assert "armbench.bench.suites.accuracy" in waiting[1]


def _counted(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The sizes of the pools started from now on."""
    made: list[int] = []
    new_pool = worker_process.new_pool

    def counted(workers: int, preload: tuple[str, ...] = ()) -> object:
        made.append(workers)
        return new_pool(workers, preload)

    monkeypatch.setattr(worker_process, "new_pool", counted)
    return made


def test_the_pool_of_a_run_is_the_one_started_as_it_began(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """A default-sized run of a suite on fake:// measures in the pool started before its plan;
    after it, none is left waiting for it: the pool is parked for the next run."""
    from armbench.bench.runner import run_sync

    made = _counted(monkeypatch)
    outcome = run_sync(RunOptions(suites=["joints"], out=tmp_path / "run", workers=2),
                       progress=None)
    assert outcome.exit_status == 0
    assert made == [2] and worker_process._prestarted is None
    assert worker_process._parked is not None and worker_process._parked[0] == 2


def test_the_next_run_of_the_process_takes_the_parked_pool(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Runs one after the other in one process start their workers once, and measure the same:
    a parked pool's workers keep nothing of a run that the next could see. A change of what
    spawned workers take from the process (here the environment) starts new ones, as does a
    pool that lost a worker while parked."""
    from armbench.bench.runner import run_sync
    from armbench.record import load_record

    made = _counted(monkeypatch)

    def run(name: str) -> dict[str, object]:
        outcome = run_sync(RunOptions(suites=["joints"], out=tmp_path / name, workers=2,
                                      seed=5), progress=None)
        assert outcome.exit_status == 0
        suite = load_record(tmp_path / name / "results.json").suites["joints"]
        return {m.name: m.value for m in suite.measurements}

    first = run("first")
    assert run("second") == first and made == [2]
    monkeypatch.setenv("ARMBENCH_TEST_POOL", "changed")
    assert run("third") == first and made == [2, 2]
    parked = worker_process._parked
    assert parked is not None
    pid = parked[1].submit(os.getpid).result(timeout=120)
    os.kill(pid, signal.SIGKILL)
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        try:
            parked[1].submit(os.getpid).result(timeout=120)
        except concurrent.futures.BrokenExecutor:
            break
        time.sleep(0.05)
    assert run("fourth") == first and made == [2, 2, 2]


def test_the_next_suites_trials_are_measured_while_the_last_one_ends(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The workers do not wait for a suite's last trial and its summary: the next suite's
    first trials are in them by then, committed after the summary, in order."""
    import time

    from armbench.bench.runner import parallel, run_sync, trials
    from armbench.record import load_record

    starts: dict[str, list[float]] = {}
    commit = parallel.ParallelTrials._commit

    def keep(self: parallel.ParallelTrials, ps: PlannedSuite, index: int, attempt: int,
             result: parallel.JobResult, wall_s: float) -> object:
        starts.setdefault(ps.name, []).append(result.worker_start_s)
        return commit(self, ps, index, attempt, result, wall_s)

    summarized: dict[str, float] = {}
    summarize = trials.TrialRunner.summarize

    async def timed(self: trials.TrialRunner, ps: PlannedSuite) -> None:
        await summarize(self, ps)
        summarized[ps.name] = time.perf_counter()

    monkeypatch.setattr(parallel.ParallelTrials, "_commit", keep)
    monkeypatch.setattr(trials.TrialRunner, "summarize", timed)
    out = tmp_path / "run"
    outcome = run_sync(RunOptions(suites=["accuracy", "joints"], out=out, workers=2),
                       progress=None)
    assert outcome.exit_status == 0
    assert min(starts["joints"]) < summarized["accuracy"]
    record = load_record(out / "results.json")
    joints = record.suites["joints"]
    assert [t.index for t in joints.trials] == list(range(len(joints.trials)))
    accuracy_end = record.suites["accuracy"].ended_s
    assert accuracy_end is not None and joints.trials[0].started_s >= accuracy_end


class FlakySuite(TinySuite):
    """``flaky``: the last trial's first attempt waits until the next suite's trials have been
    sent, then loses the port; the files named by ``ARMBENCH_TEST_FLAKY`` (``<dir>``: ``tried``,
    ``next-sent``) carry that between the test and the worker processes."""

    name = "flaky"

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        folder = os.environ.get("ARMBENCH_TEST_FLAKY")
        if folder and index == int(ctx.params["trials"]) - 1:
            tried, sent = Path(folder) / "tried", Path(folder) / "next-sent"
            if not tried.exists():
                tried.touch()
                deadline = time.monotonic() + 60.0
                while not sent.exists() and time.monotonic() < deadline:
                    time.sleep(0.01)  # a worker of its own: blocking it blocks nothing else
                raise PortLostError(ctx.arm.port, "cable pulled (test)")
        return await super().run_trial(ctx, index, trial_params)

    def summarize(self, ctx: SuiteContext, trials: Sequence[Trial]) -> list[Measurement]:
        return []  # the run's tiny suite has the suite-level names


def test_a_trial_measured_again_does_not_wait_behind_the_next_suite(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The next suite's trials are sent while a suite's last one runs: if that one ends in
    error and is measured again, the attempt keeps its worker slot instead of queueing behind
    them (whose results would wait in memory for it)."""
    from armbench.bench.runner import parallel, run_sync
    from armbench.bench.suites import SUITES

    monkeypatch.setitem(SUITES, "tiny", "test_runner:TinySuite")
    monkeypatch.setitem(SUITES, "flaky", f"{__name__}:FlakySuite")
    monkeypatch.setenv("ARMBENCH_TEST_FLAKY", str(tmp_path))
    spans: dict[tuple[str, int, int], tuple[float, float]] = {}
    commit = parallel.ParallelTrials._commit

    def keep(self: parallel.ParallelTrials, ps: PlannedSuite, index: int, attempt: int,
             result: parallel.JobResult, wall_s: float) -> object:
        spans[ps.name, index, attempt] = (result.worker_start_s,
                                          result.worker_start_s + result.worker_s)
        return commit(self, ps, index, attempt, result, wall_s)

    start = parallel.ParallelTrials.start

    async def sent(self: parallel.ParallelTrials, ps: PlannedSuite,
                   todo: Sequence[int]) -> None:
        await start(self, ps, todo)
        (tmp_path / "next-sent").touch()

    monkeypatch.setattr(parallel.ParallelTrials, "_commit", keep)
    monkeypatch.setattr(parallel.ParallelTrials, "start", sent)
    outcome = run_sync(RunOptions(suites=["flaky", "tiny"], config=write_config(tmp_path, trials=4),
                                  out=tmp_path / "run", workers=2, retries=1), progress=None)
    assert outcome.exit_status == 0
    retried = spans["flaky", 2, 1]
    assert ("flaky", 2, 0) in spans
    # the other worker measures the next suite meanwhile: one of its trials may end first;
    # queued behind them the attempt would start once three had (two workers, four trials)
    ended_before = [key for key, (_, end) in spans.items() if key[0] == "tiny" and end < retried[0]]
    assert len(ended_before) <= 1, ended_before


class GatedSuite(TinySuite):
    """The tiny suite, each trial first waiting until the file ``open`` exists in the folder
    ``ARMBENCH_TEST_GATE`` names."""

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        gate = Path(os.environ["ARMBENCH_TEST_GATE"]) / "open"
        deadline = time.monotonic() + 60.0
        while not gate.exists() and time.monotonic() < deadline:
            time.sleep(0.01)  # a worker of its own: blocking it blocks nothing else
        return await super().run_trial(ctx, index, trial_params)


def test_the_next_trial_waits_in_the_pool_while_the_workers_measure(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two jobs per worker are in flight: while both workers measure, the next two trials are
    already in the pool, so a worker that ends one starts the next without waiting for the run's
    loop (busy committing). The trials wait at a gate that opens once four jobs are sent and
    unfinished (or after 20 s, when the test has failed)."""
    from armbench.bench.runner import parallel, run_sync
    from armbench.bench.suites import SUITES

    monkeypatch.setitem(SUITES, "tiny", f"{__name__}:GatedSuite")
    monkeypatch.setenv("ARMBENCH_TEST_GATE", str(tmp_path))
    gate = tmp_path / "open"
    opened = threading.Timer(20.0, gate.touch)
    opened.start()
    outstanding: set[concurrent.futures.Future[Any]] = set()
    most = [0]
    submit = concurrent.futures.ProcessPoolExecutor.submit

    def counted(self: concurrent.futures.ProcessPoolExecutor, fn: Any, /, *args: Any,
                **kwargs: Any) -> concurrent.futures.Future[Any]:
        future = submit(self, fn, *args, **kwargs)
        if fn is parallel.run_attempts:
            outstanding.add(future)
            future.add_done_callback(outstanding.discard)
            most[0] = max(most[0], len(outstanding))
            if len(outstanding) == 4:
                gate.touch()
        return future

    monkeypatch.setattr(concurrent.futures.ProcessPoolExecutor, "submit", counted)
    try:
        outcome = run_sync(RunOptions(suites=["tiny"], config=write_config(tmp_path, trials=6),
                                      out=tmp_path / "run", workers=2), progress=None)
    finally:
        opened.cancel()
    assert outcome.exit_status == 0
    assert most[0] == 4
