"""Regression tests for the crashes the fuzzing campaign found (``fuzz/``,
``measurements/fuzzing.md``).

Each test is the smallest reproduction of one finding through the public API, starting from the
TOML text a user could write, and asserts the *correct* behaviour: a settings file is either
rejected with a ``SettingsError`` naming the field, or it is accepted and the emulator built from it
boots and runs. (While a bug is open its test is marked ``xfail(strict=True)`` with the exception it
raises, so CI stays green and turns red the moment the bug is fixed; all found so far are fixed.)

Signatures are ``ExceptionType@file:line`` of the innermost frame in the checkout when found.
"""

from __future__ import annotations

import asyncio
import tomllib

import pytest

from armbench.drivers.model.protocol import Command
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.firmware.emulator_settings import EmulatorSettings, emulator_settings
from armbench.fakes.firmware.faults import Fault, faults_from_settings

DID_NOT_RAISE = pytest.fail.Exception  # what pytest.raises raises when nothing was raised


def load(text: str) -> tuple[RobotSettings, EmulatorSettings, list[Fault]]:
    """What ``armbench emulate --settings FILE`` does with a file's text."""
    robot = RobotSettings.from_mapping(tomllib.loads(text))
    return robot, emulator_settings(robot), faults_from_settings(robot)


def run(robot: RobotSettings, emu: EmulatorSettings, faults: list[Fault],
        seconds: float = 0.05) -> None:
    """Boot the emulator on virtual time, send one command, run, close; re-raise the first
    exception of any board task."""
    async def main() -> None:
        arm = ArmEmulator(robot, emu, faults)
        arm.attach_host(lambda data: None)
        await arm.start()
        try:
            await asyncio.sleep(getattr(emu, "boot_s", 0.0) + 0.005)
            arm.host_write(Command((100, 100, 100, 100), (50, 50, 50, 50)).encode())
            await asyncio.sleep(seconds)
            errors = [t.exception() for b in arm.boards
                      if (t := b._task) is not None and t.done() and not t.cancelled()]
            for exc in errors:
                if exc is not None:
                    raise exc
        finally:
            await arm.close()

    run_virtual(main)


def rejected_or_runs(text: str, field: str) -> None:
    """Either a SettingsError naming ``field`` or an emulator that boots and runs (either fix is
    fine: reject the value, or make the emulator cope with it)."""
    try:
        loaded = load(text)
    except SettingsError as exc:
        assert _names(exc, field), str(exc)
        return
    run(*loaded)


def rejected(text: str, field: str) -> None:
    with pytest.raises(SettingsError) as info:
        load(text)
    assert _names(info.value, field), str(info.value)


def _names(exc: SettingsError, field: str) -> bool:
    """The error names ``field`` (or a key inside it, e.g. ``emulator.effects.noise_rate_hz``)."""
    return exc.field == field or exc.field.startswith(field + ".")


# --- drivers/model/settings.py: RobotSettings.from_mapping
# ----------------------------------------------
@pytest.mark.parametrize(("text", "field"), [
    ("[geometry]\nd4_m = 1" + "0" * 309, "geometry.d4_m"),
    ("[joints.j2]\nmicrosteps = 1" + "0" * 309, "joints.j2.microsteps"),
    ("[serial]\nbaudrate = -1" + "0" * 400, "serial.baudrate"),
], ids=["geometry", "joint", "serial"])
def test_huge_integer_in_a_robot_setting(text: str, field: str) -> None:
    # TOML says 64-bit integers, but tomllib returns any integer it reads.
    rejected(text, field)


@pytest.mark.parametrize("value", ["0", "0.0", "-0.0", "5e-324", "1e-310"])
def test_zero_or_subnormal_step_angle(value: str) -> None:
    rejected(f"[joints.j3]\nstep_angle_deg = {value}", "joints.j3.step_angle_deg")


def test_step_angle_giving_zero_steps_per_revolution() -> None:
    rejected_or_runs("[joints.j3]\nstep_angle_deg = 1e12", "joints.j3.step_angle_deg")


@pytest.mark.parametrize(("text", "field"), [
    ("[joints.j1]\ngear_ratio = 1e306", "joints.j1"),
    ("[joints.j1]\ngear_ratio = 1" + "0" * 306, "joints.j1"),
    ("[joints.j3]\ngear_ratio = 1" + "0" * 305 + "\nencoder_counts_per_motor_rev = 1" + "0" * 300,
     "joints.j3"),
], ids=["float", "int", "int-encoder"])
def test_gear_ratio_whose_steps_per_radian_overflow(text: str, field: str) -> None:
    rejected_or_runs(text, field)


