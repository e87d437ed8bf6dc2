"""``labgrid://PLACE`` against a real lab on loopback: a labgrid coordinator and exporter started
here, the exporter serving two ``armbench emulate --pty`` arms through ser2net (RFC 2217), places
made with ``labgrid-client``. Nothing is mocked."""

from __future__ import annotations

import asyncio
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from conftest import cli
from netutil import free_port, listening

from armbench.drivers.host.arm import Arm
from armbench.drivers.model.errors import (
    CoordinatorUnreachableError,
    NoSerialResourceError,
    PlaceLockedError,
    PlaceUnknownError,
    TransportError,
)
from armbench.drivers.transports.labgrid import parse_labgrid_url

pytest.importorskip("labgrid", reason="an optional extra: pip install 'armbench[labgrid]'")
if shutil.which("ser2net") is None and not os.path.exists("/usr/sbin/ser2net"):
    pytest.skip("ser2net not installed (Debian package 'ser2net'): the exporter serves the arms "
                "with it", allow_module_level=True)

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
ARMS = ("arm-a", "arm-b")
REPLY_TIMEOUT_S = 5.0
"""The driver's reply timeout here: an emulator process behind ser2net, starved of CPU, may fall
silent for longer than the default 0.5 s."""
MOVE_TIMEOUT_S = 20.0
"""The small moves' timeout: a starved emulator drops the loops it cannot catch up, so the arm's
time runs slower than the host's, which the default timeout (from law (12)) measures."""


def _tool(name: str) -> str:
    found = shutil.which(name, path=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}")
    assert found is not None, f"{name} is installed with labgrid"
    return found


@dataclass
class Lab:
    """A coordinator on loopback, an exporter serving the arms, the places made for them."""

    coordinator: str
    folder: Path

    def client(self, *args: str, user: str = "") -> subprocess.CompletedProcess[str]:
        env = dict(os.environ, LG_COORDINATOR=self.coordinator)
        if user:
            env["LG_USERNAME"] = user
        return subprocess.run([_tool("labgrid-client"), *args], env=env, capture_output=True,
                              text=True, timeout=60, check=False)

    def port(self, place: str) -> str:
        return f"labgrid://{place}?coordinator={self.coordinator}"


