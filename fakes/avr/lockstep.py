"""``avr://`` on virtual time: the firmware harness in lockstep with the run's event loop.

The harness (``firmware/harness/``, ``docs/firmware.md``) started with ``--lockstep`` has no
clock of its own: it runs the four simulated ATmega328P only as far as it is told and answers
with joint 1's UART bytes and the simulated cycle they left at. :class:`AvrBoards` joins it to a
:class:`~armbench.fakes.clock.vclock.VirtualTimeLoop` as a clock peer: whenever the loop is about to
jump to its next timer, the boards run up to that time, or stop at the end of a reply frame,
and the loop jumps only as far as the boards ran; the frame is handed to the host at that time.
So the boards' clock is the run's, and a run goes as fast as simavr can simulate the boards,
with the same command/reply timing as on real time.

:class:`AvrBoards` is the side-channel object of one set of boards (what ``transport.emulator``
is on ``fake://``): ground truth from the harness's joint model (:meth:`~AvrBoards.true_angles_rad`,
:attr:`~AvrBoards.truth` beside each reply), the power switch and re-referencing (``power``,
``re_reference``: :class:`~armbench.bench.runner.power.HarnessPower`) and the harness's figures
(:meth:`~AvrBoards.figures`).
:class:`AvrVirtualTransport` is the host's side of joint 1's UART, as
:class:`~armbench.fakes.links.fake_transport.FakeTransport` is to the emulator. Both need a
:class:`~armbench.fakes.clock.vclock.VirtualTimeLoop`: on a real loop ``avr://`` is the pty of
:mod:`armbench.fakes.avr.avr_transport`, paced to the wall clock.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import subprocess
import tempfile
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, Any

from armbench.drivers.model.kinematics import tcp_position
from armbench.drivers.model.protocol import Framer, Reply
from armbench.drivers.model.settings import RobotSettings, SerialSettings
from armbench.fakes.avr.harness import (
    HARNESS_NAME,
    LOCKSTEP_CAPABILITIES,
    FirmwareError,
    board_specs,
    build,
    find_images,
    parse_avr_url,
)
from armbench.fakes.clock.vclock import VirtualTimeLoop
from armbench.fakes.links.in_process import InProcessTransport
from armbench.fakes.twin.physics import TRUTH_HISTORY, TruthSample

__all__ = ["CYCLES_PER_S", "AvrBoards", "AvrVirtualTransport",
           "LockstepHarness", "fresh_boards"]

#: The boards' clock: ATmega328P at 16 MHz.
CYCLES_PER_S = 16_000_000
_NO_FAULTS = "avr:// injects no faults (the harness models none); use fake:// for a fault list"
#: How long the harness may take to quit before it is killed (s, wall).
_QUIT_TIMEOUT_S = 5.0


class LockstepHarness:
    """The harness process in ``--lockstep`` mode, driven synchronously over its stdin/stdout
    (``firmware/harness/lockstep.c``): the caller waits while it runs, so nothing happens on
    the boards between two calls."""

    def __init__(self, robot: RobotSettings, firmware: str | Path | None = None, *,
                 harness: Path | None = None, boot_ms: float = 100.0) -> None:
        images = find_images(firmware, robot)
        exe = harness if harness is not None else build() / HARNESS_NAME
        args = [str(exe), "--lockstep", "--boot-ms", str(boot_ms)]
        for spec in board_specs(robot, images):
            args += ["--board", spec]
        # kept for the process's life (its error messages), closed in close()
        self._stderr: IO[bytes] = tempfile.TemporaryFile()  # noqa: SIM115
        try:
            self._proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                          stderr=self._stderr)
        except OSError as exc:
            self._stderr.close()
            raise FirmwareError(f"cannot start the harness {exe}: {exc}") from exc
        assert self._proc.stdin is not None and self._proc.stdout is not None
        self._in: IO[bytes] = self._proc.stdin
        self._out: IO[bytes] = self._proc.stdout
        self.cycle = 0
        """The boards' clock: cycles since the harness started."""
        self.motor_steps: tuple[int, ...] = (0, 0, 0, 0)
        """The four motors' positions (microsteps) at :attr:`cycle`."""

    @property
    def pid(self) -> int:
        """The harness process's id."""
        return self._proc.pid

    def _line(self, prefix: bytes) -> bytes:
        """The next answer line starting with ``prefix`` (libsimavr's loader prints its own
        lines on the same stdout at start-up: skipped)."""
        while True:
            line = self._out.readline()
            if not line:
                raise FirmwareError(f"the harness exited (status {self._proc.poll()}): "
                                    f"{self.errors()}")
            if line.startswith(prefix):
                return line[len(prefix):].rstrip(b"\n")

    def errors(self) -> str:
        """What the harness wrote on stderr so far (its refusals and errors), last lines."""
        self._stderr.seek(0)
        lines = self._stderr.read().decode(errors="replace").strip().splitlines()
        return "; ".join(lines[-3:]) or "no message"

    def _send(self, line: str) -> None:
        try:
            self._in.write(line.encode() + b"\n")
        except (BrokenPipeError, ValueError) as exc:
            raise FirmwareError(f"the harness exited: {self.errors()}") from exc

    def run(self, until_cycle: int) -> bytes:
        """Run the boards until ``until_cycle`` or the end of a reply frame, whichever comes
        first; the UART bytes sent meanwhile (:attr:`cycle` and :attr:`motor_steps` follow)."""
        self._send(f"run {until_cycle}")
        try:
            self._in.flush()
        except BrokenPipeError as exc:
            raise FirmwareError(f"the harness exited: {self.errors()}") from exc
        fields = self._line(b"at ").split(b" ")
        self.cycle = int(fields[0])
        self.motor_steps = tuple(int(f) for f in fields[1:5])
        return b"" if fields[5] == b"-" else bytes.fromhex(fields[5].decode())

    def send(self, data: bytes) -> None:
        """Queue bytes on joint 1's UART at :attr:`cycle` (fed at 115 200 baud)."""
        for k in range(0, len(data), 128):
            self._send(f"send {data[k:k + 128].hex()}")

    def command(self, line: str) -> None:
        """One control command at :attr:`cycle` (``power off``, ``power on``, ``eeprom
        blank``, ``home``)."""
        self._send(line)

    def stats(self) -> dict[str, Any]:
        """The harness's figures (``docs/firmware.md``); ``wall_s`` is the process's age."""
        self._send("stats")
        self._in.flush()
        result: dict[str, Any] = json.loads(self._line(b"stats "))
        return result

    def close(self) -> None:
        """Quit the harness and wait for it (killed if it does not quit)."""
        if self._proc.poll() is None:
            with contextlib.suppress(OSError, ValueError, FirmwareError):
                self._send("quit")
                self._in.close()
            try:
                self._proc.wait(_QUIT_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._out.close()
        self._stderr.close()


class AvrBoards:
    """One set of four simulated boards on the running :class:`VirtualTimeLoop`, a clock peer of
    it (:meth:`run_until`): the firmware in the loop, powered at :meth:`start` and booting as the
    emulator does. ``firmware`` as ``avr://?firmware=``; ``harness`` another harness program."""

    def __init__(self, robot: RobotSettings | None = None, firmware: str | Path | None = None,
                 *, harness: Path | None = None, boot_ms: float = 100.0) -> None:
        self.robot = robot if robot is not None else RobotSettings()
        self._firmware = firmware
        self._harness_exe = harness
        self._boot_ms = boot_ms
        self._harness: LockstepHarness | None = None
        self._loop: VirtualTimeLoop | None = None
        self._t0 = 0.0
        self._sink: Callable[[bytes], None] | None = None
        self._pending: list[tuple[float, bytes]] = []
        self._framer = Framer("reply")
        self._steps_per_rad = [j.steps_per_rad for j in self.robot.joints]
        self._lower = [j.lower_rad for j in self.robot.joints]
        self._upper = [j.upper_rad for j in self.robot.joints]
        self.powered = False
        """Whether the boards have power."""
        self.truth: deque[TruthSample] = deque(maxlen=TRUTH_HISTORY)
        """Ground truth of each reply that reached the host, the newest last: the joint model's
        angles when the reply's last byte left (the harness has no gear play or deflection)."""
        self.last_stats: dict[str, Any] | None = None
        """The harness's figures when it was closed."""
        self.failure: FirmwareError | None = None
        """Why the harness stopped while running (it exited), else None."""
        self.on_lost: Callable[[FirmwareError], None] | None = None
        """Called (in a loop callback) when the harness stops while running."""

    # lifecycle ---------------------------------------------------------------------------------
    async def start(self) -> None:
        """Start the harness with the boards powered at the loop's now, and join the loop's
        clock."""
        if self._harness is not None:
            return
        loop = asyncio.get_running_loop()
        if not isinstance(loop, VirtualTimeLoop):
            raise FirmwareError("avr:// in lockstep needs the virtual-time loop "
                                "(armbench.fakes.clock.vclock); on a real loop use the pty")
        self._harness = LockstepHarness(self.robot, self._firmware, harness=self._harness_exe,
                                        boot_ms=self._boot_ms)
        self._loop = loop
        self._t0 = loop.time()
        self.powered = True
        loop.peers.append(self)
        await asyncio.sleep(0)

    async def close(self) -> None:
        """Leave the loop's clock, keep the figures and stop the harness (idempotent)."""
        harness, self._harness = self._harness, None
        if harness is None:
            return
        if self._loop is not None and self in self._loop.peers:
            self._loop.peers.remove(self)
        try:
            self.last_stats = harness.stats()
        except (FirmwareError, OSError, ValueError):
            self.last_stats = None
        harness.close()
        self.powered = False
        await asyncio.sleep(0)

    @property
    def harness(self) -> LockstepHarness:
        """The running harness; :class:`FirmwareError` before :meth:`start` or after
        :meth:`close`."""
        if self._harness is None:
            raise FirmwareError("the boards are not running (not started, or closed)")
        if self.failure is not None:
            raise self.failure
        return self._harness

    # the loop's clock ----------------------------------------------------------------------------
    def _time(self, cycle: int) -> float:
        return self._t0 + cycle / CYCLES_PER_S

    def run_until(self, t_s: float) -> float:
        """Clock peer: run the boards to loop time ``t_s`` or the end of the next reply frame,
        which is then handed to the host at its time; the time reached."""
        harness = self._harness
        if harness is None:
            return t_s
        target = math.ceil((t_s - self._t0) * CYCLES_PER_S - 1e-6)
        if target > harness.cycle:
            try:
                data = harness.run(target)
            except FirmwareError as exc:  # the harness died: the host sees a lost port
                self._fail(exc)
                return t_s
            if data:
                self._arrive(data)
        if harness.cycle >= target:
            # there (up to a quantum past): exactly the time asked, so the timer that asked for
            # it is due, not a rounding error early
            return t_s
        return self._time(harness.cycle)

    def _fail(self, exc: FirmwareError) -> None:
        """The harness is gone: leave the loop's clock (which goes on without the boards) and
        tell the host (:attr:`on_lost`) in the next loop iteration."""
        assert self._loop is not None
        self.failure = exc
        if self in self._loop.peers:
            self._loop.peers.remove(self)
        if self.on_lost is not None:
            self._loop.call_soon(self.on_lost, exc)

    def _arrive(self, data: bytes) -> None:
        """Bytes from joint 1's UART at the boards' now: to the host once the loop's clock is
        there (in this loop iteration, before timers due then)."""
        assert self._loop is not None and self._harness is not None
        t_s = self._time(self._harness.cycle)
        if data.endswith(b"#"):
            self._record_truth(t_s, data)
        self._pending.append((t_s, data))
        if len(self._pending) == 1:
            self._loop.call_soon(self._deliver)

    def _deliver(self) -> None:
        pending, self._pending = self._pending, []
        sink = self._sink
        if sink is not None:
            for _, data in pending:
                sink(data)

    def _catch_up(self) -> None:
        """Bring the boards to the loop's now before the host acts on them (a no-op while the
        boards are the loop's clock; the loop may have moved without them before they
        joined). Boards whose harness died stay where it stopped: :attr:`harness` raises why."""
        assert self._loop is not None
        now = self._loop.time()
        while (self._harness is not None and self.failure is None
               and self._time(self._harness.cycle) < now - 1e-9):
            self.run_until(now)

    def _record_truth(self, t_s: float, frame: bytes) -> None:
        replies = [r for r in self._framer.feed(frame) if isinstance(r, Reply)]
        link = self._angles()
        firmware = replies[-1].angles_rad(self._lower, self._upper) if replies else link
        self.truth.append(TruthSample(t_s, link, firmware, link, None))

    def _angles(self) -> tuple[float, float, float, float]:
        steps = self.harness.motor_steps
        q = [s / k for s, k in zip(steps, self._steps_per_rad, strict=True)]
        return q[0], q[1], q[2], q[3]

    # host side ---------------------------------------------------------------------------------
    def attach_host(self, sink: Callable[[bytes], None]) -> None:
        """Connect a host: ``sink`` receives joint 1's UART bytes at the time they left."""
        self._sink = sink

    def detach_host(self) -> None:
        """Disconnect the host; the master's replies go nowhere."""
        self._sink = None

    def host_write(self, data: bytes) -> None:
        """The host sends bytes now; they go on the line at 115 200 baud."""
        self._catch_up()
        self.harness.send(data)

    # side channels -----------------------------------------------------------------------------
    def true_angles_rad(self) -> tuple[float, ...]:
        """The joint model's angles now (rad, protocol convention): motor microsteps over
        steps per radian, as a tracker would see an arm without play or deflection."""
        self._catch_up()
        return self._angles()

    def true_position_m(self) -> tuple[float, float, float]:
        """The TCP position now (m, base frame) by forward kinematics of the true angles."""
        p = tcp_position(self.true_angles_rad(), self.robot)
        return float(p[0]), float(p[1]), float(p[2])

    async def power(self, on: bool) -> None:
        """Cut or restore the four boards' power at the loop's now (EEPROM and motor positions
        survive; the boards boot 0.1 s after power-up)."""
        self._catch_up()
        self.harness.command("power on" if on else "power off")
        self.powered = on
        await asyncio.sleep(0)

    async def re_reference(self) -> None:
        """While the power is off: every joint back to its zero position and every EEPROM
        blanked, as a lab re-homes the arm by hand (``Harness.re_reference``)."""
        self._catch_up()
        harness = self.harness
        harness.command("eeprom blank")
        harness.command("home")
        harness.run(harness.cycle)  # runs nothing: the joints' new positions
        await asyncio.sleep(0)

    def figures(self) -> dict[str, Any]:
        """The harness's figures now (``docs/firmware.md``). Not named ``stats``: that is the
        emulator's counters (``ArmStats``), which suites read where an emulator has them."""
        return self.harness.stats()


class AvrVirtualTransport(InProcessTransport[AvrBoards]):
    """Joint 1's UART of a set of :class:`AvrBoards` on the running virtual-time loop: bytes
    written go on the line at the loop's now, replies arrive at the loop time their last byte
    left. ``boards`` given: those (the caller closes them); else new ones from the ``avr://``
    URL (playing ``robot`` when given, else the URL's settings), closed with the transport.
    ``transport.emulator`` and ``transport.harness`` are the boards (ground truth, power);
    reads, the receiver and close are
    :class:`~armbench.fakes.links.in_process.InProcessTransport`'s,
    and a harness that dies is a lost port."""

    scheme = "avr"
    declared = LOCKSTEP_CAPABILITIES
    peer_errors = (FirmwareError,)

    def __init__(self, port: str, serial: SerialSettings, boards: AvrBoards | None = None, *,
                 robot: RobotSettings | None = None) -> None:
        super().__init__(port, serial, boards)
        self._robot = robot

    @property
    def emulator(self) -> AvrBoards | None:
        """The boards (:class:`~armbench.drivers.transports.base.Emulator`: ground truth from the
        harness's joint model): the ones given, else those :meth:`open` made (None before)."""
        return self._peer

    @property
    def harness(self) -> AvrBoards | None:
        """The boards, for :func:`armbench.bench.runner.power.port_power` (``HarnessPower``)."""
        return self._peer

    async def open(self) -> None:
        if self._open:
            return
        boards = self._peer
        if boards is None:
            robot, firmware, eeprom, control = parse_avr_url(self.port)
            if eeprom is not None or control is not None:
                raise self._error("eeprom= and control= need the real-time pty "
                                  "(a run on virtual time starts fresh boards per trial)")
            boards = self._peer = AvrBoards(self._robot if self._robot is not None else robot,
                                            firmware)
        try:
            await boards.start()
        except FirmwareError as exc:
            raise self._error(str(exc)) from exc
        boards.on_lost = self._peer_lost
        self._attach(boards)


def fresh_boards(robot: RobotSettings, faults: Sequence[object] = (),
                 firmware: str | Path | None = None) -> AvrBoards:
    """A new set of boards playing ``robot`` (for a trial); the firmware harness models no
    faults, so a fault list is refused."""
    if faults:
        raise FirmwareError(_NO_FAULTS)
    return AvrBoards(robot, firmware)
