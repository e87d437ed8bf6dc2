"""The step-loss structures the twin can represent (``JointPhysics.loss_law``): the torque
deficit's share (the default), a stall above the pull-out rate, and a fixed share above a duty;
each on one joint model, by hand, and through the settings file."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from test_physics import J2, run_to

from armbench.drivers.settings import RobotSettings, SettingsError
from armbench.fakes.emulator_settings import emulator_settings
from armbench.fakes.joint import CYCLE_S, JointModel
from armbench.fakes.physics import DEFAULT_JOINT_PHYSICS, LOSS_LAWS, JointPhysics

ROBOT = RobotSettings()


def test_default_law_is_the_torque_deficit() -> None:
    """Every default joint keeps the proportional law and no duty loss."""
    assert LOSS_LAWS[0] == "torque"
    for p in DEFAULT_JOINT_PHYSICS:
        assert p.loss_law == "torque" and p.loss_plus == p.loss_minus == 0.0


def test_duty_law_loses_its_share_above_the_duty_only() -> None:
    """20 % moving +, 5 % moving − above duty 90, whatever the load; nothing at 90."""
    physics = replace(JointPhysics(), loss_law="duty", loss_above_duty=90.0, loss_plus=0.2,
                      loss_minus=0.05)
    up = JointModel(J2, physics=physics, load=lambda q: 0.0, seed=1)
    run_to(up, 0, 0.3, duty=95)
    assert up.steps_missed == math.floor(up.steps_taken * 0.2 / 0.8)
    down = JointModel(J2, physics=physics, load=lambda q: 0.0, seed=1)
    run_to(down, 0, -0.3, duty=99)
    assert down.steps_missed == math.floor(down.steps_taken * 0.05 / 0.95)
    slow = JointModel(J2, physics=physics, load=lambda q: -30.0, seed=1)
    run_to(slow, 0, 0.3, duty=90)
    assert slow.steps_missed == 0


def test_stall_law_stops_the_rotor_until_the_rate_falls() -> None:
    """Lifting 15 N·m at duty 99 needs more than the pull-out torque there: the rotor stalls and
    the counter does not move; at duty 81 (a tenth of the rate) it has the torque and arrives
    without a lost step (no proportional slip under this law)."""
    physics = replace(JointPhysics(), loss_law="stall", pullout_nm=1.3)
    rate = 1.0 / (2 * CYCLE_S)
    assert physics.stalls(-15.0, +1, 50.0, rate, 1600)
    assert not physics.stalls(-15.0, -1, 50.0, rate, 1600)
    assert physics.loss_fraction(-15.0, +1, 50.0, rate, 1600, 99) == 0.0
    m = JointModel(J2, physics=physics, load=lambda q: -15.0, seed=1)
    target = round(0.3 * J2.counts_per_rad)
    m.set_reference(0, target, 99)
    m.advance(50_000)  # 4 s: a lossless move would take about 1.9 s
    assert m.counter == 0 and m.steps_taken == 0 and m.steps_blocked > 0
    m.set_reference(50_000, target, 81)
    tick = 50_000
    while (nxt := m.next_event_tick()) is not None:
        tick = nxt
        m.advance(tick)
    assert abs(m.counter - target) <= 1 and m.steps_missed == 0


def test_loss_settings_are_read_and_checked() -> None:
    s = emulator_settings(ROBOT, physics={"j3": {"loss_law": "duty", "loss_above_duty": 95,
                                                 "loss_plus": 0.1}})
    assert s.physics is not None
    j3 = s.physics.joints[2]
    assert (j3.loss_law, j3.loss_above_duty, j3.loss_plus) == ("duty", 95.0, 0.1)
    with pytest.raises(SettingsError, match=r"emulator\.physics\.j2\.loss_law"):
        emulator_settings(ROBOT, physics={"j2": {"loss_law": "slip"}})
    with pytest.raises(SettingsError, match=r"emulator\.physics\.j2\.loss_plus"):
        emulator_settings(ROBOT, physics={"j2": {"loss_plus": "a lot"}})
