"""Trial execution: connections to the arm (a fresh arm per trial on a target that starts one,
such as ``fake://``), one
attempt of a trial (:class:`TrialAttempts`, also what a worker process runs), and the trials of a
suite measured in turn and committed to the record (:class:`TrialRunner`)."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import random
import time
from collections.abc import Mapping, Sequence
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Any, Protocol

from armbench.bench.runner.capture_parts import CaptureParts
from armbench.bench.runner.options import (
    CAPTURE_FILE,
    BenchPlan,
    EmulatorFactory,
    PlannedSuite,
    RunAborted,
    RunAhead,
    derive_seed,
)
from armbench.bench.runner.part_events import emulator_truth, fault_events, logged_power
from armbench.bench.runner.power import port_power
from armbench.bench.runner.progress import ProgressPrinter
from armbench.bench.runner.truth import EmulatorTruth
from armbench.bench.suites import SuiteContext
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.transports.base import Emulator, emulated
from armbench.drivers.transports.capabilities import FreshArm
from armbench.record import (
    RESULTS_FILE,
    Measurement,
    RecordWriter,
    RunRecord,
    Trial,
    continued_clock_s,
)

if TYPE_CHECKING:
    from armbench.drivers.capture.part import PartWriter
    from armbench.drivers.host.arm import Arm
    from armbench.fakes.firmware.arm_emulator import ArmEmulator
    from armbench.fakes.firmware.emulator_settings import EmulatorSettings
    from armbench.fakes.firmware.faults import Fault

__all__ = ["Connection", "LoopClockWriter", "Messages", "RunClock", "TrialAttempts",
           "TrialRunner", "default_emulator", "describe"]

log = logging.getLogger("armbench.runner")

#: What makes a trial unmeasurable without being a bug: the driver's and transports' errors, and
#: plain timeouts and OS errors (the suites' own guard treats the same ones alike).
MEASUREMENT_ERRORS = (ArmbenchError, TimeoutError, OSError)


def describe(exc: BaseException) -> str:
    """An exception as a trial's error text; one that is not a measurement error is a bug."""
    if isinstance(exc, MEASUREMENT_ERRORS):
        return f"{type(exc).__name__}: {exc}"
    return f"bench bug: {type(exc).__name__}: {exc}"


def default_emulator(robot: RobotSettings, settings: EmulatorSettings,
                     faults: Sequence[Fault]) -> ArmEmulator:
    """The built-in emulator of a ``fake://`` connection."""
    from armbench.fakes.firmware.arm_emulator import ArmEmulator

    return ArmEmulator(robot, settings, faults)


class RunClock(Protocol):
    """What an attempt needs of the record writer: the run directory and the run clock."""

    def artifact_path(self, name: str | PurePath) -> Path:
        """A path inside the run directory."""

    def elapsed_s(self) -> float:
        """Seconds on the run clock."""


class Messages(Protocol):
    """Where an attempt's progress lines go."""

    def message(self, text: str) -> None:
        """Show (or keep) one line."""


class LoopClockWriter(RecordWriter):
    """A :class:`RecordWriter` whose run clock is the event loop's (simulated seconds on
    ``fake://``, monotonic seconds on hardware), continued across resumes."""

    def __init__(self, out_dir: str | Path, record: RunRecord, *, filename: str = RESULTS_FILE,
                 overwrite: bool = False) -> None:
        self._loop = asyncio.get_running_loop()
        self._loop_t0 = self._loop.time()
        self._start_s = continued_clock_s(Path(out_dir), record)
        super().__init__(out_dir, record, filename=filename, overwrite=overwrite)

    def elapsed_s(self) -> float:
        return self._start_s + self._loop.time() - self._loop_t0

    def advance(self, dt_s: float) -> None:
        """Move the run clock by ``dt_s`` (s) of robot time spent elsewhere: a trial measured
        in a worker process on its own loop."""
        self._start_s += dt_s


