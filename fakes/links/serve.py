"""Serve the emulated arm in real time on a pseudo-terminal or a TCP port.

Any serial program (pyserial, minicom, the paper's ROS driver) can open the pty's device as the
robot; a TCP client (``socket://`` in armbench, a ser2net-style client) gets the same byte stream.
The UART's byte timing is emulated by the arm, so the stream has the baud rate's pace even though a
pty has no baud rate of its own.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import math
import os
import selectors
import socket
from collections.abc import Callable
from pathlib import Path

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.log_limit import LogLimit
from armbench.drivers.model.protocol import Framer
from armbench.drivers.model.server_notes import note_line
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.links.pty_link import LinkError, claim_link, release_link, require_pty

__all__ = ["ClientStream", "FrameLogger", "PtyServer", "ReceiveBuffer", "TcpServer",
           "parse_host_port", "real_time_loop"]

log = logging.getLogger("armbench.emulator")

#: A TCP client that sends nothing for this long, and does not read the reply stream either, is
#: disconnected (issue: idle clients time out). A client that only listens (``armbench monitor``)
#: keeps the server's send buffer near empty and stays.
DEFAULT_IDLE_TIMEOUT_S = 300.0
#: Bytes waiting in the server's send buffer above which a silent client counts as not reading.
STALLED_BUFFER_BYTES = 64 * 1024
#: Kernel send buffer of a client's socket (the reply stream is ~11 kB/s at 115200 baud).
SEND_BUFFER_BYTES = 16 * 1024
#: Bytes kept for a client that does not read; replies beyond are dropped, as on a serial line
#: nobody reads (memory stays bounded: some 20 s of the reply stream at 115200 baud).
MAX_BUFFER_BYTES = 256 * 1024
#: Longest wait for a silent client's session to end when a newcomer takes the arm from it.
TAKE_OVER_WAIT_S = 5.0
#: Most bytes read from a client at once: a client writing faster than the line is read in chunks
#: of this size and what the receive buffer cannot hold is dropped, never queued.
READ_CHUNK_BYTES = 64 * 1024
#: Shortest time between two overrun reports (to the client and to the log) of one client.
OVERRUN_REPORT_S = 1.0


def real_time_loop() -> asyncio.AbstractEventLoop:
    """The event loop for serving in real time: a ``select()`` selector, whose timeout has
    microsecond resolution where epoll's is a millisecond (rounded up), so each reply leaves when
    its last byte would, not up to 1 ms later (the server watches a handful of descriptors)."""
    return asyncio.SelectorEventLoop(selectors.SelectSelector())


class FrameLogger:
    """Logs every frame in and out at debug level (costs nothing when debug is off)."""

    def __init__(self) -> None:
        self._in = Framer("command")
        self._out = Framer("reply")

    def received(self, data: bytes) -> None:
        """Bytes from the host."""
        if log.isEnabledFor(logging.DEBUG):
            for event in self._in.feed(data):
                log.debug("host -> arm %r", event)

    def sent(self, data: bytes) -> None:
        """Bytes to the host."""
        if log.isEnabledFor(logging.DEBUG):
            for event in self._out.feed(data):
                log.debug("arm -> host %r", event)


class ClientStream:
    """The reply stream to one client, with the server's own lines (:func:`note_line`) put
    between frames, never inside one (a reply chunk that does not end a frame holds them back)."""

    def __init__(self, write: Callable[[bytes], None]) -> None:
        self._write = write
        self._between_frames = True
        self._held: list[bytes] = []

    def reply(self, data: bytes) -> None:
        """Bytes of the arm's replies."""
        self._write(data)
        self._between_frames = data.endswith((b"#", b"\n"))
        if self._held and self._between_frames:
            held, self._held = self._held, []
            for line in held:
                self._write(line)

    def say(self, text: str) -> None:
        """A line of the server's: now if the stream is between frames, else after this frame
        (only the newest held line is kept)."""
        line = note_line(text)
        if self._between_frames:
            self._write(line)
        else:
            self._held = [line]


