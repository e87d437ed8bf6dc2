"""The far end of a real link, restartable mid-test: ``armbench emulate`` on a pty or TCP in a
subprocess, and a real ser2net serving that pty as RFC 2217. Shared by the fault campaigns."""

from __future__ import annotations

import contextlib
import os
import select
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest
from netutil import free_port, listening

ROOT = Path(__file__).resolve().parents[1]
START_S = 120.0
"""Deadline of a far end's start: a bound on a hung start, not on a slow machine."""


class Emulator:
    """``python -m armbench emulate --pty --link PATH`` or ``--tcp 127.0.0.1:PORT`` in a subprocess,
    restartable on the same link or port."""

    def __init__(self, tmp: Path, kind: str, extra: Sequence[str] = ()) -> None:
        self.kind = kind
        self.extra = list(extra)
        self.link = tmp / "arm-pty"
        self.tcp_port = free_port()
        self.log = tmp / f"emulate-{kind}.log"
        self.proc: subprocess.Popen[str] | None = None

    @property
    def port(self) -> str:
        return str(self.link) if self.kind == "pty" else f"socket://127.0.0.1:{self.tcp_port}"

    def start(self) -> None:
        where = (["--pty", "--link", str(self.link)] if self.kind == "pty"
                 else ["--tcp", f"127.0.0.1:{self.tcp_port}"])
        with self.log.open("a") as err:
            self.proc = subprocess.Popen([sys.executable, "-m", "armbench", "emulate", *where,
                                          *self.extra],
                                         cwd=ROOT, stdout=subprocess.PIPE, stderr=err, text=True)
        assert self.proc.stdout is not None
        # starting Python and the emulator takes seconds of CPU: far more on a loaded machine
        ready, _, _ = select.select([self.proc.stdout], [], [], START_S)
        line = self.proc.stdout.readline() if ready else ""
        assert "serving the arm on " in line, f"emulate did not start: {line!r}"
        self.started = time.monotonic()  # ~ the emulator's time 0 (its faults' at_s)

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)


@contextlib.contextmanager
def emulator_maker(tmp: Path) -> Iterator[Callable[..., Emulator]]:
    """``make(kind, *extra)`` starts an emulator (``"pty"`` or ``"tcp"``); all are stopped at
    the end."""
    made: list[Emulator] = []

    def make(kind: str, *extra: str) -> Emulator:
        emu = Emulator(tmp, kind, extra)
        made.append(emu)
        emu.start()
        return emu

    try:
        yield make
    finally:
        for emu in made:
            emu.stop()


@contextlib.contextmanager
def pty_numbered(path: str, tries: int = 64) -> Iterator[tuple[int, int]]:
    """A new pty pair (master, slave) whose slave is ``path``, a ``/dev/pts/N`` just freed: the
    kernel gives the lowest free number, so the first pty opened here takes it unless another
    process was quicker, and those taken meanwhile are held until the end. Skips the test when
    all ``tries`` missed (another process holds the number)."""
    with contextlib.ExitStack() as held:
        for _ in range(tries):
            master, slave = os.openpty()
            held.callback(os.close, master)
            held.callback(os.close, slave)
            if os.ttyname(slave) == path:
                yield master, slave
                return
        pytest.skip(f"{path} was taken by another process before {tries} ptys were opened here")


@dataclass
class Ser2net:
    exe: str
    config: Path
    tcp_port: int
    proc: subprocess.Popen[bytes] | None = None

    @property
    def port(self) -> str:
        return f"rfc2217://127.0.0.1:{self.tcp_port}"

    def start(self) -> None:
        self.proc = subprocess.Popen([self.exe, "-n", "-u", "-P", str(self.config) + ".pid",
                                      "-c", str(self.config)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + START_S
        while not listening(self.tcp_port):
            assert self.proc.poll() is None, f"ser2net exited with {self.proc.returncode}"
            assert time.monotonic() < deadline, "ser2net does not listen"
            time.sleep(0.01)

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(5)


@contextlib.contextmanager
def ser2net_over(tmp: Path, device: str | Path) -> Iterator[Ser2net]:
    """ser2net serving ``device`` as ``rfc2217://`` (the link of an ``armbench emulate --pty
    --link``, a pty where nothing answers, a device that is not there); the test is skipped when
    ser2net is not installed."""
    exe = shutil.which("ser2net") or shutil.which("ser2net", path="/usr/sbin:/usr/local/sbin")
    if exe is None:
        pytest.skip("ser2net not installed (Debian package 'ser2net'): the RFC 2217 campaign "
                    "needs a real one")
    tcp_port = free_port()
    config = tmp / "ser2net.yaml"
    config.write_text(
        "connection: &armbench\n"
        f"  accepter: telnet(rfc2217),tcp,127.0.0.1,{tcp_port}\n"
        f"  connector: serialdev,{device},115200n81,local\n"
        "  options:\n"
        "    chardelay: false\n")
    server = Ser2net(exe, config, tcp_port)
    server.start()
    try:
        yield server
    finally:
        server.kill()
