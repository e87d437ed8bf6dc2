"""One arm's run: :func:`execute` runs a prepared plan suite by suite, trial by trial, keeping
``results.json`` current, then compares with the baseline. Every arm of ``armbench run`` (one,
or a fleet) is run by it, on the loop :mod:`~armbench.bench.runner.fleet_run` chooses.

Each planned suite: ``begin_suite``, then every trial the record does not have yet
(``completed_trials``), each written to disk the moment it ends (``add_trial``), then
``summarize`` and ``end_suite``. The runner writes the record; ``junit.xml`` and ``report.html``
are written by whoever asked for the run (``armbench.cli.commands.run_files``).

What the run can do is the port's target's (:mod:`armbench.drivers.transports.target`), never
its scheme. On a target that starts a fresh arm per trial (``fake://``; default ``isolation =
"trial"``) every trial runs against a freshly powered arm seeded from (seed, suite, trial
index), so each trial is reproducible on its own and a resumed run measures exactly what an
uninterrupted one would. On hardware one connection serves the whole run (reconnecting with
back-off after a lost port).

The run clock of the record (``started_s``, ``duration_s``, ...) is the event loop's: monotonic
seconds on hardware, simulated seconds on a target on the virtual clock (where minutes of robot
time take seconds).
Semantics of errors, retries, cancellation and resume: ``docs/runner.md``.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import logging
import os
from collections.abc import Awaitable, Callable
from typing import IO

from armbench.bench.runner.lock import hold_run_folder
from armbench.bench.runner.options import (
    EXIT_ERROR,
    EXIT_FAIL,
    EXIT_PASS,
    EXIT_REGRESSION,
    RUNNER_FILE,
    BenchPlan,
    EmulatorFactory,
    PlannedSuite,
    RunAborted,
    RunAhead,
    RunOutcome,
    exit_status,
)
from armbench.bench.runner.parallel import ParallelTrials
from armbench.bench.runner.progress import ProgressPrinter
from armbench.bench.runner.required import truth_source_of
from armbench.bench.runner.trials import LoopClockWriter, TrialRunner, default_emulator
from armbench.bench.runner.truth import aclose_source, aopen_source
from armbench.record import (
    RESULTS_FILE,
    RunRecord,
    Trial,
    atomic_write_bytes,
    capture_environment,
)
from armbench.record.baseline import BaselineError, compare
from armbench.record.ci_run import ci_run
from armbench.record.files import make_directory

__all__ = ["execute"]

log = logging.getLogger("armbench.runner")


def _new_record(plan: BenchPlan) -> RunRecord:
    env = capture_environment(port=plan.port, settings=plan.settings, seed=plan.seed,
                              faults=[dataclasses.asdict(f) for f in plan.faults],
                              limits=plan.config, dut=plan.dut, ci=ci_run(os.environ),
                              target_kind=plan.target.scheme or "serial",
                              truth_source=truth_source_of(
                                  plan.runner_info.get("tracker"), plan.target.capabilities.truth,
                                  plan.target.scheme))
    record = RunRecord.new(env, [s.name for s in plan.suites], run_id=plan.run_id)
    record.required = list(plan.required)
    return record


def _todo(runner: TrialRunner, ps: PlannedSuite) -> list[int]:
    """The trials of ``ps`` to measure: its shard's, less those the record has done."""
    done = {t.index for t in runner.writer.completed_trials(ps.name)}
    return [i for i in runner.plan.shard_trials(ps) if i not in done]


def _start_next(runner: TrialRunner, parallel: ParallelTrials,
                following: PlannedSuite | None) -> Callable[[], Awaitable[None]] | None:
    """What sends the trials of the suite ``following`` to the workers while the one before it
    ends (its last trial, its summary): nothing when there is none or it is measured in
    turn."""
    if following is None:
        return None

    async def start() -> None:
        if runner.writer.suite_done(following.name):
            return
        todo = _todo(runner, following)
        if parallel.usable(following, todo):
            await parallel.start(following, todo)

    return start


async def _run_suite(runner: TrialRunner, parallel: ParallelTrials, ps: PlannedSuite,
                     following: PlannedSuite | None = None) -> None:
    """Every trial of ``ps`` the record lacks (in worker processes when it can; those of the
    ``following`` suite sent to them as the last of these runs), then its summary; a trial that
    stays in error ends the suite."""
    writer = runner.writer
    name = ps.name
    if writer.suite_done(name):
        runner.progress.message(f"[{name}] done in the record, skipped")
        return
    writer.begin_suite(name, ps.suite.version, ps.params)
    runner.begin_wall(name)
    n = len(ps.trials)
    done = {t.index for t in writer.completed_trials(name)}
    shard = runner.plan.shard
    todo = _todo(runner, ps)
    runner.progress.message(f"[{name}] {n} trial(s)" + (
        f", {len(done)} already measured" if done else "") + (
        f", shard {shard[0]}/{shard[1]}: {len(todo)} to measure" if shard else ""))
    stopped: Trial | None = None
    if parallel.usable(ps, todo):
        stopped = await parallel.run(ps, todo,
                                     following=_start_next(runner, parallel, following))
    else:
        for k, index in enumerate(todo):
            if k and runner.plan.settle_s > 0:
                await asyncio.sleep(runner.plan.settle_s)
            trial = await runner.run_trial(ps, index)
            if trial.status == "error":
                stopped = trial
                break
    if stopped is not None:
        runner.end_suite(name, error=f"trial {stopped.index}: {stopped.error}")
        runner.progress.message(f"[{name}] stopped: trial {stopped.index}: {stopped.error}")
        return
    if shard is not None:  # a summary of one shard's trials would mislead: merge summarises
        runner.end_suite(name)
        runner.progress.message(f"[{name}] shard {shard[0]}/{shard[1]} done (summary: "
                                "armbench merge)")
        return
    await runner.summarize(ps)


