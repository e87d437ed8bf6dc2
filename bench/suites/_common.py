"""Helpers shared by the bench suites: sampling the reply stream, ground truth, guarded trials.

Time: everything here reads time from the running loop (``loop.time()``, seconds) and waits with
asyncio only, so it runs on virtual time against ``fake://`` and in real time on hardware. Every
wait has a timeout: the driver's (reply silence, move deadlines) or one given here.

Units: positions in metres (``*_m``), joint angles in radians (``*_rad``, protocol convention),
times in seconds (``*_s``, from the trial's start in samples). Samples are rounded to
:data:`POS_DECIMALS` / :data:`RAD_DECIMALS` places *before* any metric is computed from them, so
the figures in the record can be recomputed from the record's own samples exactly.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from collections.abc import Awaitable, Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from types import TracebackType
from typing import TYPE_CHECKING, Any, Final

import numpy as np
import numpy.typing as npt

from armbench.bench.suites.base import SuiteContext
from armbench.bench.suites.truth_probe import TruthProbe
from armbench.drivers.host.arm import DriverClosedError
from armbench.drivers.host.motion import (
    MAX_PERIOD_CYCLES,
    MIN_PERIOD_CYCLES,
    duty_for_step_rate,
    step_rate,
)
from armbench.drivers.model.bounds import Bound, check
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.kinematics import BRANCHES, KinematicsError, ik_best, tcp_point
from armbench.drivers.model.protocol import MAX_DUTY, REPLY_LEN
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.drivers.model.tasks import cancel_and_wait
from armbench.drivers.transports.base import Emulator
from armbench.record import Better, Measurement, Trial
from armbench.record.suite_contract import POS_DECIMALS, RAD_DECIMALS

if TYPE_CHECKING:
    from armbench.drivers.host.arm import Arm, JointState

__all__ = [
    "MEASUREMENT_ERRORS",
    "POS_DECIMALS",
    "RAD_DECIMALS",
    "Measurements",
    "StateRecorder",
    "TrialAborted",
    "TrialSkipped",
    "check_bool",
    "check_branch",
    "check_reachable",
    "check_vec3",
    "duty_for_speed_pct",
    "eeprom_counters",
    "emulator_of",
    "fk_m",
    "guarded_trial",
    "loop_time",
    "pos_list",
    "rad_list",
    "settled_state",
    "speed_pct_for_duty",
]

FloatArray = npt.NDArray[np.float64]
Vec3 = tuple[float, float, float]


#: What makes a trial unmeasurable (status ``"error"``) rather than a badly performing robot:
#: the driver's and transports' errors (lost port, reply or move timeouts, refused targets) and
#: plain timeouts / OS errors. ``MoveTimeoutError`` and ``ReplyTimeoutError`` are both here.
MEASUREMENT_ERRORS: Final = (ArmbenchError, TimeoutError, OSError)


class TrialAborted(ArmbenchError):
    """Raised inside a trial body to end it as ``status="error"`` with this reason."""


class TrialSkipped(Exception):
    """Raised inside a trial body that cannot measure on this bench (no power switch, no
    reference instrument): the trial is kept as done but untested, with ``reason``."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


# --------------------------------------------------------------------------------------------
# Small conversions


def loop_time() -> float:
    """The running loop's clock (s): the only clock suites read."""
    return asyncio.get_running_loop().time()


def pos_list(p: Iterable[float]) -> list[float]:
    """A position (m) as a JSON list rounded to :data:`POS_DECIMALS`."""
    return [round(float(v), POS_DECIMALS) for v in p]


def rad_list(q: Iterable[float]) -> list[float]:
    """Joint angles (rad) as a JSON list rounded to :data:`RAD_DECIMALS`."""
    return [round(float(v), RAD_DECIMALS) for v in q]


def fk_m(q_rad: Sequence[float], settings: RobotSettings) -> Vec3:
    """TCP position (m, base frame) of protocol joint angles ``q_rad`` (rad)."""
    return tcp_point([float(q) for q in q_rad], settings)


