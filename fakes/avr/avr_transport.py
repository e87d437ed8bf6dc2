"""``avr://`` — the firmware in the loop: four simulated ATmega328P (simavr), on the run's virtual
time or on a pty in real time.

It lives with the emulators and is registered as the entry point of its scheme (``avr``, see
:mod:`armbench.drivers.transports`), as ``fake://`` is: the driver never imports it.

Opened on a :class:`~armbench.fakes.clock.vclock.VirtualTimeLoop` (a bench run, as ``fake://``), it
starts a new set of boards in lockstep with the loop (:mod:`armbench.fakes.avr.lockstep`): the run's
clock is the boards', as fast as simavr simulates them; ``transport.emulator`` gives ground
truth from the harness's joint model. On any other loop,
``avr://?firmware=DIR&settings=robot.toml&eeprom=DIR&control=FIFO`` starts the harness of
:mod:`armbench.fakes.avr.harness` (built on first use) in real time on a new pty, and talks to joint
1's UART there as to a serial port (``eeprom`` and ``control`` are for this real-time port only).
``firmware`` names a folder of ``joint1..4.elf/.hex`` or a path with ``{n}`` (default: the
reference firmware of ``firmware/``); ``eeprom`` a folder keeping the boards' EEPROM across runs
(default: none, a new arm); ``control`` a FIFO taking the harness's commands, so a bench can
switch the power with ``--power-command "sh -c 'echo power off > FIFO'" "sh -c 'echo power on >
FIFO'"``. The harness (the boards on virtual time) is ``transport.harness`` for its side
channels: power cut and restore, the firmware's own timing figures. When it closes, the
harness's figures are kept in ``transport.last_stats`` and a lag behind real time is declared in
the log (a warning: the arm's clock fell behind the wall clock, as on a machine too busy to
serve it).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qs

from armbench.drivers.model.errors import TransportError
from armbench.drivers.model.settings import RobotSettings, SerialSettings
from armbench.drivers.transports.base import Transport
from armbench.drivers.transports.capabilities import Capabilities
from armbench.drivers.transports.serial_port import SerialTransport
from armbench.drivers.transports.url_parts import split_port
from armbench.fakes.avr.harness import (
    AVR_FORM,
    LOCKSTEP_CAPABILITIES,
    FirmwareError,
    Harness,
    build,
    find_images,
    parse_avr_url,
)
from armbench.fakes.clock.vclock import VirtualTimeLoop

if TYPE_CHECKING:
    from armbench.fakes.avr.lockstep import AvrBoards, AvrVirtualTransport

__all__ = ["LAG_WARN_MS", "AvrTransport"]

log = logging.getLogger("armbench.firmware")

#: A harness that fell further behind real time than this (ms) is declared in a warning.
LAG_WARN_MS = 20.0

class AvrTransport(SerialTransport):
    """Joint 1's UART of the simulated boards: on a virtual-time loop the harness in lockstep
    with the loop (:class:`~armbench.fakes.avr.lockstep.AvrVirtualTransport`, fresh boards at each
    open), else through the harness's pty in real time."""

    scheme = "avr"

    @classmethod
    def capabilities(cls, port: str) -> Capabilities:
        """Lockstep boards on the run's virtual time, fresh per trial, in workers, with truth
        from the joint model and their own power switch; with ``eeprom=`` or ``control=``
        (things that outlive one set of boards) the harness's pty in real time."""
        query = parse_qs(split_port(port, AVR_FORM, address=False, query=True).query)
        if "eeprom" in query or "control" in query:
            return Capabilities(clock="real", power=True)
        return LOCKSTEP_CAPABILITIES

    def __init__(self, port: str, serial: SerialSettings, *,
                 robot: RobotSettings | None = None) -> None:
        super().__init__(port, serial)
        self._robot = robot
        self.harness: Harness | AvrBoards | None = None
        """The running harness, or on virtual time the boards (both switch the power and
        re-reference the arm); None before :meth:`open` and after :meth:`close`."""
        self._boards: AvrBoards | None = None
        self.last_stats: dict[str, Any] | None = None
        """The harness's figures when it was stopped (``docs/firmware.md``)."""
        self._lockstep: AvrVirtualTransport | None = None

    @property
    def emulator(self) -> AvrBoards | None:
        """On virtual time the boards, the side channel a runner reads as it reads
        ``fake://``'s emulator (:class:`~armbench.drivers.transports.base.Emulator`: ground
        truth); None in real time (the harness's pty carries only the UART)."""
        return self._boards

    @classmethod
    def fresh(cls, port: str, serial: SerialSettings, arm: Any) -> Transport:
        """A not-yet-opened transport to a new set of boards (one trial's arm, on the run's
        virtual-time loop): ``arm.robot`` (RobotSettings) played by the firmware the URL
        names; ``arm.faults`` must be empty (the harness models none); ``arm.seed`` is not
        used (the boards are deterministic)."""
        if getattr(arm, "faults", ()):
            raise TransportError(port, "avr:// injects no faults (the harness models none); "
                                       "use fake:// for a fault list")
        return cls(port, serial, robot=arm.robot)

    # on virtual time: the lockstep transport ----------------------------------------------------
    @property
    def is_open(self) -> bool:
        if self._lockstep is not None:
            return self._lockstep.is_open
        return super().is_open

    async def open(self) -> None:
        if not isinstance(asyncio.get_running_loop(), VirtualTimeLoop):
            await super().open()
            return
        from armbench.fakes.avr.lockstep import AvrVirtualTransport

        if self._lockstep is not None and self._lockstep.is_open:
            raise self._error("transport is already open")
        lockstep = AvrVirtualTransport(self.port, self.serial, robot=self._robot)
        await lockstep.open()
        self._lockstep = lockstep
        self._boards = self.harness = lockstep.emulator

    def set_receiver(self, receiver: Callable[[bytes], None] | None) -> None:
        """On virtual time, hand each chunk to ``receiver`` as it arrives (as ``fake://``);
        in real time nothing changes: :meth:`read` reads the pty."""
        if self._lockstep is None:
            return

        def counted(data: bytes) -> None:
            self.bytes_in += len(data)
            assert receiver is not None
            receiver(data)

        self._lockstep.set_receiver(None if receiver is None else counted)

    async def read(self) -> bytes:
        if self._lockstep is None:
            return await super().read()
        data = await self._lockstep.read()
        self.bytes_in += len(data)
        return data

    async def write(self, data: bytes) -> None:
        if self._lockstep is None:
            await super().write(data)
            return
        await self._lockstep.write(data)
        self.bytes_out += len(data)

    def preflight(self) -> None:
        """The URL's query, the firmware images and the harness (built now if needed, as
        :meth:`open` would)."""
        robot, firmware, _, _ = parse_avr_url(self.port)
        try:
            find_images(firmware, robot)
            build()
        except FirmwareError as exc:
            raise self._error(str(exc)) from exc

    async def _connect(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        robot, firmware, eeprom, control = parse_avr_url(self.port)
        try:
            self.harness = await Harness.start(robot, firmware, eeprom_dir=eeprom,
                                               control=control)
        except FirmwareError as exc:
            raise self._error(str(exc)) from exc
        device = self.port
        self.port = self.harness.pty
        try:
            return await super()._connect()
        except TransportError:
            await self._stop_harness()
            raise
        finally:
            self.port = device

    async def _stop_harness(self) -> None:
        harness, self.harness = self.harness, None
        if not isinstance(harness, Harness):
            return
        try:
            async with asyncio.timeout(2.0):
                self.last_stats = await harness.stats()
        except (FirmwareError, OSError, TimeoutError) as exc:
            log.info("%s: no figures from the harness: %s", self.port, exc)
        else:
            declare_lag(self.port, self.last_stats)
        await harness.stop()

    async def close(self) -> None:
        lockstep, self._lockstep = self._lockstep, None
        if lockstep is not None:
            await lockstep.close()  # and its boards, which it built
            boards = lockstep.emulator
            self.last_stats = None if boards is None else boards.last_stats
            self.harness = None
            return
        await super().close()
        await self._stop_harness()


def declare_lag(port: str, stats: dict[str, Any]) -> None:
    """Log how far the harness fell behind real time (its pacing catches up, docs/firmware.md):
    a warning beyond :data:`LAG_WARN_MS`, else one info line."""
    lag_ms = float(stats.get("lag_max_ms", 0.0))
    text = (f"{port}: harness ran {stats.get('sim_s', 0.0):.1f} simulated s in "
            f"{stats.get('wall_s', 0.0):.1f} wall s; worst lag behind real time {lag_ms:.1f} ms, "
            f"{stats.get('behind_s', 0.0):.2f} s spent catching up, "
            f"{stats.get('lag_drops', 0)} lags given up")
    log.log(logging.WARNING if lag_ms > LAG_WARN_MS or stats.get("lag_drops") else logging.INFO,
            text)
