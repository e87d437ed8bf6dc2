"""The firmware in the loop: the reference firmware compiled with avr-gcc and run on four
simulated ATmega328P (simavr) by the harness. Nothing is mocked: the real toolchain builds it and
the real harness runs it (CI installs gcc-avr, avr-libc, simavr, libsimavr-dev). Skipped, with
the reason, only where that toolchain is absent."""

from __future__ import annotations

import itertools
import json
import math
import re
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest

from armbench.drivers.model.protocol import Command, Framer, Reply
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.avr import harness as avr
from armbench.fakes.avr.harness import (
    FIRMWARE_SOURCE,
    HARNESS_NAME,
    FirmwareError,
    board_specs,
    build,
    find_images,
)

HAVE_TOOLCHAIN = all(shutil.which(t) for t in ("avr-gcc", "avr-objcopy", "avr-nm", "cc")) and \
    Path("/usr/include/simavr/sim_avr.h").exists()
needs_toolchain = pytest.mark.skipif(
    not HAVE_TOOLCHAIN, reason="avr-gcc/simavr absent (apt-get install gcc-avr avr-libc simavr "
                               "libsimavr-dev)")

CYCLE_BUDGET = 1280  # 80 µs at 16 MHz


Timed = list[tuple[float, Reply]]


def run_harness(script: list[tuple[float, str]], seconds: float, tmp_path: Path,
                images: list[Path] | None = None) -> tuple[Timed, dict[str, Any]]:
    """Run the harness at full speed with ``script`` on joint 1's UART; replies and figures."""
    folder = build()
    script_file, log_file = tmp_path / "script.txt", tmp_path / "replies.txt"
    script_file.write_text("".join(f"{t} {text}\n" for t, text in script))
    args = [str(folder / HARNESS_NAME), "--speed", "max", "--seconds", str(seconds),
            "--script", str(script_file), "--reply-log", str(log_file)]
    for spec in board_specs(RobotSettings(), images or find_images(None)):
        args += ["--board", spec]
    out = subprocess.run(args, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                         check=True, timeout=300).stdout
    stats = json.loads(next(line for line in out.splitlines() if line.startswith("stats "))[6:])
    framer = Framer("reply")
    replies: list[tuple[float, Reply]] = []
    for line in log_file.read_text().splitlines():
        t, _, text = line.partition(" ")
        replies.extend((float(t), r) for r in framer.feed(text.encode()) if isinstance(r, Reply))
    return replies, stats


def test_joint_constants_are_the_settings() -> None:
    """firmware/joints.h's integer constants are those the default robot settings give."""
    text = (FIRMWARE_SOURCE / "joints.h").read_text()
    blocks = re.split(r"#(?:el)?if JOINT == (\d)", text)
    robot = RobotSettings()
    tau = 2 * math.pi * 1e4
    assert f"TAU_TICKS_Q16 {round(tau * 2**16)}LL" in text
    assert f"TAU_TICKS_Q15 {round(tau * 2**15)}UL" in text
    for n, joint in enumerate(robot.joints, 1):
        block = blocks[blocks.index(str(n)) + 1]
        cpr = joint.counts_per_rad
        mid = 0.5 * (joint.lower_rad + joint.upper_rad)
        wrap = math.ceil((mid + math.pi) * 1e4 + 1e-9)
        assert f"TICKS_PER_COUNT_Q31 {round(1e4 / cpr * 2**31)}UL" in block
        assert f"COUNTS_PER_TICK_Q24 {round(cpr / 1e4 * 2**24)}L" in block
        assert f"WRAP_TICKS {wrap}U" in block
        assert f"HALL_COUNT {round(joint.hall_rad * cpr)}L" in block
        assert f"COUNTS_PER_TURN {round(2 * math.pi * cpr)}L" in block
        if joint.i2c_address is not None:
            assert f"I2C_ADDRESS {joint.i2c_address:#04x}" in block


def test_missing_toolchain_names_the_debian_packages(monkeypatch: pytest.MonkeyPatch,
                                                      tmp_path: Path) -> None:
    monkeypatch.setattr(shutil, "which", lambda name: None)  # the module's look-up of the tools
    with pytest.raises(FirmwareError, match=r"gcc-avr avr-libc simavr libsimavr-dev"):
        build(out=tmp_path)


def test_bad_firmware_names_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(FirmwareError, match="not a folder"):
        find_images(tmp_path / "nothing.hex")
    with pytest.raises(FirmwareError, match=r"no joint1\.elf or joint1\.hex"):
        find_images(tmp_path)
    with pytest.raises(FirmwareError, match="does not exist"):
        find_images(str(tmp_path / "joint{n}.hex"))