@dataclasses.dataclass(slots=True)
class Connection:
    """One open arm with its capture part file, and the side channel of a fresh simulated arm
    (``transport.emulator``: ground truth, power), closed with the connection."""

    arm: Arm
    emulator: Emulator | None
    part: Path
    writer: PartWriter | None = None


class TrialAttempts:
    """Measures attempts of trials: connects (a fresh emulator per trial with ``isolation =
    "trial"``, else the run's connection, opened again when lost), builds the suite's context and
    runs ``Suite.run_trial``. Capture parts of attempts are left in :attr:`unmerged` for the
    caller to merge once the trial is in the record."""

    def __init__(self, plan: BenchPlan, clock: RunClock, messages: Messages,
                 emulator_factory: EmulatorFactory, *, part_tag: str = "") -> None:
        self.plan = plan
        self.clock = clock
        self.messages = messages
        self.emulator_factory = emulator_factory
        self.conn: Connection | None = None
        self.captures = CaptureParts(clock.artifact_path(CAPTURE_FILE), plan.capture_max_bytes,
                                     messages.message)
        self._parts = 0
        self._part_tag = part_tag
        self.unmerged: list[Path] = []
        """Capture parts of trials not yet in the record (merged once they are)."""
        self.last_arm: Arm | None = None

    async def connect(self, emulator_seed: int, robot: RobotSettings | None = None, *,
                      own: bool = False) -> Connection:
        """Open the arm (on a target that starts fresh arms a new one seeded with
        ``emulator_seed``, playing the arm ``robot``, by default the plan's). A connection that
        fails (or is interrupted) leaves what its arm said in its capture part: a trial's
        ``own`` part goes to :attr:`unmerged`, merged once that trial is in the record (a run
        stopped by Ctrl-C while it connects keeps no frame of a trial its record lacks); the
        run's connection's is merged now, as at its close."""
        from armbench.drivers.capture.part import PartWriter
        from armbench.drivers.host.arm import Arm, ReconnectPolicy

        plan = self.plan
        self._parts += 1
        part = self.clock.artifact_path(f".capture.part{self._parts}{self._part_tag}.part")
        fresh = plan.target.capabilities.fresh_per_trial
        transport = None
        if fresh:
            robot = plan.settings if robot is None else robot
            transport = plan.target.fresh(plan.settings.serial, FreshArm(
                robot, emulator_seed, plan.faults, self.emulator_factory))
        emulator = emulated(transport)
        capture: PartWriter | None = None
        # a lost port is reopened (not a fresh arm: a new transport would be a new arm) until
        # it has been silent for the outage timeout
        reconnect: bool | ReconnectPolicy = (False if fresh else ReconnectPolicy(
            max_attempts=None, give_up_after_s=plan.outage_timeout_s))
        try:
            # t_s on the run clock straight away: the part is added to capture.mcap as is
            if plan.capture:
                capture = PartWriter(part, asyncio.get_running_loop().time()
                                     - self.clock.elapsed_s(), truth=emulator_truth(transport))
            arm = Arm.connect(plan.port, plan.settings, reply_timeout_s=plan.reply_timeout_s,
                              capture=capture, reconnect=reconnect,
                              connect_timeout_s=plan.connect_timeout_s, transport=transport,
                              move_timeout_scale=plan.move_timeout_scale)
            await arm.open()
            if emulator is None:  # a simulator may make its side channel when opened
                emulator = emulated(transport)
        except BaseException:
            if capture is not None:
                capture.close()
            if emulator is None:
                emulator = emulated(transport)
            if emulator is not None:
                with contextlib.suppress(Exception):
                    await emulator.close()
            if own:
                self.unmerged.append(part)
            else:
                self.captures.merge(part)
            raise
        self.last_arm = arm
        return Connection(arm, emulator, part, capture)

    async def disconnect(self, conn: Connection, *, merge: bool = True) -> None:
        """Close the arm (and its emulator); its capture part is merged now, or, with
        ``merge=False``, by the caller once the trial it holds is in the record."""
        try:
            fault_events(conn.emulator, conn.writer)
            await conn.arm.close()
        finally:
            if conn.emulator is not None:
                with contextlib.suppress(Exception):
                    await conn.emulator.close()
            if merge:
                self.captures.merge(conn.part)

    def context(self, ps: PlannedSuite, arm: Arm, emulator: Emulator | None,
                rng_seed: int) -> SuiteContext:
        """What suite ``ps`` may use: the arm, the power switch and the measurement source (the
        target's own when it declares them, unless the plan names others)."""
        plan = self.plan
        caps = plan.target.capabilities
        power = plan.power
        truth = plan.tracker
        source = emulator if emulator is not None else arm
        if power is None and caps.power:
            power = port_power(source)  # the emulator's (fake://), the harness's (avr://)
        if caps.truth and truth is None:
            truth = EmulatorTruth(source, plan.settings)

        def artifacts(name: str) -> Path:
            path = self.clock.artifact_path(Path(ps.name) / name)
            path.parent.mkdir(parents=True, exist_ok=True)
            return path

        def progress(message: str) -> None:
            self.messages.message(f"[{ps.name}] {message}")

        return SuiteContext(arm=arm, settings=plan.settings, limits=plan.config,
                            params=ps.params, rng=random.Random(rng_seed), power=power,
                            truth=truth, progress=progress, artifacts=artifacts)

    async def attempt(self, ps: PlannedSuite, index: int, attempt: int,
                      trial_params: Mapping[str, Any] | None = None) -> Trial:
        """Measure trial ``index`` of ``ps`` once (its parameters ``trial_params``, by default
        ``ps.trials[index]``): the trial, or a trial in error (a lost arm on hardware raises
        :class:`RunAborted`). Its ``wall_s`` is the wall-clock time the attempt took in this
        process (a worker's own, for a trial measured in one)."""
        plan = self.plan
        clock = self.clock
        if trial_params is None:
            trial_params = ps.trials[index]
        wall0 = time.perf_counter()
        t0 = clock.elapsed_s()
        t_loop0 = asyncio.get_running_loop().time()
        own: Connection | None = None
        arm: Arm | None = None
        try:
            if plan.isolation == "trial":
                own = await self.connect(derive_seed(plan.seed, "emulator", ps.name, index,
                                                     attempt),
                                         ps.suite.emulated_settings(plan.settings, trial_params),
                                         own=True)
                conn = own
            else:
                conn = await self._run_connection()
            arm = conn.arm
            ctx = self.context(ps, conn.arm, conn.emulator, derive_seed(plan.seed, ps.name,
                                                                        index))
            if ctx.power is not None and conn.writer is not None:
                ctx = dataclasses.replace(ctx, power=logged_power(ctx.power, conn.writer, ps.name,
                                                                  index))
            result = await ps.suite.run_trial(ctx, index, trial_params)
            if not isinstance(result, Trial):
                raise TypeError(f"run_trial returned {type(result).__name__}, not a Trial")
            if result.index != index:
                raise ValueError(f"run_trial({index}) returned trial index {result.index}")
            duration = max(0.0, clock.elapsed_s() - t0)
            return self._with_outages(dataclasses.replace(
                result, started_s=t0, duration_s=duration,
                wall_s=time.perf_counter() - wall0), arm, t_loop0)
        except RunAborted:
            raise
        except Exception as exc:
            if not isinstance(exc, MEASUREMENT_ERRORS):
                log.error("suite %s trial %d: %s", ps.name, index, describe(exc),
                          exc_info=True)
            return self._with_outages(
                Trial(index, t0, max(0.0, clock.elapsed_s() - t0), params=trial_params,
                      status="error", error=describe(exc), wall_s=time.perf_counter() - wall0),
                arm, t_loop0)
        finally:
            if own is not None:
                self.unmerged.append(own.part)
                await self.disconnect(own, merge=False)

    def _with_outages(self, trial: Trial, arm: Arm | None, t_loop0: float) -> Trial:
        """``trial`` with the outages of ``arm``'s link since loop time ``t_loop0`` (the trial's
        start) among its events, timed from the trial's start as its samples are; a lost port
        marks it disturbed."""
        if arm is None:
            return trial
        now = asyncio.get_running_loop().time()
        outages = arm.link_outages(t_loop0)
        if not outages:
            return trial
        return dataclasses.replace(
            trial, events=[*trial.events, *(o.to_json(now, t_loop0) for o in outages)],
            disturbed=trial.disturbed or any(o.kind == "port lost" for o in outages))

    async def _run_connection(self) -> Connection:
        """The run's connection (``isolation = "run"``), opened again when it was lost."""
        conn = self.conn
        if conn is not None and conn.arm.connected:
            return conn
        if conn is not None:
            self.conn = None
            await self.disconnect(conn)
            self.messages.message("the arm connection was lost; connecting again")
        seed = (derive_seed(self.plan.seed, "emulator", "run")
                if self.plan.target.capabilities.fresh_per_trial else 0)
        try:
            self.conn = await (self.connect(seed) if self.last_arm is not None
                               else self._first_connection(seed))
        except ArmbenchError as exc:
            raise RunAborted(f"cannot connect to {self.plan.port}: {exc}") from exc
        return self.conn

    async def _first_connection(self, emulator_seed: int) -> Connection:
        """The run's first connection, tried again with the reconnection's back-off for up to
        ``[bench] outage_timeout_s``: the arm answered the probe a moment ago
        (:mod:`~armbench.bench.runner.probe`), so a refusal now is an outage (a server that
        serves one client at a time still closing the probe's connection, a board that resets
        as its port opens), not a wrong port."""
        from armbench.drivers.host.arm import ReconnectPolicy

        loop = asyncio.get_running_loop()
        give_up_s = loop.time() + self.plan.outage_timeout_s
        delays = ReconnectPolicy(max_attempts=None).delays()
        while True:
            try:
                return await self.connect(emulator_seed)
            except ArmbenchError as exc:
                delay_s = next(delays)
                if loop.time() + delay_s > give_up_s:
                    raise
                log.info("%s: the first connection failed (%s); connecting again", self.plan.port,
                         exc)
            await asyncio.sleep(delay_s)

    async def close(self) -> None:
        """Close the run's connection, if open."""
        conn, self.conn = self.conn, None
        if conn is not None:
            await self.disconnect(conn)


