"""A client that writes faster than the line: the emulator's servers keep what waits for the line
within the board's receive buffer, drop the rest as overrun and say so, and the next client is
served as usual.

The hostile-client tests run ``armbench emulate`` as a real subprocess on real sockets and a real
pty, loopback only; their loops are bounded in count and in time. The unit tests run the receive
buffer on virtual time.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armbench.cli.perf.driver_perf import reply_rate_bound
from armbench.drivers.host.arm import Arm
from armbench.drivers.host.motion import joint_times_s
from armbench.drivers.model.errors import PortLostError
from armbench.drivers.model.protocol import Command, Framer, Reply
from armbench.drivers.model.server_notes import MAX_NOTE_BYTES, ServerNotes, note_line
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.firmware.emulator_settings import EmulatorSettings
from armbench.fakes.links.serve import ClientStream, ReceiveBuffer, TcpServer, real_time_loop

ROOT = Path(__file__).resolve().parents[1]
FLOOD_S = 3.0
"""How long the hostile client sends, at full socket speed: hundreds of megabytes, the line's
hours (it carries 11.5 kB/s), which a queue of what the line cannot take would keep."""
FLOOD_CHUNK = b"1" * 65536
MAX_SENDS = 1_000_000
"""Bound of the hostile loop's iterations besides its time."""
RSS_GROWTH_LIMIT_KB = 20 * 1024
TARGET = (0.1, -0.05, 0.08, 0.0)
"""The normal client's move after the flood (from the power-up pose)."""
REPLY_S = 1.0 / reply_rate_bound(RobotSettings().serial, EmulatorSettings())
"""The arm's time between two replies (one per firmware loop): on real time, a count of replies
is the arm's time, however late a loaded host reads them."""
REAL_REPLY_TIMEOUT_S = 5.0
"""Reply timeout over the real links here: an emulator process starved of CPU may fall silent
for longer than the driver's default 0.5 s."""
REAL_MOVE_TIMEOUT_S = 20.0
"""The normal client's move timeout: the time it took is asserted, on the arm's clock."""


# --- unit: the receive buffer on virtual time ---------------------------------------------------
def test_receive_buffer_keeps_what_fits_and_counts_the_rest() -> None:
    async def body() -> None:
        arm = ArmEmulator()
        await arm.start()
        reports: list[str] = []
        await asyncio.sleep(0.5)  # booted: the board's UART receives
        rx = ReceiveBuffer(arm, 64, reports.append)
        byte_s = arm.uart.byte_s
        loop = asyncio.get_running_loop()
        rx.feed(b"1" * 1000)
        assert rx.overrun_bytes == 1000 - 64
        assert rx.backlog_bytes(loop.time()) == 64
        rx.feed(b"2" * 10)  # still full: all dropped
        assert rx.overrun_bytes == 1000 - 64 + 10
        await asyncio.sleep(20.5 * byte_s)  # 20 bytes have left the buffer for the line
        rx.feed(b"3" * 30)
        assert rx.overrun_bytes == 1000 - 64 + 10 + 10
        assert rx.backlog_bytes(loop.time()) == 64
        await asyncio.sleep(0)
        # the first report at once (the drops of this instant), the rest a second later
        assert reports == ["overrun: 946 bytes dropped, sent faster than the line carries them "
                           "with its 64-byte buffer full (946 bytes in all)"]
        await asyncio.sleep(1.0)
        assert reports[1:] == ["overrun: 10 bytes dropped, sent faster than the line carries "
                               "them with its 64-byte buffer full (956 bytes in all)"]
        # what was kept reached the board: 64 bytes first, then 20 of the 30
        stats = arm.stats()
        assert stats.rx_bytes + stats.rx_overflow_bytes == 84
        await asyncio.sleep(5.0)
        assert len(reports) == 2  # nothing more dropped, nothing more said
        rx.close()
        await arm.close()

    run_virtual(body())


def test_back_to_back_commands_pass_whole() -> None:
    """A move and a hold written at once (74 bytes, more than the board's 64-byte buffer) reach
    the board whole: the host side holds them for the line, as a serial port's driver does."""
    async def body() -> None:
        arm = ArmEmulator()
        await arm.start()
        await asyncio.sleep(0.5)  # booted
        rx = ReceiveBuffer(arm, arm.settings.host_buffer_bytes, lambda text: None)
        move = Command.from_rad((0.2, 0.0, 0.0, 0.0), 99).encode()
        hold = Command.from_rad((0.0, 0.0, 0.0, 0.0), 0).encode()
        for _ in range(3):
            rx.feed(move + hold)
            await asyncio.sleep(0.05)
        stats = arm.stats()
        assert rx.overrun_bytes == 0 and stats.rx_overflow_bytes == 0
        assert stats.commands == 6 and stats.rx_bytes == 3 * len(move + hold)
        await arm.close()

    run_virtual(body())