class ReceiveBuffer:
    """What a server hands the emulated UART: at most ``size_bytes`` wait for the line.

    A pty or a socket has no baud rate, so a client can write far faster than the line carries
    bytes. What it writes waits for the line in a buffer of ``[emulator] host_buffer_bytes``
    (what the host side of a real serial line holds); bytes arriving when it is full are dropped
    and counted as overrun, as a UART drops a byte that finds its buffer full. On the line the
    board's own receive buffer (``rx_buffer_bytes``, ``RX_SIZE`` of ``firmware/master.c``) drops
    what its loop does not read in time, as before. Whatever a client sends, memory stays bounded
    and a later client waits behind at most ``size_bytes`` of line time (none on TCP: a client's
    unsent bytes are discarded when it leaves, :meth:`discard`).

    Overruns are reported through ``report`` (the client's stream and the emulator's log), the
    first at once, then at most one line per :data:`OVERRUN_REPORT_S` with the count since.
    """

    def __init__(self, arm: ArmEmulator, size_bytes: int, report: Callable[[str], None]) -> None:
        self.arm = arm
        self.size_bytes = size_bytes
        self.overrun_bytes = 0
        """Bytes dropped because the buffer was full."""
        self._report = report
        self._unreported = 0
        self._reported_s = -math.inf
        self._timer: asyncio.TimerHandle | None = None

    def backlog_bytes(self, now_s: float) -> int:
        """Bytes handed to the UART that have not finished arriving on the line at ``now_s``."""
        uart = self.arm.uart
        ahead_s = uart.rx_line_free_s - now_s
        return math.ceil(ahead_s / uart.byte_s - 1e-9) if ahead_s > 0 else 0

    def feed(self, data: bytes) -> None:
        """Bytes read from the client now: what fits goes on the line, the rest is dropped."""
        loop = asyncio.get_running_loop()
        room = self.size_bytes - self.backlog_bytes(loop.time())
        if len(data) <= room:
            self.arm.host_write(data)
            return
        if room > 0:
            self.arm.host_write(data[:room])
        dropped = len(data) - max(room, 0)
        self.overrun_bytes += dropped
        self._unreported += dropped
        if self._timer is None:
            self._timer = loop.call_at(max(loop.time(), self._reported_s + OVERRUN_REPORT_S),
                                      self._flush)

    def _flush(self) -> None:
        self._timer = None
        if not self._unreported:
            return
        self._reported_s = asyncio.get_running_loop().time()
        count, self._unreported = self._unreported, 0
        self._report(f"overrun: {count} bytes dropped, sent faster than the line carries them "
                     f"with its {self.size_bytes}-byte buffer full ({self.overrun_bytes} bytes "
                     f"in all)")

    def discard(self) -> int:
        """The client has gone: forget its bytes that have not begun on the line (returns how
        many) and stop reporting."""
        self.close()
        return self.arm.uart.discard_unsent(asyncio.get_running_loop().time())

    def close(self) -> None:
        """Stop reporting."""
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None


class PtyServer:
    """The arm on a pseudo-terminal pair; ``path`` is the device a client opens."""

    def __init__(self, arm: ArmEmulator, link: str | Path | None = None,
                 buffer_bytes: int | None = None) -> None:
        self.arm = arm
        self.link = Path(link) if link is not None else None
        self._master_fd = -1
        self._slave_fd = -1
        self.path = ""
        self.dropped_bytes = 0
        self._frames = FrameLogger()
        self._stream = ClientStream(self._write)
        self.receive = ReceiveBuffer(
            arm, arm.settings.host_buffer_bytes if buffer_bytes is None else buffer_bytes,
            self._overrun)
        """The receive buffer; its ``overrun_bytes`` counts what the pty's clients lost."""

    async def start(self) -> str:
        """Create the pty, start the arm and return the device path (POSIX only:
        :func:`~armbench.fakes.links.pty_link.require_pty`)."""
        require_pty()
        import termios  # POSIX: imported by the server that makes a pty
        import tty

        self._master_fd, self._slave_fd = os.openpty()
        # Raw mode: no echo, no CR/LF translation; the slave end stays open here so that a
        # client closing it does not end the stream (EIO) for the next client.
        tty.setraw(self._slave_fd, termios.TCSANOW)
        os.set_blocking(self._master_fd, False)
        self.path = os.ttyname(self._slave_fd)
        if self.link is not None:
            try:
                claim_link(self.link, self.path)
            except LinkError:
                os.close(self._master_fd)
                os.close(self._slave_fd)
                self._master_fd = self._slave_fd = -1
                raise
        loop = asyncio.get_running_loop()
        loop.add_reader(self._master_fd, self._readable)
        self.arm.attach_host(self._stream.reply)
        await self.arm.start()
        return self.path

    def _readable(self) -> None:
        try:
            data = os.read(self._master_fd, READ_CHUNK_BYTES)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            return
        if data:
            self._frames.received(data)
            self.receive.feed(data)

    def _overrun(self, text: str) -> None:
        log.warning("pty %s: %s", self.path, text)
        self._stream.say(text)

    def _write(self, data: bytes) -> None:
        self._frames.sent(data)
        try:
            os.write(self._master_fd, data)
        except (BlockingIOError, OSError):
            self.dropped_bytes += len(data)  # nobody reads the pty: the line drops it

    async def close(self) -> None:
        """Stop serving and remove the pty (and the link)."""
        self.receive.close()
        self.arm.detach_host()
        await self.arm.close()
        if self._master_fd >= 0:
            asyncio.get_running_loop().remove_reader(self._master_fd)
            os.close(self._master_fd)
            os.close(self._slave_fd)
            self._master_fd = self._slave_fd = -1
        if self.link is not None:
            release_link(self.link, self.path)


