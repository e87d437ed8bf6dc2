"""Transports against real parts: a pty pair, a TCP server on 127.0.0.1, a real ser2net, and tiny
in-test telnet servers. No mocks; every await has a deadline."""

from __future__ import annotations

import asyncio
import contextlib
import importlib.metadata
import os
import shutil
import socket
import struct
import subprocess
import termios
import tomllib
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import pytest
from far_end import pty_numbered
from netutil import free_port, listening

from armbench.drivers.model.errors import PortLostError, TransportError
from armbench.drivers.model.settings import SerialSettings
from armbench.drivers.telnet import (
    BINARY,
    COM_PORT_OPTION,
    PARITY_CODES,
    SGA,
    STOPSIZE_CODES,
    ComPort,
    ComPortRequest,
    Data,
    TelnetCodec,
)
from armbench.drivers.transports import (
    ENTRY_POINT_GROUP,
    Transport,
    known_transports,
    open_transport,
    scheme_of,
    transport_class,
)
from armbench.drivers.transports.rfc2217 import Rfc2217Transport
from armbench.drivers.transports.serial_port import IN_USE, PTY_TAKEN, SerialTransport
from armbench.drivers.transports.tcp import TcpTransport

T = TypeVar("T")
STEP_S = 10.0
"""Deadline of any single await in these tests, in seconds: a bound on a hung test, far beyond
what a real peer (a pty, a socket, ser2net) takes even on a loaded machine."""
ALL_BYTES = bytes(range(256))


async def within(aw: Awaitable[T], timeout_s: float = STEP_S) -> T:
    """``await aw`` with a deadline."""
    async with asyncio.timeout(timeout_s):
        return await aw


async def read_exactly(t: Transport, n: int, timeout_s: float = STEP_S) -> bytes:
    """Read from a transport until ``n`` bytes have arrived."""
    buf = bytearray()
    async with asyncio.timeout(timeout_s):
        while len(buf) < n:
            buf += await t.read()
    assert len(buf) == n, f"got {len(buf) - n} bytes too many"
    return bytes(buf)


async def read_fd(fd: int, n: int, timeout_s: float = STEP_S) -> bytes:
    """Read ``n`` bytes from a non-blocking fd (a pty master) through the event loop."""
    loop = asyncio.get_running_loop()
    ready = asyncio.Event()
    loop.add_reader(fd, ready.set)
    buf = bytearray()
    try:
        async with asyncio.timeout(timeout_s):
            while len(buf) < n:
                await ready.wait()
                ready.clear()
                with contextlib.suppress(BlockingIOError):
                    buf += os.read(fd, 4096)
    finally:
        loop.remove_reader(fd)
    return bytes(buf)


# --- registry -----------------------------------------------------------------------------------
def test_scheme_selection() -> None:
    assert scheme_of("/dev/ttyUSB0") is None
    assert scheme_of("COM3") is None
    assert scheme_of("socket://127.0.0.1:7000") == "socket"
    assert scheme_of("RFC2217://host:1") == "rfc2217"
    assert transport_class("/dev/ttyUSB0") is SerialTransport
    assert transport_class("/dev/pts/3") is SerialTransport
    assert transport_class("socket://127.0.0.1:7000") is TcpTransport
    assert transport_class("rfc2217://localhost:2217") is Rfc2217Transport
    assert known_transports()["fake"] == "armbench.fakes.links.fake_transport:FakeTransport"
    t = open_transport("socket://127.0.0.1:7000", SerialSettings())
    assert isinstance(t, TcpTransport) and not t.is_open
    assert (t.host, t.tcp_port, t.bytes_in, t.bytes_out) == ("127.0.0.1", 7000, 0, 0)
    assert isinstance(open_transport("rfc2217://[::1]:2217"), Rfc2217Transport)


def test_unknown_scheme_is_named() -> None:
    with pytest.raises(TransportError, match="bogus://") as info:
        open_transport("bogus://somewhere", SerialSettings())
    assert info.value.port == "bogus://somewhere"


