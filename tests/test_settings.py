"""The robot model: defaults, TOML loading and validation errors that name the field."""

from __future__ import annotations

import math
from fractions import Fraction
from pathlib import Path

import pytest

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings, SettingsError, load_settings
from armbench.fakes.firmware.emulator_settings import emulator_settings


def test_defaults_match_the_documented_assumptions() -> None:
    s = RobotSettings()
    assert (s.geometry.d1_m, s.geometry.d2_m, s.geometry.a2_m, s.geometry.a3_m) == (
        0.39, 0.009, 0.36, 0.27)
    assert s.geometry.d4_m == 0.0
    assert [j.gear_ratio for j in s.joints] == [50, 50, 38, 28]
    assert [round(math.degrees(j.lower_rad)) for j in s.joints] == [-140, -45, -90, -30]
    assert [round(math.degrees(j.upper_rad)) for j in s.joints] == [140, 70, 60, 120]
    j1 = s.joints[0]
    assert j1.steps_per_motor_rev == 1600
    assert j1.counts_per_step == Fraction(5, 4)
    assert j1.steps_per_rad == pytest.approx(1600 * 50 / (2 * math.pi))
    assert s.serial.baudrate == 115200
    assert s.serial.byte_time_s == pytest.approx(10 / 115200)


def test_load_from_toml_with_units_in_keys(tmp_path: Path) -> None:
    f = tmp_path / "robot.toml"
    f.write_text("""
[geometry]
d4_m = 0.12
[serial]
baudrate = 57600
[joints.j3]
gear_ratio = 40
lower_deg = -80
hall_deg = 10
[emulator]
uart_receive = "blocking"
""")
    s = load_settings(f)
    assert s.geometry.d4_m == 0.12
    assert s.serial.baudrate == 57600
    assert s.joints[2].gear_ratio == 40
    assert s.joints[2].lower_rad == pytest.approx(math.radians(-80))
    assert s.joints[2].hall_rad == pytest.approx(math.radians(10))
    assert s.joints[0].gear_ratio == 50
    assert s.sections["emulator"] == {"uart_receive": "blocking"}
    assert RobotSettings.from_mapping(s.to_mapping()) == s


@pytest.mark.parametrize(("toml", "field", "words"), [
    ("[geometry]\nd5_m = 1", "geometry.d5_m", "not a known setting"),
    ("[joints.j2]\nlower_deg = 80", "joints.j2.lower_deg", "must be < 70 deg (below upper_deg)"),
    ("[joints.j2]\ngear_ratio = -3", "joints.j2.gear_ratio", "must be in [0.01, 10000]"),
    ("[joints.j4]\nsign = 2", "joints.j4.sign", "must be 1 or -1"),
    ("[joints.j5]\ngear_ratio = 3", "joints.j5", "not a known setting"),
    ("[joints.j3]\ni2c_address = 0x10", "joints.j3.i2c_address", "used by another joint"),
    ("[joints.j1]\ni2c_address = 0x20", "joints.j1.i2c_address", "master"),
    ("[joints.j1]\nmicrosteps = 2.5", "joints.j1.microsteps",
     "2.5 must be a whole number in [1, 256]"),
    ("[joints.j1]\nhall_deg = 170", "joints.j1.hall_deg", "within the joint limits"),
    ("[joints.j1]\nlower_deg = -190\nupper_deg = 190", "joints.j1.upper_deg", "360"),
    ("[serial]\nbaudrate = 'fast'", "serial.baudrate", "'fast' must be a whole number > 0 baud"),
    ("[serial]\nparity = 'X'", "serial.parity", "N, E, O"),
    ("[geometry]\na2_m = nan", "geometry.a2_m", "nan must be in (0, 10] m"),
    ("geometry = 3", "geometry", "not a table"),
    ("[robot]\nx = 1", "robot", "not a known setting"),
])
def test_invalid_values_name_the_field(tmp_path: Path, toml: str, field: str, words: str) -> None:
    f = tmp_path / "bad.toml"
    f.write_text(toml)
    with pytest.raises(SettingsError) as info:
        load_settings(f)
    assert info.value.field == field
    assert words in str(info.value)
    assert str(info.value).startswith(field)
    assert isinstance(info.value, ArmbenchError)


def test_missing_and_broken_files(tmp_path: Path) -> None:
    with pytest.raises(SettingsError, match="does not exist"):
        load_settings(tmp_path / "nope.toml")
    bad = tmp_path / "broken.toml"
    bad.write_text("[geometry\n")
    with pytest.raises(SettingsError, match="not valid TOML"):
        load_settings(bad)


def test_emulator_fused_bus_is_a_boolean(tmp_path: Path) -> None:
    f = tmp_path / "robot.toml"
    f.write_text("[emulator]\nfused_bus = false\n")
    assert emulator_settings(load_settings(f)).fused_bus is False
    assert emulator_settings(RobotSettings()).fused_bus is True
    f.write_text("[emulator]\nfused_bus = 1\n")
    with pytest.raises(SettingsError) as info:
        emulator_settings(load_settings(f))
    assert info.value.field == "emulator.fused_bus" and "true or false" in str(info.value)


def test_emulator_numbers_become_plain_python_numbers() -> None:
    """A float setting given as a TOML int, or any number a caller took from numpy, reaches the
    emulator as a plain float or int: the compiled boards and ``PhysicalEffects`` take no numpy
    integer and store an int given for a float as a float, where Python would keep it."""
    np = pytest.importorskip("numpy")
    robot = RobotSettings(sections={"emulator": {
        "boot_s": np.int64(0), "loop_overhead_s": 0, "eeprom_write_s_per_byte": np.float64(0.003),
        "effects": {"miss_probability": np.float64(0.1), "miss_above_duty": np.int64(40)},
        "physics": {"noise_per_count": np.float64(0.0), "j1": {"backlash_deg": 0}}}})
    s = emulator_settings(robot)
    assert s.physics is not None
    for value in (s.boot_s, s.loop_overhead_s, s.eeprom_write_s_per_byte,
                  s.effects.miss_probability, s.physics.noise_per_count,
                  s.physics.joints[0].backlash_rad):
        assert type(value) is float, value
    assert type(s.effects.miss_above_duty) is int and s.effects.miss_above_duty == 40
    robot = RobotSettings(sections={"emulator": {"effects": {"miss_above_duty": 40.0}}})
    with pytest.raises(SettingsError, match=r"miss_above_duty: 40\.0 must be a whole number"):
        emulator_settings(robot)
