"""The connection under :class:`~armbench.drivers.host.arm.Arm`: transport, reader, newest state,
reconnection, sending and waiting.

One reader task per connection (or the transport's push callback, ``fake://``) hands each chunk to
the sans-I/O :class:`~armbench.drivers.host.replies.ReplyStream`; the newest reply is ``state`` and
is offered to the :class:`~armbench.drivers.host.waiters.Waiters`. Every wait reads time from the
running
loop and waits with asyncio only, so the same code runs in real time on hardware and on virtual
time against ``fake://``. The policies are documented in ``docs/driver.md``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Callable, Generator, Iterator
from dataclasses import replace
from pathlib import Path as FsPath
from types import TracebackType
from typing import Any, Final, Self

from armbench.drivers.capture.jsonl import CaptureWriter, frame_text
from armbench.drivers.host.intake import ReplyIntake
from armbench.drivers.host.link_options import (
    CONNECT_TIMEOUT_S,
    DEFAULT_LINK_OPTIONS,
    RESEND_AFTER_S,
    LinkOptions,
)
from armbench.drivers.host.link_outages import LinkOutage, OutageLog, ReconnectPolicy
from armbench.drivers.host.replies import ReplyStream
from armbench.drivers.host.state import JointState
from armbench.drivers.host.waiters import Waiters, any_state, never
from armbench.drivers.model.errors import (
    DriverClosedError,
    DriverError,
    LinkLostError,
    PortLostError,
    ReplyTimeoutError,
    TransportError,
)
from armbench.drivers.model.log_limit import LogLimit
from armbench.drivers.model.protocol import COMMAND_LEN, Command, FrameError, Reply
from armbench.drivers.model.server_notes import ServerNotes
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.model.tasks import cancel_and_wait
from armbench.drivers.transports import Transport, open_transport

__all__ = ["CONNECT_TIMEOUT_S", "HOLD_TIMEOUT_S", "RESEND_AFTER_S", "ArmLink", "LinkOptions",
           "LinkOutage", "ReconnectPolicy"]

log = logging.getLogger("armbench.driver")

#: How long a hold sent on cancellation or failure may take before the driver gives up on it.
HOLD_TIMEOUT_S: Final = 0.5
#: Event-loop passes a silence check gives the reader before it calls the arm silent: one to
#: select the readable port, one for the transport's read, one for the reader task.
_DRAIN_PASSES: Final = 3


def _consume(task: asyncio.Task[Any]) -> None:
    if not task.cancelled():
        exc = task.exception()
        if exc is not None:
            log.warning("hold after an aborted move failed: %s", exc)


class ArmLink:
    """A connection to the arm: life cycle, reader, reconnection, sending and waiting.
    :class:`~armbench.drivers.host.arm.Arm` adds the motion API on top.

    Counters: :attr:`frames_received` (valid replies), :attr:`frames_dropped` (framer error events
    after the stream was in sync), :attr:`discarded_bytes` (bytes thrown away, CR/LF excluded),
    :attr:`commands_sent`, :attr:`resends`, :attr:`reconnects`.
    """

    def __init__(self, port: str, settings: RobotSettings | None = None,
                 options: LinkOptions | None = None, **given: Any) -> None:
        """A connection to ``port`` (not opened yet) with ``settings`` (the robot model; default
        :class:`RobotSettings`) and ``options`` (:class:`LinkOptions`), or any of its fields
        by keyword (``reply_timeout_s=2.0``), over ``options`` when both are given."""
        opts = options if options is not None else DEFAULT_LINK_OPTIONS
        if given:
            opts = replace(opts, **given)
        self.port = port
        """The port string (``/dev/ttyUSB0``, ``socket://h:p``, ``fake://``, ...)."""
        self.settings = settings if settings is not None else RobotSettings()
        """The robot model: limits, drive trains, geometry, line settings."""
        self.options = opts
        """How this connection behaves (its timeouts, capture, reconnection)."""
        self.connect_timeout_s = opts.connect_timeout_s
        self.resend_after_s = opts.resend_after_s
        self.move_timeout_scale = opts.move_timeout_scale
        """Factor on every default move and path timeout (an arm slower than law (12))."""
        capture, reconnect, transport = opts.capture, opts.reconnect, opts.transport
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
        self._lower = self.settings.lower_rad
        self._upper = self.settings.upper_rad
        self._replies = ReplyStream(self._lower, self._upper)
        self._command_wire_s = COMMAND_LEN * self.settings.serial.byte_time_s
        self._linked_s = -math.inf
        self._linked0_s = 0.0
        self._waiters = Waiters()
        self._failure: BaseException | None = None
        self._opened = False
        self._closed = False
        self._reconnecting = False
        self._link_gen = 0
        self._generation = 0
        self.commands_sent = 0
        """Commands written (resends and holds included)."""
        self.resends = 0
        """Commands sent again because a move made no progress."""
        self.reconnects = 0
        """Successful reconnections."""
        self.reconnect_attempts = 0
        """Failed reconnection attempts."""
        self.outages = OutageLog(opts.reply_timeout_s)
        """Every loss of the link (see :mod:`~armbench.drivers.host.link_outages`)."""
        self._intake = ReplyIntake(self._replies, self._waiters, self.outages,
                                   opts.reply_timeout_s, self._on_chunk, self._reader_failed)
        if self._capture is not None:
            self._intake.capture = self._capture.reply_sink()
        self._notes = ServerNotes()
        self._note_log = LogLimit(log, logging.WARNING, "server notes")
        self.server_note: str | None = None
        """The newest line the server wrote between frames (``armbench emulate``'s ``busy``,
        ``overrun``, ...); each is logged as a warning when it arrives (from a server that
        sends many, a few per interval, then their count:
        :mod:`armbench.drivers.model.log_limit`)."""
        self._note_frames = -1

    @property
    def reply_timeout_s(self) -> float:
        """Seconds of silence after which a wait raises :class:`ReplyTimeoutError` (and a gap
        between replies counts as an outage)."""
        return self._intake.reply_timeout_s

    @reply_timeout_s.setter
    def reply_timeout_s(self, value: float) -> None:
        self._intake.reply_timeout_s = value

    @property
    def frames_received(self) -> int:
        """Valid replies decoded since connecting."""
        return self._replies.frames_received

    @property
    def frames_dropped(self) -> int:
        """Framer error events (bad frames, runs of garbage) once the stream was in sync."""
        return self._replies.frames_dropped

    @property
    def discarded_bytes(self) -> int:
        """Bytes the framer threw away (CR/LF excluded), including the partial frame a connection
        may start in the middle of."""
        return self._replies.discarded_bytes

    # --- life cycle ---------------------------------------------------------------------------

    async def open(self) -> None:
        """Open the transport, start the reader and wait for the first valid reply.

        Raises :class:`~armbench.drivers.model.errors.TransportError` if the port cannot be opened
        and :class:`ReplyTimeoutError` if no valid reply arrives within ``connect_timeout_s``;
        either way everything opened is closed again.
        """
        if self._opened:
            raise DriverError(f"{self.port}: already opened")
        self._opened = True
        self._loop = loop = asyncio.get_running_loop()
        self._intake.clock = loop.time
        transport = self._given_transport or open_transport(self.port, self.settings.serial)
        await transport.open()
        self._transport = transport
        self._linked_s = self._linked0_s = loop.time()
        try:
            if self._capture is None and self.capture_path is not None:
                self._capture = CaptureWriter(self.capture_path, loop.time())
                self._intake.capture = self._capture.reply_sink()
            self._reader = loop.create_task(self._read_loop(), name=f"arm-reader {self.port}")
            if self._intake.state is None and await self._wait(
                    any_state, loop.time() + self.connect_timeout_s, reply_timeout=False) is None:
                self._raise_if_failed()  # the port closed (a server saying why, when it did)
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
        self._intake.live = False
        self._note_log.flush()
        self._waiters.close()
        try:
            reader, self._reader = self._reader, None
            if reader is not None and not reader.done():
                await cancel_and_wait(reader)
        finally:
            try:
                if self._transport is not None:
                    with contextlib.suppress(TransportError, OSError):
                        await self._transport.close()
            finally:
                if self._capture is not None:
                    self._capture.close()

    async def __aenter__(self) -> Self:
        await self.open()
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                        tb: TracebackType | None) -> None:
        await self.close()

    def __await__(self) -> Generator[Any, None, Self]:
        return self.__aenter__().__await__()

    def __repr__(self) -> str:
        state = ("closed" if self._closed else "reconnecting" if self._reconnecting
                 else "open" if self._opened else "new")
        return (f"<{type(self).__name__} {self.port!r} {state} rx={self.frames_received} "
                f"dropped={self.frames_dropped} tx={self.commands_sent}>")

    # --- properties ---------------------------------------------------------------------------

    @property
    def state(self) -> JointState:
        """The newest state (always set once :meth:`open` has returned)."""
        if self._intake.state is None:
            raise DriverError(f"{self.port}: no state received yet")
        return self._intake.state

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

    def link_outages(self, since_s: float = -math.inf) -> list[LinkOutage]:
        """The link's outages that overlap loop times [``since_s``, now], oldest first; one
        going on now comes last, with ``ended_s`` None."""
        now = self._loop.time() if self._loop is not None else self._intake.last_rx_s
        return self.outages.between(since_s, now, self._intake.last_rx_s)

    def link_down_s(self, since_s: float) -> float:
        """Seconds since loop time ``since_s`` during which the port was lost."""
        assert self._loop is not None
        return self.outages.down_s(since_s, self._loop.time(), self._intake.last_rx_s)

    # --- reader -------------------------------------------------------------------------------

    async def _read_loop(self) -> None:
        try:
            while True:
                transport = self._transport
                assert transport is not None
                push = getattr(transport, "set_receiver", None)
                if push is not None:  # fake://: replies come straight to the intake
                    push(self._intake.push)
                try:
                    data = await transport.read()
                except TransportError as exc:
                    if self._closed:
                        return
                    exc = self._with_note(exc)
                    log.warning("%s: %s", self.port, exc)
                    self._lost(exc)
                    if self.reconnect_policy is None:
                        self._set_failure(exc)
                        return
                    if not await self._reconnect(exc):
                        return
                    continue
                self._intake.take(data)
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # a bug: show it to the waiters instead of dying silently
            self._reader_failed(exc)

    def _reader_failed(self, exc: Exception) -> None:
        """The reader, or a chunk pushed to the intake, raised ``exc`` (a bug): logged and shown
        to the waiters instead of dying silently."""
        log.error("%s: reader failed", self.port, exc_info=exc)
        self._set_failure(exc)

    def _on_chunk(self, data: bytes, t: float) -> None:
        """A chunk read at loop time ``t`` that is not exactly one reply (the intake takes
        those): through the reply stream into the state, the recorders, the capture and the
        waiters."""
        replies = self._replies
        capture = self._capture
        recorders = self._intake.recorders
        batch = replies.receive(data, t, every=bool(recorders))
        for note in self._notes.feed(data):
            self._note_log("%s: the server says: %s", self.port, note)
            self.server_note = note
            self._note_frames = replies.frames_received
        if batch.states:
            for r in recorders:
                r.extend(batch.states)
        if capture is not None:
            for ev in batch.events:
                if type(ev) is Reply:
                    capture.frame(t, "in", (data if batch.single else ev.encode()).decode("ascii"))
                elif isinstance(ev, FrameError):
                    capture.write(t, "in", frame_text(ev.raw), ev.reason)
        if batch.state is not None:
            self._intake.took(batch.state, t)

    async def _reconnect(self, exc: TransportError) -> bool:
        policy = self.reconnect_policy
        assert policy is not None and self._loop is not None
        self._reconnecting = True
        self._waiters.wake_all()
        old = self._transport
        if old is not None:
            with contextlib.suppress(TransportError, OSError):
                await old.close()
        last: BaseException = exc
        attempts = 0
        give_up_at = (math.inf if policy.give_up_after_s is None
                      else self._silent_since_s() + policy.give_up_after_s)
        for delay in policy.delays():
            if self._loop.time() >= give_up_at:
                break
            await asyncio.sleep(min(delay, max(0.0, give_up_at - self._loop.time())))
            if self._closed:
                return False
            attempts += 1
            transport = open_transport(self.port, self.settings.serial)
            if old is not None:
                transport.follow(old)
            try:
                await transport.open()
            except BaseException as err:
                if not isinstance(err, TransportError):  # cancelled (closing): do not leak it
                    with contextlib.suppress(TransportError, OSError):
                        await transport.close()
                    raise
                last = err
                self.reconnect_attempts += 1
                self.outages.attempt_failed()
                log.info("%s: reconnect attempt %d failed: %s", self.port, attempts, err)
                continue
            self._transport = transport
            self._replies.restart()
            self.reconnects += 1
            self._link_gen += 1
            self._linked_s = self._loop.time()
            self._reconnecting = False
            log.info("%s: reconnected after %d attempt(s)", self.port, attempts)
            self._waiters.wake_all()
            return True
        self._reconnecting = False
        reason = exc.reason if isinstance(exc, TransportError) else str(exc)
        if last is not exc:
            reason += f"; last attempt: {last}"
        self._set_failure(LinkLostError(self.port, reason,
                                        self._loop.time() - self._silent_since_s(), attempts))
        return False

    def _with_note(self, exc: TransportError) -> TransportError:
        """The loss ``exc``, naming what the server said last if no reply followed it (the
        ``busy`` line of a refusal, the ``disconnected`` line of a take-over)."""
        note = self.server_note
        if (note is None or self._note_frames != self._replies.frames_received
                or type(exc) is not PortLostError):
            return exc
        return PortLostError(exc.port, f"{exc.reason}; the server said: {note}")

    def _silent_since_s(self) -> float:
        """Loop time since which the link has been silent: the last reply, or the opening."""
        return max(self._intake.last_rx_s, self._linked0_s)

    def _lost(self, exc: TransportError) -> None:
        """The transport reported the port lost: an outage begins (one already going on goes
        on)."""
        assert self._loop is not None
        self.outages.lost(self._loop.time(), exc.reason, self._silent_since_s(),
                          self._intake.tx_since_rx)

    def _set_failure(self, exc: BaseException) -> None:
        if self._failure is None:
            self._failure = exc
            self._intake.live = False
        self._waiters.wake_all()

    def _raise_if_failed(self) -> None:
        if self._closed or not self._opened:
            raise DriverClosedError(self.port)
        exc = self._failure
        if exc is None:
            return
        if isinstance(exc, LinkLostError):
            raise LinkLostError(exc.port, exc.cause, exc.silent_s, exc.attempts) from exc
        if isinstance(exc, PortLostError):
            raise PortLostError(exc.port, exc.reason) from exc
        if isinstance(exc, TransportError):
            raise PortLostError(exc.port, exc.reason) from exc
        raise DriverError(f"{self.port}: the reader failed: {exc!r}") from exc

    # --- waiting ------------------------------------------------------------------------------

    async def _wait(self, predicate: Callable[[JointState], bool], deadline: float | None, *,
                    reply_timeout: bool = True, since: float | None = None) -> JointState | None:
        """The first *new* state satisfying ``predicate`` (evaluated by the reader on each new
        state), or None once ``deadline`` (loop time) has passed or the waiters were woken
        (the caller re-checks its conditions and waits again).

        Raises :class:`ReplyTimeoutError` after ``reply_timeout_s`` of silence, counted from the
        latest of the last reply, ``since`` (default: now) and the last reconnection; suspended
        while reconnecting. Raises the reader's failure and :class:`DriverClosedError`."""
        loop = self._loop
        if loop is None:
            raise DriverClosedError(self.port)
        if since is None:
            since = loop.time()
        drained = False
        while True:
            self._raise_if_failed()
            now = loop.time()
            if deadline is not None and now >= deadline:
                return None
            wake_at = math.inf if deadline is None else deadline
            if reply_timeout and not self._reconnecting:
                intake = self._intake
                silent_until = max(intake.last_rx_s, since, self._linked_s) + intake.reply_timeout_s
                if now >= silent_until and not drained:
                    # A host held up (a busy machine, a slow synchronous step) finds replies
                    # waiting unread in the OS's buffer: the reader takes them first.
                    drained = True
                    for _ in range(_DRAIN_PASSES):
                        await asyncio.sleep(0)
                    continue
                if now >= silent_until:
                    raise ReplyTimeoutError(self.port, self.reply_timeout_s, self._intake.state)
                drained = False
                wake_at = min(wake_at, silent_until)
            waiter = self._waiters.add(predicate, wake_at)
            state = await waiter.future
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
            await self._wait(never, None, reply_timeout=False)

    def _supersede(self) -> int:
        """A new command replaces whatever a waiting move or path is doing: its generation."""
        self._generation += 1
        self._waiters.wake_all()
        return self._generation

    @contextlib.contextmanager
    def _recording(self, buf: list[JointState]) -> Iterator[list[JointState]]:
        """Every state received inside the block is appended to ``buf``. Taken out by identity,
        not by value: two recorders holding the same states (two empty ones) are equal lists,
        and ``list.remove`` would take out the other one, which then gets nothing while this
        one grows for as long as the link lives."""
        self._intake.recorders.append(buf)
        try:
            yield buf
        finally:
            self._intake.recorders[:] = [r for r in self._intake.recorders if r is not buf]

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
                self.outages.command_lost()
                if not retry:  # a late hold or resend would be stale on the new link
                    raise PortLostError(self.port, "reconnecting")
                await self._wait_link(gen)
                continue
            t = self._loop.time()
            try:
                await self._transport.write(data)
            except TransportError as exc:
                if not self._closed:
                    self._lost(exc)
                    self.outages.command_lost()
                if self.reconnect_policy is None or self._closed or not retry:
                    raise
                await self._wait_link(gen)
                continue
            self.commands_sent += 1
            self._intake.tx_since_rx += 1
            if self._capture is not None:
                self._capture.frame(t, "out", data.decode("ascii"))
            return t

    async def _resend(self, cmd: Command) -> None:
        """Send ``cmd`` again because the move made no progress (counted in ``resends``)."""
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
        if self._closed or self._failure is not None or self._intake.state is None or (
                self._loop is None):
            return
        self._supersede()
        cmd = Command.from_rad(self._intake.state.q_rad, 0)
        task = self._loop.create_task(self._send(cmd, retry=False))
        with contextlib.suppress(asyncio.CancelledError):  # cancelled again: the hold goes on
            await asyncio.wait({task}, timeout=HOLD_TIMEOUT_S)
        if task.done():
            _consume(task)
        else:
            task.add_done_callback(_consume)