def duty_for_speed_pct(speed_pct: float) -> int:
    """The PWM duty whose step rate is ``speed_pct`` % of the rated (duty 99) step rate.

    Law (12): a joint steps every ``101 − v`` control cycles of 80 µs, so its speed is
    ``∝ 1 / (101 − v)``: 100 % → period 2 → duty 99; 50 % → period 4 → duty 97; 10 % → period
    20 → duty 81. The period is rounded to a whole number of cycles (law (12) allows no other),
    clamped to duty 1..99.
    """
    if not (math.isfinite(speed_pct) and 0 < speed_pct <= 100):
        raise ValueError(f"speed {speed_pct!r} % is not in (0, 100]")
    return duty_for_step_rate(step_rate(MAX_DUTY) * speed_pct / 100.0)


def speed_pct_for_duty(duty: int) -> float:
    """The step rate at ``duty`` as a percentage of the rated (duty 99) rate, law (12)."""
    return 100.0 * step_rate(duty) / step_rate(MAX_DUTY)


assert (MIN_PERIOD_CYCLES, MAX_PERIOD_CYCLES) == (2, 100)  # the mapping above relies on it


# --------------------------------------------------------------------------------------------
# Parameter checks (raise SettingsError naming ``suites.<suite>.<key>``)

#: The most laps or cycles a suite parameter may ask for: a bound on a run's length, checked
#: before anything moves (200 laps of the accuracy suite take about 45 min of robot time).
MAX_REPEATS = 1000
#: A coordinate of a point (``check_vec3``): any finite number of metres.
_COORDINATE_M = Bound(unit="m")


def check_bool(where: str, value: object) -> bool:
    """A boolean."""
    if not isinstance(value, bool):
        raise SettingsError(where, value, "is not true or false")
    return value


def check_vec3(where: str, value: object) -> Vec3:
    """Three finite numbers (m)."""
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != 3:
        raise SettingsError(where, value, "is not a list of 3 numbers")
    x, y, z = (check(where, v, _COORDINATE_M) for v in value)
    return x, y, z


def check_branch(where: str, value: object) -> str:
    """One of the IK branches (``front-up``, ...)."""
    if not isinstance(value, str) or value not in BRANCHES:
        raise SettingsError(where, value, f"is not one of {', '.join(BRANCHES)}")
    return value


def check_reachable(where: str, points_m: Iterable[Sequence[float]] | FloatArray,
                    settings: RobotSettings, *, branch: str, roll_rad: float) -> list[Vec3]:
    """Check that every point (m) has an IK solution on ``branch`` with tool roll ``roll_rad``
    (rad) within the joint limits; returns the points. Raises SettingsError naming the first
    point that has none."""
    out: list[Vec3] = []
    for p in np.asarray(points_m, dtype=np.float64).reshape(-1, 3):
        try:
            ik_best(p, settings, roll=roll_rad, branch=branch)
        except KinematicsError as exc:
            raise SettingsError(where, [round(float(v), 4) for v in p],
                                f"is not reachable on branch {branch} within the joint "
                                f"limits: {exc}") from None
        out.append((float(p[0]), float(p[1]), float(p[2])))
    return out


# --------------------------------------------------------------------------------------------
# Measurements


@dataclass(slots=True)
class Measurements:
    """Collects judged measurements; values that are not finite are left out (a figure that
    cannot be computed is absent, never NaN)."""

    ctx: SuiteContext
    items: list[Measurement] = field(default_factory=list)

    def add(self, name: str, value: float | None, unit: str, *, better: Better | None = None,
            description: str = "", undirected: bool = False) -> None:
        """Judge and keep ``name`` = ``value`` ``unit``; ``better`` defaults by unit.
        ``undirected`` figures (a signed bias, a duration set by a parameter) never regress."""
        if value is None or not math.isfinite(value):
            return
        if undirected:
            self.items.append(_undirected(self.ctx.judge(name, value, unit,
                                                         description=description)))
            return
        self.items.append(self.ctx.judge(name, float(value), unit, better=better,
                                         description=description))


def _undirected(m: Measurement) -> Measurement:
    return Measurement(m.name, m.value, m.unit, m.limit, m.outcome, None, m.description)


# --------------------------------------------------------------------------------------------
# Sampling the reply stream during a motion


