"""The step-loss structures the twin can represent (``JointPhysics.loss_law``): the torque
deficit's share (the default), a stall above the pull-out rate, and a fixed share above a duty;
each on one joint model, by hand, and through the settings file."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from test_physics import J2, run_to

from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.fakes.twin.joint import CYCLE_S, JointModel
from armbench.fakes.twin.physics import DEFAULT_JOINT_PHYSICS, LOSS_LAWS, ideal_joint

ROBOT = RobotSettings()


def test_default_law_is_the_torque_deficit() -> None:
    """Every default joint keeps the proportional law and no duty loss."""
    assert LOSS_LAWS[0] == "torque"
    for p in DEFAULT_JOINT_PHYSICS:
        assert p.loss_law == "torque" and p.loss_plus == p.loss_minus == 0.0


def test_duty_law_loses_its_share_above_the_duty_only() -> None:
    """20 % moving +, 5 % moving − above duty 90, whatever the load; nothing at 90."""
    physics = ideal_joint(loss_law="duty", loss_above_duty=90.0, loss_plus=0.2,
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
    physics = ideal_joint(loss_law="stall", pullout_nm=1.3)
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


def test_pullout_curves_halve_at_the_corner_and_differ_beyond() -> None:
    """Both shapes give the full pull-out torque at standstill and half at the corner; the
    hyperbolic one never reaches zero, the linear one does at twice the corner."""
    hyp = ideal_joint(pullout_nm=1.0, corner_steps_per_s=4000.0)
    lin = replace(hyp, pullout_curve="linear")
    assert hyp.pullout_curve == "hyperbolic"  # the default: the default arm unchanged
    for p in (hyp, lin):
        assert p.pullout_at_nm(0.0) == 1.0 and p.pullout_at_nm(4000.0) == pytest.approx(0.5)
    assert lin.pullout_at_nm(2000.0) == pytest.approx(0.75)
    assert hyp.pullout_at_nm(2000.0) == pytest.approx(1.0 / 1.5)
    assert lin.pullout_at_nm(8000.0) == 0.0 == lin.pullout_at_nm(9000.0)
    assert hyp.pullout_at_nm(9000.0) > 0.3


def test_linear_stall_rate_falls_with_the_load_and_lowering_stalls_only_beyond_it() -> None:
    """A stall arm whose pull-out rate falls linearly with the lifted torque (the foreign stall
    arm's law: 7000 microsteps/s free, none left at 14 N·m; a 50:1 worm at the self-locking
    limit, efficiency 0.5, holds the load without driving it down; a little running friction):
    lifting 7 N·m keeps up to 3500/s, not above; lowering stalls only above the free rate, as
    an unloaded lift does. A worm of efficiency 0.35 must drive the load down, so lowering it
    stalls below the free rate; the hyperbolic curve never stalls unloaded."""
    lin = ideal_joint(loss_law="stall", pullout_curve="linear", pullout_nm=14.0 / (50 * 0.5),
                       corner_steps_per_s=3500.0, efficiency=0.5, friction_nm=0.001,
                       inertia_kgm2=0.0)
    assert not lin.stalls(-7.0, +1, 50.0, 3400.0, 1600)
    assert lin.stalls(-7.0, +1, 50.0, 3600.0, 1600)
    assert not lin.stalls(-7.0, -1, 50.0, 6900.0, 1600)
    assert lin.stalls(-7.0, -1, 50.0, 7100.0, 1600)
    assert lin.stalls(0.0, +1, 50.0, 7100.0, 1600)
    assert replace(lin, efficiency=0.35).stalls(-7.0, -1, 50.0, 6900.0, 1600)
    assert not replace(lin, pullout_curve="hyperbolic").stalls(0.0, +1, 50.0, 1e6, 1600)


def test_pullout_curve_is_read_and_checked() -> None:
    s = emulator_settings(ROBOT, physics={"j3": {"pullout_curve": "linear"}})
    assert s.physics is not None and s.physics.joints[2].pullout_curve == "linear"
    assert s.physics.joints[1].pullout_curve == "hyperbolic"
    with pytest.raises(SettingsError, match=r"emulator\.physics\.j3\.pullout_curve.*cubic"):
        emulator_settings(ROBOT, physics={"j3": {"pullout_curve": "cubic"}})


def test_a_stalled_joint_restarts_when_its_load_lightens_and_only_below_pull_in() -> None:
    """Under the stall law the load and the rate are read again while the rotor hums (other
    joints' motion changes the load): a joint stalled lifting 25 N·m at duty 99 moves once the
    load falls enough, without a new command. With ``pullin_share = 0.8`` it falls back into
    step only where its rate is below 0.8 of the rate it could keep: a load it could lift from
    rest at that rate does not restart it."""
    physics = ideal_joint(loss_law="stall", pullout_curve="linear", pullout_nm=1.3,
                      corner_steps_per_s=8000.0, friction_nm=0.0, inertia_kgm2=0.0,
                      efficiency=0.5, pullin_share=0.8)
    rate = 1.0 / (2 * CYCLE_S)  # duty 99
    # the heaviest lift the drive keeps up with at duty 99, from rest and humming
    keep = 1.3 * (1 - rate / 16000.0) * 50 * 0.5
    pull_in = 1.3 * (1 - rate / 0.8 / 16000.0) * 50 * 0.5
    assert not physics.stalls(-0.99 * keep, +1, 50.0, rate, 1600)
    assert physics.stalls(-0.99 * keep, +1, 50.0, rate, 1600, humming=True)
    assert not physics.stalls(-0.99 * pull_in, +1, 50.0, rate, 1600, humming=True)
    load = [-25.0]
    m = JointModel(J2, physics=physics, load=lambda q: load[0], seed=1)
    target = round(0.3 * J2.counts_per_rad)
    m.set_reference(0, target, 99)
    m.advance(25_000)  # 2 s
    assert m.counter == 0 and m.steps_blocked > 0
    load[0] = -0.99 * keep  # light enough to lift from rest, not to pull in
    m.advance(50_000)
    assert m.counter == 0
    load[0] = -0.99 * pull_in
    m.advance(100_000)  # 4 s more: a lossless move takes about 1.9 s
    assert abs(m.counter - target) <= 1 and m.steps_missed == 0


def test_a_stop_puts_a_humming_rotor_back_in_step() -> None:
    """A stalled joint that is stopped (duty 0) is at rest and in step again: the next command
    is judged against the pull-out rate, not the lower pull-in rate."""
    physics = ideal_joint(loss_law="stall", pullout_curve="linear", pullout_nm=1.3,
                      corner_steps_per_s=8000.0, friction_nm=0.0, inertia_kgm2=0.0,
                      efficiency=0.5, pullin_share=0.8)
    rate = 1.0 / (2 * CYCLE_S)
    keep = 1.3 * (1 - rate / 16000.0) * 50 * 0.5
    load = [-25.0]
    m = JointModel(J2, physics=physics, load=lambda q: load[0], seed=1)
    target = round(0.3 * J2.counts_per_rad)
    m.set_reference(0, target, 99)
    m.advance(25_000)
    assert m.counter == 0
    load[0] = -0.99 * keep  # liftable from rest, not enough to pull a humming rotor in
    m.set_reference(25_000, 0, 0)
    m.advance(30_000)
    m.set_reference(30_000, target, 99)
    m.advance(80_000)  # 4 s: a lossless move takes about 1.9 s
    assert abs(m.counter - target) <= 1