def test_a_departed_clients_unsent_bytes_are_discarded() -> None:
    async def body() -> None:
        arm = ArmEmulator()
        await arm.start()
        await asyncio.sleep(0.5)
        rx = ReceiveBuffer(arm, 1000, lambda text: None)
        rx.feed(b"1" * 1000)
        await asyncio.sleep(100.5 * arm.uart.byte_s)  # 101 bytes have begun on the line
        assert rx.discard() == 899
        loop = asyncio.get_running_loop()
        assert rx.backlog_bytes(loop.time()) <= 1
        await asyncio.sleep(0.01)
        stats = arm.stats()
        assert stats.rx_bytes + stats.rx_overflow_bytes == 101
        await arm.close()

    run_virtual(body())


def test_server_lines_go_between_frames() -> None:
    out: list[bytes] = []
    stream = ClientStream(out.append)
    reply = Reply(1, 2, 3, 4).encode()
    stream.say("first")  # nothing sent yet: between frames
    stream.reply(reply[:10])
    stream.say("held")
    stream.say("newest")  # only the newest held line is kept
    assert out == [note_line("first"), reply[:10]]
    stream.reply(reply[10:])
    assert out[2:] == [reply[10:], note_line("newest")]
    events = Framer().feed(b"".join(out))
    assert [e for e in events if isinstance(e, Reply)] == [Reply(1, 2, 3, 4)]
    assert ServerNotes().feed(b"".join(out)) == ["first", "newest"]


def test_note_line_has_no_frame_delimiters() -> None:
    line = note_line("a $ b # c\r\nd")
    assert b"$" not in line and b"#" not in line and line.count(b"\n") == 2
    assert ServerNotes().feed(line) == ["a ? b ? c  d"]


@settings(max_examples=200, deadline=None)
@given(texts=st.lists(st.text(alphabet="abc: 0123456789", max_size=40), min_size=1, max_size=4),
       cuts=st.lists(st.integers(min_value=0, max_value=400), max_size=12))
def test_server_notes_survive_any_chunking(texts: list[str], cuts: list[int]) -> None:
    reply = Reply(10, 20, 30, 40).encode()
    stream = reply + b"".join(note_line(t) + reply for t in texts)
    points = sorted({min(c, len(stream)) for c in cuts})
    chunks = [stream[a:b] for a, b in zip([0, *points], [*points, len(stream)], strict=True)]
    notes = ServerNotes()
    found = [n for c in chunks for n in notes.feed(c)]
    assert found == texts


def test_server_notes_bound_a_line_without_end() -> None:
    notes = ServerNotes()
    assert notes.feed(b"armbench emulate: " + b"x" * 100) == []
    got = notes.feed(b"x" * 10 * MAX_NOTE_BYTES)
    assert got == ["x" * MAX_NOTE_BYTES]
    assert notes.feed(b"x" * 1000) == []


def test_the_driver_shows_the_servers_overrun_line(caplog: pytest.LogCaptureFixture) -> None:
    """5000 bytes at once through the driver's own transport: the 904 beyond the 4096-byte buffer
    are dropped, the driver logs the server's line and keeps it as ``server_note``, and a move
    goes through once the line has carried the rest."""
    async def body() -> None:
        server = TcpServer(ArmEmulator())
        host, port = await server.start()
        try:
            # the emulator shares this loop: a starved process may answer later than the
            # driver's defaults (silence, resend), which are not what this test is about
            async with Arm.connect(f"socket://{host}:{port}", reply_timeout_s=REAL_REPLY_TIMEOUT_S,
                                   resend_after_s=REAL_REPLY_TIMEOUT_S) as arm:
                await arm.transport.write(b"x" * 5000)
                await arm.wait_state(lambda s: arm.server_note is not None, 5.0)
                assert arm.server_note == ("overrun: 904 bytes dropped, sent faster than the "
                                           "line carries them with its 4096-byte buffer full "
                                           "(904 bytes in all)")
                await asyncio.sleep(4096 * arm.settings.serial.byte_time_s + 0.01)  # line free
                done = await arm.move_joints((0.02, 0.0, 0.0, 0.0), 99)
                assert done is not None and server.overrun_bytes == 904 and arm.resends == 0
        finally:
            await server.close()

    with asyncio.Runner(loop_factory=real_time_loop) as runner:
        runner.run(body())
    assert "the server says: overrun: 904 bytes dropped" in caplog.text


