"""Both limits of every joint are within the emulated arm's reach (``docs/emulator.md``,
Hard limits): the end stops lie 1° beyond the configured limits, so the Hall sensor's error, which
shifts what the firmware counts against the motor, never puts a stop inside a limit.

Before: joint 1's end stop sat on its limit and its Hall sensor 0.02° off, so the firmware
counted the stop at +2.4431 rad and ``armbench move --port fake:// 2.4434 0 0 0`` timed out.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from armbench.cli.main import main
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.errors import MoveTimeoutError
from armbench.drivers.model.protocol import TICKS_PER_RAD
from armbench.drivers.model.settings import RobotSettings, load_settings
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.twin.physics import END_STOP_MARGIN_RAD


def _wire_limits(settings: RobotSettings) -> list[tuple[float, float]]:
    """Each joint's limits as the wire can aim at them: the last whole tick inside each."""
    return [(math.ceil(j.lower_rad * TICKS_PER_RAD) / TICKS_PER_RAD,
             math.floor(j.upper_rad * TICKS_PER_RAD) / TICKS_PER_RAD) for j in settings.joints]


async def _visit_limits(port: str, settings: RobotSettings) -> list[tuple[int, float, float]]:
    """Move each joint to its lower, then its upper limit (the others at 0); (joint, target,
    reached) of every move that did not arrive within the default tolerance and time."""
    missed = []
    async with Arm.connect(port, settings) as arm:
        for k, limits in enumerate(_wire_limits(settings)):
            for target in limits:
                q = [0.0, 0.0, 0.0, 0.0]
                q[k] = target
                try:
                    await arm.move_joints(q)
                except MoveTimeoutError:  # the stop short of the limit, as before
                    missed.append((k + 1, target, arm.state.q_rad[k]))
    return missed


def _hall_errors(tmp_path: Path, deg: float) -> Path:
    """Robot settings whose four Hall sensors are all ``deg`` off (the bound a settings file
    may give is ±0.5°)."""
    path = tmp_path / f"hall{'-' if deg < 0 else ''}{abs(deg):g}.toml"  # no + in a URL
    path.write_text("".join(f"[emulator.physics.j{n}]\nhall_error_deg = {deg}\n"
                            for n in range(1, 5)))
    return path


def test_every_limit_of_every_joint_is_reached() -> None:
    assert run_virtual(_visit_limits("fake://", RobotSettings())) == []


@pytest.mark.parametrize("deg", [0.5, -0.5])
def test_every_limit_is_reached_whatever_the_hall_error(tmp_path: Path, deg: float) -> None:
    path = _hall_errors(tmp_path, deg)
    assert math.radians(abs(deg)) < END_STOP_MARGIN_RAD
    assert run_virtual(_visit_limits(f"fake://?settings={path}", load_settings(path))) == []


def test_move_to_joint_1s_upper_limit_on_the_command_line(capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    """The case as it was reported (real time would take 5 s; the command runs fake:// on
    virtual time)."""
    assert main(["move", "--port", "fake://", "2.4434", "0", "0", "0"]) == 0
    assert "arrived" in capsys.readouterr().out