# --- fakes/firmware/emulator_settings.py: emulator_settings
# ------------------------------------------------
def test_huge_integer_in_an_emulator_setting() -> None:
    rejected("[emulator]\nloop_overhead_s = 1" + "0" * 309, "emulator.loop_overhead_s")


@pytest.mark.parametrize("text", [
    "[emulator]\nseed = -384",
    "[emulator]\nseed = 0.5\n[emulator.effects]\nmiss_probability = 0.1",
], ids=["negative", "fractional"])
def test_emulator_seed_that_no_board_accepts(text: str) -> None:
    rejected_or_runs(text, "emulator.seed")


@pytest.mark.parametrize("value", ["3", "-1000", "2.5"])
def test_eeprom_cells_the_record_does_not_fit(value: str) -> None:
    rejected_or_runs(f"[emulator]\neeprom_cells = {value}", "emulator.eeprom_cells")


@pytest.mark.parametrize("text", ["[emulator.effects]\nnoise_rate_hz = 5e-324",
                                  "[emulator.physics]\nnoise_per_count = 5e-324"],
                         ids=["merged key", "per count"])
def test_subnormal_encoder_noise(text: str) -> None:
    """A noise too small to give a step any chance of a spurious count draws none (the geometric
    draw takes no chance of 0); the merged ``noise_rate_hz`` is refused, naming it."""
    rejected_or_runs(text, text.split("]")[0][1:])


def test_eeprom_cells_that_exhaust_memory() -> None:
    rejected("[emulator]\neeprom_cells = 1_000_000_000_000", "emulator.eeprom_cells")


# --- fakes/firmware/faults.py: parse_faults
# ----------------------------------------------------------------
@pytest.mark.parametrize(("line", "field"), [
    ("probability = 'high'", "faults[0].probability"),
    ("count = 'many'", "faults[0].count"),
    ("count = [1]", "faults[0].count"),
])
def test_non_numeric_fault_probability_or_count(line: str, field: str) -> None:
    rejected(f"[[faults]]\nkind = 'uart_insert'\nat_s = 0\n{line}", field)


def test_fractional_fault_count() -> None:
    rejected_or_runs("[[faults]]\nkind = 'uart_insert'\nat_s = 0\ndirection = 'to_robot'\n"
                     "count = 2.5", "faults[0].count")


def test_fault_count_that_exhausts_memory() -> None:
    rejected("[[faults]]\nkind = 'uart_insert'\nat_s = 0\ncount = 9223372036854775807",
             "faults[0].count")


@pytest.mark.parametrize("name", ["at_s", "duration_s", "delay_s"])
def test_nan_fault_time(name: str) -> None:
    timing = "" if name == "at_s" else "at_s = 1\n"
    rejected(f"[[faults]]\nkind = 'power_cut'\n{timing}{name} = nan", f"faults[0].{name}")


@pytest.mark.parametrize("value", ["0", "0.5", "-3", "''"])
def test_after_frames_that_is_never_reached(value: str) -> None:
    rejected(f"[[faults]]\nkind = 'power_cut'\nafter_frames = {value}", "faults[0].after_frames")


@pytest.mark.parametrize(("line", "field"), [("probability = true", "faults[0].probability"),
                                             ("count = true", "faults[0].count")])
def test_boolean_fault_probability_or_count(line: str, field: str) -> None:
    rejected(f"[[faults]]\nkind = 'uart_insert'\nat_s = 0\n{line}", field)


def test_float_fault_joint() -> None:
    rejected_or_runs("[[faults]]\nkind = 'stall'\nat_s = 0\njoint = 2.0", "faults[0].joint")


# --- fixed while the campaign ran (commit b29e4c9): keep them fixed -------------------------------
@pytest.mark.parametrize("value", ['"uart_insert"', "1", "[-1000, -1000]"])
def test_emulator_section_that_is_not_a_table(value: str) -> None:
    # was ValueError/TypeError@fakes/firmware/emulator_settings.py:57 (dict() of a str, int or list)
    rejected(f"emulator = {value}", "emulator")


def test_empty_top_level_key_is_named() -> None:
    # was a SettingsError with field "" (found by the fuzz_config.py field check)
    with pytest.raises(SettingsError) as info:
        load('"" = 1')
    assert info.value.field == '""'