class StateRecorder:
    """``async with StateRecorder(ctx, t0, period_s) as rec:`` records the reply stream.

    A background task follows the reply stream and keeps one sample per ``period_s`` (s; 0 =
    every reply): ``{"t_s": s from t0, "q_rad": reported joints, "reported_m": FK of them,
    "true_m": true TCP (when truth exists)}`` plus ``extra`` keys. The period is kept on the
    line's clock too: a busy host reads the replies that waited for it all at once, at one loop
    time, but the line carried them a reply period (:data:`REPLY_LEN` bytes) apart at least, so
    they are sampled as they came (:meth:`_take`), not one per read. The driver raises on a
    silent arm (``reply_timeout_s``) or a lost port; the error is kept and re-raised by
    :meth:`check` and on exit, so a trial whose recording broke becomes an error trial.
    """

    def __init__(self, ctx: SuiteContext, t0: float, period_s: float, *,
                 extra: Mapping[str, Any] | None = None,
                 into: list[dict[str, Any]] | None = None) -> None:
        self._ctx = ctx
        self._t0 = t0
        self._period = max(0.0, period_s)
        self._extra = dict(extra or {})
        self._probe = TruthProbe(ctx)
        self._task: asyncio.Task[None] | None = None
        self.samples: list[dict[str, Any]] = into if into is not None else []
        """The recorded samples, oldest first (``into`` when given: the trial's sample list)."""
        self.error: BaseException | None = None
        """Why the recording stopped early, if it did."""
        self.last_state: JointState | None = None
        self._reply_s = REPLY_LEN * ctx.settings.serial.byte_time_s
        self._last_t = -math.inf
        """Loop time of the last sample (its reply's, dated on the line's clock)."""
        self._last_seq = 0
        self._seen = 0
        """Number of the newest reply looked at."""
        self._received: list[JointState] = []
        """Every reply received since the task last ran (the driver's recorder list)."""

    def sample(self, state: JointState, **extra: Any) -> dict[str, Any]:
        """Record ``state`` now (also used for single pose samples) and return the sample."""
        q = rad_list(state.q_rad)
        s: dict[str, Any] = {"t_s": round(state.t_s - self._t0, 6), **self._extra, **extra,
                             "q_rad": q, "reported_m": pos_list(fk_m(q, self._ctx.settings))}
        true_m = self._probe.position(state)
        if true_m is not None:
            s["true_m"] = pos_list(true_m)
        self.samples.append(s)
        self.last_state = state
        return s

    def _due(self, state: JointState, t_s: float) -> bool:
        """Whether a reply dated ``t_s`` is a period after the last sample, on the loop's clock
        or by the replies the line carried since."""
        period = self._period
        return (t_s - self._last_t + 1e-9 >= period
                or (state.seq - self._last_seq) * self._reply_s + 1e-9 >= period)

    def _take(self, replies: Sequence[JointState]) -> None:
        """Sample the replies received since the last call (oldest first) that are due. Each is
        dated no later than its read, nor than the newest one's read less a reply period for
        each reply after it (the latest it can have come off the line), nor before the last
        sample: replies read one at a time keep their reads' times."""
        newest = replies[-1]
        for state in replies:
            if state.seq <= self._seen:
                continue
            t_s = max(self._last_t, min(state.t_s, newest.t_s
                                        - (newest.seq - state.seq) * self._reply_s))
            if self._due(state, t_s):
                self.sample(state if t_s == state.t_s else state._replace(t_s=t_s))
                self._last_t, self._last_seq = t_s, state.seq
        self._seen = max(self._seen, newest.seq)

    async def _run(self) -> None:
        arm = self._ctx.arm
        # The driver checks the newest reply of each read and wakes this task only when it is
        # due (its older ones, kept by the driver's recorder, are dated before it), not for
        # every reply (~420/s) as ``async for state in arm.states()`` would.
        try:
            with arm.record_states() as received:
                self._received = received
                while True:
                    state = await arm.wait_state(
                        lambda s: s.seq > self._seen and self._due(s, s.t_s))
                    replies = received[:] or [state]  # the current one, when due at the start
                    del received[:]
                    self._take(replies)
        except DriverClosedError:
            return  # the connection ended: so does the recording
        except asyncio.CancelledError:
            raise
        except MEASUREMENT_ERRORS as exc:
            self.error = exc

    def check(self) -> None:
        """Re-raise the error that stopped the recording, if any."""
        if self.error is not None:
            raise self.error

    async def __aenter__(self) -> StateRecorder:
        self._task = asyncio.get_running_loop().create_task(self._run(), name="suite-recorder")
        await asyncio.sleep(0)
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> None:
        await self.stop()
        if exc is None:
            self.check()

    async def stop(self) -> None:
        """Stop recording (idempotent); records the newest state once more so the series ends at
        the arrival."""
        task, self._task = self._task, None
        if task is None:
            return
        await cancel_and_wait(task)
        if self.error is None:
            if self._received:  # replies the task did not get to
                self._take(self._received)
                del self._received[:]
            with contextlib.suppress(ArmbenchError):
                state = self._ctx.arm.state
                if self.last_state is None or state.seq != self.last_state.seq:
                    self.sample(state)