class TrialRunner:
    """The trials of a run measured in turn on the run's loop, each attempt written to the
    record the moment it ends, then each suite's summary."""

    def __init__(self, plan: BenchPlan, writer: LoopClockWriter, progress: ProgressPrinter,
                 emulator_factory: EmulatorFactory, *,
                 ahead: RunAhead | None = None) -> None:
        self.plan = plan
        self.writer = writer
        self.progress = progress
        self.attempts = TrialAttempts(plan, writer, progress, emulator_factory)
        if plan.capture:
            self.attempts.captures.open_run(plan.settings, writer.record)
        self._wall0: dict[str, float] = {}
        self._ahead = ahead
        self._started = False

    def committed(self) -> None:
        """A trial is in the record: the first time, the run is under way, and the caller's
        work ahead (:class:`RunAhead`: the report's modules) starts, so it is done while the
        trials go on instead of after them."""
        if not self._started:
            self._started = True
            if self._ahead is not None:
                self._ahead.started()

    def begin_wall(self, name: str) -> None:
        """Start the wall clock of suite ``name`` (begun in the record), counting the wall time
        earlier sessions of a resumed run spent on it (its recorded time, else its trials')."""
        suite = self.writer.suite(name)
        carried = suite.wall_s
        if carried is None:
            carried = sum(t.wall_s or 0.0 for t in (*suite.trials, *suite.superseded_trials))
        self._wall0[name] = time.perf_counter() - carried

    def end_suite(self, name: str, measurements: Sequence[Measurement] = (), *,
                  error: str | None = None) -> None:
        """End suite ``name`` in the record with the wall-clock time since :meth:`begin_wall`
        (None if its clock was never started)."""
        wall0 = self._wall0.pop(name, None)
        self.writer.end_suite(name, measurements, error=error,
                              wall_s=None if wall0 is None else time.perf_counter() - wall0)

    @property
    def captures(self) -> CaptureParts:
        """The run's ``capture.mcap``."""
        return self.attempts.captures

    async def run_trial(self, ps: PlannedSuite, index: int) -> Trial:
        """Measure trial ``index`` of ``ps`` (with its retries); the last attempt."""
        attempts = self.plan.retries + 1
        trial: Trial | None = None
        for attempt in range(attempts):
            wall0 = time.perf_counter()
            trial = await self.attempts.attempt(ps, index, attempt)
            self.writer.add_trial(ps.name, trial)
            self.committed()
            self.captures.trial(ps.name, trial)
            for part in self.attempts.unmerged:  # after the record: see CaptureParts.recover
                self.captures.merge(part)
            self.attempts.unmerged.clear()
            self.show_attempt(ps, index, attempt, trial, time.perf_counter() - wall0)
            if trial.status == "done":
                break
        assert trial is not None
        return trial

    def show_attempt(self, ps: PlannedSuite, index: int, attempt: int, trial: Trial,
                     wall_s: float) -> None:
        """The progress line of a recorded attempt: done, or its error and whether it is
        retried."""
        status = trial.status if trial.status == "done" else f"error ({trial.error})"
        lost = [ev for ev in trial.events
                if ev.get("event") == "link outage" and ev.get("kind") == "port lost"]
        if lost:
            status += (f" (disturbed: the link was lost {len(lost)} time(s), "
                       f"{sum(float(ev['duration_s']) for ev in lost):.1f} s in all)")
        retry = trial.status == "error" and attempt < self.plan.retries
        if retry:
            status += f", retrying ({attempt + 1}/{self.plan.retries})"
        self.progress.trial(ps.name, index + 1, len(ps.trials), status, wall_s, retry=retry)

    async def summarize(self, ps: PlannedSuite) -> None:
        """``Suite.summarize`` over the suite's completed trials, and the suite's end in the
        record. Both run in a thread of its own, so that the loop goes on sending the next
        suite's trials to the workers meanwhile (the summary and the record's write of a suite
        of many trials take a large part of a second); the loop waits for the thread, a
        cancellation too, so that nothing else writes the record meanwhile."""
        writer = self.writer
        arm = self.attempts.last_arm
        if arm is None:
            from armbench.drivers.host.arm import Arm

            arm = Arm(self.plan.port, self.plan.settings)  # never opened: summaries don't move
        ctx = self.attempts.context(ps, arm, None, derive_seed(self.plan.seed, ps.name,
                                                               "summary"))
        trials = writer.completed_trials(ps.name)

        def work() -> str | None:
            try:
                self.end_suite(ps.name, ps.suite.summarize(ctx, trials))
            except Exception as exc:
                log.debug("summary of %s failed", ps.name, exc_info=True)
                self.end_suite(ps.name, error=f"summary: {describe(exc)}")
                return describe(exc)
            return None

        done = asyncio.get_running_loop().run_in_executor(None, work)
        try:
            error = await asyncio.shield(done)
        except asyncio.CancelledError:
            await asyncio.wait([done])
            raise
        if error is not None:
            self.progress.message(f"[{ps.name}] summary failed: {error}")
            return
        suite = writer.suite(ps.name)
        every = [*(m for t in suite.trials for m in t.measurements), *suite.measurements]
        failed = [m.name for m in every if m.outcome == "fail"]
        # the count the report shows: trial-level and suite-level measurements alike
        self.progress.message(f"[{ps.name}] done: {len(every)} measurement(s) "
                              f"({len(suite.measurements)} at suite level)"
                              + (f", {len(failed)} outside limits" if failed else ""))
        if self._ahead is not None:
            self._ahead.summarized(writer.record, ps.name)
