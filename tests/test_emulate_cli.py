"""``armbench emulate``: the emulator served in real time on a pty (driven with plain pyserial)
and on TCP (driven with a plain socket), as separate processes."""

from __future__ import annotations

import asyncio
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable, Iterator
from pathlib import Path

import pytest
import serial

from armbench.cli.main import main
from armbench.drivers.model.protocol import Command, Framer, Reply
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.links.serve import TcpServer, real_time_loop

ROOT = Path(__file__).resolve().parents[1]


def start(*args: str) -> tuple[subprocess.Popen[str], str]:
    """Start ``armbench emulate ARGS`` and return it with the address it printed."""
    proc = subprocess.Popen([sys.executable, "-m", "armbench", "emulate", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stderr is not None
    line = proc.stdout.readline()
    m = re.search(r"serving the arm on (\S+)", line)
    if m is None:
        proc.kill()
        raise AssertionError(f"unexpected first line {line!r}; stderr: {proc.stderr.read()}")
    return proc, m.group(1)


def stop(proc: subprocess.Popen[str]) -> str:
    proc.send_signal(signal.SIGINT)
    out, _ = proc.communicate(timeout=10)
    assert proc.returncode == 0
    return out


def replies(data: bytes) -> list[Reply]:
    return [e for e in Framer().feed(data) if isinstance(e, Reply)]


def read_until(read: Callable[[], bytes], done: Callable[[list[Reply]], bool],
               deadline_s: float = 20.0) -> list[Reply]:
    """The replies read until ``done(replies)`` holds or ``deadline_s`` has passed: what the test
    asserts on is what arrived, however late a loaded machine lets it arrive."""
    framer = Framer()
    got: list[Reply] = []
    deadline = time.monotonic() + deadline_s
    while not done(got) and time.monotonic() < deadline:
        got += [e for e in framer.feed(read()) if isinstance(e, Reply)]
    return got


@pytest.fixture
def pty_emulator(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], str, Path]]:
    link = tmp_path / "arm"
    proc, path = start("--pty", "--link", str(link), "--duration", "60")
    try:
        yield proc, path, link
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_pty_with_plain_pyserial(pty_emulator: tuple[subprocess.Popen[str], str, Path]) -> None:
    proc, path, link = pty_emulator
    assert path.startswith("/dev/pts/")
    assert os.path.realpath(link) == path
    with serial.Serial(str(link), 115200, timeout=0.05) as port:
        got = read_until(lambda: port.read(4096), lambda r: len(r) > 50)
        assert len(got) > 50  # one a loop, ~420 a second
        assert got[-1] == Reply(0, 0, 0, 0)
        port.write(Command.from_rad([0.02, 0.0, 0.0, 0.0], 99).encode())
        after = read_until(lambda: port.read(4096), lambda r: bool(r) and r[-1].j1 >= 198)
        assert abs(after[-1].j1 - 200) <= 2  # within the firmware's 1-count deadband
    out = stop(proc)
    assert "stopped after" in out and "1 commands received" in out
    assert not link.exists()


def test_pty_survives_a_client_closing_and_reopening(
        pty_emulator: tuple[subprocess.Popen[str], str, Path]) -> None:
    _, path, _ = pty_emulator
    for _ in range(2):
        with serial.Serial(path, 115200, timeout=0.05) as port:
            assert read_until(lambda: port.read(4096), bool)


