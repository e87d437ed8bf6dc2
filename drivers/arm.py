"""The asyncio driver of the RoboLink arm: what user code is written against.

::

    async with Arm.connect("/dev/ttyUSB0") as arm:          # or "fake://", "socket://h:p", ...
        print(arm.state.q_rad)
        await arm.move_joints([0.2, 0.1, -0.3, 0.0], duty=80)
        await arm.move_to((0.45, 0.0, 0.55))
        run = await arm.follow_path(line((0.45, -0.05, 0.55), (0.45, 0.05, 0.55)), speed_m_s=0.02)

One reader task per connection feeds a :class:`~armbench.drivers.protocol.Framer`; the newest reply
is
``arm.state``. Every wait reads time from the running loop and waits with asyncio only, so the
same code runs in real time on hardware and on virtual time against ``fake://``.
The policies (resend, tolerance, timeouts, coordinated duty quantisation, streaming, reconnect,
capture) are documented in ``docs/driver.md``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Callable, Generator, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path as FsPath
from types import TracebackType
from typing import Any, Final, Literal, NamedTuple

import numpy as np
import numpy.typing as npt

from armbench.drivers.capture import CaptureWriter, frame_text, replay_capture
from armbench.drivers.errors import (
    DriverClosedError,
    DriverError,
    InvalidTargetError,
    JointRangeError,
    MoveInterruptedError,
    MoveTimeoutError,
    PortLostError,
    ReplyTimeoutError,
    TransportError,
    WaitTimeoutError,
)
from armbench.drivers.kinematics import Vec4, ik_best, tcp_position
from armbench.drivers.motion import (
    CYCLE_S,
    Path,
    PathError,
    coordinated_duties,
    joint_times_s,
    period_for_duty,
    point_to_polyline_m,
    polyline,
    segment_duties,
)
from armbench.drivers.protocol import (
    COMMAND_LEN,
    JOINTS,
    MAX_DUTY,
    REPLY_LEN,
    AngleDecoder,
    Command,
    FrameError,
    Reply,
    rad_to_ticks,
    ticks_to_rad,
)
from armbench.drivers.protocol import Framer as _Framer
from armbench.drivers.settings import RobotSettings
from armbench.drivers.state import GroundTruth, JointState
from armbench.drivers.transports import Transport, open_transport

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

log = logging.getLogger("armbench.driver")

#: Default arrival tolerance per joint (rad): a few protocol ticks (1e-4 rad) and encoder counts.
DEFAULT_TOLERANCE_RAD: Final = 3e-4
#: A move's default timeout is this many times the slowest joint's time by law (12) ...
MOVE_TIMEOUT_MARGIN: Final = 1.5
#: ... plus this many seconds (command on the wire, loop latency, start-up of the stepping).
MOVE_TIMEOUT_SLACK_S: Final = 1.0
#: While waiting for arrival, the command is sent again when the distance to go has not shrunk
#: for this long (a command lost or corrupted on the line, an emulator restarted).
RESEND_AFTER_S: Final = 0.3
#: How long a hold sent on cancellation or failure may take before the driver gives up on it.
HOLD_TIMEOUT_S: Final = 0.5
#: After ``stop()`` the state returned is the first one this long after the hold has arrived.
HOLD_SETTLE_S: Final = 0.02
#: How long ``connect`` waits for the first valid reply (an Arduino resets when the port opens
#: and its boot loader takes up to ~2 s before the firmware replies).
CONNECT_TIMEOUT_S: Final = 3.0
#: ``follow_path`` sends the next waypoint when every joint is this close (in time, at its duty)
#: to the current one: about the latency from a reply being sampled to a command taking effect.
LOOKAHEAD_S: Final = 0.010
#: ``follow_path`` stops at a waypoint where the path turns by more than this (a corner).
CORNER_RAD: Final = math.radians(10.0)
#: ``follow_path`` refuses a path whose IK jumps by more than this between two waypoints.
MAX_WAYPOINT_JUMP_RAD: Final = 0.5
#: Distance to go (sum over joints, rad) that counts as progress: one protocol tick.
_PROGRESS_RAD: Final = 1e-4

_new = tuple.__new__

Duties = tuple[int, int, int, int]
FloatArray = npt.NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# Options and records


@dataclass(frozen=True, slots=True)
class ReconnectPolicy:
    """Exponential back-off of the reader's reconnection after a lost port: wait
    ``initial_delay_s``, then ``factor`` times longer each attempt up to ``max_delay_s``; give up
    after ``max_attempts`` (None: never) and surface :class:`PortLostError`."""

    initial_delay_s: float = 0.05
    factor: float = 2.0
    max_delay_s: float = 1.0
    max_attempts: int | None = 20

    def __post_init__(self) -> None:
        for name in ("initial_delay_s", "max_delay_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InvalidTargetError(None, f"reconnect.{name}", v, "must be a number >= 0")
        if not self.factor >= 1:
            raise InvalidTargetError(None, "reconnect.factor", self.factor, "must be >= 1")
        if self.max_attempts is not None and self.max_attempts < 1:
            raise InvalidTargetError(None, "reconnect.max_attempts", self.max_attempts,
                                     "must be >= 1 or None")

    def delays(self) -> Iterator[float]:
        """The waits before each attempt."""
        delay = self.initial_delay_s
        n = 0
        while self.max_attempts is None or n < self.max_attempts:
            yield delay
            n += 1
            delay = min(delay * self.factor, self.max_delay_s)


class SentWaypoint(NamedTuple):
    """A path command as sent: loop time, target (rad, as on the wire), duties, TCP target (m)."""

    t_s: float
    q_rad: Vec4
    duties: Duties
    xyz_m: tuple[float, float, float]


@dataclass
class PathRun:
    """What :meth:`Arm.follow_path` did: the reference waypoints (N, 3, metres), every command
    sent, and every state received from the first path command to the arrival at the end."""

    reference_m: FloatArray
    waypoints: list[SentWaypoint] = field(default_factory=list)
    states: list[JointState] = field(default_factory=list)
    t_start_s: float = 0.0
    t_end_s: float = 0.0
    resends: int = 0

    @property
    def duration_s(self) -> float:
        """Seconds from the first path command to the arrival at the last waypoint."""
        return self.t_end_s - self.t_start_s

    def samples(self) -> list[tuple[float, Vec4]]:
        """``(t_s, q_rad)`` of every recorded state."""
        return [(s.t_s, s.q_rad) for s in self.states]

    def joint_angles(self) -> FloatArray:
        """Recorded joint angles, (M, 4) rad."""
        return np.array([s.q_rad for s in self.states], dtype=np.float64).reshape(-1, 4)

    def tcp_m(self, settings: RobotSettings) -> FloatArray:
        """TCP positions of the recorded states by forward kinematics, (M, 3) metres."""
        if not self.states:
            return np.zeros((0, 3))
        out: FloatArray = tcp_position(self.joint_angles(), settings)
        return out

    def path_errors_m(self, settings: RobotSettings) -> FloatArray:
        """Distance of each recorded TCP position to the reference polyline, (M,) metres."""
        return point_to_polyline_m(self.tcp_m(settings), self.reference_m)

    def mean_error_m(self, settings: RobotSettings) -> float:
        """Mean distance of the recorded TCP positions to the reference (the paper's figure of
        merit: 12.4 mm on its square), metres."""
        e = self.path_errors_m(settings)
        return float(e.mean()) if len(e) else 0.0


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
        state = arm._state
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
            state = arm._state
            if state is not None and state.seq > self._seen:
                if self._counting:
                    self.skipped += state.seq - self._seen - 1
                self._counting = True
                self._seen = state.seq
                self.yielded += 1
                return state
            try:
                await arm._wait(_any_state, None)
            except DriverClosedError:
                raise StopAsyncIteration from None


# --------------------------------------------------------------------------------------------
# The driver


def _any_state(state: JointState) -> bool:
    return True


def _never(state: JointState) -> bool:
    return False


class _Waiter:
    """A task waiting for a state that satisfies ``predicate``: the reader evaluates it on each
    new state and resolves ``future`` with the first state that does (no task switch per reply).
    The arm's alarm resolves it with None at loop time ``wake_at`` (``inf``: never),
    :meth:`Arm._wake_all` too, marking it ``woken`` so that the waiting task returns to re-check
    its conditions."""

    __slots__ = ("future", "predicate", "wake_at", "woken")

    def __init__(self, predicate: Callable[[JointState], bool],
                 future: asyncio.Future[JointState | None], wake_at: float) -> None:
        self.predicate = predicate
        self.future = future
        self.wake_at = wake_at
        self.woken = False

    def wake(self) -> None:
        self.woken = True
        if not self.future.done():
            self.future.set_result(None)


def _consume(task: asyncio.Task[Any]) -> None:
    if not task.cancelled():
        exc = task.exception()
        if exc is not None:
            log.warning("hold after an aborted move failed: %s", exc)


class Arm:
    """A connection to the arm. Make one with :meth:`connect` and use it as ``async with``.

    Counters: :attr:`frames_received` (valid replies), :attr:`frames_dropped` (framer error events
    after the stream was in sync), :attr:`discarded_bytes` (bytes thrown away, CR/LF excluded),
    :attr:`commands_sent`, :attr:`resends`, :attr:`reconnects`.
    """

    def __init__(self, port: str, settings: RobotSettings | None = None, *,
                 reply_timeout_s: float = 0.5,
                 capture: str | FsPath | CaptureWriter | None = None,
                 reconnect: bool | ReconnectPolicy = False,
                 connect_timeout_s: float = CONNECT_TIMEOUT_S,
                 resend_after_s: float = RESEND_AFTER_S,
                 transport: Transport | None = None) -> None:
        self.port = port
        """The port string (``/dev/ttyUSB0``, ``socket://h:p``, ``fake://``, ...)."""
        self.settings = settings if settings is not None else RobotSettings()
        """The robot model: limits, drive trains, geometry, line settings."""
        for name, v in (("reply_timeout_s", reply_timeout_s),
                        ("connect_timeout_s", connect_timeout_s),
                        ("resend_after_s", resend_after_s)):
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidTargetError(None, name, v, "must be a number > 0")
        self.reply_timeout_s = float(reply_timeout_s)
        self.connect_timeout_s = float(connect_timeout_s)
        self.resend_after_s = float(resend_after_s)
        self._capture = capture if isinstance(capture, CaptureWriter) else None
        self.capture_path = (capture.path if isinstance(capture, CaptureWriter)
                             else FsPath(capture) if capture is not None else None)
        self.reconnect_policy: ReconnectPolicy | None = (
            reconnect if isinstance(reconnect, ReconnectPolicy)
            else ReconnectPolicy() if reconnect else None)
        self._given_transport = transport
        self._transport: Transport | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._reader: asyncio.Task[None] | None = None
        self._framer = _Framer("reply")
        self._lower = self.settings.lower_rad
        self._upper = self.settings.upper_rad
        self._decode = AngleDecoder(self._lower, self._upper)
        self._default_tol: Vec4 = tuple(  # type: ignore[assignment]
            max(DEFAULT_TOLERANCE_RAD, 1.5 / j.counts_per_rad + 1e-4)
            for j in self.settings.joints)
        self._command_wire_s = COMMAND_LEN * self.settings.serial.byte_time_s
        self._state: JointState | None = None
        self._seq = 0
        self._synced = False
        self._last_rx_s = -math.inf
        self._linked_s = -math.inf
        self._linked0_s = 0.0
        self._waiters: list[_Waiter] = []
        self._alarm: asyncio.TimerHandle | None = None
        self._alarm_at = math.inf
        self._recorders: list[list[JointState]] = []
        self._failure: BaseException | None = None
        self._opened = False
        self._closed = False
        self._reconnecting = False
        self._link_gen = 0
        self._generation = 0
        self.frames_received = 0
        """Valid replies decoded since connecting."""
        self.frames_dropped = 0
        """Framer error events (bad frames, runs of garbage) once the stream was in sync."""
        self.discarded_bytes = 0
        """Bytes the framer threw away (CR/LF excluded), including the partial frame a connection
        may start in the middle of."""
        self.commands_sent = 0
        """Commands written (resends and holds included)."""
        self.resends = 0
        """Commands sent again because a move made no progress."""
        self.reconnects = 0
        """Successful reconnections."""
        self.reconnect_attempts = 0
        """Failed reconnection attempts."""

    # --- life cycle ---------------------------------------------------------------------------

    @classmethod
    def connect(cls, port: str, settings: RobotSettings | None = None, *,
                reply_timeout_s: float = 0.5,
                capture: str | FsPath | CaptureWriter | None = None,
                reconnect: bool | ReconnectPolicy = False,
                connect_timeout_s: float = CONNECT_TIMEOUT_S,
                resend_after_s: float = RESEND_AFTER_S,
                transport: Transport | None = None) -> Arm:
        """A connection to the arm on ``port``, opened by ``async with`` (or ``await``).

        ``settings``: the robot model (defaults: :class:`RobotSettings`). ``reply_timeout_s``:
        longest silence tolerated while waiting for replies. ``capture``: a JSON Lines file that
        receives every frame in and out (see :mod:`armbench.drivers.capture`), times counted from
        the
        opening; or a :class:`~armbench.drivers.capture.CaptureWriter` with a time origin of the
        caller's, which the connection uses and closes. ``reconnect``: True or a
        :class:`ReconnectPolicy` to reopen a lost port with back-off. ``connect_timeout_s``: wait
        for the first valid reply. ``resend_after_s``: resend policy of moves. ``transport``: an
        unopened transport to use instead of ``open_transport(port)`` (reconnections still use
        ``open_transport``).
        """
        return cls(port, settings, reply_timeout_s=reply_timeout_s, capture=capture,
                   reconnect=reconnect, connect_timeout_s=connect_timeout_s,
                   resend_after_s=resend_after_s, transport=transport)

    async def open(self) -> None:
        """Open the transport, start the reader and wait for the first valid reply.

        Raises :class:`~armbench.drivers.errors.TransportError` if the port cannot be opened and
        :class:`ReplyTimeoutError` if no valid reply arrives within ``connect_timeout_s``;
        either way everything opened is closed again.
        """
        if self._opened:
            raise DriverError(f"{self.port}: already opened")
        self._opened = True
        self._loop = loop = asyncio.get_running_loop()
        transport = self._given_transport or open_transport(self.port, self.settings.serial)
        await transport.open()
        self._transport = transport
        self._linked_s = self._linked0_s = loop.time()
        try:
            if self._capture is None and self.capture_path is not None:
                self._capture = CaptureWriter(self.capture_path, loop.time())
            self._reader = loop.create_task(self._read_loop(), name=f"arm-reader {self.port}")
            if self._state is None and await self._wait(
                    _any_state, loop.time() + self.connect_timeout_s, reply_timeout=False) is None:
                raise ReplyTimeoutError(self.port, self.connect_timeout_s, None)
            log.info("%s: connected, first reply after %.3f s", self.port,
                     loop.time() - self._linked_s)
        except BaseException:
            await self.close()
            raise

    async def close(self) -> None:
        """Stop the reader (cancelled and awaited), close the transport and the capture.
        Idempotent; waiters and iterators see :class:`DriverClosedError` / the end."""
        if self._closed:
            return
        self._closed = True
        self._wake_all()
        if self._alarm is not None:
            self._alarm.cancel()
            self._alarm = None
        try:
            reader, self._reader = self._reader, None
            if reader is not None and not reader.done():
                reader.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await reader
        finally:
            try:
                if self._transport is not None:
                    with contextlib.suppress(TransportError, OSError):
                        await self._transport.close()
            finally:
                if self._capture is not None:
                    self._capture.close()

    async def __aenter__(self) -> Arm:
        await self.open()
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> None:
        await self.close()

    def __await__(self) -> Generator[Any, None, Arm]:
        return self.__aenter__().__await__()

    def __repr__(self) -> str:
        state = ("closed" if self._closed else "reconnecting" if self._reconnecting
                 else "open" if self._opened else "new")
        return (f"<Arm {self.port!r} {state} rx={self.frames_received} "
                f"dropped={self.frames_dropped} tx={self.commands_sent}>")

    # --- properties ---------------------------------------------------------------------------

    @property
    def state(self) -> JointState:
        """The newest state (always set once :meth:`open` has returned)."""
        if self._state is None:
            raise DriverError(f"{self.port}: no state received yet")
        return self._state

    @property
    def transport(self) -> Transport:
        """The current transport (a new one after each reconnection)."""
        if self._transport is None:
            raise DriverClosedError(self.port)
        return self._transport

    @property
    def connected(self) -> bool:
        """True while open and not lost or reconnecting."""
        return (self._opened and not self._closed and not self._reconnecting
                and self._failure is None)

    @property
    def emulator(self) -> Any:
        """The emulator behind the transport (``fake://``), for its side channels; else None."""
        return getattr(self._transport, "emulator", None)

    def ground_truth(self) -> GroundTruth | None:
        """The emulator's newest ground-truth sample when the transport has an emulator
        (``fake://``), else None. Real hardware has no ground truth."""
        truth = getattr(self.emulator, "truth", None)
        if not truth:
            return None
        sample: GroundTruth = truth[-1]
        return sample

    def default_tolerance_rad(self) -> Vec4:
        """Per-joint arrival tolerance used when none is given (rad): ``max(3e-4, 1.5 encoder
        counts + 1e-4)`` (the firmware's 1-count deadband, half a count of rounding of the target
        and one protocol tick of rounding of the reply)."""
        return self._default_tol

    # --- reader -------------------------------------------------------------------------------

    async def _read_loop(self) -> None:
        try:
            while True:
                transport = self._transport
                assert transport is not None
                push = getattr(transport, "set_receiver", None)
                if push is not None:  # fake://: replies come straight to _on_pushed
                    push(self._on_pushed)
                try:
                    data = await transport.read()
                except TransportError as exc:
                    if self._closed:
                        return
                    log.warning("%s: %s", self.port, exc)
                    if self.reconnect_policy is None:
                        self._set_failure(exc)
                        return
                    if not await self._reconnect(exc):
                        return
                    continue
                self._on_data(data)
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # a bug: show it to the waiters instead of dying silently
            log.exception("%s: reader failed", self.port)
            self._set_failure(exc)

    def _on_pushed(self, data: bytes) -> None:
        """A chunk a transport hands over as it arrives (``set_receiver``, ``fake://``): handled
        as the reader handles a read, minus a future and a task switch per reply."""
        if self._closed or self._failure is not None:  # the reader would have stopped by now
            return
        try:
            self._on_data(data)
        except Exception as exc:  # a bug: show it to the waiters, as the reader does
            log.exception("%s: reader failed", self.port)
            self._set_failure(exc)

    def _on_data(self, data: bytes) -> None:
        assert self._loop is not None
        t = self._loop.time()
        framer = self._framer
        if self._capture is None and not self._recorders:
            one = framer.one_reply(data)
            if one is not None:  # what follows does for a chunk that is exactly one reply
                self._synced = True
                self._seq = seq = self._seq + 1
                self.frames_received += 1
                state = self._state = _new(JointState, (t, self._decode(one), one, seq))
                self._last_rx_s = t
                if self._waiters:
                    self._offer(state)
                return
        # a chunk that starts a frame, one frame long: if it is a reply, its bytes are the reply
        single = len(data) == REPLY_LEN and not framer.buffered
        before = framer.discarded_bytes
        events = framer.feed(data)
        self.discarded_bytes += framer.discarded_bytes - before
        capture = self._capture
        recorders = self._recorders
        decode = self._decode
        last: Reply | None = None
        recorded: JointState | None = None
        n = 0
        for ev in events:
            if type(ev) is Reply:
                n += 1
                last = ev
                self._synced = True
                if recorders:
                    recorded = _new(JointState, (t, decode(ev), ev, self._seq + n))
                    for r in recorders:
                        r.append(recorded)
                if capture is not None:
                    capture.frame(t, "in", (data if single else ev.encode()).decode("ascii"))
            elif isinstance(ev, FrameError):
                if self._synced:
                    self.frames_dropped += 1
                if capture is not None:
                    capture.write(t, "in", frame_text(ev.raw), ev.reason)
        if last is not None:
            self._seq += n
            self.frames_received += n
            state = self._state = (
                recorded if recorded is not None and recorded.ticks is last
                else _new(JointState, (t, decode(last), last, self._seq)))
            self._last_rx_s = t
            if self._waiters:
                self._offer(state)

    def _offer(self, state: JointState) -> None:
        """Resolve the waiters whose predicate the new state satisfies; drop the resolved ones
        (and those whose task was cancelled)."""
        done = False
        for w in self._waiters:
            fut = w.future
            if fut.done():
                done = True
                continue
            try:
                hit = w.predicate(state)
            except Exception as exc:  # a user predicate failed: its waiter raises it
                fut.set_exception(exc)
                done = True
                continue
            if hit:
                fut.set_result(state)
                done = True
        if done:
            self._waiters = [w for w in self._waiters if not w.future.done()]

    def _set_alarm(self, when: float) -> None:
        """Wake :meth:`_on_alarm` at loop time ``when`` (instead of a later alarm)."""
        assert self._loop is not None
        if self._alarm is not None:
            self._alarm.cancel()
        self._alarm_at = when
        self._alarm = self._loop.call_at(when, self._on_alarm)

    def _on_alarm(self) -> None:
        """Expire the waiters due at the alarm's time, then set it for the next one due.

        One timer for all waiters instead of one per wait: a wait that ends with a reply (most
        do, hundreds per second) leaves no cancelled timer behind in the loop's heap."""
        due = self._alarm_at
        self._alarm, self._alarm_at = None, math.inf
        keep: list[_Waiter] = []
        nxt = math.inf
        for w in self._waiters:
            fut = w.future
            if fut.done():
                continue
            if w.wake_at <= due:
                fut.set_result(None)
                continue
            keep.append(w)
            nxt = min(nxt, w.wake_at)
        self._waiters = keep
        if nxt < math.inf:
            self._set_alarm(nxt)

    async def _reconnect(self, exc: TransportError) -> bool:
        policy = self.reconnect_policy
        assert policy is not None and self._loop is not None
        self._reconnecting = True
        self._wake_all()
        old = self._transport
        if old is not None:
            with contextlib.suppress(TransportError, OSError):
                await old.close()
        last: BaseException = exc
        attempts = 0
        for delay in policy.delays():
            await asyncio.sleep(delay)
            if self._closed:
                return False
            attempts += 1
            transport = open_transport(self.port, self.settings.serial)
            try:
                await transport.open()
            except BaseException as err:
                if not isinstance(err, TransportError):  # cancelled (closing): do not leak it
                    with contextlib.suppress(TransportError, OSError):
                        await transport.close()
                    raise
                last = err
                self.reconnect_attempts += 1
                log.info("%s: reconnect attempt %d failed: %s", self.port, attempts, err)
                continue
            self._transport = transport
            self._framer = _Framer("reply")
            self._synced = False
            self.reconnects += 1
            self._link_gen += 1
            self._linked_s = self._loop.time()
            self._reconnecting = False
            log.info("%s: reconnected after %d attempt(s)", self.port, attempts)
            self._wake_all()
            return True
        self._reconnecting = False
        reason = exc.reason if isinstance(exc, TransportError) else str(exc)
        self._set_failure(PortLostError(self.port, f"{reason}; gave up after {attempts} "
                                                   f"reconnect attempts (last: {last})"))
        return False

    def _set_failure(self, exc: BaseException) -> None:
        if self._failure is None:
            self._failure = exc
        self._wake_all()

    def _wake_all(self) -> None:
        """Wake every waiter to re-check (closed, failed, reconnecting, superseded)."""
        waiters, self._waiters = self._waiters, []
        for w in waiters:
            w.wake()

    def _raise_if_failed(self) -> None:
        if self._closed or not self._opened:
            raise DriverClosedError(self.port)
        exc = self._failure
        if exc is None:
            return
        if isinstance(exc, PortLostError):
            raise PortLostError(exc.port, exc.reason) from exc
        if isinstance(exc, TransportError):
            raise PortLostError(exc.port, exc.reason) from exc
        raise DriverError(f"{self.port}: the reader failed: {exc!r}") from exc

    async def _wait(self, predicate: Callable[[JointState], bool], deadline: float | None, *,
                    reply_timeout: bool = True, since: float | None = None) -> JointState | None:
        """The first *new* state satisfying ``predicate`` (evaluated by the reader on each new
        state), or None once ``deadline`` (loop time) has passed or :meth:`_wake_all` was called
        (the caller re-checks its conditions and waits again).

        Raises :class:`ReplyTimeoutError` after ``reply_timeout_s`` of silence, counted from the
        latest of the last reply, ``since`` (default: now) and the last reconnection; suspended
        while reconnecting. Raises the reader's failure and :class:`DriverClosedError`."""
        loop = self._loop
        if loop is None:
            raise DriverClosedError(self.port)
        if since is None:
            since = loop.time()
        while True:
            self._raise_if_failed()
            now = loop.time()
            if deadline is not None and now >= deadline:
                return None
            wake_at = math.inf if deadline is None else deadline
            if reply_timeout and not self._reconnecting:
                silent_until = max(self._last_rx_s, since, self._linked_s) + self.reply_timeout_s
                if now >= silent_until:
                    raise ReplyTimeoutError(self.port, self.reply_timeout_s, self._state)
                wake_at = min(wake_at, silent_until)
            fut: asyncio.Future[JointState | None] = loop.create_future()
            waiter = _Waiter(predicate, fut, wake_at)
            self._waiters.append(waiter)  # whoever resolves it drops it from the list
            if wake_at < self._alarm_at:
                self._set_alarm(wake_at)
            state = await fut
            if state is not None:
                return state
            if waiter.woken:
                return None
            # the alarm: the deadline (returns above) or a silence check (raises or waits again)

    async def _wait_link(self, gen: int) -> None:
        """Wait until the reader has reconnected (link generation past ``gen``) or failed."""
        assert self._loop is not None
        while self._reconnecting or self._link_gen == gen:
            self._raise_if_failed()
            await self._wait(_never, None, reply_timeout=False)

    # --- sending ------------------------------------------------------------------------------

    async def _send(self, command: Command, *, retry: bool = True) -> float:
        """Write one command; returns the loop time it was handed to the transport. With a
        reconnect policy, a write that fails on a lost port waits for the reconnection and is
        written again (once per reconnection)."""
        data = command.encode()
        while True:
            self._raise_if_failed()
            assert self._loop is not None and self._transport is not None
            gen = self._link_gen
            if self._reconnecting:
                if not retry:  # a late hold or resend would be stale on the new link
                    raise PortLostError(self.port, "reconnecting")
                await self._wait_link(gen)
                continue
            t = self._loop.time()
            try:
                await self._transport.write(data)
            except TransportError:
                if self.reconnect_policy is None or self._closed or not retry:
                    raise
                await self._wait_link(gen)
                continue
            self.commands_sent += 1
            if self._capture is not None:
                self._capture.frame(t, "out", data.decode("ascii"))
            return t

    async def send(self, command: Command) -> float:
        """Write a raw command (no waiting, no resend), after checking that its targets are
        within the joint limits; returns the loop time it was written. Used by :meth:`replay`."""
        q = command.angles_rad(self._lower, self._upper)
        for i, (v, j) in enumerate(zip(q, self.settings.joints, strict=True), 1):
            if v < j.lower_rad - 1e-4:
                raise JointRangeError(i, j.name, v, j.lower_rad, "lower")
            if v > j.upper_rad + 1e-4:
                raise JointRangeError(i, j.name, v, j.upper_rad, "upper")
        self._supersede()
        return await self._send(command)

    # --- validation ---------------------------------------------------------------------------

    def check_target(self, q_rad: Sequence[float] | npt.ArrayLike) -> Vec4:
        """Four finite joint angles (rad) within the limits, as floats; raises
        :class:`InvalidTargetError` / :class:`JointRangeError` naming the joint otherwise."""
        try:
            values = [float(v) for v in np.asarray(q_rad, dtype=np.float64).reshape(-1)]
        except (TypeError, ValueError):
            raise InvalidTargetError(None, "target", q_rad,
                                     "is not a sequence of numbers") from None
        if len(values) != JOINTS:
            raise InvalidTargetError(None, "target", q_rad,
                                     f"has {len(values)} values; the arm has {JOINTS} joints")
        for i, (v, j) in enumerate(zip(values, self.settings.joints, strict=True), 1):
            if not math.isfinite(v):
                raise InvalidTargetError(i, "target", v, "is not a finite angle")
            if v < j.lower_rad - 1e-9:
                raise JointRangeError(i, j.name, v, j.lower_rad, "lower")
            if v > j.upper_rad + 1e-9:
                raise JointRangeError(i, j.name, v, j.upper_rad, "upper")
        return (values[0], values[1], values[2], values[3])

    @staticmethod
    def _check_duty(duty: object, joint: int | None = None) -> int:
        if isinstance(duty, bool) or not isinstance(duty, (int, np.integer)):
            raise InvalidTargetError(joint, "duty", duty, "is not a whole number 1..99")
        d = int(duty)
        if not 1 <= d <= MAX_DUTY:
            raise InvalidTargetError(joint, "duty", d, "is outside 1..99 (00 holds: use stop())")
        return d

    def _check_duties(self, duty: int | Sequence[int]) -> Duties:
        if isinstance(duty, (int, np.integer)) and not isinstance(duty, bool):
            d = self._check_duty(duty)
            return (d, d, d, d)
        if isinstance(duty, (str, bytes)) or not isinstance(duty, Sequence):
            raise InvalidTargetError(None, "duty", duty, "is not a duty or 4 duties")
        if len(duty) != JOINTS:
            raise InvalidTargetError(None, "duty", duty, f"has {len(duty)} values, not {JOINTS}")
        ds = [self._check_duty(v, i) for i, v in enumerate(duty, 1)]
        return (ds[0], ds[1], ds[2], ds[3])

    def _tolerances(self, tolerance_rad: float | Sequence[float] | None) -> Vec4:
        if tolerance_rad is None:
            return self._default_tol
        values = ([tolerance_rad] * JOINTS if isinstance(tolerance_rad, (int, float))
                  else list(tolerance_rad))
        if len(values) != JOINTS or not all(
                isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in values):
            raise InvalidTargetError(None, "tolerance_rad", tolerance_rad,
                                     "must be one or 4 finite numbers > 0")
        return (float(values[0]), float(values[1]), float(values[2]), float(values[3]))

    def _command(self, target: Sequence[float], duties: Sequence[int]) -> Command:
        """The command for a checked target; a wire value that rounds just past a limit is moved
        one tick (1e-4 rad) inwards, so the firmware never aims beyond a limit."""
        cmd = Command.from_rad(target, list(duties))
        ticks = list(cmd.ticks)
        changed = False
        for i, j in enumerate(self.settings.joints):
            q = ticks_to_rad(ticks[i], j.lower_rad, j.upper_rad)
            if q < j.lower_rad:
                ticks[i], changed = rad_to_ticks(q + 1e-4), True
            elif q > j.upper_rad:
                ticks[i], changed = rad_to_ticks(q - 1e-4), True
        if changed:
            cmd = Command((ticks[0], ticks[1], ticks[2], ticks[3]), cmd.duties)
        return cmd

    def _goal(self, cmd: Command) -> Vec4:
        return cmd.angles_rad(self._lower, self._upper)

    def move_timeout_s(self, start: Sequence[float], target: Sequence[float],
                       duties: Sequence[int]) -> float:
        """Default timeout of a move: ``MOVE_TIMEOUT_MARGIN`` × the slowest joint's time by law
        (12) + ``MOVE_TIMEOUT_SLACK_S`` + the command's time on the wire."""
        slowest = max(joint_times_s(start, target, duties, self.settings))
        return MOVE_TIMEOUT_MARGIN * slowest + MOVE_TIMEOUT_SLACK_S + self._command_wire_s

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
        state = self._state
        if state is not None and predicate(state):
            return state
        while True:
            got = await self._wait(predicate, deadline, since=since)
            if got is not None:
                return got
            if deadline is not None and loop.time() >= deadline:
                assert timeout_s is not None
                raise WaitTimeoutError("wait_state", timeout_s, self._state)

    @contextlib.contextmanager
    def record_states(self) -> Iterator[list[JointState]]:
        """``with arm.record_states() as states:`` collects every state received inside the block
        (not only the newest of each read)."""
        buf: list[JointState] = []
        self._recorders.append(buf)
        try:
            yield buf
        finally:
            self._recorders.remove(buf)

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

    def _supersede(self) -> int:
        """A new command replaces whatever a waiting move or path is doing: its generation."""
        self._generation += 1
        self._wake_all()
        return self._generation

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
        together (see :func:`armbench.drivers.motion.coordinated_duties`).

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
            d = self._check_duty(duty)
            duties = coordinated_duties(self.state.q_rad, target, d, self.settings)
        else:
            duties = self._check_duties(duty)
        tol = self._tolerances(tolerance_rad)
        if timeout_s is not None and not (math.isfinite(timeout_s) and timeout_s > 0):
            raise InvalidTargetError(None, "timeout_s", timeout_s, "must be a number > 0")
        cmd = self._command(target, duties)
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
        loop = self._loop
        t_start = loop.time()
        best = math.inf
        last_progress = last_send = t_start
        resend_after = self.resend_after_s

        g1, g2, g3, g4 = goal
        tol1, tol2, tol3, tol4 = tol

        def arrived(state: JointState) -> bool:
            """Evaluated by the reader on every new state: arrival, and progress bookkeeping."""
            nonlocal best, last_progress
            q1, q2, q3, q4 = state.q_rad
            e1, e2, e3, e4 = abs(q1 - g1), abs(q2 - g2), abs(q3 - g3), abs(q4 - g4)
            if e1 <= tol1 and e2 <= tol2 and e3 <= tol3 and e4 <= tol4:
                return True
            total = e1 + e2 + e3 + e4
            if total < best - _PROGRESS_RAD:
                best, last_progress = total, state.t_s
            return False

        try:
            while True:
                if self._generation != gen:
                    raise MoveInterruptedError(goal, self._state)
                state = self.state
                if arrived(state):
                    return state
                # the very sum the wake-up below is set at: comparing differences instead can
                # miss it by one ulp on virtual time, and the loop would spin without yielding
                if loop.time() >= max(last_progress, last_send) + resend_after:
                    await self._resend(cmd)
                    last_send = last_progress = loop.time()
                wake = min(deadline, max(last_progress, last_send) + resend_after)
                got = await self._wait(arrived, wake, since=t_start)
                if self._generation != gen:
                    raise MoveInterruptedError(goal, self._state)
                if got is not None:
                    return got
                if loop.time() >= deadline:
                    raise MoveTimeoutError(goal, tol, timeout_s, self._state)
        except (asyncio.CancelledError, KeyboardInterrupt, MoveTimeoutError, ReplyTimeoutError):
            await self._hold_best_effort()
            raise

    async def _resend(self, cmd: Command) -> None:
        self.resends += 1
        log.info("%s: no progress for %.2f s, sending the command again", self.port,
                 self.resend_after_s)
        try:
            await self._send(cmd, retry=False)
        except TransportError:
            if self.reconnect_policy is None:
                raise  # with reconnection, the next resend goes to the new link

    async def _hold_best_effort(self) -> None:
        """Send a hold without letting a second cancellation or a dead link get in the way."""
        if self._closed or self._failure is not None or self._state is None or (
                self._loop is None):
            return
        self._supersede()
        cmd = Command.from_rad(self._state.q_rad, 0)
        task = self._loop.create_task(self._send(cmd, retry=False))
        with contextlib.suppress(asyncio.CancelledError):  # cancelled again: the hold goes on
            await asyncio.wait({task}, timeout=HOLD_TIMEOUT_S)
        if task.done():
            _consume(task)
        else:
            task.add_done_callback(_consume)

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
        :class:`~armbench.drivers.kinematics.UnreachableError`, one outside the limits
        :class:`~armbench.drivers.kinematics.JointLimitError`, before anything is sent. Then as
        :meth:`move_joints`.
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
        :class:`~armbench.drivers.motion.PathError` if the IK jumps between neighbouring
        waypoints."""
        p = path if isinstance(path, Path) else polyline(list(np.asarray(path, dtype=np.float64)))
        pts = p.waypoints(spacing_m)
        first = ik_best(pts[0], self.settings, roll=roll_rad, branch=branch,
                        near=self.state.q_rad)
        chosen = branch or first.branch
        qs: list[Vec4] = [first.q_protocol]
        for k in range(1, len(pts)):
            sol = ik_best(pts[k], self.settings, roll=roll_rad, branch=chosen, near=qs[-1])
            jump = max(abs(a - b) for a, b in zip(sol.q_protocol, qs[-1], strict=True))
            if jump > MAX_WAYPOINT_JUMP_RAD:
                raise PathError(f"IK jumps by {jump:.3f} rad between waypoints {k - 1} and {k} "
                                f"({pts[k - 1].tolist()} → {pts[k].tolist()} m): the path "
                                "passes a singularity or a branch boundary")
            qs.append(sol.q_protocol)
        return pts, qs

    async def follow_path(self, path: Path | Sequence[Sequence[float]] | npt.ArrayLike, *,
                          speed_m_s: float = 0.05, roll_rad: float = 0.0,
                          spacing_m: float = 0.005, branch: str | None = None,
                          max_duty: int = MAX_DUTY, approach_duty: int = MAX_DUTY,
                          lookahead_s: float = LOOKAHEAD_S,
                          tolerance_rad: float | Sequence[float] | None = None,
                          timeout_s: float | None = None) -> PathRun:
        """Move the TCP along ``path`` (a :class:`~armbench.drivers.motion.Path` or a sequence of
        points,
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
        if not (isinstance(speed_m_s, (int, float)) and math.isfinite(speed_m_s)
                and speed_m_s > 0):
            raise InvalidTargetError(None, "speed_m_s", speed_m_s, "must be a number > 0")
        if not (isinstance(lookahead_s, (int, float)) and lookahead_s >= 0):
            raise InvalidTargetError(None, "lookahead_s", lookahead_s, "must be a number >= 0")
        max_duty = self._check_duty(max_duty)
        approach_duty = self._check_duty(approach_duty)
        tol = self._tolerances(tolerance_rad)
        pts, qs = self.plan_path(path, roll_rad=roll_rad, spacing_m=spacing_m, branch=branch)
        cmds: list[Command] = [self._command(qs[0], (approach_duty,) * JOINTS)]
        planned = 0.0
        for k in range(1, len(qs)):
            seg_s = float(np.linalg.norm(pts[k] - pts[k - 1])) / speed_m_s
            duties, dur = segment_duties(qs[k - 1], qs[k], seg_s, self.settings, max_duty)
            cmds.append(self._command(qs[k], duties))
            planned += dur
        corners = _corners(pts)
        await self.move_joints(qs[0], approach_duty, coordinated=True, tolerance_rad=tol)
        run = PathRun(reference_m=pts)
        if len(qs) == 1:
            return run
        if timeout_s is None:
            timeout_s = MOVE_TIMEOUT_MARGIN * planned + MOVE_TIMEOUT_SLACK_S
        assert self._loop is not None
        loop = self._loop
        gen = self._supersede()
        self._recorders.append(run.states)
        resends0 = self.resends
        last = len(qs) - 1
        resend_after = self.resend_after_s
        k = 1
        goal = self._goal(cmds[k])
        duties = cmds[k].duties
        ahead = 0.0
        best = math.inf
        last_progress = last_send = loop.time()

        def reached(state: JointState) -> bool:
            """Evaluated by the reader on every new state: near enough to send the next
            waypoint (or arrived at the last), and progress bookkeeping."""
            nonlocal best, last_progress
            if self._near(state.q_rad, goal, duties, tol, ahead):
                return True
            total = sum(abs(a - b) for a, b in zip(state.q_rad, goal, strict=True))
            if total < best - _PROGRESS_RAD:
                best, last_progress = total, state.t_s
            return False

        try:
            t = await self._send(cmds[k])
            run.t_start_s = t
            deadline = t + timeout_s
            run.waypoints.append(_sent(t, goal, cmds[k], pts[k]))
            last_progress = last_send = t
            ahead = 0.0 if (k == last or k in corners) else lookahead_s
            while True:
                if self._generation != gen:
                    raise MoveInterruptedError(goal, self._state)
                state = self.state
                if not reached(state):
                    if loop.time() >= max(last_progress, last_send) + resend_after:
                        await self._resend(cmds[k])
                        last_send = last_progress = loop.time()
                    wake = min(deadline, max(last_progress, last_send) + resend_after)
                    got = await self._wait(reached, wake, since=run.t_start_s)
                    if got is None:
                        if loop.time() >= deadline:
                            raise MoveTimeoutError(goal, tol, timeout_s, self._state)
                        continue
                    state = got
                if self._generation != gen:
                    raise MoveInterruptedError(goal, self._state)
                if k == last:
                    run.t_end_s = state.t_s
                    return run
                k += 1
                goal, duties = self._goal(cmds[k]), cmds[k].duties
                ahead = 0.0 if (k == last or k in corners) else lookahead_s
                best = math.inf
                t = await self._send(cmds[k])
                run.waypoints.append(_sent(t, goal, cmds[k], pts[k]))
                last_progress = last_send = t
        except (asyncio.CancelledError, KeyboardInterrupt, MoveTimeoutError, ReplyTimeoutError):
            await self._hold_best_effort()
            raise
        finally:
            run.resends = self.resends - resends0
            with contextlib.suppress(ValueError):
                self._recorders.remove(run.states)

    def _near(self, q: Vec4, goal: Vec4, duties: Duties, tol: Vec4, ahead_s: float) -> bool:
        """Whether every joint is within tolerance of ``goal`` or less than ``ahead_s`` away at
        its duty."""
        for i, j in enumerate(self.settings.joints):
            e = abs(q[i] - goal[i])
            if e <= tol[i]:
                continue
            if ahead_s <= 0 or e * j.steps_per_rad * period_for_duty(duties[i]) * CYCLE_S > ahead_s:
                return False
        return True

    # --- replay -------------------------------------------------------------------------------

    async def replay(self, capture: str | FsPath, *, speed: float = 1.0,
                     align: Literal["first", "connect"] = "first") -> int:
        """Send the host → arm commands of a capture file with their recorded spacing (divided
        by ``speed``); returns how many were sent. Does not wait for the arm at the end.

        ``align="first"``: the first command goes out now; ``"connect"``: each command goes out
        at its recorded time after the capture started, counted from this connection's opening
        (a recording made right after connecting is then reproduced to the loop, e.g. into a
        fresh ``fake://`` emulator on virtual time)."""
        if not speed > 0:
            raise InvalidTargetError(None, "speed", speed, "must be > 0")
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


def _sent(t: float, goal: Vec4, cmd: Command, xyz: FloatArray) -> SentWaypoint:
    return SentWaypoint(t, goal, cmd.duties, (float(xyz[0]), float(xyz[1]), float(xyz[2])))


def _corners(pts: FloatArray) -> set[int]:
    """Indices of interior waypoints where the path turns by more than ``CORNER_RAD``."""
    out: set[int] = set()
    for k in range(1, len(pts) - 1):
        a, b = pts[k] - pts[k - 1], pts[k + 1] - pts[k]
        na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
        if na == 0 or nb == 0:
            continue
        c = float(np.dot(a, b)) / (na * nb)
        if math.acos(max(-1.0, min(1.0, c))) > CORNER_RAD:
            out.add(k)
    return out


#: ``armbench.connect(port, ...)``: the same as :meth:`Arm.connect`.
connect = Arm.connect
