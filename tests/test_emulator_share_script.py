"""``scripts/emulator_share.py``: a trial's emulator replayed without the bench, to split the
trial's CPU between the emulated arm and the bench."""

from __future__ import annotations

import asyncio
import re
import subprocess
import sys
from types import ModuleType
from typing import Any

import pytest
from script_loader import SCRIPTS, load_script

from armbench.drivers.model.protocol import Command
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.firmware.eeprom import Eeprom

SCRIPT = SCRIPTS / "emulator_share.py"


def _script() -> ModuleType:
    return load_script("emulator_share")


async def _session(emulator: ArmEmulator) -> None:
    """What a trial does to its emulator: a move, a power cut and restore, the EEPROMs erased
    while the power is off (a re-referencing), another move, a board reset."""
    await emulator.start()
    emulator.attach_host(lambda data: None)
    await asyncio.sleep(0.5)  # booted
    emulator.host_write(Command.from_rad([0.4, -0.3, 0.5, 0.2], 80).encode())
    await asyncio.sleep(1.7)
    emulator.power_off()
    for eeprom in emulator.eeproms:
        eeprom.erase()
    await asyncio.sleep(0.5)
    emulator.power_on()
    await asyncio.sleep(2.0)
    emulator.host_write(Command.from_rad([-0.2, 0.1, -0.4, 0.0], 99).encode())
    await asyncio.sleep(0.9)
    emulator.reset_board(3)
    await asyncio.sleep(1.5)
    await emulator.close()


def _watched_session(script: ModuleType) -> Any:
    with script.watching("session") as watched:
        run_virtual(_session(ArmEmulator()))
    assert len(watched) == 1
    return watched[0]


def test_a_replayed_emulator_does_the_trials_work_again() -> None:
    script = _script()
    w = _watched_session(script)
    assert ArmEmulator.__init__.__qualname__ == "ArmEmulator.__init__"  # the class restored
    assert Eeprom.erase.__qualname__ == "Eeprom.erase"
    names = [name for _, name, _, _ in w.calls]
    assert names == ["host_write", "power_off", *["erase"] * 4, "power_on", "host_write",
                     "reset_board"]
    assert w.group == "session" and w.end_s - w.start_s == pytest.approx(7.1)
    assert w.stats["commands"] == 2 and w.cpu_s > 0
    cpu_s, faithful = script.replay(w, ArmEmulator)
    assert faithful and cpu_s > 0


@pytest.mark.parametrize("left_out", ["host_write", "erase", "reset_board"])
def test_a_replay_missing_one_action_is_not_faithful(left_out: str) -> None:
    script = _script()
    w = _watched_session(script)
    k = next(i for i, call in enumerate(w.calls) if call[1] == left_out)
    del w.calls[k]
    _, faithful = script.replay(w, ArmEmulator)
    assert not faithful


@pytest.mark.slow
def test_the_trials_of_a_run_are_split_between_the_emulator_and_the_bench() -> None:
    done = subprocess.run([sys.executable, str(SCRIPT), "accuracy", "startup-recovery"],
                          capture_output=True, text=True, timeout=600, check=True)
    rows = {m[0]: m[1:] for m in re.findall(
        r"^(\S+)\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+"
        r"(\d+)/(\d+)$", done.stdout, re.MULTILINE)}
    assert set(rows) == {"accuracy", "startup-recovery/cut", "startup-recovery/wear", "all"}
    trials, robot_s, trial_cpu_s, emulator_cpu_s, replay_cpu_s, _, faithful, of = rows["all"]
    assert int(trials) == int(of) == int(faithful) == 6 + 21  # one emulator a trial
    assert float(robot_s) > 100
    # the trial's CPU holds its emulator's time, which holds the arm's own work and the bench's
    assert float(trial_cpu_s) >= float(emulator_cpu_s) > float(replay_cpu_s) > 0
    assert "did not end as" not in done.stdout
