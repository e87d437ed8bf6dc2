"""Settings of the firmware emulator: the ``[emulator]`` table of a robot settings file.

Every choice the paper leaves open is a field here, with the default the real firmware most
plausibly has (see ``docs/emulator.md``). ``profile`` picks the mechanism: ``physical`` (the
default: the plausible arm of ``[emulator.physics]``, ``docs/robot-model.md``) or ``ideal``
(rigid, play-free, exact: what tests of the firmware's exact behaviour use).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any, Final, Literal

from armbench.drivers.model.bounds import Bound, check, check_whole
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.drivers.model.twin_parameters import TWIN
from armbench.fakes.twin.joint import CYCLE_S, PhysicalEffects, StopRule
from armbench.fakes.twin.physics import DEFAULT_ARM, PROFILES, ArmPhysics, arm_physics
from armbench.fakes.twin.stepper import STOP_RULES

__all__ = ["BOUNDS", "CYCLE_S", "MAX_DEADBAND_COUNTS", "MAX_TIMES_S", "PROFILES", "ArmPhysics",
           "EmulatorSettings", "PhysicalEffects", "actual_robot", "emulator_settings",
           "with_emulator_overrides"]

@dataclass(frozen=True, slots=True)
class EmulatorSettings:
    """How the emulated firmware behaves where the paper is silent."""

    uart_receive: Literal["polling", "blocking"] = "polling"
    """Polling: the master's loop runs continuously and replies every loop (what the ROS driver's
    continuous stream needs); blocking: each loop waits for a whole command frame."""
    i2c_hz: int = 100_000
    """I²C bus clock: 100 kHz (Arduino Wire default) or 400 kHz."""
    rx_buffer_bytes: int = 64
    """The board's serial receive buffer (``RX_SIZE`` in ``firmware/master.c``, the Arduino core's
    ``SERIAL_RX_BUFFER_SIZE``); bytes arriving when it is full are dropped."""
    tx_buffer_bytes: int = 64
    """The serial transmit buffer; a longer print blocks the loop until it drains."""
    host_buffer_bytes: int = 4096
    """What the host side of the line holds for it when a client of ``armbench emulate`` writes
    faster than the baud rate: a USB-serial port's write FIFO in Linux is one page, and the
    firmware-in-the-loop harness queues as much (``rx_queue`` in ``firmware/harness/harness.h``).
    Bytes arriving when it is full are dropped and counted as overrun (``docs/emulator.md``)."""
    loop_overhead_s: float = 100e-6
    """CPU time of one master loop besides I²C and UART (parsing, formatting) at 16 MHz."""
    reply_line_end: str = ""
    """Bytes after each reply's '#': the paper shows none (``Serial.print``)."""
    deadband_counts: int = 1
    """A joint at rest starts when |target − counter| exceeds this many encoder counts."""
    stop_rule: StopRule = "window"
    """When a moving joint stops: ``window``, once |target − counter| ≤ ``deadband_counts``;
    ``reach``, once its counter meets or passes the target (``docs/emulator.md``)."""
    recovery_duty: int = 90
    """Duty used when driving to the Hall sensor at start-up (§5.2)."""
    eeprom_write_s_per_byte: float = 3.3e-3
    """ATmega328P EEPROM write time per byte; the master's loop stalls while it writes."""
    boot_s: float = 0.1
    """From power-up to ``setup()``: the ATmega328P's 65 ms oscillator start-up delay (fuses of an
    Arduino Pro Mini) plus the core's initialisation; a boot loader that waits for an upload on
    every reset would add about 1 s (set it here)."""
    eeprom_cells: int = 1024
    seed: int = 0
    fused_bus: bool = True
    """Run a steady main loop's six I²C transactions (no new command, no bus fault, every
    slave answering and holding the repeated reference) as their known outcome at their exact
    bus times, instead of message by message through ``I2CBus.i2c_rdwr``: the same replies,
    times, counters and EEPROM, at about half the cost per loop. False: every transaction goes
    through the bus, as the master's code would on a real ``smbus2.SMBus``."""
    effects: PhysicalEffects = field(default_factory=PhysicalEffects)
    profile: Literal["physical", "ideal"] = "physical"
    """``physical``: the mechanism of ``physics``; ``ideal``: none (rigid, play-free, exact)."""
    physics: ArmPhysics | None = DEFAULT_ARM
    """The physical arm (``fakes/twin/physics.py``, ``[emulator.physics]``); None in the ideal
    profile."""

    @property
    def i2c_bit_s(self) -> float:
        """Seconds per bit on the I²C bus."""
        return 1.0 / self.i2c_hz


