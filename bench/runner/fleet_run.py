"""The one run path behind ``armbench run``: every arm of a run (one, or a fleet of several at
once: ``--port P1 --port P2 ...``) is laid out (:func:`~armbench.bench.runner.arms.lay_out`),
prepared (:func:`~armbench.bench.runner.plan.prepare`) and probed, then run by
:func:`~armbench.bench.runner.execute.execute` on one event loop. A run of one arm is a fleet
of one: the same steps, its folder laid out as a run of its own.

::

    result = run_arms_sync(RunOptions(suites=["accuracy"], ports=["a=fake://", "b=fake://?seed=5"],
                                      out="runs/x"))
    result.exit_status, result.failed    # the worst arm's status; the arms that did not pass
    outcome = run_sync(RunOptions(suites=["accuracy"], out="runs/y"))   # a run of one arm
    outcome.exit_status    # 0 pass, 1 limit, 2 bad input, 3 regression, 4 incomplete, 130

Every arm's plan is prepared (checked), and every arm that is already there must answer at its
port (:mod:`~armbench.bench.runner.probe`), before any arm moves or the run's folder is made: a
port where no arm answers refuses the run as bad input. Once begun, one arm failing (a lost
port, a limit, a bug) does not stop the others; the exit status is the worst of the arms'
(:func:`fleet_exit_status`). A fleet's folder holds ``fleet.json`` (the arms, their ports,
verdicts and exit statuses: what the fleet page reads) and a folder per arm, its progress lines
start with the arm's name. The one arm of a run that is not a fleet has its folder for itself,
and what ended it early is the run's: its exception is raised, and Ctrl-C before it wrote a
record is ``KeyboardInterrupt``. The loop is the virtual-time one when every arm's target is on
the virtual clock (``fake://``), a real one otherwise (a ``fake://`` arm beside real ones then
runs on real time).
"""

from __future__ import annotations

import asyncio
import contextlib
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, cast

from armbench.bench.runner.arms import Arm, ArmRun, RunLayout, arm_name, lay_out, parse_arms
from armbench.bench.runner.execute import execute
from armbench.bench.runner.lock import hold_run_folder
from armbench.bench.runner.options import (
    EXIT_ERROR,
    EXIT_INTERRUPTED,
    EXIT_PASS,
    BenchPlan,
    EmulatorFactory,
    RunAhead,
    RunOptions,
    RunOutcome,
)
from armbench.bench.runner.overwrite import remove_earlier_run
from armbench.bench.runner.parallel import prestart_workers
from armbench.bench.runner.plan import BENCH_BOUNDS, prepare
from armbench.bench.runner.probe import probe_arms, probe_arms_sync
from armbench.bench.workers.worker_process import park_prestarted
from armbench.drivers.model.bounds import check_whole
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import SettingsError
from armbench.record import RESULTS_FILE, load_record
from armbench.record.files import make_directory
from armbench.record.fleet_index import FLEET_FILE, FleetArm, FleetIndex, write_fleet_index
from armbench.record.verdict import worst_exit_status

__all__ = ["FLEET_FILE", "Arm", "RunResult", "arm_name", "fleet_exit_status", "parse_arms",
           "run_arms", "run_arms_sync", "run_bench", "run_sync"]


def fleet_exit_status(statuses: Sequence[int]) -> int:
    """The run's exit status: the worst arm's (:func:`armbench.record.verdict.worst_exit_status`:
    130, then 2, 4, 1, 3, 0)."""
    return worst_exit_status(statuses)


@dataclass(slots=True)
class RunResult:
    """What a run left: its folder, each arm's outcome (in ``--port`` order; None for an arm
    that has no record: it failed before its run began), the errors that ended arms early and
    the run's exit status."""

    out_dir: Path
    arms: tuple[ArmRun, ...]
    outcomes: list[RunOutcome | None]
    errors: list[str | None]
    exit_status: int
    fleet: bool
    """Whether the folder is a fleet's; False: the one arm's run folder."""

    @property
    def names(self) -> list[str]:
        """Each arm's name (a fleet's; the one arm of a run is ``arm``)."""
        return [a.name or "arm" for a in self.arms]

    @property
    def failed(self) -> list[str]:
        """Names of the arms that did not pass."""
        return [n for n, s in zip(self.names, self.statuses, strict=True) if s != EXIT_PASS]

    @property
    def statuses(self) -> list[int]:
        """Each arm's exit status."""
        return [EXIT_ERROR if o is None else o.exit_status for o in self.outcomes]

    def only(self) -> RunOutcome:
        """The outcome of a run of one arm."""
        if self.fleet or self.outcomes[0] is None:
            raise ArmbenchError(f"{self.out_dir}: a run of {len(self.arms)} arms has no one "
                                "outcome")
        return self.outcomes[0]


