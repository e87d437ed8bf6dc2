"""The robot model: geometry, per-joint drive and limits, serial defaults, loadable from TOML.

One frozen, validated object that the codec, kinematics, emulator, driver and suites all read.
Angles are stored in radians and lengths in metres; the TOML file spells units in its keys
(``lower_deg``, ``d4_m``) so a reader never has to guess. Defaults are documented in
``docs/robot-model.md``; the joint limits and gear ratios are assumptions taken from published igus
4-DoF configurations until better data exists.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from fractions import Fraction
from pathlib import Path
from typing import Any

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.numbers import finite_float
from armbench.drivers.model.user_files import MAX_TOML_BYTES, FileRefused, read_regular_file

__all__ = [
    "DEFAULT_JOINTS",
    "UNCERTAINTY_TABLE",
    "Geometry",
    "JointSettings",
    "RobotSettings",
    "SerialSettings",
    "SettingsError",
    "load_settings",
    "read_toml",
    "read_toml_document",
]

JOINT_COUNT = 4
#: The most tables and arrays a user's TOML file may nest: the formats nest four at most, and a
#: file nested hundreds deep would exhaust Python's recursion when copied.
MAX_TOML_DEPTH = 32


class SettingsError(ArmbenchError, ValueError):
    """A settings value is invalid; ``field`` is its dotted path in the TOML file."""

    def __init__(self, field: str, value: object, reason: str) -> None:
        super().__init__(f"{field}: {value!r} {reason}")
        self.field = field
        self.value = value
        self.reason = reason


@dataclass(frozen=True, slots=True)
class Geometry:
    """Standard-DH lengths of Table 1 in metres; ``d4_m`` is the gripper offset (0 by default)."""

    d1_m: float = 0.39
    d2_m: float = 0.009
    a2_m: float = 0.36
    a3_m: float = 0.27
    d4_m: float = 0.0


@dataclass(frozen=True, slots=True)
class JointSettings:
    """One joint: its drive train, encoder, Hall sensor, limits and protocol↔DH mapping.

    The DH angle is ``sign * q_protocol + offset_rad``. ``lower_rad``/``upper_rad`` are the joint
    limits in the protocol convention (zero = "all joints looking up, joint 1 to the front").
    """

    name: str
    gear_ratio: float
    lower_rad: float
    upper_rad: float
    offset_rad: float = 0.0
    sign: int = 1
    hall_rad: float = 0.0
    step_angle_deg: float = 1.8
    microsteps: int = 8
    encoder_counts_per_motor_rev: int = 2000
    i2c_address: int | None = None

    @property
    def steps_per_motor_rev(self) -> int:
        """Microsteps per motor revolution (1600 for a 1.8° motor at 8 microsteps)."""
        return round(360.0 / self.step_angle_deg) * self.microsteps

    @property
    def steps_per_rad(self) -> float:
        """Motor microsteps per radian of joint rotation."""
        return self.steps_per_motor_rev * self.gear_ratio / (2.0 * math.pi)

    @property
    def counts_per_rad(self) -> float:
        """Quadrature encoder counts per radian of joint rotation."""
        return self.encoder_counts_per_motor_rev * self.gear_ratio / (2.0 * math.pi)

    @property
    def counts_per_step(self) -> Fraction:
        """Encoder counts per motor microstep, exact (5/4 with the defaults)."""
        return Fraction(self.encoder_counts_per_motor_rev, self.steps_per_motor_rev)

    def to_dh(self, q_rad: float) -> float:
        """DH angle of a protocol-convention joint angle."""
        return self.sign * q_rad + self.offset_rad

    def from_dh(self, theta_rad: float) -> float:
        """Protocol-convention joint angle of a DH angle."""
        return self.sign * (theta_rad - self.offset_rad)


def _deg(x: float) -> float:
    return math.radians(x)


DEFAULT_JOINTS: tuple[JointSettings, ...] = (
    JointSettings("j1", 50.0, _deg(-140), _deg(140), 0.0, 1, 0.0, i2c_address=None),
    JointSettings("j2", 50.0, _deg(-45), _deg(70), math.pi / 2, 1, 0.0, i2c_address=0x10),
    JointSettings("j3", 38.0, _deg(-90), _deg(60), 0.0, 1, 0.0, i2c_address=0x11),
    JointSettings("j4", 28.0, _deg(-30), _deg(120), 0.0, 1, 0.0, i2c_address=0x12),
)


@dataclass(frozen=True, slots=True)
class SerialSettings:
    """UART line settings of the master board (8N1 at 115200 baud by default)."""

    baudrate: int = 115200
    bytesize: int = 8
    parity: str = "N"
    stopbits: float = 1

    @property
    def bits_per_byte(self) -> float:
        """Bits on the wire per byte: start bit, data, parity, stop bits."""
        return 1 + self.bytesize + (0 if self.parity == "N" else 1) + self.stopbits

    @property
    def byte_time_s(self) -> float:
        """Seconds one byte occupies on the line."""
        return self.bits_per_byte / self.baudrate


@dataclass(frozen=True, slots=True)
class RobotSettings:
    """The whole robot model. ``sections`` keeps the raw tables other packages validate
    (``emulator``, ``faults``, ``bench``) so one TOML file can describe a whole set-up;
    ``uncertainty`` the standard error (1 σ) of settings the file holds, by dotted key, in the
    unit of the key (the ``[uncertainty]`` table ``armbench calibrate`` writes, which campaigns
    draw from)."""

    geometry: Geometry = field(default_factory=Geometry)
    joints: tuple[JointSettings, ...] = DEFAULT_JOINTS
    serial: SerialSettings = field(default_factory=SerialSettings)
    sections: Mapping[str, Any] = field(default_factory=dict)
    uncertainty: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _validate(self)

    @property
    def lower_rad(self) -> tuple[float, ...]:
        """Lower joint limits, protocol convention."""
        return tuple(j.lower_rad for j in self.joints)

    @property
    def upper_rad(self) -> tuple[float, ...]:
        """Upper joint limits, protocol convention."""
        return tuple(j.upper_rad for j in self.joints)

    def with_d4(self, d4_m: float) -> RobotSettings:
        """A copy with another gripper offset."""
        return replace(self, geometry=replace(self.geometry, d4_m=d4_m))

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any]) -> RobotSettings:
        """Build from a TOML-shaped mapping; unknown keys are errors, missing ones take defaults."""
        return _from_mapping(data)

    def to_mapping(self) -> dict[str, Any]:
        """The TOML-shaped mapping of these settings (units in the keys), for records and files."""
        g = self.geometry
        return {
            "geometry": {"d1_m": g.d1_m, "d2_m": g.d2_m, "a2_m": g.a2_m, "a3_m": g.a3_m,
                         "d4_m": g.d4_m},
            "serial": {"baudrate": self.serial.baudrate, "bytesize": self.serial.bytesize,
                       "parity": self.serial.parity, "stopbits": self.serial.stopbits},
            "joints": {j.name: _joint_to_mapping(j) for j in self.joints},
            **{k: _plain(v) for k, v in self.sections.items()},
            **({UNCERTAINTY_TABLE: dict(self.uncertainty)} if self.uncertainty else {}),
        }


def load_settings(path: str | Path | None = None) -> RobotSettings:
    """Load robot settings from a TOML file (defaults when ``path`` is None)."""
    if path is None:
        return RobotSettings()
    return RobotSettings.from_mapping(read_toml(path, "settings"))


def read_toml(path: str | Path, what: str) -> dict[str, Any]:
    """The TOML file at ``path`` as a table; anything that keeps it from being one (missing, a
    directory, a FIFO or device, more than :data:`MAX_TOML_BYTES`, unreadable, not UTF-8, not
    TOML, nested deeper than :data:`MAX_TOML_DEPTH`) raises :class:`SettingsError` naming
    ``what`` and the path, in one line."""
    return read_toml_document(path, what)[1]


def read_toml_document(path: str | Path, what: str) -> tuple[str, dict[str, Any]]:
    """:func:`read_toml`, with the file's text too (for readers of its comments)."""
    p = Path(path)
    try:
        raw = read_regular_file(p, "a TOML file", MAX_TOML_BYTES)
    except FileRefused as exc:
        raise SettingsError(what, str(p), exc.reason) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SettingsError(what, str(p), f"is not UTF-8 text: {exc.reason} at byte "
                                          f"{exc.start}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SettingsError(what, str(p), f"is not valid TOML: {exc}") from None
    except RecursionError:
        data = None
    if data is None or _depth(data) > MAX_TOML_DEPTH:
        raise SettingsError(what, str(p), f"is nested more than {MAX_TOML_DEPTH} tables or "
                                          "arrays deep") from None
    return text, data


def _depth(value: object) -> int:
    """How many tables and arrays deep ``value`` is nested (iteratively: any depth is measured
    without recursion)."""
    deepest = 0
    stack: list[tuple[object, int]] = [(value, 0)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, Mapping):
            children: list[object] = list(node.values())
        elif isinstance(node, list):
            children = list(node)
        else:
            continue
        deepest = max(deepest, depth + 1)
        stack.extend((child, depth + 1) for child in children)
    return deepest


_JOINT_KEYS_DEG = {"lower_deg": "lower_rad", "upper_deg": "upper_rad", "offset_deg": "offset_rad",
                   "hall_deg": "hall_rad"}
_JOINT_KEYS_PLAIN = ("gear_ratio", "sign", "step_angle_deg", "microsteps",
                     "encoder_counts_per_motor_rev", "i2c_address")
_EXTENSION_SECTIONS = ("emulator", "faults", "bench")
#: The table of standard errors: ``"emulator.physics.j1.backlash_deg" = 0.003`` (one σ).
UNCERTAINTY_TABLE = "uncertainty"


def _joint_to_mapping(j: JointSettings) -> dict[str, Any]:
    out: dict[str, Any] = {k: math.degrees(getattr(j, attr)) for k, attr in _JOINT_KEYS_DEG.items()}
    for k in _JOINT_KEYS_PLAIN:
        v = getattr(j, k)
        if v is not None:
            out[k] = v
    return out


def _plain(value: Any) -> Any:
    """A deep copy of a TOML-shaped value with plain dicts and lists."""
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


#: No setting of the robot needs a magnitude beyond this; larger ones (TOML integers are unbounded)
#: are refused before any arithmetic can overflow.
_MAGNITUDE_LIMIT = 1e12


def _number(path: str, value: object, *, integer: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SettingsError(path, value, "is not a number")
    if integer and not isinstance(value, int):
        raise SettingsError(path, value, "is not an integer")
    if isinstance(value, float) and finite_float(value) is None:
        raise SettingsError(path, value, "is not finite")
    if abs(value) > _MAGNITUDE_LIMIT:
        raise SettingsError(path, value, f"is beyond ±{_MAGNITUDE_LIMIT:g}")
    return value


def _table(path: str, value: object) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise SettingsError(path, value, "is not a table")
    return value


def _unknown(path: str, table: Mapping[str, Any], known: set[str]) -> None:
    for key in table:
        if key not in known:
            name = key if key else '""'
            where = f"{path}.{name}" if path else name
            raise SettingsError(where, table[key], f"is not a known setting (known: "
                                                   f"{', '.join(sorted(known))})")


def _from_mapping(data: Mapping[str, Any]) -> RobotSettings:
    _unknown("", data, {"geometry", "serial", "joints", UNCERTAINTY_TABLE, *_EXTENSION_SECTIONS})
    geo_in = _table("geometry", data.get("geometry", {}))
    _unknown("geometry", geo_in, set(Geometry.__slots__))
    geometry = Geometry(**{k: _number(f"geometry.{k}", v) for k, v in geo_in.items()})

    ser_in = _table("serial", data.get("serial", {}))
    _unknown("serial", ser_in, set(SerialSettings.__slots__))
    ser_kwargs: dict[str, Any] = {}
    for k, v in ser_in.items():
        ser_kwargs[k] = v if k == "parity" else _number(f"serial.{k}", v, integer=k != "stopbits")
    serial = SerialSettings(**ser_kwargs)

    joints_in = _table("joints", data.get("joints", {}))
    names = [j.name for j in DEFAULT_JOINTS]
    _unknown("joints", joints_in, set(names))
    joints = []
    for default in DEFAULT_JOINTS:
        jt = _table(f"joints.{default.name}", joints_in.get(default.name, {}))
        _unknown(f"joints.{default.name}", jt, set(_JOINT_KEYS_DEG) | set(_JOINT_KEYS_PLAIN))
        kwargs: dict[str, Any] = {}
        for k, v in jt.items():
            path = f"joints.{default.name}.{k}"
            if k in _JOINT_KEYS_DEG:
                kwargs[_JOINT_KEYS_DEG[k]] = math.radians(_number(path, v))
            else:
                kwargs[k] = _number(path, v, integer=k not in ("gear_ratio", "step_angle_deg"))
        joints.append(replace(default, **kwargs))
    sections = {k: data[k] for k in _EXTENSION_SECTIONS if k in data}
    return RobotSettings(geometry, tuple(joints), serial, sections, _uncertainty(data))


def _uncertainty(data: Mapping[str, Any]) -> dict[str, float]:
    """The ``[uncertainty]`` table of ``data``: each key the dotted path of a number the file
    sets, each value a finite standard error >= 0."""
    out: dict[str, float] = {}
    for key, sigma in _table(UNCERTAINTY_TABLE, data.get(UNCERTAINTY_TABLE, {})).items():
        path = f"{UNCERTAINTY_TABLE}.{json.dumps(key)}"
        value = _number(path, sigma)
        if value < 0:
            raise SettingsError(path, sigma, "is not a standard error (a number >= 0)")
        node: object = data
        for part in str(key).split("."):
            node = node.get(part) if isinstance(node, Mapping) else None
        if isinstance(node, bool) or not isinstance(node, (int, float)):
            raise SettingsError(path, sigma, f"is the standard error of {key}, which this file "
                                             "does not set to a number")
        out[str(key)] = float(value)
    return out


def _validate(s: RobotSettings) -> None:
    g = s.geometry
    for name in ("d1_m", "d2_m", "a2_m", "a3_m", "d4_m"):
        v = _number(f"geometry.{name}", getattr(g, name))
        if name in ("a2_m", "a3_m") and v <= 0:
            raise SettingsError(f"geometry.{name}", v, "must be > 0")
        if abs(v) > 10:
            raise SettingsError(f"geometry.{name}", v, "is not a plausible length in metres")
    if len(s.joints) != JOINT_COUNT:
        raise SettingsError("joints", len(s.joints), f"joints given; the arm has {JOINT_COUNT}")
    addresses: set[int] = set()
    for i, j in enumerate(s.joints):
        p = f"joints.{j.name}"
        _number(f"{p}.gear_ratio", j.gear_ratio)
        _number(f"{p}.step_angle_deg", j.step_angle_deg)
        if not 0.01 <= j.gear_ratio <= 10_000:
            raise SettingsError(f"{p}.gear_ratio", j.gear_ratio, "must be in 0.01..10000")
        if j.sign not in (1, -1):
            raise SettingsError(f"{p}.sign", j.sign, "must be 1 or -1")
        if not j.lower_rad < j.upper_rad:
            raise SettingsError(f"{p}.lower_deg", math.degrees(j.lower_rad),
                                f"must be below upper_deg {math.degrees(j.upper_rad):g}")
        if j.upper_rad - j.lower_rad >= 2 * math.pi:
            raise SettingsError(f"{p}.upper_deg", math.degrees(j.upper_rad),
                                "gives a range of 360° or more; the protocol cannot tell such "
                                "angles apart")
        if not j.lower_rad <= j.hall_rad <= j.upper_rad:
            raise SettingsError(f"{p}.hall_deg", math.degrees(j.hall_rad),
                                "must lie within the joint limits")
        if not 0.01 <= j.step_angle_deg <= 90:
            raise SettingsError(f"{p}.step_angle_deg", j.step_angle_deg, "must be in 0.01..90")
        full_steps = 360.0 / j.step_angle_deg
        if abs(full_steps - round(full_steps)) > 1e-9:
            raise SettingsError(f"{p}.step_angle_deg", j.step_angle_deg,
                                "must divide 360° into a whole number of steps")
        if not 1 <= j.microsteps <= 256:
            raise SettingsError(f"{p}.microsteps", j.microsteps, "must be 1..256")
        if not 1 <= j.encoder_counts_per_motor_rev <= 10_000_000:
            raise SettingsError(f"{p}.encoder_counts_per_motor_rev",
                                j.encoder_counts_per_motor_rev, "must be 1..10000000")
        if i == 0:
            if j.i2c_address is not None:
                raise SettingsError(f"{p}.i2c_address", j.i2c_address,
                                    "is set, but joint 1 is the I²C master and has no address")
            continue
        if j.i2c_address is None or not 0x08 <= j.i2c_address <= 0x77:
            raise SettingsError(f"{p}.i2c_address", j.i2c_address,
                                "must be a 7-bit slave address in 0x08..0x77")
        if j.i2c_address in addresses:
            raise SettingsError(f"{p}.i2c_address", j.i2c_address, "is used by another joint")
        addresses.add(j.i2c_address)
    ser = s.serial
    if ser.baudrate <= 0:
        raise SettingsError("serial.baudrate", ser.baudrate, "must be > 0")
    if ser.bytesize not in (5, 6, 7, 8):
        raise SettingsError("serial.bytesize", ser.bytesize, "must be 5, 6, 7 or 8")
    if ser.parity not in ("N", "E", "O", "M", "S"):
        raise SettingsError("serial.parity", ser.parity, "must be one of N, E, O, M, S")
    if ser.stopbits not in (1, 1.5, 2):
        raise SettingsError("serial.stopbits", ser.stopbits, "must be 1, 1.5 or 2")
