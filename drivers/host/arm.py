"""The asyncio driver of the RoboLink arm: what user code is written against.

::

    async with Arm.connect("/dev/ttyUSB0") as arm:          # or "fake://", "socket://h:p", ...
        print(arm.state.q_rad)
        await arm.move_joints([0.2, 0.1, -0.3, 0.0], duty=80)
        await arm.move_to((0.45, 0.0, 0.55))
        run = await arm.follow_path(line((0.45, -0.05, 0.55), (0.45, 0.05, 0.55)), speed_m_s=0.02)

:class:`Arm` is a façade over rooms of one job each: the connection (:mod:`.link`: transport,
reader, reconnection, sending, waiting), the sans-I/O reply stream (:mod:`.replies`), the waiters
(:mod:`.waiters`), target validation (:mod:`.targets`), the arrival tracker shared by moves and
paths (:mod:`.arrival`) and path following (:mod:`.paths`). Every wait reads time from the running
loop and waits with asyncio only, so the same code runs in real time on hardware and on virtual
time against ``fake://``. The policies (resend, tolerance, timeouts, coordinated duty
quantisation, streaming, reconnect, capture) are documented in ``docs/driver.md``.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
from collections.abc import Callable, Sequence
from pathlib import Path as FsPath
from typing import Any, Final, Literal

import numpy as np
import numpy.typing as npt

from armbench.drivers.host.arrival import (
    HOLD_ON,
    MOVE_TIMEOUT_MARGIN,
    MOVE_TIMEOUT_SLACK_S,
    ArrivalTracker,
)
from armbench.drivers.host.link import (
    CONNECT_TIMEOUT_S,
    HOLD_TIMEOUT_S,
    RESEND_AFTER_S,
    ArmLink,
    LinkOptions,
    ReconnectPolicy,
)
from armbench.drivers.host.motion import Path, coordinated_duties, joint_times_s
from armbench.drivers.host.move_targets import (
    DEFAULT_TOLERANCE_RAD,
    check_command,
    check_duties,
    check_duty,
    check_target,
    default_tolerances,
    tolerances,
    wire_command,
)
from armbench.drivers.host.paths import CORNER_RAD as CORNER_RAD
from armbench.drivers.host.paths import (
    LOOKAHEAD_S,
    PathRun,
    SentWaypoint,
    path_commands,
    plan_path,
    stream_path,
)
from armbench.drivers.host.paths import MAX_WAYPOINT_JUMP_RAD as MAX_WAYPOINT_JUMP_RAD
from armbench.drivers.host.state import JointState
from armbench.drivers.host.waiters import any_state
from armbench.drivers.model.bounds import Bound, check, option_refused
from armbench.drivers.model.errors import (
    DriverClosedError,
    DriverError,
    InvalidTargetError,
    JointRangeError,
    MoveInterruptedError,
    MoveTimeoutError,
    ReplyTimeoutError,
    WaitTimeoutError,
)
from armbench.drivers.model.kinematics import Vec4, ik_best
from armbench.drivers.model.protocol import MAX_DUTY, Command
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.transports.base import Emulator, GroundTruth

__all__ = [
    "CONNECT_TIMEOUT_S",
    "DEFAULT_TOLERANCE_RAD",
    "HOLD_TIMEOUT_S",
    "LOOKAHEAD_S",
    "MOVE_TIMEOUT_MARGIN",
    "MOVE_TIMEOUT_SLACK_S",
    "RESEND_AFTER_S",
    "Arm",
    "DriverClosedError",
    "DriverError",
    "GroundTruth",
    "InvalidTargetError",
    "JointRangeError",
    "JointState",
    "LinkOptions",
    "MoveInterruptedError",
    "MoveTimeoutError",
    "PathRun",
    "ReconnectPolicy",
    "ReplyTimeoutError",
    "SentWaypoint",
    "StateStream",
    "WaitTimeoutError",
    "connect",
]

#: After ``stop()`` the state returned is the first one this long after the hold has arrived.
HOLD_SETTLE_S: Final = 0.02
#: A move's timeout, a path's speed and look-ahead, a replay's speed factor.
_POSITIVE_S: Final = Bound(0.0, unit="s", low_open=True)
_SPEED_M_S: Final = Bound(0.0, unit="m/s", low_open=True)
_LOOKAHEAD_S: Final = Bound(0.0, unit="s")
_REPLAY_SPEED: Final = Bound(0.0, low_open=True)

FloatArray = npt.NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# The state stream


class StateStream:
    """``async for state in arm.states()``: always the newest state, never a stale one.

    The first item is the state current when iteration starts (with ``include_current``), then
    each item is the newest state that arrived since the previous one; a consumer slower than the
    stream skips the states in between, counted in :attr:`skipped`. Ends when the arm is closed;
    raises :class:`ReplyTimeoutError` when the arm falls silent (iteration may go on after it) and
    :class:`PortLostError` when the port is lost for good.
    """

    def __init__(self, arm: Arm, include_current: bool = True) -> None:
        self._arm = arm
        state = arm._intake.state
        self._seen = 0 if include_current or state is None else state.seq
        self._counting = not include_current
        self.skipped = 0
        """States that arrived between two items and were not yielded."""
        self.yielded = 0
        """Items yielded so far."""

    def __aiter__(self) -> StateStream:
        return self

    async def __anext__(self) -> JointState:
        arm = self._arm
        while True:
            if arm._closed:
                raise StopAsyncIteration
            state = arm._intake.state
            if state is not None and state.seq > self._seen:
                if self._counting:
                    self.skipped += state.seq - self._seen - 1
                self._counting = True
                self._seen = state.seq
                self.yielded += 1
                return state
            try:
                await arm._wait(any_state, None)
            except DriverClosedError:
                raise StopAsyncIteration from None


# --------------------------------------------------------------------------------------------
# The driver


class Arm(ArmLink):
    """A connection to the arm. Make one with :meth:`connect` and use it as ``async with``.

    The connection, its counters and its life cycle are
    :class:`~armbench.drivers.host.link.ArmLink`'s: :attr:`frames_received` (valid replies),
    :attr:`frames_dropped` (framer error events after the
    stream was in sync), :attr:`discarded_bytes` (bytes thrown away, CR/LF excluded),
    :attr:`commands_sent`, :attr:`resends`, :attr:`reconnects`.
    """

    @classmethod
    def connect(cls, port: str, settings: RobotSettings | None = None,
                options: LinkOptions | None = None, **given: Any) -> Arm:
        """A connection to the arm on ``port``, opened by ``async with`` (or ``await``).

        ``settings``: the robot model (defaults: :class:`RobotSettings`). ``options``: how the
        connection behaves (:class:`~armbench.drivers.host.link.LinkOptions`: the reply and
        connect timeouts, the capture, the reconnection, the resend policy, a transport of the
        caller's, the factor on move timeouts), or any of its fields by keyword
        (``Arm.connect(port, reply_timeout_s=2.0, reconnect=True)``).
        """
        return cls(port, settings, options, **given)

    @property
    def emulator(self) -> Emulator | None:
        """The emulator behind the current transport (``fake://``, ``avr://`` on virtual time),
        for its side channels; else None (:meth:`Transport.emulator`)."""
        transport = self._transport  # a truth match reads this once a reply: one call less
        return None if transport is None else transport.emulator

    def ground_truth(self) -> GroundTruth | None:
        """The emulator's newest ground-truth sample when the transport has an emulator, else
        None. Real hardware has no ground truth."""
        emulator = self.emulator
        truth = () if emulator is None else emulator.truth
        return truth[-1] if truth else None

    @functools.cached_property
    def _default_tol(self) -> Vec4:
        return default_tolerances(self.settings)

    def default_tolerance_rad(self) -> Vec4:
        """Per-joint arrival tolerance used when none is given (rad): ``max(3e-4, 1.5 encoder
        counts + 1e-4)`` (the firmware's 1-count deadband, half a count of rounding of the target
        and one protocol tick of rounding of the reply)."""
        return self._default_tol

    async def send(self, command: Command) -> float:
        """Write a raw command (no waiting, no resend), after checking that its targets are
        within the joint limits; returns the loop time it was written. Used by :meth:`replay`."""
        check_command(command, self.settings)
        self._supersede()
        return await self._send(command)

    # --- validation ---------------------------------------------------------------------------

    def check_target(self, q_rad: Sequence[float] | npt.ArrayLike) -> Vec4:
        """Four finite joint angles (rad) within the limits, as floats; raises
        :class:`InvalidTargetError` / :class:`JointRangeError` naming the joint otherwise."""
        return check_target(q_rad, self.settings)

    def _tolerances(self, tolerance_rad: float | Sequence[float] | None) -> Vec4:
        return tolerances(tolerance_rad, self._default_tol)

    def _goal(self, cmd: Command) -> Vec4:
        return cmd.angles_rad(self._lower, self._upper)

    def move_timeout_s(self, start: Sequence[float], target: Sequence[float],
                       duties: Sequence[int]) -> float:
        """Default timeout of a move: ``MOVE_TIMEOUT_MARGIN`` × the slowest joint's time by law
        (12) + ``MOVE_TIMEOUT_SLACK_S`` + the command's time on the wire, all times
        :attr:`move_timeout_scale`."""
        slowest = max(joint_times_s(start, target, duties, self.settings))
        return self.move_timeout_scale * (
            MOVE_TIMEOUT_MARGIN * slowest + MOVE_TIMEOUT_SLACK_S + self._command_wire_s)

    # --- waiting ------------------------------------------------------------------------------

    def states(self, *, include_current: bool = True) -> StateStream:
        """An async iterator over the newest states (see :class:`StateStream`)."""
        return StateStream(self, include_current)

    async def wait_state(self, predicate: Callable[[JointState], bool],
                         timeout_s: float | None = None) -> JointState:
        """The first state (the current one included) for which ``predicate`` is true.

        The predicate sees the newest state each time replies arrive (replies that arrive in the
        same read are not shown one by one; use :meth:`record_states` for every one). Raises
        :class:`WaitTimeoutError` after ``timeout_s`` and :class:`ReplyTimeoutError` when the
        arm falls silent for ``reply_timeout_s``.
        """
        loop = self._loop
        if loop is None:
            raise DriverClosedError(self.port)
        since = loop.time()
        deadline = None if timeout_s is None else since + timeout_s
        self._raise_if_failed()
        state = self._intake.state
        if state is not None and predicate(state):
            return state
        while True:
            got = await self._wait(predicate, deadline, since=since)
            if got is not None:
                return got
            if deadline is not None and loop.time() >= deadline:
                assert timeout_s is not None
                raise WaitTimeoutError("wait_state", timeout_s, self._intake.state)

    def record_states(self) -> contextlib.AbstractContextManager[list[JointState]]:
        """``with arm.record_states() as states:`` collects every state received inside the block
        (not only the newest of each read)."""
        return self._recording([])

    async def _settle(self, t_s: float) -> JointState:
        """The first state that arrived at or after loop time ``t_s``."""
        assert self._loop is not None
        since = self._loop.time()
        while True:
            state = self.state
            if state.t_s >= t_s:
                return state
            got = await self._wait(lambda s: s.t_s >= t_s, None, since=since)
            if got is not None:
                return got

    # --- motion -------------------------------------------------------------------------------

    async def move_joints(self, q_rad: Sequence[float] | npt.ArrayLike,
                          duty: int | Sequence[int] = MAX_DUTY, *, wait: bool = True,
                          tolerance_rad: float | Sequence[float] | None = None,
                          timeout_s: float | None = None,
                          coordinated: bool = False) -> JointState | None:
        """Move to joint angles ``q_rad`` (rad, protocol convention) at ``duty`` (1..99, one for
        all joints or one per joint; speed law (12)).

        Everything is checked before anything is sent: NaN/inf and targets outside the joint
        limits raise :class:`InvalidTargetError` / :class:`JointRangeError`. With ``coordinated``
        the joint with the longest way runs at ``duty`` and the others slower so that all arrive
        together (see :func:`armbench.drivers.host.motion.coordinated_duties`).

        With ``wait`` (default) returns the first state within ``tolerance_rad`` (default
        :meth:`default_tolerance_rad`) of the target as put on the wire; raises
        :class:`MoveTimeoutError` after ``timeout_s`` (default :meth:`move_timeout_s`),
        :class:`ReplyTimeoutError` if the arm falls silent, :class:`MoveInterruptedError` if
        another command supersedes this one. The command is sent again when the distance to go
        stops shrinking for ``resend_after_s``. If the wait is cancelled (Ctrl-C, a timeout
        around it) or times out, a hold (``stop()``) is sent before the error propagates.
        Without ``wait`` returns None once the command is written.
        """
        target = self.check_target(q_rad)
        if coordinated:
            d = check_duty(duty)
            duties = coordinated_duties(self.state.q_rad, target, d, self.settings)
        else:
            duties = check_duties(duty)
        tol = self._tolerances(tolerance_rad)
        if timeout_s is not None:
            check("timeout_s", timeout_s, _POSITIVE_S, option_refused)
        cmd = wire_command(target, duties, self.settings)
        goal = self._goal(cmd)
        if timeout_s is None:
            timeout_s = self.move_timeout_s(self.state.q_rad, goal, duties)
        gen = self._supersede()
        t_sent = await self._send(cmd)
        if not wait:
            return None
        return await self._await_arrival(cmd, goal, tol, t_sent + timeout_s, timeout_s, gen)

    async def _await_arrival(self, cmd: Command, goal: Vec4, tol: Vec4, deadline: float,
                             timeout_s: float, gen: int) -> JointState:
        assert self._loop is not None
        t_start = self._loop.time()
        tracker = ArrivalTracker(self, tol, deadline, timeout_s, gen, since=t_start)
        tracker.aim(cmd, goal, t_start)
        try:
            return await tracker.arrive()
        except HOLD_ON:
            await self._hold_best_effort()
            raise

    async def stop(self, *, wait: bool = True) -> JointState:
        """Hold: send the current position with duty 00, which stops every joint where it is
        (and supersedes a move in progress). With ``wait`` returns the first state received
        ``HOLD_SETTLE_S`` after the hold reached the arm, else the current one."""
        state = self.state
        self._supersede()
        t = await self._send(Command.from_rad(state.q_rad, 0))
        if not wait:
            return self.state
        return await self._settle(t + self._command_wire_s + HOLD_SETTLE_S)

    async def move_to(self, xyz_m: Sequence[float] | npt.ArrayLike, roll_rad: float = 0.0, *,
                      branch: str | None = None, duty: int = MAX_DUTY, wait: bool = True,
                      coordinated: bool = False,
                      tolerance_rad: float | Sequence[float] | None = None,
                      timeout_s: float | None = None) -> JointState | None:
        """Move the TCP to ``xyz_m`` (metres, base frame) with tool roll ``roll_rad``.

        IK picks ``branch`` if given, else the solution within the limits closest to the current
        joint state; an unreachable target raises
        :class:`~armbench.drivers.model.kinematics.UnreachableError`, one outside the limits
        :class:`~armbench.drivers.model.kinematics.JointLimitError`, before anything is sent. Then
        as :meth:`move_joints`.
        """
        sol = ik_best(xyz_m, self.settings, roll=roll_rad, branch=branch, near=self.state.q_rad)
        return await self.move_joints(sol.q_protocol, duty, wait=wait, coordinated=coordinated,
                                      tolerance_rad=tolerance_rad, timeout_s=timeout_s)

    # --- paths --------------------------------------------------------------------------------

    def plan_path(self, path: Path | Sequence[Sequence[float]] | npt.ArrayLike, *,
                  roll_rad: float = 0.0, spacing_m: float = 0.005,
                  branch: str | None = None) -> tuple[FloatArray, list[Vec4]]:
        """The waypoints (N, 3, metres) of ``path`` at most ``spacing_m`` apart and their IK
        solutions on one branch (``branch``, else the one closest to the current state).

        Raises the kinematics errors for an unreachable or out-of-limits waypoint and
        :class:`~armbench.drivers.host.motion.PathError` if the IK jumps between neighbouring
        waypoints."""
        return plan_path(path, self.settings, self.state.q_rad, roll_rad=roll_rad,
                         spacing_m=spacing_m, branch=branch)

    async def follow_path(self, path: Path | Sequence[Sequence[float]] | npt.ArrayLike, *,
                          speed_m_s: float = 0.05, roll_rad: float = 0.0,
                          spacing_m: float = 0.005, branch: str | None = None,
                          max_duty: int = MAX_DUTY, approach_duty: int = MAX_DUTY,
                          lookahead_s: float = LOOKAHEAD_S,
                          tolerance_rad: float | Sequence[float] | None = None,
                          timeout_s: float | None = None) -> PathRun:
        """Move the TCP along ``path`` (a :class:`~armbench.drivers.host.motion.Path` or a sequence
        of points,
        metres) at ``speed_m_s`` with tool roll ``roll_rad``.

        The path is cut into waypoints at most ``spacing_m`` apart (corners kept), solved by IK on
        one branch, and checked whole before anything is sent. The arm first moves to the start
        (coordinated, ``approach_duty``); then the waypoints are streamed: each is sent with
        per-joint duties that make all joints arrive together after the segment's length /
        ``speed_m_s`` (never above ``max_duty``; a segment too fast for that is stretched), and
        the next is sent as soon as every joint is within ``lookahead_s`` of the current one at
        its duty (at corners sharper than 10° the arm arrives first). Returns a
        :class:`PathRun` with every state received and every command sent.
        """
        check("speed_m_s", speed_m_s, _SPEED_M_S, option_refused)
        check("lookahead_s", lookahead_s, _LOOKAHEAD_S, option_refused)
        max_duty = check_duty(max_duty)
        approach_duty = check_duty(approach_duty)
        tol = self._tolerances(tolerance_rad)
        pts, qs = self.plan_path(path, roll_rad=roll_rad, spacing_m=spacing_m, branch=branch)
        cmds, planned_s = path_commands(pts, qs, speed_m_s, max_duty, approach_duty,
                                        self.settings)
        await self.move_joints(qs[0], approach_duty, coordinated=True, tolerance_rad=tol)
        return await stream_path(self, pts, cmds, planned_s, tol, lookahead_s, timeout_s)

    # --- replay -------------------------------------------------------------------------------

    async def replay(self, capture: str | FsPath, *, speed: float = 1.0,
                     align: Literal["first", "connect"] = "first") -> int:
        """Send the host → arm commands of a capture file with their recorded spacing (divided
        by ``speed``); returns how many were sent. Does not wait for the arm at the end.

        ``align="first"``: the first command goes out now; ``"connect"``: each command goes out
        at its recorded time after the capture started, counted from this connection's opening
        (a recording made right after connecting is then reproduced to the loop, e.g. into a
        fresh ``fake://`` emulator on virtual time). The capture reader (MCAP among its
        formats) is imported here: a connection that replays nothing does not load it."""
        from armbench.drivers.capture.read import replay_capture

        check("speed", speed, _REPLAY_SPEED, option_refused)
        if align not in ("first", "connect"):
            raise InvalidTargetError(None, "align", align, "is not 'first' or 'connect'")
        assert self._loop is not None
        loop = self._loop
        t0 = loop.time() if align == "first" else self._linked0_s
        n = 0
        for item in replay_capture(capture):
            at = item.t_s if align == "first" else item.capture_t_s
            delay = t0 + at / speed - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            await self.send(item.command)
            n += 1
        return n


#: ``armbench.connect(port, ...)``: the same as :meth:`Arm.connect`.
connect = Arm.connect