@pytest.mark.skipif(sys.platform == "win32", reason="the build lock is POSIX flock")
def test_builds_of_one_folder_at_once_take_turns(monkeypatch: pytest.MonkeyPatch,
                                                  tmp_path: Path) -> None:
    """Two builds of one folder at the same time (parallel test workers, two runs): one
    compiles while the other waits, then finds the images complete and compiles nothing, so
    no image is rewritten under a harness running it. The compiler is replaced by a slow
    stand-in that records how many compile at once (the lock is what is tested)."""
    active: list[int] = []
    commands: list[str] = []
    guard = threading.Lock()

    def slow_tool(cmd: Sequence[str], cwd: Path) -> None:
        with guard:
            active.append(active[-1] + 1 if active else 1)
            commands.append(cmd[0])
        time.sleep(0.02)
        with guard:
            active.append(active[-1] - 1)

    monkeypatch.setattr(avr, "_require_toolchain", lambda: None)
    monkeypatch.setattr(avr, "_run", slow_tool)
    out = tmp_path / "fw"
    builds = [threading.Thread(target=build, kwargs={"out": out}) for _ in range(2)]
    for t in builds:
        t.start()
    for t in builds:
        t.join(30)
    assert max(active) == 1, active
    assert commands == ["avr-gcc", "avr-objcopy"] * 4 + ["cc"]
    assert (out / ".complete").is_file()


@needs_toolchain
def test_build_goes_to_its_folder_not_the_sources(tmp_path: Path) -> None:
    before = sorted(p.name for p in FIRMWARE_SOURCE.rglob("*"))
    out = build(out=tmp_path / "fw", force=True)
    names = {p.name for p in out.iterdir()}
    assert {f"joint{n}.{ext}" for n in range(1, 5) for ext in ("elf", "hex")} <= names
    assert HARNESS_NAME in names
    assert sorted(p.name for p in FIRMWARE_SOURCE.rglob("*")) == before


@needs_toolchain
def test_firmware_moves_every_joint_to_the_command(tmp_path: Path) -> None:
    """Algorithm 1 and 2 over the routed I²C bus: a command reaches all four joints, each stops
    within its deadband (1 count) of the target, and the master replies every loop."""
    target = [0.25, 0.3, -0.2, 0.35]
    frame = Command.from_rad(target, 99).encode().decode()
    replies, stats = run_harness([(0.2, frame)], 2.0, tmp_path)
    robot = RobotSettings()
    final = replies[-1][1]
    for j, joint in enumerate(robot.joints):
        want = round(target[j] * joint.counts_per_rad)
        got = round(((final[j] / 1e4 + math.pi) % (2 * math.pi) - math.pi) * joint.counts_per_rad)
        assert abs(got - want) <= 2, (j + 1, got, want)  # deadband 1 + 1 for tick rounding
    periods = [b[0] - a[0] for a, b in itertools.pairwise(replies) if a[0] > 0.5]
    assert min(periods) > 2.4e-3
    assert max(periods) < 20e-3  # EEPROM records stall a loop
    assert stats["i2c"]["naks"] == 0
    assert stats["boards"][0]["fw"]["i2c_errors"] == 0
    assert stats["i2c"]["transactions"] >= 6 * (len(replies) - 1)


@needs_toolchain
def test_control_interrupt_fits_its_80us_budget(tmp_path: Path) -> None:
    """The measured worst case of the 80 µs interrupt, every board, arm moving: < 1 280
    cycles; and it ran once per 1 280 cycles."""
    frame = Command.from_rad([1.0, 0.8, -0.9, 1.2], 99).encode().decode()
    _, stats = run_harness([(0.2, frame)], 1.0, tmp_path)
    for board in stats["boards"]:
        assert 0 < board["isr_worst_cycles"] < CYCLE_BUDGET
        assert board["steps"] > 1000
        assert abs(board["isr_count"] - (1.0 - 0.1) * 16e6 / CYCLE_BUDGET) < 20
    assert 2.9e3 < stats["uart"]["period_us_mean"] < 3.5e3


@needs_toolchain
def test_a_labs_hex_images_run_the_same_way(tmp_path: Path) -> None:
    """Intel hex images named with {n} (no symbols: no firmware counters) run in the harness."""
    folder = build()
    for n in range(1, 5):
        shutil.copy(folder / f"joint{n}.hex", tmp_path / f"lab{n}.hex")
    images = find_images(str(tmp_path / "lab{n}.hex"))
    frame = Command.from_rad([0.1, 0.1, 0.1, 0.1], 99).encode().decode()
    replies, stats = run_harness([(0.2, frame)], 1.0, tmp_path, images)
    assert all(abs(ticks - 1000) <= 2 for ticks in replies[-1][1])  # deadband: 1 count
    assert "fw" not in stats["boards"][0]
