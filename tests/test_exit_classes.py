"""Exit statuses by class, per transport (issue 37 point 4; issue 38 items 8 and 12), the table of
``docs/ci.md``: a port that cannot be opened, is no serial device or usable endpoint, or answers
no valid frame before the first trial is bad input (exit 2, one line naming the port, no run
folder); a link lost once the run has begun leaves it incomplete (exit 4, the record kept), and
resuming it while the arm is still gone is bad input again, the record untouched.

Real parts throughout: ptys, sockets, ``armbench emulate`` processes, a real ser2net, a real
labgrid coordinator and exporter (``test_labgrid.py``'s lab), simavr; a case whose part is not
installed is skipped saying which. Waits come from the link: a port where nothing will ever
answer is given up after ``connect_timeout_s = 0.5``; a live arm gets 30 s for its first reply
(a starved emulator process) and its loss is given up 3 s after the last reply.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from conftest import cli, one_line_error
from far_end import ROOT, Emulator, emulator_maker, ser2net_over
from netutil import free_port
from test_firmware import HAVE_TOOLCHAIN

from armbench.record import load_record

try:
    from test_labgrid import Lab, lab  # noqa: F401  (the real lab fixture: coordinator + exporter)
except (ImportError, pytest.skip.Exception):
    Lab = None  # type: ignore[assignment, misc]

CONFIG = """\
spec_version = "armbench-limits/1"

[bench]
{bench}

[suites.accuracy]
laps = {laps}
styles = ["coordinated"]
side_m = 0.01
settle_s = 0.0

[limits."accuracy.coordinated.lap_time_s"]
high = 60.0
unit = "s"
"""
"""Laps of a 1 cm square (about a second each in real time), the lap time judged (a run that
measures passes), with the ``[bench]`` times of the case."""

SILENT = CONFIG.format(bench="connect_timeout_s = 0.5", laps=1)
"""For ports where nothing will ever answer: the probe gives up after half a second."""


def _live(laps: int) -> str:
    """For a live arm: the first reply, the replies and the moves with room for an emulator
    process starved of CPU; a lost link given up 3 s after the last reply."""
    return CONFIG.format(bench="connect_timeout_s = 30.0\nreply_timeout_s = 5.0\n"
                               "move_timeout_scale = 10.0\noutage_timeout_s = 3.0", laps=laps)


CUT = '[[faults]]\nkind = "power_cut"\nat_s = 0.5\n'
"""The simulated arm's power cut half a second into the trial: it falls silent."""

MID_RUN_LAPS = 10
"""Trials of a run whose link is lost after the first: the suite stops at the first trial in
error, so the laps after it cost nothing, and the loss still lands mid-run if this process is
starved of CPU for seconds after the first trial's line."""

RUN_DEADLINE_S = 300.0
"""Bound on a whole ``armbench run`` process here: a hung run, not a slow machine."""


class Rig:
    """The far ends of one case, started on demand and stopped when the test ends; ``lose``
    is what takes the link away mid-run (kills the emulator or ser2net)."""

    def __init__(self, tmp: Path, stack: contextlib.ExitStack,
                 request: pytest.FixtureRequest) -> None:
        self.tmp = tmp
        self.stack = stack
        self.request = request
        self.lose: Callable[[], None] | None = None
        self._make: Callable[..., Emulator] | None = None

    def emulator(self, kind: str) -> Emulator:
        """``armbench emulate --pty --link`` or ``--tcp`` in a process; losing it kills it (and
        the pty's link goes with it, as an unplugged adapter's device node does)."""
        if self._make is None:
            self._make = self.stack.enter_context(emulator_maker(self.tmp))
        emu = self._make(kind)

        def lose() -> None:
            emu.stop(signal.SIGKILL)
            emu.link.unlink(missing_ok=True)

        self.lose = lose
        return emu

    def silent_pty(self) -> str:
        """A pty pair whose far end never writes: a terminal with no arm on it."""
        master, slave = os.openpty()
        self.stack.callback(os.close, master)
        self.stack.callback(os.close, slave)
        return os.ttyname(slave)

    def silent_listener(self) -> str:
        """A TCP listener that takes connections (the kernel accepts them) and says nothing."""
        server = self.stack.enter_context(socket.socket())
        server.bind(("127.0.0.1", 0))
        server.listen(4)
        return f"socket://127.0.0.1:{server.getsockname()[1]}"

    def ser2net(self, device: str | Path) -> str:
        """A real ser2net serving ``device`` as RFC 2217; losing it kills ser2net."""
        server = self.stack.enter_context(ser2net_over(self.tmp, device))
        self.lose = server.kill
        return server.port

    def lab(self) -> Lab:
        """The real labgrid lab of ``test_labgrid.py``: places arm-a, arm-b (each an emulator
        behind the exporter's ser2net) and empty (no serial port)."""
        if Lab is None:
            pytest.skip("labgrid or ser2net not installed (pip install 'armbench[labgrid]'; "
                        "Debian package 'ser2net')")
        found: Lab = self.request.getfixturevalue("lab")
        return found

    def fifo(self) -> str:
        path = self.tmp / "a-fifo"
        os.mkfifo(path)
        return str(path)

    def regular_file(self) -> str:
        path = self.tmp / "ttyUSB0.txt"
        path.write_text("not a device\n")
        return str(path)

    def fault_file(self) -> str:
        path = self.tmp / "cut.toml"
        path.write_text(CUT)
        return str(path)