#: Upper bounds of the emulator's times (s), checked when the settings are read: a master loop
#: or an EEPROM byte of a second, a boot of a minute are already far beyond any ATmega328P.
MAX_TIMES_S: dict[str, float] = {"loop_overhead_s": 1.0, "eeprom_write_s_per_byte": 1.0,
                                 "boot_s": 60.0}

#: The widest firmware deadband the emulator takes (encoder counts): 4 mrad on joints 1–2 and
#: 7 mrad on joint 4, over ten times the driver's default arrival tolerance (3e-4 rad) and four
#: times the start-up suite's 1 mrad. A firmware that stops that far from its target holds no
#: position the bench can judge; a larger value is a mistake (100 000 counts holds every joint
#: still, and every move of a run then times out).
MAX_DEADBAND_COUNTS: Final = 64

#: The ``float`` fields: made plain floats, as the compiled boards read them.
_FLOATS = frozenset(f.name for f in fields(EmulatorSettings) if f.type in ("float", float))
#: The ``int`` fields: a whole number of any int type is made a plain int.
_INTS = frozenset(f.name for f in fields(EmulatorSettings) if f.type in ("int", int))
_PAYLOAD: Final = TWIN["payload_kg"]
#: The ``[emulator.effects]`` keys merged into the arm's physics, and where each went: one
#: vocabulary per effect (``docs/emulator.md``).
_MERGED: Final = {
    "backlash_rad": (f"is no longer read: the gear play is {TWIN['backlash_rad'].key} of each "
                     "joint's [emulator.physics.jN] table (the physical play it was added to)"),
    "noise_rate_hz": (f"is no longer read: encoder noise is {TWIN['noise_per_count'].path()} "
                      "(spurious counts per encoder count)"),
}
#: Every number of the ``[emulator]`` table and its bound, checked when the settings are read.
BOUNDS: Final[Mapping[str, Bound]] = {
    "i2c_hz": Bound(10_000, 3_400_000, "Hz", whole=True, why="an I²C clock"),
    "rx_buffer_bytes": Bound(1, 1e12, "bytes", whole=True),
    "tx_buffer_bytes": Bound(1, 1e12, "bytes", whole=True),
    "host_buffer_bytes": Bound(1, 1 << 20, "bytes", whole=True,
                               why="what a client may queue is bounded"),
    **{name: Bound(0.0, high_s, "s") for name, high_s in MAX_TIMES_S.items()},
    "deadband_counts": Bound(0, MAX_DEADBAND_COUNTS, "encoder counts", whole=True),
    "recovery_duty": Bound(1, 99, whole=True),
    "seed": Bound(0, 2**32 - 1, whole=True),
    "eeprom_cells": Bound(5, 65536, whole=True, why="the record takes 5 bytes"),
}
#: A number of ``[emulator.effects]`` (``PhysicalEffects`` checks their ranges).
_EFFECT = Bound(-1e12, 1e12)
_MISS_ABOVE_DUTY = Bound(0, 99, whole=True)
_PAYLOAD_KG = Bound(*_PAYLOAD.accepted(), "kg", why="the paper's maximum")

_TYPES: dict[str, type] = {"uart_receive": str, "reply_line_end": str, "fused_bus": bool,
                           "profile": str, "stop_rule": str}


def actual_robot(robot: RobotSettings) -> RobotSettings:
    """The robot model of the arm the emulator builds from ``robot`` with its default settings:
    the actual DH lengths and joint offsets (the truth's), ``robot`` itself when ideal."""
    physics = emulator_settings(robot).physics
    return robot if physics is None else physics.actual_settings(robot)


