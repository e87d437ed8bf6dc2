"""``armbench i2c scan``: probe the joint boards on the I²C bus and read their WHO_AM_I register.

On a Linux host wired to the arm's bus (``--bus N``, ``/dev/i2c-N`` through smbus2) or on the
emulator's bus (``--port fake://``, the default, in-process on virtual time). Every address that
acknowledges is listed; the addresses of the robot settings' joints 2–4 are then read at register
0x04 (WHO_AM_I, ``0xA0 | joint number``; see ``fakes/firmware/i2c.py`` for the register layout).
Joint 1 is the bus master and has no address.

Exit status: 0 when every slave joint answers with its WHO_AM_I, 1 when one is missing or answers
wrongly, 2 for an unusable bus or port.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from armbench.cli.commands.monitor import (
    close_emulator,
    command_inputs,
    fresh_transport,
    run_on_port,
)
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings, load_settings
from armbench.drivers.transports.base import emulated
from armbench.drivers.transports.capabilities import ArmInputs
from armbench.drivers.transports.target import Target
from armbench.fakes.firmware.i2c_messages import I2CMessage

__all__ = ["REG_WHO_AM_I", "ScanResult", "register", "scan_bus"]

#: The WHO_AM_I register of a joint board.
REG_WHO_AM_I = 0x04
#: The 7-bit addresses probed (0x08..0x77, as ``i2cdetect`` does).
ADDRESSES = range(0x08, 0x78)


class I2CBusLike(Protocol):
    """What the scan needs of a bus: smbus2's combined transaction."""

    def i2c_rdwr(self, *msgs: Any) -> None: ...


class MessageType(Protocol):
    """The bus's message class: smbus2's ``i2c_msg`` on a real bus, or the emulator's."""

    def read(self, address: int, length: int) -> Any: ...

    def write(self, address: int, data: list[int]) -> Any: ...


@dataclass(frozen=True, slots=True)
class ScanResult:
    """The addresses that answered and the WHO_AM_I of each (None if the read failed)."""

    found: tuple[int, ...]
    who_am_i: dict[int, int | None]

    def check(self, settings: RobotSettings) -> list[tuple[str, int, str, bool]]:
        """(joint name, address, verdict, ok) for each slave joint of ``settings``."""
        out = []
        for number, joint in enumerate(settings.joints, 1):
            addr = joint.i2c_address
            if addr is None:
                continue
            if addr not in self.found:
                out.append((joint.name, addr, "missing", False))
                continue
            who = self.who_am_i.get(addr)
            want = 0xA0 | number
            if who == want:
                out.append((joint.name, addr, f"WHO_AM_I 0x{who:02x} (joint {number})", True))
            elif who is None:
                out.append((joint.name, addr, "WHO_AM_I unreadable", False))
            else:
                out.append((joint.name, addr, f"WHO_AM_I 0x{who:02x}, expected 0x{want:02x}",
                            False))
        return out


def read_who_am_i(bus: I2CBusLike, address: int,
                  messages: MessageType = I2CMessage) -> int | None:
    """Register 0x04 of ``address`` (write the pointer, read one byte), None on a bus error."""
    write = messages.write(address, [REG_WHO_AM_I])
    read = messages.read(address, 1)
    try:
        bus.i2c_rdwr(write, read)
    except OSError:
        return None
    return int(next(iter(read)))


def scan_bus(bus: I2CBusLike, probe: Callable[[int], bool],
             messages: MessageType = I2CMessage) -> ScanResult:
    """Probe every address with ``probe`` and read WHO_AM_I from those that answer, with
    ``messages`` of the bus's own class."""
    found = tuple(a for a in ADDRESSES if probe(a))
    return ScanResult(found, {a: read_who_am_i(bus, a, messages) for a in found})