class TcpServer:
    """The arm on a TCP port, one client at a time.

    A second client is refused with a line saying why, unless the connected one has sent nothing
    for ``idle_timeout_s``: then the newcomer takes the arm and the silent one is told so and
    disconnected (a listener such as ``armbench monitor`` keeps the arm until someone else asks
    for it). A silent client that does not read either is dropped once its replies back up past
    ``stalled_buffer_bytes``; what waits for one client is bounded by :data:`MAX_BUFFER_BYTES`.
    """

    def __init__(self, arm: ArmEmulator, host: str = "127.0.0.1", port: int = 0,
                 idle_timeout_s: float = DEFAULT_IDLE_TIMEOUT_S,
                 stalled_buffer_bytes: int = STALLED_BUFFER_BYTES,
                 buffer_bytes: int | None = None) -> None:
        self.arm = arm
        self.buffer_bytes = arm.settings.host_buffer_bytes if buffer_bytes is None else buffer_bytes
        """Size of each client's receive buffer (:class:`ReceiveBuffer`)."""
        self._overrun_before = 0
        self._receive: ReceiveBuffer | None = None
        self.host = host
        self.port = port
        self.idle_timeout_s = idle_timeout_s
        self.stalled_buffer_bytes = stalled_buffer_bytes
        self.dropped_bytes = 0
        """Reply bytes dropped because the client did not read them."""
        self._server: asyncio.Server | None = None
        self._client: asyncio.StreamWriter | None = None
        self._client_peer = ""
        self._last_input_s = 0.0
        self._slot_free = asyncio.Event()
        self._slot_free.set()
        self.clients_served = 0
        self.clients_refused = 0
        self.clients_taken_over = 0
        """Silent clients disconnected because another one asked for the arm."""
        self.on_client: Callable[[str], None] | None = None
        # a client storm logs a few lines of each kind, then how many it held back
        self._refusals = LogLimit(log, logging.WARNING, "refused clients")
        self._sessions = LogLimit(log, logging.INFO, "client lines")

    @property
    def overrun_bytes(self) -> int:
        """Bytes dropped at the receive buffer, all clients together."""
        now = self._receive.overrun_bytes if self._receive is not None else 0
        return self._overrun_before + now

    async def start(self) -> tuple[str, int]:
        """Listen, start the arm, and return the bound (host, port)."""
        self._server = await asyncio.start_server(self._serve, self.host, self.port)
        sock = self._server.sockets[0].getsockname()
        self.host, self.port = sock[0], sock[1]
        await self.arm.start()
        return self.host, self.port

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        name = writer.get_extra_info("peername")
        peer = f"{name[0]}:{name[1]}" if isinstance(name, tuple) else str(name)
        if not await self._take_slot(peer, writer):
            return
        self._client = writer
        self._client_peer = peer
        self._last_input_s = asyncio.get_running_loop().time()
        self.clients_served += 1
        self._sessions("client %s connected", peer)
        if self.on_client is not None:
            self.on_client(peer)
        try:
            await self._session(peer, reader, writer)
        finally:
            self.arm.detach_host()
            self._client = None
            writer.close()
            with contextlib.suppress(ConnectionError, OSError):
                await writer.wait_closed()
            self._sessions("client %s left", peer)
            self._slot_free.set()

    async def _take_slot(self, peer: str, writer: asyncio.StreamWriter) -> bool:
        """Free slot: take it. Busy with a client silent for the idle timeout: disconnect that
        one and take it. Busy otherwise: tell ``writer`` why and refuse."""
        current = self._client
        if current is not None:
            silent_s = asyncio.get_running_loop().time() - self._last_input_s
            if silent_s < self.idle_timeout_s:
                self.clients_refused += 1
                self._refusals("refusing %s: client %s is connected", peer,
                               self._client_peer)
                await _say_and_close(writer, f"busy: another client ({self._client_peer}) has the "
                                             f"arm; it frees after {self.idle_timeout_s:g} s "
                                             f"without input from that client")
                return False
            self.clients_taken_over += 1
            log.warning("client %s silent for %.0f s: %s takes the arm", self._client_peer,
                        silent_s, peer)
            current.write(_line(f"disconnected: no input for {silent_s:.0f} s and another "
                                f"client ({peer}) asked for the arm"))
            current.close()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(TAKE_OVER_WAIT_S):
                    await self._slot_free.wait()  # its session has detached from the arm
            if self._client is not None:  # another newcomer was faster
                self.clients_refused += 1
                await _say_and_close(writer, f"busy: another client ({self._client_peer}) has "
                                             f"just taken the arm")
                return False
        self._slot_free.clear()
        return True

    async def _session(self, peer: str, reader: asyncio.StreamReader,
                       writer: asyncio.StreamWriter) -> None:
        """Relay bytes both ways until the client leaves, stalls or is taken over."""
        frames = FrameLogger()
        transport = writer.transport
        sock = transport.get_extra_info("socket")
        if sock is not None:  # ~1.5 s of replies in the kernel: a client that stops reading shows
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)

        def sink(data: bytes) -> None:
            frames.sent(data)
            if writer.is_closing():
                return
            if transport.get_write_buffer_size() > MAX_BUFFER_BYTES:
                self.dropped_bytes += len(data)
                return
            writer.write(data)

        stream = ClientStream(sink)

        def overrun(text: str) -> None:
            log.warning("client %s: %s", peer, text)
            stream.say(text)

        self._receive = receive = ReceiveBuffer(self.arm, self.buffer_bytes, overrun)
        self.arm.attach_host(stream.reply)
        try:
            await self._relay(peer, reader, receive, transport, frames)
        finally:
            unsent = receive.discard()
            if unsent:
                log.info("client %s: %d bytes it sent were still waiting for the line: discarded",
                         peer, unsent)
            self._receive = None
            self._overrun_before += receive.overrun_bytes
            if receive.overrun_bytes:
                log.warning("client %s: %d bytes dropped in all (overrun)", peer,
                            receive.overrun_bytes)

    async def _relay(self, peer: str, reader: asyncio.StreamReader, receive: ReceiveBuffer,
                     transport: asyncio.WriteTransport, frames: FrameLogger) -> None:
        loop = asyncio.get_running_loop()
        try:
            while True:
                try:
                    async with asyncio.timeout(self.idle_timeout_s):
                        data = await reader.read(READ_CHUNK_BYTES)
                except TimeoutError:
                    if transport.get_write_buffer_size() <= self.stalled_buffer_bytes:
                        continue  # silent but reading the replies: a listener, not idle
                    raise
                if not data:
                    break
                self._last_input_s = loop.time()
                frames.received(data)
                receive.feed(data)
        except TimeoutError:
            log.warning("client %s idle for %.0f s: disconnected", peer, self.idle_timeout_s)
        except (ConnectionError, OSError) as exc:
            self._sessions("client %s: %s", peer, exc)

    async def close(self) -> None:
        """Stop listening, drop the client, power the arm down."""
        self._refusals.flush()
        self._sessions.flush()
        if self._server is not None:
            self._server.close()
            if self._client is not None:
                self._client.close()
            await self._server.wait_closed()
            self._server = None
        self.arm.detach_host()
        await self.arm.close()


def _line(text: str) -> bytes:
    """A message to a client, on a line of its own (no ``$``, so no framer takes it for a frame)."""
    return note_line(text)


async def _say_and_close(writer: asyncio.StreamWriter, text: str) -> None:
    with contextlib.suppress(ConnectionError, OSError):
        writer.write(_line(text))
        await writer.drain()
    writer.close()
    with contextlib.suppress(ConnectionError, OSError):
        await writer.wait_closed()


def parse_host_port(text: str, default_host: str = "127.0.0.1") -> tuple[str, int]:
    """``HOST:PORT``, ``:PORT`` or ``PORT`` → (host, port); ``[::1]:PORT`` for IPv6."""
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = "", text
    host = host.strip("[]") or default_host
    try:
        number = int(port)
    except ValueError:
        raise ArmbenchError(f"--tcp: {text!r} is not HOST:PORT") from None
    if not 0 <= number <= 65535:
        raise ArmbenchError(f"--tcp: port {number} is not in 0..65535")
    return host, number
