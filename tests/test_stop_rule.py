"""The firmware's stop rule (``emulator.stop_rule``): a setting of the emulator, chosen by
calibrate from where the approaches came to rest, and the twin's counters at the start of a
replay (a new arm's, or as the Hall sensors set them)."""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import pytest

from armbench.bench.calibrate import calibrate_port
from armbench.bench.calibrate.model import Approach, Observations
from armbench.bench.calibrate.stop_rule import STOP_RULE_KEY, choose_stop_rule
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.firmware.emulator_settings import emulator_settings


def _robot(**emulator: object) -> RobotSettings:
    return RobotSettings.from_mapping({"emulator": dict(emulator)})


def test_the_setting_is_read_and_checked() -> None:
    assert emulator_settings(RobotSettings()).stop_rule == "window"
    assert emulator_settings(_robot(stop_rule="reach")).stop_rule == "reach"
    with pytest.raises(SettingsError, match=r"emulator\.stop_rule.*'exact'"):
        emulator_settings(_robot(stop_rule="exact"))
    with pytest.raises(SettingsError, match=r"emulator\.stop_rule"):
        emulator_settings(_robot(stop_rule=1))


@pytest.mark.parametrize("rule", ["window", "reach"])
@pytest.mark.parametrize("hall_deg", [0.025, -0.08])
def test_calibrate_finds_the_rule_of_the_arm(rule: str, hall_deg: float, tmp_path: Path) -> None:
    """An emulated arm of either rule, its Hall sensors off by ``hall_deg``, calibrated from the
    default settings (``window``): its approaches' rests name its rule, written to the settings
    only where it differs; so they do without the Hall errors the emulator's truth identifies
    (over a port: each joint's error unknown within its range)."""
    arm = tmp_path / "arm.toml"
    arm.write_text(f'[emulator]\nstop_rule = "{rule}"\n'
                   + "".join(f"[emulator.physics.j{n}]\nhall_error_deg = {hall_deg}\n"
                             for n in range(1, 5)))
    out = tmp_path / "fitted.toml"
    result = run_virtual(calibrate_port(f"fake://?settings={arm}", RobotSettings(), out,
                                        budget_s=60))
    fitted = {f.key: f for f in result.fitted}[STOP_RULE_KEY]
    assert fitted.choice == rule
    assert fitted.identified == (rule == "reach"), fitted.reason
    assert emulator_settings(result.settings).stop_rule == rule
    assert "approaches rested" in fitted.reason
    blind = choose_stop_rule(result.observations, RobotSettings())
    assert (blind.choice, blind.identified) == (fitted.choice, fitted.identified), blind.reason


def test_no_approaches_keep_the_prior() -> None:
    fitted = choose_stop_rule(Observations("nothing"), _robot(stop_rule="reach"))
    assert (fitted.choice, fitted.identified) == ("reach", False)
    assert "no approaches" in fitted.reason


def test_rests_that_no_rule_explains_keep_the_prior() -> None:
    """Rests 3 ticks off the target every time: neither rule says so, the prior stays."""
    obs = Observations("odd", approaches=[
        Approach(1, 0.0, d, 99, [3e-4, 0.0, 0.0, 0.0]) for d in (1, -1) * 10])
    fitted = choose_stop_rule(obs, RobotSettings())
    assert (fitted.choice, fitted.identified) == ("window", False), fitted.reason


def _truth_minus_belief(resumed: bool | tuple[bool, ...]) -> tuple[float, float]:
    """Joint 1's true angle minus its counter's (rad) of a twin with its Hall sensor 0.2° off,
    at power-up at +0.05 rad and after a move across the sensor (at 0) to −0.05 rad and back."""
    robot = _robot(physics={"j1": {"hall_error_deg": 0.2, "backlash_deg": 0.0,
                                   "stick_deg": 0.0}})

    async def body() -> tuple[float, float]:
        emulator = ArmEmulator(robot, initial_q_rad=[0.05, 0.0, 0.0, 0.0], resumed=resumed)
        await emulator.start()
        await asyncio.sleep(0.5)
        board = emulator.master
        first = board.true_rad() - board.counter_rad()
        for target in (-0.05, 0.05):
            board.apply_reference(asyncio.get_running_loop().time(),
                                  round(target % math.tau * 1e4), 99)
            await asyncio.sleep(3.0)
        back = board.true_rad() - board.counter_rad()
        await emulator.close()
        return first, back

    return run_virtual(body())


def test_a_resumed_twin_agrees_with_its_hall_sensor() -> None:
    """A new arm's counter is true at power-up and takes the Hall's position error where it
    first passes the sensor; a resumed arm's counter has it already (the sensor set it)."""
    error = math.radians(0.2)
    tol = 2.5 / RobotSettings().joints[0].counts_per_rad
    assert _truth_minus_belief(resumed=True) == pytest.approx((error, error), abs=tol)
    assert _truth_minus_belief(resumed=False) == pytest.approx((0.0, error), abs=tol)
    # per joint: each joint's sensor sets its own counter
    assert _truth_minus_belief(resumed=(True, False, False, False)) == pytest.approx(
        (error, error), abs=tol)
    assert _truth_minus_belief(resumed=(False, True, True, True)) == pytest.approx(
        (0.0, error), abs=tol)
    with pytest.raises(ValueError, match="resumed names 3 joints; the arm has 4"):
        ArmEmulator(RobotSettings(), resumed=(True, True, True))