def test_tcp_with_a_plain_socket_one_client_at_a_time() -> None:
    proc, url = start("--tcp", "127.0.0.1:0", "--duration", "60")
    try:
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        assert host == "127.0.0.1"
        with socket.create_connection((host, int(port)), timeout=2) as sock:
            sock.settimeout(0.05)

            def read() -> bytes:
                try:
                    return sock.recv(4096)
                except TimeoutError:
                    return b""

            assert len(read_until(read, lambda r: len(r) > 50)) > 50
            with socket.create_connection((host, int(port)), timeout=2) as other:
                other.settimeout(2)
                told = b"".join(iter(lambda: other.recv(4096), b""))  # until it closes
                # turned away while the first is connected, with a line saying why (issue 20)
                assert b"armbench emulate: busy: another client" in told and not replies(told)
            sock.sendall(Command.from_rad([0.0, 0.0, 0.0, 0.01], 99).encode())
            after = read_until(read, lambda r: bool(r) and r[-1].j4 >= 98)
            assert abs(after[-1].j4 - 100) <= 2
        served: list[Reply] = []
        deadline = time.monotonic() + 20.0
        while not served and time.monotonic() < deadline:  # once the server has seen it leave
            with socket.create_connection((host, int(port)), timeout=5) as again:
                again.settimeout(5)
                served = replies(again.recv(4096) + again.recv(4096))
            time.sleep(0.1)
        assert served  # the next client is served after the first left
        assert "stopped after" in stop(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_tcp_refuses_a_remote_bind_without_the_flag(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["emulate", "--tcp", "0.0.0.0:0", "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "not a loopback address" in err and "--allow-remote" in err


def test_bad_settings_file_is_a_one_line_error(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "robot.toml"
    bad.write_text("[emulator]\ni2c_hz = 5\n")
    assert main(["emulate", "--pty", "--settings", str(bad), "--duration", "0.1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "emulator.i2c_hz" in err[0]


def test_tcp_listener_stays_and_a_stalled_client_is_dropped() -> None:
    """Idle timeout (issue 7): a client that only reads the reply stream (as ``armbench monitor``
    does) stays past the timeout; one that neither writes nor reads is disconnected. Real sockets
    on a real-time loop; the client that stalls has a tiny receive buffer so the server's send
    buffer fills within seconds."""
    from armbench.fakes.firmware.arm_emulator import ArmEmulator
    from armbench.fakes.links.serve import TcpServer

    async def main() -> None:
        server = TcpServer(ArmEmulator(), idle_timeout_s=0.3, stalled_buffer_bytes=2048)
        host, port = await server.start()
        loop = asyncio.get_running_loop()
        try:
            reader, writer = await asyncio.open_connection(host, port)
            got = 0
            t_end = loop.time() + 1.5
            while loop.time() < t_end:  # five idle timeouts long, reading all the while
                chunk = await asyncio.wait_for(reader.read(4096), 1.0)
                assert chunk, "the listening client was disconnected"
                got += len(chunk)
            # replies kept coming (every read above had some); how many is the machine's (an
            # emulator starved of CPU drops the loops it cannot catch up)
            assert got > 25 * 10
            writer.close()
            await writer.wait_closed()
            await asyncio.sleep(0.1)

            sock = socket.socket()
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1024)
            sock.setblocking(False)
            await loop.sock_connect(sock, (host, port))
            t0 = loop.time()
            while server._client is not None or loop.time() - t0 < 0.5:
                assert loop.time() - t0 < 30, "the stalled client was never dropped"
                await asyncio.sleep(0.1)
            sock.close()
            assert server.clients_served == 2
        finally:
            await server.close()

    asyncio.run(main())


def _tcp_server_test(body: Callable[[TcpServer, str, int], Awaitable[None]],
                     idle_timeout_s: float) -> None:
    """Run ``body(server, host, port)`` against a real TCP server on a real-time loop."""
    async def main() -> None:
        server = TcpServer(ArmEmulator(), idle_timeout_s=idle_timeout_s)
        host, port = await server.start()
        try:
            await body(server, host, port)
        finally:
            await server.close()

    with asyncio.Runner(loop_factory=real_time_loop) as runner:
        runner.run(main())


async def _read_until(reader: asyncio.StreamReader, needle: bytes, timeout_s: float) -> bytes:
    data = b""
    async with asyncio.timeout(timeout_s):
        while needle not in data:
            chunk = await reader.read(4096)
            if not chunk:
                break
            data += chunk
    return data


def test_tcp_a_silent_client_that_does_not_read_gives_the_arm_to_the_next() -> None:
    """Issue 20: a client that neither reads nor sends held the only slot for good (its replies
    pile up in its own kernel, unseen by the server). Now the next client takes the arm once the
    silent one has sent nothing for the idle timeout, and the silent one is told why."""
    async def body(server: TcpServer, host: str, port: int) -> None:
        silent_r, silent_w = await asyncio.open_connection(host, port)
        silent_w.transport.pause_reading()  # type: ignore[attr-defined]  # a socket transport
        await asyncio.sleep(0.8)  # past the idle timeout
        reader, writer = await asyncio.open_connection(host, port)
        writer.write(Command.from_rad([0.01, 0.0, 0.0, 0.0], 99).encode())
        got = await _read_until(reader, b"#", 3.0)
        assert replies(got), got[:200]
        assert server.clients_taken_over == 1 and server.clients_refused == 0
        silent_w.transport.resume_reading()  # type: ignore[attr-defined]
        told = await _read_until(silent_r, b"asked for the arm", 3.0)
        assert b"armbench emulate: disconnected: no input for" in told
        writer.close()
        silent_w.close()

    _tcp_server_test(body, idle_timeout_s=0.5)


def test_tcp_a_refused_client_is_told_why() -> None:
    """A second client while the first one is active: refused with a line saying why (it read
    as "no valid reply within 3 s" before)."""
    async def body(server: TcpServer, host: str, port: int) -> None:
        _, first = await asyncio.open_connection(host, port)
        first.write(Command.from_rad([0.0, 0.0, 0.0, 0.0], 0).encode())
        await asyncio.sleep(0.1)
        second_r, _ = await asyncio.open_connection(host, port)
        told = await _read_until(second_r, b"\n", 3.0)
        told += await second_r.read()
        assert b"armbench emulate: busy: another client" in told
        assert server.clients_refused == 1 and server.clients_taken_over == 0
        first.close()

    _tcp_server_test(body, idle_timeout_s=30.0)


def test_move_against_a_busy_emulator_shows_the_servers_line(
        capsys: pytest.CaptureFixture[str], caplog: pytest.LogCaptureFixture) -> None:
    """``armbench move`` while another client has the arm: the error is the server's ``busy``
    line (it read "no valid reply within 3 s (no reply ever received)" before)."""
    proc, url = start("--tcp", "127.0.0.1:0", "--duration", "60")
    try:
        host, port = url.removeprefix("socket://").rsplit(":", 1)
        with socket.create_connection((host, int(port)), timeout=5) as first:
            first.sendall(Command.from_rad([0.0, 0.0, 0.0, 0.0], 0).encode())
            first.settimeout(5)
            assert first.recv(4096)  # the first client is being served
            # the busy line must come, not the first reply: a connect timeout a starved server
            # cannot outlast
            assert main(["move", "0", "0", "0", "0", "--port", url, "--connect-timeout",
                         "30"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert "the server said: busy: another client" in err[-1], err
        assert err[-1].startswith("armbench move: error: ") and "no valid reply" not in err[-1]
        assert "the server says: busy: another client" in caplog.text  # logged as it came
    finally:
        proc.kill()
        proc.wait()


@pytest.mark.parametrize("argv", [
    ["emulate", "--pty", "--foxglove", "0.0.0.0:0", "--duration", "0.1"],
    ["emulate", "--tcp", "127.0.0.1:0", "--foxglove", "[::]:0", "--duration", "0.1"],
    ["monitor", "--foxglove", "0.0.0.0:0", "--duration", "0.1"],
    ["monitor", "--foxglove", "example.org:8765", "--duration", "0.1"],
])
def test_foxglove_refuses_a_remote_bind_without_the_flag(
        argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    """``--foxglove`` follows ``--tcp``'s rule: the live server has no authentication and takes
    any Origin, so binding anything but loopback needs ``--allow-remote`` (nothing starts)."""
    assert main(argv) == 2
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "--foxglove" in lines[0] and "not a loopback address" in lines[0]
    assert "--allow-remote" in lines[0] and "without authentication" in lines[0]
    assert "serving" not in out and "Foxglove live view" not in out + err


def test_remote_binds_are_warned_about_with_the_flag() -> None:
    from armbench.frontends.foxglove.live import check_bind, check_live_endpoint, is_loopback

    assert all(is_loopback(h) for h in ("127.0.0.1", "127.3.2.1", "::1", "localhost"))
    assert not any(is_loopback(h) for h in ("0.0.0.0", "::", "10.0.0.1", "example.org", ""))
    assert check_live_endpoint("127.0.0.1:0", allow_remote=False) is None
    assert check_live_endpoint(":8765", allow_remote=False) is None  # loopback by default
    warning = check_live_endpoint("0.0.0.0:8765", allow_remote=True)
    assert warning is not None and warning.startswith("WARNING: --foxglove serves on 0.0.0.0")
    assert "without authentication" in warning
    tcp = check_bind("--tcp", "::", True, "move the arm")
    assert tcp is not None and "move the arm" in tcp