async def execute(plan: BenchPlan, *, progress: IO[str] | None = None,
                  emulator_factory: EmulatorFactory | None = None,
                  writer_class: type[LoopClockWriter] = LoopClockWriter,
                  ahead: RunAhead | None = None) -> RunOutcome:
    """Run a prepared plan (see the module docstring); returns the outcome. ``ahead`` hears
    when the first trial is in the record and when each suite's summary is
    (:class:`~armbench.bench.runner.options.RunAhead`).

    Cancellation (Ctrl-C) abandons the current trial (the driver tells the arm to hold), keeps
    the record as it is on disk (every finished trial) and propagates
    :class:`asyncio.CancelledError`. The run folder is locked while the run writes it
    (:mod:`armbench.bench.runner.lock`): a second writer is refused before anything is written.
    """
    if plan.resume is None:
        make_directory(plan.out_dir, "run folder")
    with hold_run_folder(plan.out_dir):
        return await _execute(plan, progress=progress, emulator_factory=emulator_factory,
                              writer_class=writer_class, ahead=ahead)


async def _execute(plan: BenchPlan, *, progress: IO[str] | None,
                   emulator_factory: EmulatorFactory | None,
                   writer_class: type[LoopClockWriter],
                   ahead: RunAhead | None) -> RunOutcome:
    if plan.resume is not None:
        resumed = writer_class.resume(plan.out_dir)
        assert isinstance(resumed, LoopClockWriter)
        writer = resumed
        for ps in plan.suites:  # planned suites may be re-checked, never changed
            if ps.name not in writer.record.planned_suites:
                writer.record.planned_suites.append(ps.name)
    else:
        writer = writer_class(plan.out_dir, _new_record(plan))
    atomic_write_bytes(writer.artifact_path(RUNNER_FILE),
                       (json.dumps(plan.runner_info, indent=1) + "\n").encode())
    t_run0 = writer.elapsed_s()
    printer = ProgressPrinter(progress, plan.total_trials(),
                              robot_clock=(lambda: writer.elapsed_s() - t_run0)
                              if plan.target.virtual else None)
    for ps in plan.suites:
        printer.plan(ps.name, len(plan.remaining_trials(ps)))
    runner = TrialRunner(plan, writer, printer,
                         emulator_factory if emulator_factory is not None else default_emulator,
                         ahead=ahead)
    parallel = ParallelTrials(runner)
    if plan.resume is not None:
        runner.captures.recover(writer.record, writer.out_dir)
    printer.message(f"armbench run {plan.run_id}: {', '.join(s.name for s in plan.suites)} on "
                    f"{plan.port} -> {plan.out_dir}")
    for warning in plan.warnings:
        printer.message(f"warning: {warning}")
    error: str | None = None
    interrupted = False
    try:
        if plan.tracker is not None:
            await aopen_source(plan.tracker)
        try:
            for k, ps in enumerate(plan.suites):
                await _run_suite(runner, parallel, ps, plan.suites[k + 1]
                                 if k + 1 < len(plan.suites) else None)
        finally:
            try:
                parallel.close()
                await runner.attempts.close()
            finally:
                if plan.tracker is not None:
                    await aclose_source(plan.tracker)
        if plan.baseline is not None:
            try:
                writer.set_baseline(compare(writer.record, plan.baseline, plan.config))
            except BaselineError as exc:
                error = f"baseline: {exc}"
    except RunAborted as exc:
        error = str(exc)
    except (asyncio.CancelledError, KeyboardInterrupt):
        interrupted = True
        raise
    finally:
        try:
            if writer_class is not LoopClockWriter:  # a batching writer's last trials
                writer.write()
        finally:
            _close_capture(runner, writer)
        printer.finish()
        if interrupted:
            printer.message(f"interrupted: the record keeps every finished trial; continue with "
                            f"armbench run --resume {plan.out_dir}")
    record = writer.record
    status = exit_status(record.verdict)
    if error is not None and status in (EXIT_PASS, EXIT_FAIL, EXIT_REGRESSION):
        status = EXIT_ERROR  # a baseline that cannot be used: bad input
    return RunOutcome(plan.out_dir, record, status, error=error, warnings=tuple(plan.warnings),
                      capture_max_bytes=plan.capture_max_bytes)


def _close_capture(runner: TrialRunner, writer: LoopClockWriter) -> None:
    """Write the rest of the capture and close it. An OS error here (a full disk) costs the
    capture's tail, said in the log, never the record or the error that stopped the run: the
    record is what the run is for, and is already on disk."""
    try:
        runner.captures.flush()
        runner.captures.finish({RESULTS_FILE: writer.artifact_path(RESULTS_FILE)})
    except OSError as exc:
        log.warning("capture %s could not be completed: %s", runner.captures.capture,
                    exc.strerror or exc)