class EchoTransport(Transport):
    """A third-party transport as another distribution would register it: writes come back as
    reads (in memory)."""

    scheme = "echo"

    def __init__(self, port: str, serial: SerialSettings) -> None:
        super().__init__(port, serial)
        self._open = False
        self._buf = bytearray()

    @property
    def is_open(self) -> bool:
        return self._open

    async def open(self) -> None:
        self._open = True

    async def read(self) -> bytes:
        data, self._buf = bytes(self._buf), bytearray()
        self.bytes_in += len(data)
        return data

    async def write(self, data: bytes) -> None:
        self._buf += data
        self.bytes_out += len(data)

    async def close(self) -> None:
        self._open = False


def _registered(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, **schemes: str) -> None:
    """A distribution ``other-transports`` declaring ``schemes`` as entry points of
    ``armbench.transports``, installed for this test (its ``.dist-info`` on ``sys.path``)."""
    site = tmp_path / "site"
    info = site / "other_transports-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: other-transports\n"
                                   "Version: 1.0\n", encoding="utf-8")
    (info / "entry_points.txt").write_text(
        f"[{ENTRY_POINT_GROUP}]\n" + "".join(f"{k} = {v}\n" for k, v in schemes.items()),
        encoding="utf-8")
    monkeypatch.syspath_prepend(str(site))