# --- the hostile client against a real emulator process ------------------------------------------
class Emulator:
    """``armbench emulate ARGS`` in a subprocess, its log in a file."""

    def __init__(self, tmp: Path, *args: str) -> None:
        self.log = tmp / "emulate.log"
        with self.log.open("w") as err:
            self.proc = subprocess.Popen([sys.executable, "-m", "armbench", "emulate", *args],
                                         cwd=ROOT, stdout=subprocess.PIPE, stderr=err, text=True)
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], 120.0)  # slow on a loaded host
        line = self.proc.stdout.readline() if ready else ""
        m = re.search(r"serving the arm on (\S+)", line)
        assert m is not None, f"emulate did not start: {line!r} {self.log.read_text()}"
        self.where = m.group(1)

    def status_kb(self, field: str) -> int:
        """A ``/proc/PID/status`` figure in kB (VmRSS, VmHWM)."""
        text = Path(f"/proc/{self.proc.pid}/status").read_text()
        m = re.search(rf"^{field}:\s+(\d+) kB", text, re.MULTILINE)
        assert m is not None
        return int(m.group(1))

    def stop(self) -> str:
        self.proc.send_signal(signal.SIGINT)
        out, _ = self.proc.communicate(timeout=15)
        assert self.proc.returncode == 0, self.log.read_text()
        return out

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)


@pytest.fixture
def tcp_emulator(tmp_path: Path) -> Iterator[Emulator]:
    emu = Emulator(tmp_path, "--tcp", "127.0.0.1:0", "--duration", "120")
    try:
        yield emu
    finally:
        emu.kill()


@pytest.fixture
def pty_emulator(tmp_path: Path) -> Iterator[Emulator]:
    emu = Emulator(tmp_path, "--pty", "--duration", "120")
    try:
        yield emu
    finally:
        emu.kill()


def flood_tcp(host: str, port: int, seconds: float) -> tuple[int, bytes]:
    """Send ``FLOOD_CHUNK`` as fast as the socket takes it for ``seconds`` (and at most
    ``MAX_SENDS`` sends), reading what comes back; returns (bytes sent, the server's lines)."""
    sent = 0
    lines = bytearray()
    with socket.create_connection((host, port), timeout=5) as sock:
        sock.setblocking(False)
        view = memoryview(FLOOD_CHUNK)
        offset = 0
        t_end = time.monotonic() + seconds
        for _ in range(MAX_SENDS):
            if time.monotonic() >= t_end:
                break
            readable, writable, _ = select.select([sock], [sock], [], 0.5)
            if readable:
                data = sock.recv(65536)
                if not data:
                    break
                if b"armbench emulate:" in data and len(lines) < 65536:
                    lines += data
            if writable:
                with_room = sock.send(view[offset:])
                sent += with_room
                offset = (offset + with_room) % len(FLOOD_CHUNK)
    return sent, bytes(lines)


#: How long a client waits for a departed flooder's slot: the server reads and drops what the
#: flooder's socket still held (megabytes in the kernel's buffers) before it sees the close.
SLOT_FREED_WITHIN_S = 60.0


async def _connect_when_free(port: str) -> Arm:
    """An open ``Arm.connect(port)``, tried again while the server says its slot is busy
    (bounded in time); the caller closes it."""
    loop = asyncio.get_running_loop()
    give_up = loop.time() + SLOT_FREED_WITHIN_S
    while True:
        try:
            return await Arm.connect(port, reply_timeout_s=REAL_REPLY_TIMEOUT_S)
        except PortLostError as exc:
            if "busy" not in str(exc) or loop.time() > give_up:
                raise
            await asyncio.sleep(0.2)


def move_time_s(port: str) -> tuple[float, float]:
    """A normal client's connection and move to ``TARGET``: (seconds the move took on the arm's
    clock, from the newest reply read before the command to the first one there; law (12)'s
    prediction). A backlog of queued bytes delays the command while the arm goes on replying, so
    it counts; a host that reads late does not. Raises if the move fails."""
    async def body() -> tuple[float, float]:
        arm = await _connect_when_free(port)
        try:
            seq = arm.state.seq
            before = await arm.wait_state(lambda s: s.seq > seq, REAL_REPLY_TIMEOUT_S)
            start = before.q_rad
            done = await arm.move_joints(TARGET, 99, timeout_s=REAL_MOVE_TIMEOUT_S)
            assert done is not None
            predicted = max(joint_times_s(start, TARGET, (99,) * 4, RobotSettings()))
            return (done.seq - before.seq) * REPLY_S, predicted
        finally:
            await arm.close()

    return asyncio.run(body())