def emulator_settings(robot: RobotSettings, **overrides: Any) -> EmulatorSettings:
    """Validated emulator settings from the robot file's ``[emulator]`` table plus overrides."""
    section = robot.sections.get("emulator", {})
    if not isinstance(section, Mapping):
        raise SettingsError("emulator", section, "is not a table")
    table: dict[str, Any] = dict(section)
    table.update(overrides)
    effects_in = table.pop("effects", {})
    if isinstance(effects_in, PhysicalEffects):
        effects = effects_in
    else:
        if not isinstance(effects_in, Mapping):
            raise SettingsError("emulator.effects", effects_in, "is not a table")
        known_fx = {f.name for f in fields(PhysicalEffects)}
        values: dict[str, Any] = {}
        for k, v in effects_in.items():
            if k in _MERGED:
                raise SettingsError(f"emulator.effects.{k}", v, _MERGED[k])
            if k not in known_fx:
                raise SettingsError(f"emulator.effects.{k}", v, "is not a known setting")
            where = f"emulator.effects.{k}"
            values[k] = (check_whole(where, v, _MISS_ABOVE_DUTY) if k == "miss_above_duty"
                         else check(where, v, _EFFECT))
        try:  # plain ints and floats: the compiled class takes no numpy integer, keeps no int
            effects = PhysicalEffects(**values)
        except ValueError as exc:
            raise SettingsError("emulator.effects", dict(effects_in), str(exc)) from None
    physics_in = table.pop("physics", {})
    if isinstance(physics_in, ArmPhysics):
        physics: ArmPhysics | None = physics_in
    elif physics_in is None:
        physics = None
    else:
        if not isinstance(physics_in, Mapping):
            raise SettingsError("emulator.physics", physics_in, "is not a table")
        physics = arm_physics(physics_in)
    profile = table.get("profile", "physical")
    if profile not in PROFILES:
        raise SettingsError("emulator.profile", profile, f"must be one of {', '.join(PROFILES)}")
    if profile == "ideal":
        physics = None
    known = {f.name for f in fields(EmulatorSettings)} - {"effects", "physics"}
    for k, v in table.items():
        if k not in known:
            raise SettingsError(f"emulator.{k}", v, f"is not a known setting (known: "
                                                    f"{', '.join(sorted(known))})")
        if _TYPES.get(k) is str:
            if not isinstance(v, str):
                raise SettingsError(f"emulator.{k}", v, "is not a string")
        elif _TYPES.get(k) is bool:
            if not isinstance(v, bool):
                raise SettingsError(f"emulator.{k}", v, "is not true or false")
        else:  # a plain int or float for the compiled boards (no numpy number)
            bound = BOUNDS[k]
            table[k] = (check_whole(f"emulator.{k}", v, bound) if bound.whole
                        else check(f"emulator.{k}", v, bound))
    s = replace(EmulatorSettings(), effects=effects, physics=physics, **table)
    _validate(s)
    return s


def with_emulator_overrides(robot: RobotSettings, *, profile: str | None = None,
                            payload_kg: str | float | None = None) -> RobotSettings:
    """``robot`` with its ``[emulator]`` table's ``profile`` and ``physics.payload_kg`` replaced
    (the ``fake://?profile=…&payload=…`` query); each value checked, errors naming it."""
    if profile is None and payload_kg is None:
        return robot
    section = robot.sections.get("emulator", {})
    if not isinstance(section, Mapping):
        raise SettingsError("emulator", section, "is not a table")
    table: dict[str, Any] = dict(section)
    if profile is not None:
        if profile not in PROFILES:
            raise SettingsError("profile", profile, f"must be one of {', '.join(PROFILES)}")
        table["profile"] = profile
    if payload_kg is not None:
        try:
            kg = float(payload_kg)
        except ValueError:
            raise SettingsError("payload", payload_kg, "is not a number of kg") from None
        check("payload", kg, _PAYLOAD_KG)
        physics = table.get("physics", {})
        if not isinstance(physics, Mapping):
            raise SettingsError("emulator.physics", physics, "is not a table")
        table["physics"] = {**physics, "payload_kg": kg}
    out = replace(robot, sections={**robot.sections, "emulator": table})
    emulator_settings(out)  # validates the result
    return out


def _validate(s: EmulatorSettings) -> None:
    if s.uart_receive not in ("polling", "blocking"):
        raise SettingsError("emulator.uart_receive", s.uart_receive,
                            "must be 'polling' or 'blocking'")
    for name, bound in BOUNDS.items():
        check(f"emulator.{name}", getattr(s, name), bound)
    if s.reply_line_end not in ("", "\n", "\r\n"):
        raise SettingsError("emulator.reply_line_end", s.reply_line_end,
                            "must be '', '\\n' or '\\r\\n'")
    if s.stop_rule not in STOP_RULES:
        raise SettingsError("emulator.stop_rule", s.stop_rule,
                            f"must be one of {', '.join(map(repr, STOP_RULES))}")
    check_whole("emulator.effects.miss_above_duty", s.effects.miss_above_duty, _MISS_ABOVE_DUTY)