async def test_a_third_party_scheme_is_found_through_its_entry_point(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _registered(tmp_path, monkeypatch, echo=f"{__name__}:EchoTransport")
    assert transport_class("echo://anything") is EchoTransport
    assert known_transports()["echo"] == f"{__name__}:EchoTransport"
    async with open_transport("ECHO://x") as t:
        await t.write(b"$00000,00000,00000,00000#")
        assert await t.read() == b"$00000,00000,00000,00000#"
    known = r"known: avr://, echo://, fake://, labgrid://, rfc2217://, socket://"
    with pytest.raises(TransportError, match=known):
        open_transport("bogus://somewhere")


def test_a_scheme_two_distributions_register_is_refused_naming_both(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """No silent pick between two claims of one scheme: opening it names both."""
    _registered(tmp_path, monkeypatch, socket="elsewhere.module:NotTcp")
    with pytest.raises(TransportError, match=r"entry point armbench.transports: socket: "
                                             r"registered differently by several "
                                             r"distributions: armbench.drivers.transports.tcp:"
                                             r"TcpTransport \(armbench\), elsewhere.module:NotTcp "
                                             r"\(other-transports\)"):
        transport_class("socket://127.0.0.1:7000")
    assert transport_class("rfc2217://h:1") is Rfc2217Transport  # the others are unaffected


def test_a_broken_entry_point_is_a_transport_error(tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    _registered(tmp_path, monkeypatch, gone="no_such_module_anywhere:Transport",
                notone=f"{__name__}:within")
    with pytest.raises(TransportError, match=r"entry point armbench.transports: gone = "
                                             r"no_such_module_anywhere:Transport: "
                                             r"ModuleNotFoundError") as info:
        open_transport("gone://x")
    assert info.value.port == "gone://x"
    with pytest.raises(TransportError, match=r"notone = test_transports:within: <function "
                                             r"within at 0x[0-9a-f]+> is not a Transport class"):
        open_transport("notone://x")


def test_the_builtin_schemes_are_registered_once_as_entry_points() -> None:
    """pyproject.toml declares the built-in schemes, the installed metadata holds exactly those
    (a checkout whose entry points changed is installed again), and each loads its class."""
    project = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    declared = project["project"]["entry-points"][ENTRY_POINT_GROUP]
    installed = {ep.name: ep.value for ep in importlib.metadata.entry_points(
        group=ENTRY_POINT_GROUP) if ep.dist is not None and ep.dist.name == "armbench"}
    assert declared == installed == known_transports()
    for scheme in declared:
        assert transport_class(f"{scheme}://h:1").scheme == scheme


@pytest.mark.parametrize("port", ["socket://127.0.0.1", "socket://:7000", "rfc2217://h:99999",
                                  "socket://h:port"])
def test_bad_tcp_urls(port: str) -> None:
    with pytest.raises(TransportError) as info:
        open_transport(port, SerialSettings())
    assert info.value.port == port


async def test_use_before_open_is_an_error() -> None:
    for port in ("socket://127.0.0.1:9", "rfc2217://127.0.0.1:9", "/dev/null-port"):
        t = open_transport(port, SerialSettings())
        with pytest.raises(TransportError, match="not open"):
            await within(t.read())
        with pytest.raises(TransportError, match="not open"):
            await within(t.write(b"x"))
        await within(t.close())


# --- serial over a real pty ---------------------------------------------------------------------
@dataclass
class Pty:
    master: int
    slave: int
    path: str
    closed: set[int] = field(default_factory=set)

    def close(self, fd: int) -> None:
        if fd not in self.closed:
            self.closed.add(fd)
            os.close(fd)


@pytest.fixture
def pty() -> Iterator[Pty]:
    master, slave = os.openpty()
    os.set_blocking(master, False)
    p = Pty(master, slave, os.ttyname(slave))
    yield p
    p.close(master)
    p.close(slave)


async def test_serial_both_ways(pty: Pty) -> None:
    t = open_transport(pty.path, SerialSettings(115200))
    assert isinstance(t, SerialTransport)
    await within(t.open())
    try:
        assert t.is_open
        attrs = termios.tcgetattr(pty.slave)
        assert attrs[4] == attrs[5] == termios.B115200
        await within(t.write(ALL_BYTES))
        assert await read_fd(pty.master, 256) == ALL_BYTES
        os.write(pty.master, ALL_BYTES[::-1])
        assert await read_exactly(t, 256) == ALL_BYTES[::-1]
        assert (t.bytes_in, t.bytes_out) == (256, 256)
    finally:
        await within(t.close())
    assert not t.is_open
    await within(t.close())  # idempotent


async def test_serial_line_settings(pty: Pty) -> None:
    """Baud rate and stop bits reach the tty (a Linux pty forces 8 bits, no parity)."""
    async with open_transport(pty.path, SerialSettings(57600, 8, "N", 2)) as t:
        _, _, cflag, _, ispeed, ospeed, _ = termios.tcgetattr(pty.slave)
        assert ispeed == ospeed == termios.B57600
        assert cflag & termios.CSTOPB
        assert t.is_open


async def test_serial_a_held_port_is_refused_and_its_holder_loses_nothing(pty: Pty) -> None:
    """A second opener of a port armbench holds is refused, naming the port, and the holder
    still reads every byte: two readers would each get part of the stream, and pyserial reports
    the reads the other took as a lost device. Once the holder closes, the port opens again."""
    holder = open_transport(pty.path, SerialSettings())
    await within(holder.open())
    try:
        intruder = open_transport(pty.path, SerialSettings())
        with pytest.raises(TransportError) as info:
            await within(intruder.open())
        assert (info.value.port, info.value.reason) == (pty.path, IN_USE)
        assert not intruder.is_open
        os.write(pty.master, ALL_BYTES)
        assert await read_exactly(holder, 256) == ALL_BYTES
    finally:
        await within(holder.close())
    async with open_transport(pty.path, SerialSettings()) as again:
        os.write(pty.master, ALL_BYTES)
        assert await read_exactly(again, 256) == ALL_BYTES


COARSE_CLOCK_S = 0.05
"""More than a tick of the kernel's coarse clock (1–10 ms), which stamps a file's change time."""


async def _lose(pty: Pty, port: str) -> SerialTransport:
    """A serial transport on ``port`` (leading to ``pty``) that lost its pty: the far end
    closed, as a killed emulator's does, and the number is free again."""
    lost = SerialTransport(port, SerialSettings())
    await within(lost.open())
    assert lost.pty is not None
    pty.close(pty.master)
    with pytest.raises(PortLostError):
        await within(lost.read())
    await within(lost.close())
    pty.close(pty.slave)
    return lost


@pytest.mark.parametrize("via", ["/dev/pts/N", "a link left behind"])
async def test_serial_a_new_pty_under_the_lost_ones_name_is_not_opened(
        pty: Pty, via: str, tmp_path: Path) -> None:
    """After a loss, the pty that took the lost one's number is another program's: reconnecting
    through the same name, or the same link a killed emulator left, does not open it (it would
    hold that program's port and read its bytes). A new process cannot know and opens it."""
    port = pty.path
    if via != "/dev/pts/N":
        port = str(tmp_path / "arm-pty")
        os.symlink(pty.path, port)
        await asyncio.sleep(COARSE_CLOCK_S)  # the link older than the next pty, as a real one
    lost = await _lose(pty, port)
    with pty_numbered(pty.path) as (master, _):
        again = SerialTransport(port, SerialSettings())
        again.follow(lost)
        with pytest.raises(TransportError) as info:
            await within(again.open())
        assert (info.value.port, info.value.reason) == (port, PTY_TAKEN)
        async with SerialTransport(port, SerialSettings()) as unknowing:
            os.write(master, b"$1#")
            assert await read_exactly(unknowing, 3) == b"$1#"


async def test_serial_a_link_made_anew_is_followed_to_its_pty(pty: Pty, tmp_path: Path) -> None:
    """An emulator restarted with ``--link`` makes the link anew: the reconnection follows it,
    to a pty of the lost one's number too."""
    link = tmp_path / "arm-pty"
    link.symlink_to(pty.path)
    lost = await _lose(pty, str(link))
    with pty_numbered(pty.path) as (master, _):
        link.unlink()
        link.symlink_to(pty.path)
        again = SerialTransport(str(link), SerialSettings())
        again.follow(lost)
        async with again:
            os.write(master, b"$1#")
            assert await read_exactly(again, 3) == b"$1#"


async def test_serial_lost_when_peer_closes(pty: Pty) -> None:
    t = open_transport(pty.path, SerialSettings())
    await within(t.open())
    try:
        reading = asyncio.create_task(t.read())
        await asyncio.sleep(0.05)
        pty.close(pty.master)
        with pytest.raises(PortLostError) as info:
            await within(reading)
        assert info.value.port == pty.path
        assert not t.is_open
        with pytest.raises(PortLostError):
            await within(t.read())
        with pytest.raises(PortLostError):
            await within(t.write(b"x"))
    finally:
        await within(t.close())
        await within(t.close())


async def test_serial_write_after_peer_closed(pty: Pty) -> None:
    t = open_transport(pty.path, SerialSettings())
    await within(t.open())
    try:
        pty.close(pty.master)
        with pytest.raises(PortLostError):
            for _ in range(3):
                await within(t.write(b"hello"))
                await asyncio.sleep(0.02)
    finally:
        await within(t.close())


async def test_serial_missing_device() -> None:
    with pytest.raises(TransportError, match="no such serial device") as info:
        await within(open_transport("/dev/armbench-no-such-tty", SerialSettings()).open())
    assert info.value.port == "/dev/armbench-no-such-tty"
    assert not isinstance(info.value, PortLostError)


# --- raw TCP against a real asyncio server --------------------------------------------------------
@dataclass
class TcpPeer:
    """An asyncio TCP server on 127.0.0.1 that hands each connection to the test."""

    server: asyncio.Server
    conns: asyncio.Queue[tuple[asyncio.StreamReader, asyncio.StreamWriter]]

    @property
    def port(self) -> int:
        sock = self.server.sockets[0]
        return int(sock.getsockname()[1])


@pytest.fixture
async def tcp_peer() -> AsyncIterator[TcpPeer]:
    conns: asyncio.Queue[tuple[asyncio.StreamReader, asyncio.StreamWriter]] = asyncio.Queue()

    async def handle(r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        await conns.put((r, w))

    server = await within(asyncio.start_server(handle, "127.0.0.1", 0))
    yield TcpPeer(server, conns)
    server.close()
    await within(server.wait_closed())


async def test_tcp_both_ways(tcp_peer: TcpPeer) -> None:
    async with open_transport(f"socket://127.0.0.1:{tcp_peer.port}", SerialSettings()) as t:
        r, w = await within(tcp_peer.conns.get())
        await within(t.write(ALL_BYTES))
        assert await within(r.readexactly(256)) == ALL_BYTES
        w.write(ALL_BYTES * 3)
        await within(w.drain())
        assert await read_exactly(t, 768) == ALL_BYTES * 3
        assert (t.bytes_in, t.bytes_out) == (768, 256)
        w.close()


async def test_tcp_lost_on_server_close(tcp_peer: TcpPeer) -> None:
    t = open_transport(f"socket://127.0.0.1:{tcp_peer.port}", SerialSettings())
    await within(t.open())
    try:
        _, w = await within(tcp_peer.conns.get())
        w.write(b"last words")
        w.close()
        assert await read_exactly(t, 10) == b"last words"  # data before the close is delivered
        with pytest.raises(PortLostError, match="closed by the peer"):
            await within(t.read())
        with pytest.raises(PortLostError):
            await within(t.write(b"x"))
        assert not t.is_open
    finally:
        await within(t.close())
        await within(t.close())


async def test_tcp_lost_on_reset(tcp_peer: TcpPeer) -> None:
    t = open_transport(f"socket://127.0.0.1:{tcp_peer.port}", SerialSettings())
    await within(t.open())
    try:
        _, w = await within(tcp_peer.conns.get())
        sock = w.get_extra_info("socket")
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        w.transport.abort()  # close with linger 0: the client gets an RST
        with pytest.raises(PortLostError):
            await within(t.read())
        with pytest.raises(PortLostError):
            await within(t.write(b"x"))
    finally:
        await within(t.close())


async def test_tcp_connection_refused() -> None:
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(TransportError, match="cannot connect"):
        await within(open_transport(f"socket://127.0.0.1:{port}", SerialSettings()).open())


# --- RFC 2217 against a real ser2net ------------------------------------------------------------
@dataclass
class Ser2net:
    proc: subprocess.Popen[bytes]
    port: str
    pty: Pty




@pytest.fixture
async def ser2net(tmp_path: Path, pty: Pty) -> AsyncIterator[Ser2net]:
    """ser2net 4.x serving ``pty``'s slave as ``rfc2217://127.0.0.1:PORT`` (one per test, so a
    test may kill it)."""
    exe = shutil.which("ser2net") or shutil.which("ser2net", path="/usr/sbin:/usr/local/sbin")
    if exe is None:
        pytest.skip("ser2net not installed (Debian package 'ser2net'): RFC 2217 tests need it")
    tcp_port = free_port()
    config = tmp_path / "ser2net.yaml"
    config.write_text(
        "connection: &armbench\n"
        f"  accepter: telnet(rfc2217),tcp,127.0.0.1,{tcp_port}\n"
        f"  connector: serialdev,{pty.path},9600n81,local\n"
        "  options:\n"
        "    chardelay: false\n")
    proc = subprocess.Popen([exe, "-n", "-u", "-P", str(tmp_path / "ser2net.pid"),
                             "-c", str(config)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        async with asyncio.timeout(STEP_S):
            while not listening(tcp_port):
                if proc.poll() is not None:
                    pytest.fail(f"ser2net exited with {proc.returncode}; config:\n"
                                f"{config.read_text()}")
                await asyncio.sleep(0.01)
        yield Ser2net(proc, f"rfc2217://127.0.0.1:{tcp_port}", pty)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait(timeout=5)


@pytest.mark.parametrize(("settings", "speed"), [
    (SerialSettings(115200), termios.B115200),
    (SerialSettings(57600, 7, "E", 2), termios.B57600),
])
async def test_rfc2217_sets_the_line_remotely(ser2net: Ser2net, settings: SerialSettings,
                                              speed: int) -> None:
    t = Rfc2217Transport(ser2net.port, settings)
    await within(t.open())
    try:
        _, _, cflag, _, ispeed, ospeed, _ = termios.tcgetattr(ser2net.pty.slave)
        assert ispeed == ospeed == speed != termios.B9600  # ser2net opened the pty at 9600
        assert bool(cflag & termios.CSTOPB) == (settings.stopbits == 2)
        # A Linux pty forces 8 data bits and no parity; ser2net's acknowledgements must match.
        assert t.replies == {ComPort.SET_BAUDRATE: settings.baudrate,
                             ComPort.SET_DATASIZE: settings.bytesize,
                             ComPort.SET_PARITY: PARITY_CODES[settings.parity],
                             ComPort.SET_STOPSIZE: STOPSIZE_CODES[settings.stopbits]}
        assert t.codec.local_enabled(COM_PORT_OPTION)
        assert t.codec.local_enabled(BINARY) and t.codec.remote_enabled(BINARY)
        assert t.codec.violations == 0
    finally:
        await within(t.close())


async def test_rfc2217_data_both_ways(ser2net: Ser2net) -> None:
    master = ser2net.pty.master
    async with Rfc2217Transport(ser2net.port, SerialSettings()) as t:
        await within(t.write(b"\xff"))
        assert await read_fd(master, 1) == b"\xff"
        await within(t.write(ALL_BYTES * 4))
        assert await read_fd(master, 1024) == ALL_BYTES * 4
        os.write(master, b"\xff")
        assert await read_exactly(t, 1) == b"\xff"
        os.write(master, ALL_BYTES * 4)
        assert await read_exactly(t, 1024) == ALL_BYTES * 4
        assert (t.bytes_in, t.bytes_out) == (1025, 1025)
        assert t.codec.violations == 0


async def test_rfc2217_lost_when_ser2net_dies(ser2net: Ser2net) -> None:
    t = open_transport(ser2net.port, SerialSettings())
    await within(t.open())
    try:
        reading = asyncio.create_task(t.read())
        await asyncio.sleep(0.05)
        ser2net.proc.kill()
        with pytest.raises(PortLostError) as info:
            await within(reading)
        assert info.value.port == ser2net.port
        assert not t.is_open
        with pytest.raises(PortLostError):
            await within(t.write(b"x"))
    finally:
        await within(t.close())
        await within(t.close())


# --- RFC 2217 against tiny in-test servers ------------------------------------------------------
@dataclass
class MiniServer:
    """A telnet server built on the codec's server role.

    ``accept`` lists the options it agrees to (empty: it refuses everything); ``ack`` maps a
    setting request to the value it acknowledges (None: no answer); ``silent`` never answers.
    """

    accept: tuple[int, ...] = ()
    ack: Callable[[int, int], int | None] = lambda command, value: value
    silent: bool = False
    received: bytearray = field(default_factory=bytearray)
    got_data: asyncio.Event = field(default_factory=asyncio.Event)
    codec: TelnetCodec | None = None
    writer: asyncio.StreamWriter | None = None
    connected: asyncio.Event = field(default_factory=asyncio.Event)

    async def handle(self, r: asyncio.StreamReader, w: asyncio.StreamWriter) -> None:
        codec = self.codec = TelnetCodec(role="server", accept_local=self.accept,
                                         accept_remote=self.accept)
        self.writer = w
        self.connected.set()
        try:
            while chunk := await r.read(4096):
                if self.silent:
                    continue
                for e in codec.receive_data(chunk):
                    if isinstance(e, Data):
                        self.received += e.data
                        self.got_data.set()
                    elif isinstance(e, ComPortRequest) and e.command != ComPort.SET_CONTROL:
                        value = self.ack(e.command, e.value)
                        if value is not None:
                            size = 4 if e.command == ComPort.SET_BAUDRATE else 1
                            codec.send_com_port(e.command, value.to_bytes(size, "big"))
                w.write(codec.data_to_send())
        except OSError:
            pass
        finally:
            w.close()

    def send(self, wire: bytes = b"", data: bytes = b"") -> None:
        assert self.codec is not None and self.writer is not None
        self.codec.send_data(data)
        self.writer.write(wire + self.codec.data_to_send())


@pytest.fixture
async def mini() -> AsyncIterator[Callable[[MiniServer], Awaitable[str]]]:
    servers: list[asyncio.Server] = []

    async def start(spec: MiniServer) -> str:
        server = await within(asyncio.start_server(spec.handle, "127.0.0.1", 0))
        servers.append(server)
        return f"rfc2217://127.0.0.1:{server.sockets[0].getsockname()[1]}"

    yield start
    for server in servers:
        server.close()
        await within(server.wait_closed())


async def test_rfc2217_server_refusing_everything(
        mini: Callable[[MiniServer], Awaitable[str]]) -> None:
    port = await mini(MiniServer(accept=()))
    t = Rfc2217Transport(port, SerialSettings(), negotiation_timeout_s=30.0)
    loop = asyncio.get_running_loop()
    start = loop.time()
    with pytest.raises(TransportError, match="refuses COM-PORT-OPTION") as info:
        await within(t.open())
    assert loop.time() - start < 5.0  # failed on the refusal, not on the timeout
    assert info.value.port == port
    assert not t.is_open
    await within(t.close())


async def test_rfc2217_silent_server_times_out(
        mini: Callable[[MiniServer], Awaitable[str]]) -> None:
    port = await mini(MiniServer(silent=True))
    t = Rfc2217Transport(port, SerialSettings(), negotiation_timeout_s=0.3)
    with pytest.raises(TransportError, match=r"no answer to WILL COM-PORT-OPTION within 0.3 s"):
        await within(t.open())


async def test_rfc2217_settings_not_acknowledged(
        mini: Callable[[MiniServer], Awaitable[str]]) -> None:
    spec = MiniServer(accept=(BINARY, SGA, COM_PORT_OPTION),
                      ack=lambda c, v: None if c == ComPort.SET_PARITY else v)
    t = Rfc2217Transport(await mini(spec), SerialSettings(), negotiation_timeout_s=0.3)
    with pytest.raises(TransportError, match="did not acknowledge parity within"):
        await within(t.open())


async def test_rfc2217_server_sets_another_baud_rate(
        mini: Callable[[MiniServer], Awaitable[str]]) -> None:
    spec = MiniServer(accept=(BINARY, SGA, COM_PORT_OPTION),
                      ack=lambda c, v: 9600 if c == ComPort.SET_BAUDRATE else v)
    t = Rfc2217Transport(await mini(spec), SerialSettings(115200))
    with pytest.raises(TransportError, match="baud rate 9600 instead of 115200"):
        await within(t.open())


async def test_rfc2217_flow_control_and_notifications(
        mini: Callable[[MiniServer], Awaitable[str]]) -> None:
    """A server without modem control (SET-CONTROL never answered) that suspends our output,
    notifies modem state and asks for an unknown option mid-stream."""
    spec = MiniServer(accept=(BINARY, SGA, COM_PORT_OPTION))
    async with Rfc2217Transport(await mini(spec), SerialSettings()) as t:
        assert spec.codec is not None
        t.codec.set_control(ComPort.CONTROL_DTR_ON)  # ignored by the server: harmless
        await within(t.write(b"a\xffb"))
        await within(spec.got_data.wait())
        assert spec.received == b"a\xffb"
        spec.codec.flowcontrol(True)
        spec.codec.send_com_port(ComPort.NOTIFY_MODEMSTATE, bytes([ComPort.MODEM_CD | 0x0F]))
        spec.send(wire=bytes([255, 253, 24]), data=b"\xff\xffx\r\n")  # IAC DO TTYPE + data
        assert await read_exactly(t, 5) == b"\xff\xffx\r\n"
        assert t.suspended and t.modem_state == 0x8F
        writing = asyncio.create_task(t.write(b"after resume"))
        await asyncio.sleep(0.1)
        assert not writing.done() and spec.received == b"a\xffb"
        spec.got_data.clear()
        spec.codec.flowcontrol(False)
        spec.send()
        await within(writing)
        await within(spec.got_data.wait())
        assert spec.received == b"a\xffbafter resume"
        assert not t.suspended
        assert t.codec.declined == 1 and t.codec.violations == 0



async def test_rfc2217_reader_buffer_is_bounded(
        mini: Callable[[MiniServer], Awaitable[str]]) -> None:
    """With a small receive buffer the reader stops reading the socket until ``read`` drains it;
    nothing is lost and every 0xFF survives the escaping."""
    spec = MiniServer(accept=(BINARY, SGA, COM_PORT_OPTION))
    payload = ALL_BYTES * 2048  # 512 KiB, 2 KiB of which are 0xFF
    async with Rfc2217Transport(await mini(spec), SerialSettings(),
                                max_buffer_bytes=16 * 1024) as t:
        spec.send(data=payload)
        await asyncio.sleep(0.1)
        assert len(t._rx) < 16 * 1024 + 65536  # white-box: the bound holds
        assert await read_exactly(t, len(payload), timeout_s=10.0) == payload


async def test_rfc2217_server_hangs_up_during_negotiation(tcp_peer: TcpPeer) -> None:
    t = Rfc2217Transport(f"rfc2217://127.0.0.1:{tcp_peer.port}", SerialSettings())
    opening = asyncio.create_task(t.open())
    _, w = await within(tcp_peer.conns.get())
    w.close()
    with pytest.raises(TransportError, match="RFC 2217 negotiation failed: connection"):
        await within(opening)
    assert not t.is_open
