"""``avr://`` — the firmware in the loop: four simulated ATmega328P (simavr) on a pty.

It lives with the emulators and is registered by name (the scheme ``avr``, see
:mod:`armbench.drivers.transports`), as ``fake://`` is: the driver never imports it.

``avr://?firmware=DIR&settings=robot.toml&eeprom=DIR&control=FIFO``: starts the harness of
:mod:`armbench.fakes.avr` (built on first use) in real time on a new pty, and talks to joint 1's
UART there as to a serial port. ``firmware`` names a folder of ``joint1..4.elf/.hex`` or a path
with ``{n}`` (default: the reference firmware of ``firmware/``); ``eeprom`` a folder keeping the
boards' EEPROM across runs (default: none, a new arm); ``control`` a FIFO taking the harness's
commands, so a bench can switch the power with ``--power-command "sh -c 'echo power off >
FIFO'" "sh -c 'echo power on > FIFO'"``. The harness is ``transport.harness`` for its side
channels: power cut and restore, the firmware's own timing figures.
"""

from __future__ import annotations

import asyncio
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from armbench.drivers.errors import TransportError
from armbench.drivers.settings import RobotSettings, SerialSettings, load_settings
from armbench.drivers.transports.serial_port import SerialTransport
from armbench.fakes.avr import FirmwareError, Harness

__all__ = ["AvrTransport", "parse_avr_url"]

_KNOWN = {"firmware", "settings", "eeprom", "control"}


def parse_avr_url(port: str) -> tuple[RobotSettings, str | None, Path | None, Path | None]:
    """Robot settings, firmware, EEPROM folder and control FIFO named by an ``avr://`` URL."""
    parts = urlsplit(port)
    if parts.scheme.lower() != "avr":
        raise TransportError(port, "not an avr:// port")
    query = parse_qs(parts.query, keep_blank_values=True)
    for key in query:
        if key not in _KNOWN:
            raise TransportError(port, f"unknown query parameter {key!r} "
                                       f"(known: {', '.join(sorted(_KNOWN))})")
    robot = load_settings(query["settings"][-1]) if "settings" in query else RobotSettings()
    firmware = query["firmware"][-1] if "firmware" in query else None
    eeprom = Path(query["eeprom"][-1]) if "eeprom" in query else None
    control = Path(query["control"][-1]) if "control" in query else None
    return robot, firmware, eeprom, control


class AvrTransport(SerialTransport):
    """Joint 1's UART of the simulated boards, through the harness's pty."""

    scheme = "avr"

    def __init__(self, port: str, serial: SerialSettings) -> None:
        super().__init__(port, serial)
        self.harness: Harness | None = None
        """The running harness (None before :meth:`open` and after :meth:`close`)."""

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
        if harness is not None:
            await harness.stop()

    async def close(self) -> None:
        await super().close()
        await self._stop_harness()