def needs_simavr() -> None:
    if not HAVE_TOOLCHAIN:
        pytest.skip("avr-gcc/simavr absent (apt-get install gcc-avr avr-libc simavr "
                    "libsimavr-dev)")


def avr(port: str) -> Callable[[Rig], str]:
    def start(rig: Rig) -> str:
        needs_simavr()
        return port.format(tmp=rig.tmp)

    return start


@dataclass(frozen=True)
class Case:
    """One row of the table: the transport, what stands at the port, the exit status and (for
    2) what the one line names. A case of status 4 loses its link after the first trial."""

    transport: str
    what: str
    port: Callable[[Rig], str]
    status: int
    names: tuple[str, ...] = ()
    config: str = SILENT

    @property
    def id(self) -> str:
        return f"{self.transport}: {self.what}"


CASES = [
    Case("serial", "a device that is not there", lambda rig: str(rig.tmp / "ttyNOPE0"), 2,
         ("ttyNOPE0", "no such serial device")),
    Case("serial", "/dev/tty and 10 000 characters more", lambda rig: "/dev/tty" + "x" * 10_000,
         2, ("no such serial device", "10008 characters")),
    Case("serial", "/dev/tty", lambda rig: "/dev/tty", 2, ("controlling terminal",)),
    Case("serial", "/dev/null", lambda rig: "/dev/null", 2, ("/dev/null", "not a terminal")),
    Case("serial", "/dev/zero", lambda rig: "/dev/zero", 2, ("/dev/zero", "not a terminal")),
    Case("serial", "a FIFO", Rig.fifo, 2, ("a-fifo", "is a FIFO, not a serial device")),
    Case("serial", "a regular file", Rig.regular_file, 2, ("is a regular file",)),
    Case("serial", "a pty where nothing answers", Rig.silent_pty, 2,
         ("/dev/pts/", "no valid reply frame came within 0.5 s", "no run folder")),
    Case("serial", "armbench emulate --pty, lost mid-run", lambda rig: rig.emulator("pty").port,
         4, config=_live(MID_RUN_LAPS)),
    Case("socket", "a port nobody listens on",
         lambda rig: f"socket://127.0.0.1:{free_port()}", 2, ("cannot connect", "no run folder")),
    Case("socket", "a listener that says nothing", Rig.silent_listener, 2,
         ("no valid reply frame came within 0.5 s",)),
    Case("socket", "a path of 10 kB", lambda rig: "socket://127.0.0.1:1/" + "p" * 10_000, 2,
         ("the path '/ppp", "is not understood")),
    Case("socket", "a query", lambda rig: "socket://127.0.0.1:1?baud=9600", 2,
         ("the query 'baud=9600' is not understood",)),
    Case("socket", "armbench emulate --tcp, lost mid-run", lambda rig: rig.emulator("tcp").port,
         4, config=_live(MID_RUN_LAPS)),
    Case("rfc2217", "a port nobody listens on",
         lambda rig: f"rfc2217://127.0.0.1:{free_port()}", 2, ("cannot connect",)),
    Case("rfc2217", "ser2net on a pty where nothing answers",
         lambda rig: rig.ser2net(rig.silent_pty()), 2, ("no valid reply frame",)),
    Case("rfc2217", "ser2net on a device that is not there",
         lambda rig: rig.ser2net(rig.tmp / "ttyNOPE0"), 2, ("no run folder",)),
    Case("rfc2217", "ser2net on armbench emulate --pty, lost mid-run",
         lambda rig: rig.ser2net(rig.emulator("pty").link), 4, config=_live(MID_RUN_LAPS)),
    Case("labgrid", "a place that does not exist", lambda rig: rig.lab().port("arm-z"), 2,
         ("no place 'arm-z'", "no run folder")),
    Case("labgrid", "a place without a serial port", lambda rig: rig.lab().port("empty"), 2,
         ("NetworkSerialPort",)),
    Case("labgrid", "a path after the place", lambda rig: "labgrid://arm-a/x", 2,
         ("the path '/x' after the place",)),
    Case("labgrid", "a place with an arm", lambda rig: rig.lab().port("arm-a"), 0,
         config=_live(1)),
    Case("avr", "firmware that is not there", lambda rig: f"avr://?firmware={rig.tmp}/none", 2,
         ("firmware", "not a folder")),
    Case("avr", "an address", lambda rig: "avr://x", 2, ("the address 'x' is not understood",)),
    Case("avr", "simavr on virtual time", avr("avr://"), 0, config=_live(1)),
    Case("avr", "simavr in real time (EEPROM kept)", avr("avr://?eeprom={tmp}"), 0,
         config=_live(1)),
    Case("fake", "an address", lambda rig: "fake://x", 2, ("the address 'x' is not understood",)),
    Case("fake", "the emulator", lambda rig: "fake://", 0),
    Case("fake", "a power cut in the trial", lambda rig: f"fake://?faults={rig.fault_file()}",
         4),
]