@dataclass(slots=True)
class _Planned:
    """A run laid out, every arm's plan prepared."""

    layout: RunLayout
    plans: list[BenchPlan]


@dataclass(slots=True)
class _ArmEnd:
    """How one arm's run ended: its outcome (None: no record), the error that ended it early and
    the exception, if one did."""

    outcome: RunOutcome | None
    error: str | None
    exception: BaseException | None = None


def _plan(options: RunOptions) -> _Planned:
    layout = lay_out(options)
    plans = [prepare(options, arm) for arm in layout.arms]
    if layout.fleet and plans[0].resume is None and plans[0].dut.serial is not None:
        raise SettingsError("dut.serial", plans[0].dut.serial,
                            f"is one arm's serial number, not each of {len(plans)} arms'")
    return _Planned(layout, plans)


def _begin(planned: _Planned, held: contextlib.ExitStack, *, overwrite: bool) -> None:
    """Make the run's folder (when new) and lock it (held by ``held``), remove the run it
    holds (``overwrite``) and, for a fleet, write its index before any arm starts."""
    layout = planned.layout
    if planned.plans[0].resume is None:
        make_directory(layout.out_dir, layout.out_flag)
    held.enter_context(hold_run_folder(layout.out_dir))
    if overwrite:
        remove_earlier_run(layout.out_dir)
    if layout.fleet:
        _write_index(planned, [_ArmEnd(None, None)] * len(planned.plans), None)


def _write_index(planned: _Planned, ends: Sequence[_ArmEnd], status: int | None) -> None:
    layout = planned.layout
    assert layout.fleet_id is not None
    write_fleet_index(layout.out_dir, FleetIndex(layout.fleet_id, tuple(
        FleetArm(arm.name or "", arm.port or plan.port,
                 None if e.outcome is None else e.outcome.verdict,
                 None if e.outcome is None else e.outcome.exit_status, e.error)
        for arm, plan, e in zip(layout.arms, planned.plans, ends, strict=True)), status))


class _Prefixed:
    """A progress stream that starts every line with the arm's name (never a terminal: the
    lines of several arms interleave, none is rewritten in place)."""

    def __init__(self, stream: IO[str], name: str) -> None:
        self.stream = stream
        self.prefix = f"{name}: "
        self._at_line_start = True

    def write(self, text: str) -> int:
        out = []
        for piece in text.splitlines(keepends=True):
            if self._at_line_start:
                out.append(self.prefix)
            out.append(piece)
            self._at_line_start = piece.endswith("\n")
        self.stream.write("".join(out))
        return len(text)

    def flush(self) -> None:
        self.stream.flush()

    @staticmethod
    def isatty() -> bool:
        return False

    def __getattr__(self, name: str) -> object:
        """How much to show (``verbosity``, ``interval_s``): the wrapped stream's to say."""
        return getattr(self.stream, name)


def _from_disk(plan: BenchPlan, status: int, error: str) -> RunOutcome | None:
    """The outcome of an arm whose run ended on an exception: its record as on disk."""
    path = plan.out_dir / RESULTS_FILE
    if not path.exists():
        return None
    return RunOutcome(plan.out_dir, load_record(path), status, interrupted=status ==
                      EXIT_INTERRUPTED, error=error, warnings=tuple(plan.warnings),
                      capture_max_bytes=plan.capture_max_bytes)


async def _run_arm(plan: BenchPlan, progress: IO[str] | None,
                   emulator_factory: EmulatorFactory | None,
                   ahead: RunAhead | None) -> _ArmEnd:
    """One arm's run; an exception that escapes it ends this arm only."""
    try:
        outcome = await execute(plan, progress=progress, emulator_factory=emulator_factory,
                                ahead=ahead)
    except Exception as exc:  # the other arms go on: this one is in error
        error = f"{type(exc).__name__}: {exc}"
        return _ArmEnd(_from_disk(plan, EXIT_ERROR, error), error, exc)
    return _ArmEnd(outcome, outcome.error)


async def _run_all(planned: _Planned, progress: IO[str] | None,
                   emulator_factory: EmulatorFactory | None,
                   ahead: RunAhead | None = None) -> list[_ArmEnd]:
    layout = planned.layout
    return list(await asyncio.gather(*(
        _run_arm(plan, cast(IO[str], _Prefixed(progress, arm.name or ""))
                 if layout.fleet and progress is not None else progress, emulator_factory, ahead)
        for plan, arm in zip(planned.plans, layout.arms, strict=True))))