def test_a_flooding_tcp_client_leaves_no_backlog_and_little_memory(
        tcp_emulator: Emulator) -> None:
    """:data:`FLOOD_S` of bytes at full socket speed into ``emulate --tcp``: memory grows by less
    than 20 MB, the client is told of the overrun, and the next client's move takes its usual
    time (it hung behind hours of queued bytes before)."""
    emu = tcp_emulator
    host, port_text = emu.where.removeprefix("socket://").rsplit(":", 1)
    rss0, hwm0 = emu.status_kb("VmRSS"), emu.status_kb("VmHWM")
    sent, lines = flood_tcp(host, int(port_text), FLOOD_S)
    assert sent > FLOOD_S * 1024 * 1024  # the flood did flow (far beyond the line's 11.5 kB/s)
    notes = ServerNotes().feed(lines)
    assert notes and all(n.startswith("overrun: ") for n in notes), lines[:300]
    rss_growth = emu.status_kb("VmRSS") - rss0
    hwm_growth = emu.status_kb("VmHWM") - max(hwm0, rss0)
    assert rss_growth < RSS_GROWTH_LIMIT_KB and hwm_growth < RSS_GROWTH_LIMIT_KB, (rss0, hwm0)
    took_s, predicted_s = move_time_s(emu.where)
    # the flood's unsent bytes left with it: the move waits behind nothing
    assert took_s <= predicted_s + 0.3, (took_s, predicted_s)
    print(f"tcp flood: {sent / 1e6:.0f} MB sent in {FLOOD_S:g} s, RSS growth "
          f"{rss_growth / 1024:.1f} MB (peak {hwm_growth / 1024:.1f} MB), then move "
          f"{took_s:.3f} s (law (12): {predicted_s:.3f} s)")
    out = emu.stop()
    m = re.search(r"(\d+) bytes dropped as overrun", out)
    assert m is not None and int(m.group(1)) > sent // 2, out
    log = emu.log.read_text()
    assert "overrun" in log and len(log) < 200_000  # reported at most once a second


def test_a_flooding_pty_client_leaves_no_backlog(pty_emulator: Emulator) -> None:
    """The same on ``emulate --pty`` for three seconds: a writer that never waits."""
    emu = pty_emulator
    rss0 = emu.status_kb("VmRSS")
    fd = os.open(emu.where, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    sent = 0
    lines = bytearray()
    try:
        t_end = time.monotonic() + 3.0
        for _ in range(MAX_SENDS):
            if time.monotonic() >= t_end:
                break
            readable, writable, _ = select.select([fd], [fd], [], 0.5)
            if readable:
                data = os.read(fd, 65536)
                if b"armbench emulate:" in data and len(lines) < 65536:
                    lines += data
            if writable:
                with contextlib.suppress(BlockingIOError):
                    sent += os.write(fd, FLOOD_CHUNK)
    finally:
        os.close(fd)
    assert sent > 1024 * 1024  # far beyond the 35 kB the line carries in 3 s
    notes = ServerNotes().feed(bytes(lines))
    assert notes and all(n.startswith("overrun: ") for n in notes), lines[:300]
    assert emu.status_kb("VmRSS") - rss0 < RSS_GROWTH_LIMIT_KB
    took_s, predicted_s = move_time_s(emu.where)
    # behind at most the host buffer's 4096 bytes of line time (a pty has no "client left")
    assert took_s <= predicted_s + 4096 * RobotSettings().serial.byte_time_s + 0.3, took_s
    print(f"pty flood: {sent / 1e6:.1f} MB written in 3 s, then move {took_s:.3f} s "
          f"(law (12): {predicted_s:.3f} s)")
    out = emu.stop()
    m = re.search(r"(\d+) bytes dropped as overrun", out)
    assert m is not None and int(m.group(1)) > sent // 2, out


def test_the_host_buffer_is_a_bounded_setting() -> None:
    from dataclasses import replace

    from armbench.drivers.model.settings import SettingsError
    from armbench.fakes.firmware.emulator_settings import EmulatorSettings, emulator_settings

    assert EmulatorSettings().host_buffer_bytes == 4096
    assert EmulatorSettings().rx_buffer_bytes == 64  # RX_SIZE of firmware/master.c
    robot = replace(RobotSettings(), sections={"emulator": {"host_buffer_bytes": 256}})
    assert emulator_settings(robot).host_buffer_bytes == 256
    for bad in (0, 2**21, 1.5, "x"):
        robot = replace(RobotSettings(), sections={"emulator": {"host_buffer_bytes": bad}})
        with pytest.raises(SettingsError, match=r"emulator\.host_buffer_bytes"):
            emulator_settings(robot)