@pytest.fixture
def rig(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[Rig]:
    with contextlib.ExitStack() as stack:
        yield Rig(tmp_path, stack, request)


def _args(config: Path, out: Path, port: str) -> list[str]:
    return ["run", "accuracy", "--config", str(config), "--out", str(out), "--port", port,
            "--workers", "1"]


def _lose_after_first_trial(rig: Rig, args: list[str]) -> tuple[int, str]:
    """``armbench run`` in a process; once its first trial is done (its progress line), the
    link is taken away. The exit status and the run's output."""
    assert rig.lose is not None
    proc = subprocess.Popen([sys.executable, "-m", "armbench", "-v", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    assert proc.stdout is not None
    lines: list[str] = []  # a line per trial (-v)
    deadline = time.monotonic() + RUN_DEADLINE_S
    try:
        while not any(f"trial 1/{MID_RUN_LAPS} done" in line for line in lines):
            assert time.monotonic() < deadline, "".join(lines)
            ready, _, _ = select.select([proc.stdout], [], [], 1.0)
            if ready:
                line = proc.stdout.readline()
                assert line, "".join(lines)  # the run ended before its first trial was done
                lines.append(line)
        rig.lose()
        rest, _ = proc.communicate(timeout=RUN_DEADLINE_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
    return proc.returncode, "".join(lines) + rest


def _check_incomplete_and_kept(out: Path, port: str, capsys: pytest.CaptureFixture[str],
                               output: str) -> None:
    """The record of a run whose link was lost: the first trial measured and kept, the suite
    ended in error; ``--resume`` with the arm still gone is bad input and changes nothing."""
    record = load_record(out / "results.json")
    suite = record.suites["accuracy"]
    assert suite.trials[0].status == "done" and suite.trials[0].measurements, output
    assert suite.status == "error" and any(t.status == "error" for t in suite.trials), output
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    status, _, err = cli(capsys, "run", "--resume", str(out), "--port", port)
    one_line_error(status, err, port)
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_exit_status_by_class(case: Case, rig: Rig, tmp_path: Path,
                              capsys: pytest.CaptureFixture[str]) -> None:
    port = case.port(rig)
    config = tmp_path / "bench.toml"
    config.write_text(case.config)
    out = tmp_path / "run"
    args = _args(config, out, port)
    if case.status == 4 and rig.lose is not None:
        status, output = _lose_after_first_trial(rig, args)
    else:
        status, output, err = cli(capsys, *args)
        output += err
    if case.status == 2:
        one_line_error(status, output, *case.names)
        assert not out.exists(), "bad input made a run folder"
        return
    assert status == case.status, output
    assert (out / "results.json").is_file() and (out / "report.html").is_file(), output
    if case.status == 4 and rig.lose is not None:
        _check_incomplete_and_kept(out, port, capsys, output)


BAD_PORTS = [
    pytest.param(lambda rig: "/dev/null", "not a terminal", id="/dev/null"),
    pytest.param(Rig.fifo, "is a FIFO", id="a FIFO"),
    pytest.param(lambda rig: "/dev/tty" + "x" * 10_000, "10008 characters", id="a long name"),
    pytest.param(lambda rig: "socket://127.0.0.1:1/p?q=1", "the path '/p'", id="a socket path"),
    pytest.param(lambda rig: f"socket://127.0.0.1:{free_port()}", "cannot connect",
                 id="a refused port"),
]


@pytest.mark.parametrize(("port", "names"), BAD_PORTS)
@pytest.mark.parametrize("command", [("monitor", "--duration", "1"), ("move", "0", "0", "0", "0"),
                                     ("perf", "--only", "driver"), ("calibrate", "--out", "cal")],
                         ids=lambda c: c[0])
def test_every_command_refuses_a_bad_port_before_it_works(
        command: tuple[str, ...], port: Callable[[Rig], str], names: str, rig: Rig,
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The same port, the same class everywhere: one line, exit 2, nothing measured or written
    (``perf`` checks ``--port`` before minutes of figures, ``calibrate`` before ``--out``)."""
    monkeypatch.chdir(tmp_path)
    status, out, err = cli(capsys, *command, "--port", port(rig))
    one_line_error(status, err, names)
    assert out == "" and not (tmp_path / "cal").exists()
