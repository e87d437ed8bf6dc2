"""``avr://`` — the firmware in the loop: four simulated ATmega328P (simavr) on a pty.

It lives with the emulators and is registered by name (the scheme ``avr``, see
:mod:`armbench.drivers.transports`), as ``fake://`` is: the driver never imports it.

``avr://?firmware=DIR&settings=robot.toml&eeprom=DIR&control=FIFO``: starts the harness of
:mod:`armbench.fakes.avr` (built on first use) in real time on a new pty, and talks to joint 1's
UART there as to a serial port. ``firmware`` names a folder of ``joint1..4.elf/.hex`` or a path
with ``{n}`` (default: the reference firmware of ``firmware/``); ``eeprom`` a folder keeping the
boards' EEPROM across runs (default: none, a new arm); ``control`` a FIFO taking the harness's
commands, so a bench can switch the power with ``--power-command "sh -c 'echo power off >
FIFO'" "sh -c 'echo power on > FIFO'"``. A run on virtual time takes fresh boards per trial
from :meth:`AvrTransport.fresh` instead (:mod:`armbench.fakes.avr_vt`: the harness in lockstep
with the run's clock, as fast as simavr can). The harness is ``transport.harness`` for its side
channels: power cut and restore, the firmware's own timing figures. When it closes, the harness's
figures are kept in ``transport.last_stats`` and a lag behind real time is declared in the log (a
warning: the arm's clock fell behind the wall clock, as on a machine too busy to serve it).
"""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

from armbench.drivers.errors import TransportError
from armbench.drivers.settings import RobotSettings, SerialSettings, load_settings
from armbench.drivers.transports.base import Transport
from armbench.drivers.transports.serial_port import SerialTransport
from armbench.fakes.avr import FirmwareError, Harness, build, find_images

__all__ = ["LAG_WARN_MS", "AvrTransport", "parse_avr_url"]

log = logging.getLogger("armbench.firmware")

#: A harness that fell further behind real time than this (ms) is declared in a warning.
LAG_WARN_MS = 20.0

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
        self.last_stats: dict[str, Any] | None = None
        """The harness's figures when it was stopped (``docs/firmware.md``)."""

    @classmethod
    def fresh(cls, port: str, serial: SerialSettings, arm: Any) -> Transport:
        """A not-yet-opened transport to a new set of boards on the run's virtual-time loop
        (:mod:`armbench.fakes.avr_vt`): ``arm.robot`` (RobotSettings) played by the firmware
        the URL names; ``arm.faults`` must be empty (the harness models none); ``arm.seed`` is
        not used (the boards are deterministic)."""
        from armbench.fakes.avr_vt import fresh_transport

        try:
            return fresh_transport(port, serial, arm.robot, getattr(arm, "faults", ()))
        except FirmwareError as exc:
            raise TransportError(port, str(exc)) from exc

    def preflight(self) -> None:
        """The URL's query, the firmware images and the harness (built now if needed, as
        :meth:`open` would)."""
        _, firmware, _, _ = parse_avr_url(self.port)
        try:
            find_images(firmware)
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
        if harness is None:
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