def _finish(planned: _Planned, ends: Sequence[_ArmEnd]) -> RunResult:
    """The run's result, in the fleet's index too; the one arm of a run that is not a fleet
    raises what ended it (its exception, or Ctrl-C before its record was written)."""
    layout = planned.layout
    if not layout.fleet:
        (end,) = ends
        if end.exception is not None:
            raise end.exception
        if end.outcome is None:  # Ctrl-C before anything was written
            raise KeyboardInterrupt
    statuses = [EXIT_ERROR if e.outcome is None else e.outcome.exit_status for e in ends]
    if any(e.error == "interrupted" for e in ends):
        statuses.append(EXIT_INTERRUPTED)
    status = fleet_exit_status(statuses)
    if layout.fleet:
        _write_index(planned, ends, status)
    return RunResult(layout.out_dir, layout.arms, [e.outcome for e in ends],
                     [e.error for e in ends], status, layout.fleet)


def _workers_in_bound(options: RunOptions) -> bool:
    """Whether ``--workers`` is absent or within its bound: a count beyond it (``--workers
    1000000``) must be refused by the plan, not started as processes first."""
    if options.workers is None:
        return True
    try:
        check_whole("--workers", options.workers, BENCH_BOUNDS["workers"])
    except ArmbenchError:
        return False
    return True


def run_arms_sync(options: RunOptions, *, progress: IO[str] | None = sys.stderr,
                  emulator_factory: EmulatorFactory | None = None,
                  then: Callable[[RunOutcome], None] | None = None,
                  ahead: RunAhead | None = None) -> RunResult:
    """Check every arm, find every arm that is already there, then run them all at once on a
    loop of the right kind (see the module docstring). Ctrl-C returns each arm's record on disk
    with exit status 130. ``then`` is called with each arm's outcome while the run's folder is
    still locked (the command writes the reports there).

    A folder to resume is locked before anything of it is read (a run still writing it is
    refused); a new run's folder once it is made, after the arms answered at their ports. Each
    arm's folder is locked by the runner too (:mod:`~armbench.bench.runner.lock`).

    ``ahead`` hears when a first trial is in each record and when each suite's summary is
    (:class:`~armbench.bench.runner.options.RunAhead`): it does work ``then`` will need while
    the trials go on (the command imports the report's modules and draws the plots).
    """
    with contextlib.ExitStack() as held:
        if _workers_in_bound(options):  # else the plan refuses them, before any process starts
            prestart_workers(options)  # they start while the run is planned
        held.callback(park_prestarted)
        if options.resume is not None and any(
                (Path(options.resume) / name).is_file() for name in (RESULTS_FILE, FLEET_FILE)):
            held.enter_context(hold_run_folder(options.resume))
        planned = _plan(options)
        probe_arms_sync(planned.plans)  # every arm answers before the run's folder is made
        _begin(planned, held, overwrite=options.overwrite)
        main = _run_all(planned, progress, emulator_factory, ahead)
        try:
            if all(plan.target.virtual for plan in planned.plans):
                from armbench.fakes.clock.vclock import run_virtual

                ends = run_virtual(main)
            else:
                ends = asyncio.run(main)
        except (KeyboardInterrupt, asyncio.CancelledError):
            ends = [_ArmEnd(_from_disk(plan, EXIT_INTERRUPTED, "interrupted"), "interrupted")
                    for plan in planned.plans]
        result = _finish(planned, ends)
        if then is not None:
            for outcome in result.outcomes:
                if outcome is not None:
                    then(outcome)
        return result


async def run_arms(options: RunOptions, *, progress: IO[str] | None = None,
                   emulator_factory: EmulatorFactory | None = None) -> RunResult:
    """:func:`run_arms_sync` on the running loop (its kind is the caller's); cancelling it
    propagates :class:`asyncio.CancelledError`, each record keeping its finished trials."""
    planned = _plan(options)
    await probe_arms(planned.plans)
    with contextlib.ExitStack() as held:
        _begin(planned, held, overwrite=options.overwrite)
        return _finish(planned, await _run_all(planned, progress, emulator_factory))


def run_sync(options: RunOptions, *, progress: IO[str] | None = sys.stderr,
             emulator_factory: EmulatorFactory | None = None,
             then: Callable[[RunOutcome], None] | None = None) -> RunOutcome:
    """A run of one arm (:func:`run_arms_sync`): its outcome."""
    return run_arms_sync(options, progress=progress, emulator_factory=emulator_factory,
                         then=then).only()


async def run_bench(options: RunOptions, *, progress: IO[str] | None = None,
                    emulator_factory: EmulatorFactory | None = None) -> RunOutcome:
    """A run of one arm on the running loop (:func:`run_arms`): its outcome."""
    return (await run_arms(options, progress=progress, emulator_factory=emulator_factory)).only()