def register(sub: Any) -> None:
    """Add the ``i2c`` subcommand (``i2c scan``)."""
    p: argparse.ArgumentParser = sub.add_parser(
        "i2c",
        description="Tools for the I²C bus between the joint boards.")
    isub = p.add_subparsers(dest="i2c_command", required=True, metavar="ACTION")
    s: argparse.ArgumentParser = isub.add_parser(
        "scan", help="list the addresses that answer and check each joint's WHO_AM_I",
        description="Probe addresses 0x08..0x77 and read WHO_AM_I (register 0x04) of each joint "
                    "board: on a Linux I²C bus (--bus N) or on the emulator's bus (--port "
                    "fake://, the default).",
        epilog="Exit status: 0 all joints answer correctly, 1 some do not, 2 unusable bus.")
    s.add_argument("--bus", type=int, default=None, metavar="N",
                   help="Linux I²C bus number (/dev/i2c-N, through smbus2)")
    s.add_argument("--port", default=None,
                   help="fake:// (with its query) to scan the emulator's bus (default when no "
                        "--bus is given)")
    s.add_argument("--settings", default=None, metavar="FILE",
                   help="robot settings TOML (joint addresses)")
    s.add_argument("--json", action="store_true", help="print one JSON object")
    s.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    port = args.port or "fake://"
    target, inputs = (command_inputs(port, args.settings) if args.bus is None
                      else (None, None))
    settings = inputs.robot if inputs is not None else load_settings(args.settings)
    if args.bus is not None and args.port is not None:
        raise ArmbenchError("i2c scan: give --bus or --port, not both")
    if args.bus is not None:
        result = _scan_linux(args.bus)
        where = f"/dev/i2c-{args.bus}"
    else:
        assert target is not None and inputs is not None
        if not target.capabilities.i2c_bus:
            raise ArmbenchError(f"i2c scan: --port {port}: only an emulated bus (fake://) is "
                                "reachable through a port; a real arm's bus needs --bus N on a "
                                "host wired to it")
        result = run_on_port(port, _scan_fake(target, inputs))
        where = f"{port} (emulator)"
    checks = result.check(settings)
    ok = all(c[3] for c in checks)
    if args.json:
        print(json.dumps({
            "bus": where, "found": [f"0x{a:02x}" for a in result.found],
            "who_am_i": {f"0x{a:02x}": v for a, v in result.who_am_i.items()},
            "joints": [{"joint": n, "address": f"0x{a:02x}", "verdict": v, "ok": k}
                       for n, a, v, k in checks],
            "ok": ok}))
        return 0 if ok else 1
    print(f"I²C scan of {where}: {len(result.found)} address(es) answer")
    print(_grid(result.found))
    for name, addr, verdict, good in checks:
        print(f"  {name}  0x{addr:02x}  {verdict}  {'ok' if good else 'FAIL'}")
    extra = [a for a in result.found if a not in {j.i2c_address for j in settings.joints}]
    for a in extra:
        who = result.who_am_i.get(a)
        text = f"0x{who:02x}" if who is not None else "unreadable"
        print(f"  ?    0x{a:02x}  not a joint of the settings (WHO_AM_I {text})")
    return 0 if ok else 1


def _grid(found: tuple[int, ...]) -> str:
    """An ``i2cdetect``-style table."""
    rows = ["     " + " ".join(f"{c:2x}" for c in range(16))]
    for base in range(0, 0x80, 0x10):
        cells = []
        for a in range(base, base + 16):
            cells.append("  " if a not in ADDRESSES else f"{a:02x}" if a in found else "--")
        rows.append(f"{base:02x}:  " + " ".join(cells))
    return "\n".join(rows)


def _scan_linux(number: int) -> ScanResult:
    device = f"/dev/i2c-{number}"
    if not os.path.exists(device):
        raise ArmbenchError(f"i2c scan: {device} does not exist (no such bus, or the i2c-dev "
                            "module is not loaded: 'modprobe i2c-dev'; 'i2cdetect -l' lists the "
                            "buses)")
    from smbus2 import SMBus, i2c_msg  # fcntl inside: Linux only, and only here

    try:
        bus = SMBus(number)
    except OSError as exc:
        raise ArmbenchError(f"i2c scan: cannot open {device}: {exc.strerror or exc}") from exc
    try:
        def probe(address: int) -> bool:
            try:
                bus.write_quick(address)
            except OSError:
                return False
            return True

        return scan_bus(bus, probe, i2c_msg)
    finally:
        bus.close()


async def _scan_fake(target: Target, inputs: ArmInputs) -> ScanResult:
    port = target.port
    fresh = fresh_transport(target, inputs)
    transport = fresh if fresh is not None else target.connect(inputs.robot.serial)
    await transport.open()
    try:
        bus = getattr(emulated(transport), "bus", None)
        if bus is None:
            raise ArmbenchError(f"i2c scan: {port} has no emulated bus")
        async with asyncio.timeout(5.0):  # the arm is up (booted) once it replies
            await transport.read()
        found = set(bus.scan())
        return scan_bus(bus, lambda a: a in found)
    finally:
        await transport.close()
        await close_emulator(fresh)