def _wait(condition: object, what: str, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():  # type: ignore[operator]
        assert time.monotonic() < deadline, f"{what} within {timeout_s:g} s"
        time.sleep(0.2)


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for proc in reversed(procs):
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    for proc in reversed(procs):
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def start_coordinator(folder: Path, procs: list[subprocess.Popen[bytes]]) -> str:
    """A labgrid coordinator on a free loopback port, added to ``procs``: its address."""
    port = free_port()
    coordinator = f"127.0.0.1:{port}"
    procs.append(subprocess.Popen([_tool("labgrid-coordinator"), "--listen", coordinator],
                                  cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    _wait(lambda: listening(port), "the coordinator listens")
    return coordinator


def start_exporter(folder: Path, coordinator: str, procs: list[subprocess.Popen[bytes]]) -> Lab:
    """A labgrid exporter of ``folder/exporter.yaml`` as ``bench-pc``, added to ``procs``."""
    procs.append(subprocess.Popen([_tool("labgrid-exporter"), "--coordinator", coordinator,
                                   "--name", "bench-pc", "--hostname", "127.0.0.1",
                                   str(folder / "exporter.yaml")], cwd=folder,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    return Lab(coordinator, folder)


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Lab]:
    folder = tmp_path_factory.mktemp("lab")
    procs: list[subprocess.Popen[bytes]] = []
    try:
        coordinator = start_coordinator(folder, procs)
        config = []
        for name in ARMS:
            emulator = subprocess.Popen([sys.executable, "-m", "armbench", "emulate", "--pty"],
                                        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
            procs.append(emulator)
            assert emulator.stdout is not None
            device = emulator.stdout.readline().decode().split(" on ")[-1].strip()
            # the exporter takes devices under /dev only: the pty itself, not a link to it
            assert device.startswith("/dev/pts/"), device
            config.append(f"{name}:\n  RawSerialPort:\n    port: {device}\n    speed: 115200\n")
        (folder / "exporter.yaml").write_text("".join(config), encoding="utf-8")
        the_lab = start_exporter(folder, coordinator, procs)
        _wait(lambda: all(f"bench-pc/{name}/NetworkSerialPort" in the_lab.client(
            "resources").stdout for name in ARMS), "the exporter publishes both serial ports")
        for name in ARMS:
            for args in (("create",), ("add-match", f"bench-pc/{name}/NetworkSerialPort")):
                done = the_lab.client("-p", name, *args)
                assert done.returncode == 0, done.stderr
        assert the_lab.client("-p", "empty", "create").returncode == 0  # a place with no arm
        yield the_lab
    finally:
        _stop(procs)


def _acquired_by(lab: Lab, place: str) -> str:
    out = lab.client("-p", place, "show").stdout
    for line in out.splitlines():
        if line.strip().startswith("acquired:"):
            holder = line.split(":", 1)[1].strip()
            return "" if holder == "None" else holder
    return ""


def test_url_and_coordinator(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("LG_COORDINATOR", raising=False)
    assert parse_labgrid_url("labgrid://arm-a") == ("arm-a", "127.0.0.1:20408")
    monkeypatch.setenv("LG_COORDINATOR", "lab.example:5000")
    assert parse_labgrid_url("labgrid://arm-a") == ("arm-a", "lab.example:5000")
    assert parse_labgrid_url("labgrid://arm-a?coordinator=10.0.0.2") == ("arm-a", "10.0.0.2:20408")
    with pytest.raises(TransportError, match="unknown query parameter 'seed'"):
        parse_labgrid_url("labgrid://arm-a?seed=1")
    with pytest.raises(TransportError, match="not a labgrid://PLACE"):
        parse_labgrid_url("labgrid://")


async def _move(port: str) -> float:
    async with Arm.connect(port, connect_timeout_s=10.0, reply_timeout_s=REPLY_TIMEOUT_S) as arm:
        state = await arm.move_joints([0.05, 0.0, 0.0, 0.0], 99, timeout_s=MOVE_TIMEOUT_S)
        assert state is not None
        return float(state.q_rad[0])


def test_a_place_is_acquired_used_and_released(lab: Lab) -> None:
    port = lab.port("arm-a")

    async def main() -> None:
        async with Arm.connect(port, connect_timeout_s=10.0,
                               reply_timeout_s=REPLY_TIMEOUT_S) as arm:
            assert _acquired_by(lab, "arm-a") != ""  # held for the run
            state = await arm.move_joints([0.05, 0.0, 0.0, 0.0], 99, timeout_s=MOVE_TIMEOUT_S)
            assert state is not None and abs(state.q_rad[0] - 0.05) < 3e-4  # arrival tolerance

    asyncio.run(main())
    assert _acquired_by(lab, "arm-a") == ""  # released when the run ended


def test_two_places_at_once(lab: Lab) -> None:
    async def main() -> list[float]:
        return list(await asyncio.gather(*(_move(lab.port(name)) for name in ARMS)))

    assert all(abs(q - 0.05) < 3e-4 for q in asyncio.run(main()))  # arrival tolerance
    assert [_acquired_by(lab, name) for name in ARMS] == ["", ""]


def test_a_place_locked_by_someone_else_is_refused_with_the_owner(lab: Lab) -> None:
    assert lab.client("-p", "arm-b", "acquire", user="alice").returncode == 0
    try:
        with pytest.raises(PlaceLockedError, match="alice") as caught:
            asyncio.run(_move(lab.port("arm-b")))
        assert caught.value.owner.endswith("/alice")
    finally:
        assert lab.client("-p", "arm-b", "release", user="alice").returncode == 0


def test_the_coordinators_text_is_quoted_shortened(lab: Lab) -> None:
    """An owner's name comes from the coordinator (a peer): the error quotes its start and its
    length (:mod:`armbench.drivers.model.peer_text`), the exception keeps it whole."""
    user = "u" * 5000
    assert lab.client("-p", "arm-b", "acquire", user=user).returncode == 0
    try:
        with pytest.raises(PlaceLockedError, match="characters") as caught:
            asyncio.run(_move(lab.port("arm-b")))
        assert len(str(caught.value)) < 1000 and caught.value.owner.endswith("/" + user)
    finally:
        assert lab.client("-p", "arm-b", "release", user=user).returncode == 0


def test_an_unknown_place_and_a_place_without_an_arm(lab: Lab) -> None:
    with pytest.raises(PlaceUnknownError, match=r"no place 'arm-z'.*arm-a, arm-b"):
        asyncio.run(_move(lab.port("arm-z")))
    with pytest.raises(NoSerialResourceError, match="'empty' has no NetworkSerialPort"):
        asyncio.run(_move(lab.port("empty")))
    assert _acquired_by(lab, "empty") == ""  # nothing stays acquired after the error


def test_an_unreachable_coordinator() -> None:
    port = f"labgrid://arm-a?coordinator=127.0.0.1:{free_port()}"
    with pytest.raises(CoordinatorUnreachableError, match="did not answer"):
        asyncio.run(_move(port))


def test_a_coordinator_that_starts_late_is_asked_again(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A coordinator starting (or restarting) when the session begins: the client asks again
    until its deadline (here long enough for a coordinator started on a busy machine) and gets
    the coordinator's own answer, not "did not answer"."""
    from armbench.drivers.transports import labgrid as labgrid_transport

    monkeypatch.setattr(labgrid_transport, "COORDINATOR_TIMEOUT_S", 120.0)
    coordinator = f"127.0.0.1:{free_port()}"
    procs: list[subprocess.Popen[bytes]] = []

    def start() -> None:
        procs.append(subprocess.Popen([_tool("labgrid-coordinator"), "--listen", coordinator],
                                      cwd=tmp_path, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL))

    later = threading.Timer(1.0, start)
    later.start()
    try:
        with pytest.raises(PlaceUnknownError, match="no place 'arm-z'"):
            asyncio.run(_move(f"labgrid://arm-z?coordinator={coordinator}"))
    finally:
        later.cancel()
        later.join()
        _stop(procs)


def test_the_cli_moves_the_arm_of_a_place(lab: Lab, capsys: pytest.CaptureFixture[str]) -> None:
    """``armbench move`` and ``monitor`` on a place, in this process (the command's process is
    ``test_ctrl_c_releases_the_place``'s)."""
    status, _, err = cli(capsys, "move", "--port", lab.port("arm-a"), "--reply-timeout",
                         str(REPLY_TIMEOUT_S), "--timeout", str(MOVE_TIMEOUT_S), "0.02", "0", "0",
                         "0")
    assert status == 0, err
    assert _acquired_by(lab, "arm-a") == ""
    locked = lab.client("-p", "arm-a", "acquire", user="bob")
    assert locked.returncode == 0
    try:
        status, _, err = cli(capsys, "monitor", "--port", lab.port("arm-a"))
        assert status == 2
        assert "acquired by" in err and "bob" in err
        assert len(err.strip().splitlines()) == 1
    finally:
        lab.client("-p", "arm-a", "release", user="bob")


def test_ctrl_c_releases_the_place(lab: Lab) -> None:
    """Ctrl-C to a monitor streaming from a labgrid place: no traceback, the place released."""
    monitor = subprocess.Popen([sys.executable, "-m", "armbench", "monitor", "--json", "--port",
                                lab.port("arm-b"), "--reply-timeout", str(REPLY_TIMEOUT_S)],
                               cwd=ROOT, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    try:
        assert monitor.stdout is not None
        assert monitor.stdout.readline().startswith("{"), "the monitor streams states"
        assert _acquired_by(lab, "arm-b") != ""
        monitor.send_signal(signal.SIGINT)
        _, err = monitor.communicate(timeout=60)
        assert "Traceback" not in err, err
    finally:
        if monitor.poll() is None:
            monitor.kill()
            monitor.wait()
    assert _acquired_by(lab, "arm-b") == ""
