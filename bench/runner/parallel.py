"""Parallel execution: trials on a target that allows it (``fake://``: its capabilities say
``parallel``) measured in worker processes, several at once.

With ``isolation = "trial"`` each trial on the emulator is self-contained: a freshly built and
powered emulator seeded from (seed, suite, index, attempt), its own connection and capture part.
Nothing of it depends on the absolute loop time (the emulator's clock is put on a nanosecond
grid from its power-up, ``fakes/firmware/boards.py``), so a trial measured on a fresh virtual-time
loop in another process gives the same figures as one measured in turn on the run's loop.
:class:`ParallelTrials` hands such trials to ``[bench] workers`` processes (default: one per CPU,
at most two; the process machinery is ``armbench.bench.workers.worker_process``) and commits them
in order:
``started_s`` on the run clock, ``results.json``, and the capture part merged with its times
moved onto the run clock.

With a Dask scheduler (``plan.scheduler``, ``armbench.bench.runner.cluster``) the same jobs go
to the cluster's workers instead, whatever ``workers`` says; a job then sends its capture part
back as bytes (workers may have no access to the run directory) and the parent writes it.

A worker runs :func:`run_attempts`: :meth:`TrialJob.measure`, the same
:meth:`TrialAttempts.attempt` the sequential path runs, on a ``VirtualTimeLoop`` starting at 0,
with a stand-in for the record writer (the worker never writes ``results.json``) and the trial's
progress messages collected for the parent to print; an attempt that does not end ``done`` is
measured again in the same worker, each on a fresh loop, so a trial measured again never waits
behind the jobs queued after it. Two jobs per worker are in flight: the next one is there when one
ends, while the run's loop commits the last.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import dataclasses
import logging
import pickle
import tempfile
import time
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import Any

from armbench.bench.runner.arms import parse_arms
from armbench.bench.runner.capture_parts import job_part_tag
from armbench.bench.runner.cluster import DaskCluster
from armbench.bench.runner.options import (
    BenchPlan,
    PlannedSuite,
    RunAborted,
    RunOptions,
    default_workers,
)
from armbench.bench.runner.trials import TrialAttempts, TrialRunner, default_emulator, describe
from armbench.bench.suites import registered_suites, suite_names
from armbench.bench.workers.worker_process import new_pool, park, prestart, run_job, take_pool
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.transports.target import target_of
from armbench.record import Trial, path_inside

__all__ = ["TRIAL_MODULES", "JobResult", "ParallelTrials", "TrialJob", "prestart_workers",
           "run_attempts"]

#: What every trial job imports in its worker, besides its suite's module: imported by each
#: worker as it starts (``worker_process.worker_init``), not by its first job.
TRIAL_MODULES: tuple[str, ...] = (
    "armbench.bench.runner.parallel", "armbench.drivers.host.arm",
    "armbench.drivers.capture.part", "armbench.fakes.firmware.arm_emulator")

log = logging.getLogger("armbench.runner")


@dataclass(frozen=True, slots=True)
class JobResult:
    """What a worker sends back: the trial on the worker's clock (``started_s`` from its loop's
    0), its capture parts (times on the same clock: files in the run directory, or their bytes
    from a Dask worker), its progress messages, and what the job cost the worker: its wall
    seconds, its CPU seconds and when it began (the worker's ``time.perf_counter()``, one clock
    for every process of a machine on Linux and Windows: what ``armbench perf`` lines the jobs
    up with the run's own process by)."""

    trial: Trial
    parts: tuple[Path, ...]
    messages: tuple[str, ...]
    shipped: tuple[bytes, ...] = ()
    worker_s: float = 0.0
    worker_cpu_s: float = 0.0
    worker_start_s: float = 0.0


class _JobClock:
    """What :class:`TrialAttempts` needs of a record writer inside a worker: the run directory
    for artifacts and a clock (the worker's loop time: the parent moves the trial onto the run
    clock)."""

    def __init__(self, out_dir: Path) -> None:
        self.out_dir = out_dir

    def artifact_path(self, name: str | PurePath) -> Path:
        return path_inside(self.out_dir, name)

    @staticmethod
    def elapsed_s() -> float:
        return asyncio.get_running_loop().time()


class _Messages:
    """Collects the progress lines a trial prints."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def message(self, text: str) -> None:
        self.lines.append(text)


@dataclass(frozen=True, slots=True)
class TrialJob:
    """One attempt of one trial, sent to a worker (pickled)."""

    plan: BenchPlan
    """The run's plan, without what a worker does not need (records, power, tracker)."""
    suite: PlannedSuite
    """The suite, without its trial plan (thousands of trials in a campaign): ``params``."""
    index: int
    attempt: int
    params: Mapping[str, Any]
    """The trial's parameters."""
    attempts: int = 1
    """How many attempts the trial has in all (``retries`` + 1): :func:`run_attempts` measures
    from ``attempt`` on until one is done."""
    ship: bool = False
    """Send the capture back as bytes (a Dask worker) instead of leaving it in the run
    directory (a local worker process)."""

    async def measure(self) -> JobResult:
        """Measure the attempt on the running loop (a worker's fresh virtual-time loop)."""
        t0, cpu0 = time.perf_counter(), time.process_time()
        if not self.ship:
            result = await self._measure(self.plan.out_dir)
        else:
            with tempfile.TemporaryDirectory(prefix="armbench-job-") as tmp:
                result = await self._measure(Path(tmp))
                result = dataclasses.replace(
                    result, parts=(), shipped=tuple(p.read_bytes() for p in result.parts
                                                    if p.exists()))
        return dataclasses.replace(result, worker_s=time.perf_counter() - t0,
                                   worker_cpu_s=time.process_time() - cpu0, worker_start_s=t0)

    async def _measure(self, out_dir: Path) -> JobResult:
        messages = _Messages()
        plan = self.plan if out_dir == self.plan.out_dir else dataclasses.replace(
            self.plan, out_dir=out_dir)
        attempts = TrialAttempts(plan, _JobClock(out_dir), messages, default_emulator,
                                 part_tag=job_part_tag(self.suite.name, self.index, self.attempt))
        trial = await attempts.attempt(self.suite, self.index, self.attempt, self.params)
        return JobResult(trial, tuple(attempts.unmerged), tuple(messages.lines))


def run_attempts(job: TrialJob) -> list[JobResult]:
    """The attempts of ``job``'s trial from ``job.attempt`` on, each on a fresh virtual-time loop
    (:func:`run_job`), until one is done or none is left (runs in a worker process)."""
    results = []
    for attempt in range(job.attempt, max(job.attempt + 1, job.attempts)):
        results.append(run_job(dataclasses.replace(job, attempt=attempt)))
        if results[-1].trial.status == "done":
            break
    return results


def _worker_modules(suite_refs: Sequence[str]) -> tuple[str, ...]:
    """:data:`TRIAL_MODULES` and the modules of the suites ``suite_refs`` names (names or
    ``module:Class``)."""
    registered = registered_suites()
    targets = [registered.get(ref, ref) for ref in suite_refs]
    return TRIAL_MODULES + tuple(dict.fromkeys(
        target.partition(":")[0] for target in targets if ":" in target))


def prestart_workers(options: RunOptions) -> None:
    """Start the worker processes of a run that will measure in them, as it begins: while its
    process plans the run, they start and import what a trial needs (a second of the run's
    wall time before its first trial). Taken by the run's :class:`ParallelTrials` when its plan
    asks for as many workers (``[bench] workers`` of a config may ask for others: a new pool
    then), let go at the run's end otherwise (``worker_process.discard_prestarted``). Only a
    new run of one arm on a target that measures in workers (``fake://``), with no Dask
    scheduler named."""
    workers = options.workers if options.workers is not None else default_workers()
    if workers < 2 or options.scheduler is not None or options.resume is not None:
        return
    try:
        arms = parse_arms(options.ports or ["fake://"])
        if len(arms) != 1 or not target_of(arms[0].port).capabilities.parallel:
            return
    except ArmbenchError:
        return  # the plan says what is wrong with it
    prestart(workers, _worker_modules(list(options.suites) or suite_names()))


class ParallelTrials:
    """The trials of a suite measured in worker processes and committed in order, as
    :meth:`TrialRunner.run_trial` would, each attempt on the run clock."""

    def __init__(self, runner: TrialRunner) -> None:
        self.runner = runner
        self.pool: concurrent.futures.ProcessPoolExecutor | None = None
        """The worker processes, once started."""
        self.cluster: DaskCluster | None = None
        """The Dask client (``plan.scheduler``), once connected."""
        self.worker_s = 0.0
        """Seconds the committed jobs took inside the workers (with the wall time of the run:
        the overhead of sending trials out)."""
        self.jobs = 0
        self._sent: list[concurrent.futures.Future[list[JobResult]]] = []
        """The jobs sent to :attr:`pool` not known to be done: a pool is parked for the next run
        only when they all are (a busy worker finishes its trial alone)."""
        self._in_flight: asyncio.Semaphore | None = None
        self._started: tuple[str, tuple[int, ...],
                             list[asyncio.Future[list[JobResult]]]] | None = None
        """The trials :meth:`start` sent (suite, indices, tasks), for :meth:`run`."""

    def usable(self, ps: PlannedSuite, todo: Sequence[int]) -> bool:
        """Whether the trials of ``ps`` go to worker processes: a target that declares
        ``parallel`` (``fake://``) with trial isolation and the built-in emulator factory, more
        than one worker and trial, on a virtual-time loop (the run clock is moved by each
        trial's duration), and a plan that can be sent."""
        runner = self.runner
        plan = runner.plan
        spread = plan.workers > 1 or plan.scheduler is not None
        if not (plan.target.capabilities.parallel and plan.isolation == "trial" and spread
                and len(todo) > 1
                and runner.attempts.emulator_factory is default_emulator
                and plan.tracker is None and plan.power is None):
            return False
        from armbench.fakes.clock.vclock import VirtualTimeLoop

        if not isinstance(asyncio.get_running_loop(), VirtualTimeLoop):
            return False
        try:
            pickle.dumps(self._job(ps, todo[0], 0))
        except Exception as exc:  # a user's suite that cannot be sent: measured in turn
            log.info("suite %s: trials measured in turn (%s cannot be sent to a worker: %s)",
                     ps.name, type(exc).__name__, exc)
            return False
        return True

    def _job(self, ps: PlannedSuite, index: int, attempt: int) -> TrialJob:
        plan = dataclasses.replace(self.runner.plan, suites=[], resume=None, baseline=None,
                                   runner_info={})
        return TrialJob(plan, dataclasses.replace(ps, trials=[]), index, attempt,
                        ps.trials[index], attempts=self.runner.plan.retries + 1,
                        ship=self.runner.plan.scheduler is not None)

    async def _connect(self) -> DaskCluster:
        """The Dask client, connected on first use (in a thread: connecting blocks)."""
        if self.cluster is None:
            address = self.runner.plan.scheduler
            assert address is not None
            loop = asyncio.get_running_loop()
            try:
                self.cluster = await loop.run_in_executor(None, DaskCluster, address)
            except (OSError, TimeoutError) as exc:
                raise RunAborted(f"cannot reach the Dask scheduler {address}: {exc}") from exc
        return self.cluster

    async def _slots(self) -> asyncio.Semaphore:
        """The jobs in flight at once, every suite's: two per worker process or thread of a
        Dask cluster, so that the next trial is there when one ends (a worker would wait for the
        run's loop to send it otherwise); the queue stays short."""
        if self._in_flight is None:
            if self.runner.plan.scheduler is not None:
                cluster = await self._connect()
                self._in_flight = asyncio.Semaphore(2 * cluster.threads())
            else:
                self._in_flight = asyncio.Semaphore(2 * self.runner.plan.workers)
        return self._in_flight

    async def start(self, ps: PlannedSuite, todo: Sequence[int]) -> None:
        """Send the trials ``todo`` of ``ps`` to the workers now, behind the jobs already
        waiting for a worker, for :meth:`run` to commit later: the next suite's, while this
        one's last trial and its summary finish (the workers would wait for them otherwise)."""
        self._drop_started()
        self._started = (ps.name, tuple(todo), await self._measure_all(ps, todo))

    def _drop_started(self) -> None:
        started, self._started = self._started, None
        if started is not None:
            for task in started[2]:
                task.cancel()

    async def run(self, ps: PlannedSuite, todo: Sequence[int], *,
                  following: Callable[[], Awaitable[None]] | None = None) -> Trial | None:
        """Measure ``todo`` in worker processes (those :meth:`start` sent already, or now),
        commit them in order; the trial that stopped the suite, or None. ``following`` is
        awaited once every trial is sent and the last one is awaited (it starts the next
        suite's)."""
        runner = self.runner
        started = self._started
        if started is not None and started[:2] == (ps.name, tuple(todo)):
            self._started = None
            tasks = started[2]
        else:
            tasks = await self._measure_all(ps, todo)
        last_commit = wall0 = time.perf_counter()
        jobs0, worker_s0 = self.jobs, self.worker_s
        try:
            for k, (index, task) in enumerate(zip(todo, tasks, strict=True)):
                if following is not None and k == len(todo) - 1:
                    await following()
                await asyncio.sleep(0)  # a cancellation asked for meanwhile stops here, as in turn
                results = await task
                if k and runner.plan.settle_s > 0:
                    runner.writer.advance(runner.plan.settle_s)
                for attempt, result in enumerate(results):
                    # wall time per commit: what the progress estimate needs (throughput)
                    now = time.perf_counter()
                    trial = self._commit(ps, index, attempt, result, now - last_commit)
                    last_commit = now
                if trial.status == "error":
                    return trial
            runner.progress.message(
                f"[{ps.name}] {self.jobs - jobs0} job(s) took {self.worker_s - worker_s0:.2f} s "
                f"in the workers, {time.perf_counter() - wall0:.2f} s of wall time")
            return None
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            runner.captures.flush()  # the committed trials' parts: on disk, deleted
            if not runner.captures.failed:  # else committed ones may be among them: resume
                for path in runner.writer.out_dir.glob(f".capture.part*-job-{ps.name}-*.part"):
                    with contextlib.suppress(OSError):  # parts of trials never committed
                        path.unlink()

    async def _measure_all(self, ps: PlannedSuite,
                           todo: Sequence[int]) -> list[asyncio.Future[list[JobResult]]]:
        """A task per trial of ``todo``: its attempts measured in the workers, as slots free."""
        runner = self.runner
        loop = asyncio.get_running_loop()
        attempts = runner.plan.retries + 1
        in_flight = await self._slots()

        async def shared(job: TrialJob) -> list[JobResult]:
            if self.cluster is not None:
                on_cluster: list[JobResult] = await loop.run_in_executor(
                    self.cluster.executor, run_attempts, job)
                return on_cluster
            if self.pool is None:
                self.pool = take_pool(runner.plan.workers,
                                      _worker_modules([s.ref for s in runner.plan.suites]))
            pool = self.pool
            try:
                sent = pool.submit(run_attempts, job)
                self._sent = [f for f in self._sent if not f.done()]
                self._sent.append(sent)
                results: list[JobResult] = await asyncio.wrap_future(sent, loop=loop)
            except concurrent.futures.BrokenExecutor:
                if self.pool is pool:
                    self.close(park_pool=False)
                raise
            return results

        async def alone(job: TrialJob) -> list[JobResult]:
            """In a process of its own: a dying worker breaks the whole pool, failing the
            trials beside it too; measured alone, only the trial that kills its process fails."""
            pool = new_pool(1, _worker_modules([ps.ref]))
            try:
                results: list[JobResult] = await loop.run_in_executor(pool, run_attempts, job)
            finally:
                pool.shutdown(wait=False)
            return results

        async def measure(index: int) -> list[JobResult]:
            """Every attempt of trial ``index`` (until one is done), in one slot and, unless its
            worker fails, in one job (:func:`run_attempts`): a trial measured again does not
            wait behind the trials sent after it (the next suite's among them), which would wait
            in memory for it to be committed. A worker that fails costs the attempts of its job
            not yet returned; the first of them counts as the attempt in error."""
            results: list[JobResult] = []
            async with in_flight:
                while len(results) < attempts:
                    job = self._job(ps, index, len(results))
                    try:
                        try:
                            results += await shared(job)
                        except concurrent.futures.BrokenExecutor:
                            results += await alone(job)
                    except Exception as exc:  # the worker failed (killed, KilledWorker on Dask)
                        log.error("suite %s trial %d: worker failed: %s", ps.name, index, exc)
                        results.append(JobResult(Trial(index, 0.0, 0.0, params=ps.trials[index],
                                                       status="error",
                                                       error=f"worker: {describe(exc)}"), (), ()))
                    if results[-1].trial.status == "done":
                        break
            return results

        return [asyncio.ensure_future(measure(index)) for index in todo]

    def _commit(self, ps: PlannedSuite, index: int, attempt: int, result: JobResult,
                wall_s: float) -> Trial:
        """One attempt measured by a worker, into the record as :meth:`TrialRunner.run_trial`
        does: it starts on the run clock now and moves it by its duration; its capture is
        merged with its times moved onto the run clock."""
        runner = self.runner
        clock = runner.writer
        start = clock.elapsed_s()
        trial = dataclasses.replace(result.trial, started_s=start)
        clock.advance(trial.duration_s)
        parts = list(result.parts)
        for k, data in enumerate(result.shipped, 1):  # on disk before the record: see recover
            part = runner.writer.artifact_path(
                f".capture.part{k}{job_part_tag(ps.name, index, attempt)}.part")
            part.write_bytes(data)
            parts.append(part)
        runner.writer.add_trial(ps.name, trial)
        runner.committed()
        runner.captures.trial(ps.name, trial)
        self.worker_s += result.worker_s
        self.jobs += 1
        for part in parts:
            runner.captures.merge(part, start - result.trial.started_s)
        for line in result.messages:
            runner.progress.message(line)
        runner.show_attempt(ps, index, attempt, trial, wall_s)
        return trial

    def close(self, park_pool: bool = True) -> None:
        """Let the worker processes go: parked for the next run of this process when every job
        sent is done and ``park_pool`` (not after a worker died), else shut down (a busy one
        finishes its trial alone)."""
        self._drop_started()
        self._in_flight = None
        pool, self.pool = self.pool, None
        sent, self._sent = self._sent, []
        if pool is not None:
            if park_pool and all(f.done() for f in sent):
                park(pool, self.runner.plan.workers)
            else:
                pool.shutdown(wait=False, cancel_futures=True)
        cluster, self.cluster = self.cluster, None
        if cluster is not None:
            cluster.close()
