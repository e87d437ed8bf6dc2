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
from typing import Any, Final

from armbench.drivers.model.bounds import Bound, check, check_whole
from armbench.drivers.model.errors import SettingsError
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
_MAGNITUDE = Bound(-1e12, 1e12)
#: The DH lengths (m): within a few metres of the base, a2 and a3 (the arm's links) longer than 0.
_LENGTH_M = Bound(-10.0, 10.0, "m", why="a plausible length in metres")
_LINK_M = Bound(0.0, 10.0, "m", low_open=True, why="a plausible link length in metres")
#: The drive train and sensors of a joint.
_GEAR_RATIO = Bound(0.01, 10_000.0)
_STEP_ANGLE_DEG = Bound(0.01, 90.0, "deg")
_MICROSTEPS = Bound(1, 256, whole=True)
_ENCODER_COUNTS = Bound(1, 10_000_000, whole=True)
_I2C_ADDRESS = Bound(0x08, 0x77, whole=True, why="a 7-bit slave address, 0x08..0x77")
_BAUDRATE = Bound(0, math.inf, "baud", low_open=True, whole=True)
_WHOLE = Bound(-1e12, 1e12, whole=True)
#: The bound each number of the file is read with (the rest of a joint's checks, which relate
#: its values, are :func:`_validate`'s).
_GEOMETRY_BOUNDS = {"d1_m": _LENGTH_M, "d2_m": _LENGTH_M, "a2_m": _LINK_M, "a3_m": _LINK_M,
                    "d4_m": _LENGTH_M}
_SERIAL_BOUNDS = {"baudrate": _BAUDRATE, "bytesize": _WHOLE, "stopbits": _MAGNITUDE}
_JOINT_BOUNDS = {"gear_ratio": _GEAR_RATIO, "step_angle_deg": _STEP_ANGLE_DEG,
                 "microsteps": _MICROSTEPS, "encoder_counts_per_motor_rev": _ENCODER_COUNTS,
                 "sign": _WHOLE, "i2c_address": _WHOLE}


#: A standard error of the ``[uncertainty]`` table.
_STANDARD_ERROR: Final = Bound(0.0, 1e12, why="a standard error")


def _number(path: str, value: object, bound: Bound = _MAGNITUDE) -> float:
    """``value`` once it is a number within ``bound`` (whole, if the bound is); an int stays an
    int (the file's 40, not 40.0)."""
    if bound.whole:
        return check_whole(path, value, bound)
    number = check(path, value, bound)
    return value if isinstance(value, int) else number


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
    geometry = Geometry(**{k: _number(f"geometry.{k}", v, _GEOMETRY_BOUNDS[k])
                           for k, v in geo_in.items()})

    ser_in = _table("serial", data.get("serial", {}))
    _unknown("serial", ser_in, set(SerialSettings.__slots__))
    ser_kwargs: dict[str, Any] = {}
    for k, v in ser_in.items():
        ser_kwargs[k] = v if k == "parity" else _number(f"serial.{k}", v, _SERIAL_BOUNDS[k])
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
                kwargs[k] = _number(path, v, _JOINT_BOUNDS[k])
        joints.append(replace(default, **kwargs))
    sections = {k: data[k] for k in _EXTENSION_SECTIONS if k in data}
    return RobotSettings(geometry, tuple(joints), serial, sections, _uncertainty(data))


def _uncertainty(data: Mapping[str, Any]) -> dict[str, float]:
    """The ``[uncertainty]`` table of ``data``: each key the dotted path of a number the file
    sets, each value a finite standard error >= 0."""
    out: dict[str, float] = {}
    for key, sigma in _table(UNCERTAINTY_TABLE, data.get(UNCERTAINTY_TABLE, {})).items():
        path = f"{UNCERTAINTY_TABLE}.{json.dumps(key)}"
        value = _number(path, sigma, _STANDARD_ERROR)
        node: object = data
        for part in str(key).split("."):
            node = node.get(part) if isinstance(node, Mapping) else None
        if isinstance(node, bool) or not isinstance(node, (int, float)):
            raise SettingsError(path, sigma, f"is the standard error of {key}, which this file "
                                             "does not set to a number")
        out[str(key)] = float(value)
    return out


def _check_range(p: str, j: JointSettings) -> None:
    """A joint's limits and Hall position (deg in the messages, as in the file): lower below
    upper, less than a turn apart, the Hall sensor between them."""
    lower_deg, upper_deg = math.degrees(j.lower_rad), math.degrees(j.upper_rad)
    check(f"{p}.lower_deg", lower_deg, Bound(high=upper_deg, high_open=True, unit="deg",
                                             why="below upper_deg"))
    check(f"{p}.upper_deg", upper_deg, Bound(
        high=lower_deg + 360.0, high_open=True, unit="deg",
        why="a range of 360° or more from lower_deg: the protocol cannot tell such angles apart"))
    check(f"{p}.hall_deg", math.degrees(j.hall_rad),
          Bound(lower_deg, upper_deg, "deg", why="within the joint limits"))


def _validate(s: RobotSettings) -> None:
    g = s.geometry
    for name in ("d1_m", "d2_m", "a2_m", "a3_m", "d4_m"):
        check(f"geometry.{name}", getattr(g, name),
              _LINK_M if name in ("a2_m", "a3_m") else _LENGTH_M)
    if len(s.joints) != JOINT_COUNT:
        raise SettingsError("joints", len(s.joints), f"joints given; the arm has {JOINT_COUNT}")
    addresses: set[int] = set()
    for i, j in enumerate(s.joints):
        p = f"joints.{j.name}"
        check(f"{p}.gear_ratio", j.gear_ratio, _GEAR_RATIO)
        if j.sign not in (1, -1):
            raise SettingsError(f"{p}.sign", j.sign, "must be 1 or -1")
        _check_range(p, j)
        step_angle_deg = check(f"{p}.step_angle_deg", j.step_angle_deg, _STEP_ANGLE_DEG)
        full_steps = 360.0 / step_angle_deg
        if not math.isclose(full_steps, round(full_steps), rel_tol=0.0, abs_tol=1e-9):
            raise SettingsError(f"{p}.step_angle_deg", j.step_angle_deg,
                                "must divide 360° into a whole number of steps")
        check_whole(f"{p}.microsteps", j.microsteps, _MICROSTEPS)
        check_whole(f"{p}.encoder_counts_per_motor_rev", j.encoder_counts_per_motor_rev,
                    _ENCODER_COUNTS)
        if i == 0:
            if j.i2c_address is not None:
                raise SettingsError(f"{p}.i2c_address", j.i2c_address,
                                    "is set, but joint 1 is the I²C master and has no address")
            continue
        address = check_whole(f"{p}.i2c_address", j.i2c_address, _I2C_ADDRESS)
        if address in addresses:
            raise SettingsError(f"{p}.i2c_address", j.i2c_address, "is used by another joint")
        addresses.add(address)
    ser = s.serial
    check_whole("serial.baudrate", ser.baudrate, _BAUDRATE)
    if ser.bytesize not in (5, 6, 7, 8):
        raise SettingsError("serial.bytesize", ser.bytesize, "must be 5, 6, 7 or 8")
    if ser.parity not in ("N", "E", "O", "M", "S"):
        raise SettingsError("serial.parity", ser.parity, "must be one of N, E, O, M, S")
    if ser.stopbits not in (1, 1.5, 2):
        raise SettingsError("serial.stopbits", ser.stopbits, "must be 1, 1.5 or 2")