# --------------------------------------------------------------------------------------------
# Guarded trials


async def guarded_trial(ctx: SuiteContext, index: int, params: Mapping[str, Any],
                        body: Callable[[list[dict[str, Any]]], Awaitable[
                            tuple[list[dict[str, Any]], list[Measurement]]]],
                        *, timeout_s: float) -> Trial:
    """Run ``body(samples)`` as trial ``index`` under an overall ``timeout_s`` (s).

    ``body`` gets a list it may append samples to as it goes (kept in an error trial) and returns
    the final samples and measurements. A driver/transport error, a timeout, or
    :class:`TrialAborted` makes the trial ``status="error"`` with the reason; :class:`TrialSkipped`
    a done trial that measured nothing (``skipped``); the samples gathered so far are kept.
    ``started_s`` is the loop time (s) the trial began: the runner re-stamps it
    on the run clock when it records the trial.
    """
    t0 = loop_time()
    partial: list[dict[str, Any]] = []
    try:
        async with asyncio.timeout(timeout_s):
            samples, measurements = await body(partial)
    except TimeoutError as exc:
        reason = str(exc) or f"trial did not finish within {timeout_s:.1f} s"
        return Trial(index, t0, max(0.0, loop_time() - t0), dict(params), partial, (),
                     "error", f"{type(exc).__name__}: {reason}")
    except MEASUREMENT_ERRORS as exc:
        return Trial(index, t0, max(0.0, loop_time() - t0), dict(params), partial, (),
                     "error", f"{type(exc).__name__}: {exc}")
    except TrialSkipped as exc:
        return Trial(index, t0, max(0.0, loop_time() - t0), dict(params), partial, (),
                     skipped=exc.reason)
    return Trial(index, t0, max(0.0, loop_time() - t0), dict(params), samples, measurements)


async def settled_state(arm: Arm, settle_s: float) -> JointState:
    """Wait ``settle_s`` (s), then return the first reply received at or after that moment
    (raises the driver's timeout errors if the arm is silent)."""
    loop = asyncio.get_running_loop()
    if settle_s > 0:
        await asyncio.sleep(settle_s)
    t = loop.time()
    return await arm.wait_state(lambda s: s.t_s >= t, timeout_s=max(1.0, 4 * arm.reply_timeout_s))


# --------------------------------------------------------------------------------------------
# The emulator's side channels (fake://)


def emulator_of(arm: Arm) -> Emulator | None:
    """The emulator behind ``arm``'s port (``fake://``, ``avr://`` on virtual time), else None
    (hardware, pty, TCP)."""
    return arm.emulator


def eeprom_counters(arm: Arm) -> tuple[tuple[int, ...], tuple[int, ...]] | None:
    """``(record writes, max cell wear)`` per joint from the emulator's statistics, or None
    when the port has no emulator (hardware: EEPROM writes are not observable)."""
    emu = emulator_of(arm)
    stats = getattr(emu, "stats", None)
    if stats is None:
        return None
    s = stats()
    return tuple(s.eeprom_record_writes), tuple(s.eeprom_max_cell_wear)
