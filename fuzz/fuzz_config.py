"""atheris harness: TOML text → robot settings, emulator settings and fault lists.

The input is UTF-8 TOML text (other bytes are skipped), parsed with ``tomllib.loads``
(``TOMLDecodeError`` is skipped: not ours), then handed to what ``load_settings``,
``emulator_settings`` and ``load_faults`` do with a parsed file. An input starting with a NUL
byte is instead a *recipe*: ``recipe_to_toml`` builds a TOML document from the settings' own
section and key names with values of every TOML type (huge integers, NaN, infinities, strings,
arrays, inline tables), which random byte mutations of text rarely reach. Either way:

* ``RobotSettings.from_mapping(doc)``;
* ``emulator_settings(robot)`` — with the robot just loaded, or, when the robot was rejected,
  a default robot carrying the file's ``[emulator]`` table (so that table is fuzzed on its own);
* ``faults_from_settings(robot)`` (``parse_faults`` of the ``[[faults]]`` array) — again with a
  default robot carrying the file's ``faults`` when the robot was rejected.

Invariants (any violation is a crash):

* only ``SettingsError`` escapes, its ``field`` a non-empty dotted path that starts the message;
* accepted robot settings survive their own record: ``from_mapping(robot.to_mapping())`` loads and
  gives the same robot (angles within 1e-9 rad: the file spells degrees);
* accepted faults are usable: no NaN times, whole-number ``count``/``joint``/``after_frames``
  (``after_frames`` >= 1: frames are counted from 1), a numeric ``probability``;
* accepted settings run: with robot, emulator settings and faults all accepted, an
  ``ArmEmulator`` is built, started on virtual time, booted, sent one command, run 20 ms and closed
  without an exception in any board task. Sizes that would exhaust memory (EEPROM cells, inserted
  byte counts > 2**20) are reported as findings instead of being allocated.

Run: ``python fuzz/fuzz_config.py -max_total_time=60 -rss_limit_mb=512 fuzz/corpus/config``
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Sequence
from typing import Any

import atheris
from _harness import fuzz_main

with atheris.instrument_imports(include=["tomllib", "drivers", "fakes"]):
    import tomllib

    from armbench.drivers.model.protocol import Command
    from armbench.drivers.model.settings import RobotSettings, SettingsError
    from armbench.fakes.clock.vclock import run_virtual
    from armbench.fakes.firmware.arm_emulator import ArmEmulator
    from armbench.fakes.firmware.emulator_settings import EmulatorSettings, emulator_settings
    from armbench.fakes.firmware.faults import Fault, faults_from_settings

#: Anything the emulator would allocate per unit beyond this is reported instead of run.
MAX_ALLOCATION = 1 << 20
RUN_S = 0.02


def _error_ok(exc: SettingsError) -> None:
    # (the field may be "": an unknown key spelled "" = 1 at the top level is named as it is)
    assert isinstance(exc.field, str), repr(exc.field)
    assert str(exc).startswith(exc.field), str(exc)


def _round_trip(robot: RobotSettings) -> None:
    try:
        again = RobotSettings.from_mapping(robot.to_mapping())
    except SettingsError as exc:
        raise AssertionError(f"accepted settings do not load back from to_mapping(): {exc}") \
            from exc
    assert again.geometry == robot.geometry and again.serial == robot.serial
    for a, b in zip(again.joints, robot.joints, strict=True):
        for name in ("lower_rad", "upper_rad", "offset_rad", "hall_rad"):
            assert math.isclose(getattr(a, name), getattr(b, name), rel_tol=1e-12, abs_tol=1e-9), \
                (a.name, name, getattr(a, name), getattr(b, name))
        for name in ("gear_ratio", "sign", "step_angle_deg", "microsteps",
                     "encoder_counts_per_motor_rev", "i2c_address"):
            assert getattr(a, name) == getattr(b, name), (a.name, name)


def _accepted_fault(f: Fault) -> None:
    """What an accepted fault must be for the injector to use it (each its own assert, so each
    gap has its own crash signature)."""
    times = [getattr(f, n) for n in ("at_s", "duration_s", "delay_s")]
    assert not any(isinstance(t, float) and math.isnan(t) for t in times), f"NaN time: {f}"
    assert f.after_frames is None or type(f.after_frames) is int, \
        f"after_frames = {f.after_frames!r} accepted: not a frame count"
    assert f.after_frames is None or f.after_frames >= 1, \
        f"after_frames = {f.after_frames!r} accepted: frames count from 1, never reached"
    assert type(f.count) is int, f"count = {f.count!r} accepted: the injector needs an int"
    assert f.joint is None or type(f.joint) is int, f"joint = {f.joint!r} accepted: not an index"
    assert type(f.probability) in (int, float), f"probability = {f.probability!r} accepted"


def _check_sizes(emu: EmulatorSettings, faults: Sequence[Fault]) -> None:
    assert emu.eeprom_cells <= MAX_ALLOCATION, \
        f"emulator.eeprom_cells = {emu.eeprom_cells} accepted: each board allocates that many"
    for f in faults:
        if f.kind == "uart_insert":
            assert f.count <= MAX_ALLOCATION, \
                f"uart_insert count = {f.count} accepted: that many random bytes per chunk"


def run_emulator(robot: RobotSettings, emu: EmulatorSettings, faults: Sequence[Fault]) -> None:
    """Build, start, command, run ``RUN_S`` of virtual time and close; re-raise task failures."""
    _check_sizes(emu, faults)
    arm = ArmEmulator(robot, emu, faults)
    replies: list[bytes] = []
    arm.attach_host(replies.append)
    command = Command((100, 100, 100, 100), (50, 50, 50, 50)).encode()

    async def main() -> None:
        await arm.start()
        try:
            await asyncio.sleep(getattr(emu, "boot_s", 0.0) + 0.005)  # boards boot first
            arm.host_write(command)
            await asyncio.sleep(RUN_S)
            errors = [t.exception() for b in arm.boards
                      if (t := b._task) is not None and t.done() and not t.cancelled()]
            for exc in errors:  # all retrieved: no "exception never retrieved" noise
                if exc is not None:
                    raise exc
        finally:
            await arm.close()

    run_virtual(main)


def check(text: str) -> None:
    """All invariants for one TOML document."""
    try:
        doc: dict[str, Any] = tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        return
    robot: RobotSettings | None = None
    try:
        robot = RobotSettings.from_mapping(doc)
    except SettingsError as exc:
        _error_ok(exc)
    if robot is not None:
        _round_trip(robot)

    emu: EmulatorSettings | None = None
    emu_robot = robot if robot is not None else RobotSettings(
        sections={"emulator": doc["emulator"]} if "emulator" in doc else {})
    try:
        emu = emulator_settings(emu_robot)
    except SettingsError as exc:
        _error_ok(exc)

    faults: list[Fault] | None = None
    faults_robot = robot if robot is not None else RobotSettings(
        sections={"faults": doc["faults"]} if "faults" in doc else {})
    try:
        faults = faults_from_settings(faults_robot)
    except SettingsError as exc:
        _error_ok(exc)
    for f in faults or ():
        _accepted_fault(f)

    if robot is not None and emu is not None and faults is not None:
        run_emulator(robot, emu, faults)


# --- structured mode: bytes → a TOML document built from the settings' own keys ---------------
_SECTIONS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("[geometry]", ("d1_m", "d2_m", "a2_m", "a3_m", "d4_m")),
    ("[serial]", ("baudrate", "bytesize", "parity", "stopbits")),
    *((f"[joints.j{n}]", ("gear_ratio", "lower_deg", "upper_deg", "offset_deg", "sign",
                           "hall_deg", "step_angle_deg", "microsteps",
                           "encoder_counts_per_motor_rev", "i2c_address")) for n in range(1, 5)),
    ("[emulator]", ("uart_receive", "i2c_hz", "rx_buffer_bytes", "tx_buffer_bytes",
                    "loop_overhead_s", "reply_line_end", "deadband_counts", "recovery_duty",
                    "eeprom_write_s_per_byte", "eeprom_cells", "seed")),
    ("[emulator.effects]", ("miss_probability", "miss_above_duty")),
    ("[emulator.physics]", ("payload_kg", "noise_per_count", "gravity_m_s2")),
    ("[emulator.physics.j2]", ("backlash_deg", "stiffness_nm_per_rad", "pullout_nm", "loss_law")),
    ("[[faults]]", ("kind", "at_s", "after_frames", "duration_s", "joint", "probability", "count",
                    "delay_s", "direction")),
    ("[bench]", ("name", "speeds")),
)
_WORDS = ("N", "E", "O", "M", "S", "X", "polling", "blocking", "", "\n", "\r\n", "to_host",
          "to_robot", "uart_corrupt", "uart_drop", "uart_insert", "split_write", "delay_write",
          "i2c_nak", "i2c_bus_error", "slave_reset", "stall", "power_cut", "power_restore", "j1")
_SPECIAL = ("0", "0.0", "-0.0", "1", "-1", "2", "1.5", "0.5", "1e-320", "5e-324", "1e308",
            "-1e308", "360", "0x08", "0x77", "0x78", "4294967296", "2147483647", "inf", "-inf",
            "nan", "100_000", "400_000", "99", "100", "1024", "4", "5")


def _value(fdp: atheris.FuzzedDataProvider, depth: int) -> str:
    kind = fdp.ConsumeIntInRange(0, 9 if depth < 2 else 7)
    if kind == 0:
        return str(fdp.ConsumeIntInRange(-1000, 1000))
    if kind == 1:
        return str(fdp.ConsumeIntInRange(-(2**63), 2**63 - 1))
    if kind == 2:
        digits: int = fdp.ConsumeIntInRange(19, 400)
        return "9" * digits  # TOML says 64 bits; tomllib keeps any integer
    if kind == 3:
        x: float = fdp.ConsumeFloat()
        return "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf") if math.isinf(x) \
            else repr(x)
    if kind == 4:
        return _SPECIAL[fdp.ConsumeIntInRange(0, len(_SPECIAL) - 1)]
    if kind == 5:
        return "true" if fdp.ConsumeBool() else "false"
    if kind == 6:
        return f'"{_WORDS[fdp.ConsumeIntInRange(0, len(_WORDS) - 1)]}"'
    if kind == 7:
        return "1979-05-27T07:32:00Z"
    if kind == 8:
        return "[" + ", ".join(_value(fdp, depth + 1)
                               for _ in range(fdp.ConsumeIntInRange(0, 3))) + "]"
    keys = ("kind", "at_s", "joint", "x", "uart_receive", "d1_m")
    pairs = {keys[fdp.ConsumeIntInRange(0, len(keys) - 1)]: _value(fdp, depth + 1)
             for _ in range(fdp.ConsumeIntInRange(0, 3))}
    return "{" + ", ".join(f"{k} = {v}" for k, v in pairs.items()) + "}"


def recipe_to_toml(recipe: bytes) -> str:
    """A TOML document of up to 8 sections of known keys (sometimes an unknown one) with values
    of every TOML type, chosen by ``recipe``: structure the byte mutations cannot easily reach."""
    fdp = atheris.FuzzedDataProvider(recipe)
    top: dict[str, str] = {}
    sections: dict[str, dict[str, str]] = {}
    faults: list[dict[str, str]] = []
    for _ in range(fdp.ConsumeIntInRange(0, 8)):
        which = fdp.ConsumeIntInRange(0, len(_SECTIONS))
        if which == len(_SECTIONS):  # a top-level key: an extension table given as a scalar
            top[("emulator", "faults", "bench", "joints", "colour")[
                fdp.ConsumeIntInRange(0, 4)]] = _value(fdp, 1)
            continue
        header, keys = _SECTIONS[which]
        table: dict[str, str] = {}
        for _ in range(fdp.ConsumeIntInRange(0, 5)):
            k = fdp.ConsumeIntInRange(0, len(keys))
            table[keys[k] if k < len(keys) else "colour"] = _value(fdp, 0)
        if header == "[[faults]]":
            faults.append(table)
        else:
            sections.setdefault(header, {}).update(table)
    lines = [f"{k} = {v}" for k, v in top.items()]
    for header, table in sections.items():
        lines += ["", header, *(f"{k} = {v}" for k, v in table.items())]
    for table in faults:
        lines += ["", "[[faults]]", *(f"{k} = {v}" for k, v in table.items())]
    return "\n".join(lines) + "\n"


def test_one_input(data: bytes) -> None:
    """Text mode: the input is TOML text. Structured mode (first byte NUL, which TOML text never
    holds): the rest is a recipe for :func:`recipe_to_toml`."""
    if data[:1] == b"\0":
        text = recipe_to_toml(data[1:])
    else:
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            return
    try:
        check(text)
    except Exception as exc:
        exc.add_note(f"TOML text:\n{text}")
        raise


if __name__ == "__main__":
    fuzz_main("config", test_one_input)
