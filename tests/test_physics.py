"""The physics of the emulated mechanism (``fakes/twin/physics.py``) against hand-computed cases,
the
ideal profile against the cycle-by-cycle reference, and reproducibility of the physical arm."""

from __future__ import annotations

import asyncio
import copy
import math
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from joint_reference import ReferenceJoint
from test_joint_model import snapshot

from armbench.drivers.model.kinematics import dh_parameters, tcp_position
from armbench.drivers.model.protocol import Command
from armbench.drivers.model.settings import DEFAULT_JOINTS, RobotSettings, SettingsError
from armbench.drivers.model.twin_parameters import TWIN
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.fakes.links.fake_transport import parse_fake_url
from armbench.fakes.twin.joint import CYCLE_S, JointModel
from armbench.fakes.twin.physics import (
    DEFAULT_ARM,
    DEFAULT_JOINT_PHYSICS,
    ArmPhysics,
    Mechanism,
    ideal_geometry,
    ideal_joint,
)

G = 9.80665
ROBOT = RobotSettings()


def exact_arm(payload_kg: float = 0.0) -> ArmPhysics:
    """The default arm without kinematic error (nominal lengths and offsets)."""
    joints = tuple(replace(p, offset_error_rad=0.0, hall_error_rad=0.0)
                   for p in DEFAULT_JOINT_PHYSICS)
    return replace(DEFAULT_ARM, joints=joints, payload_kg=payload_kg,
                   geometry_error=ideal_geometry(), gravity_m_s2=G)


def mechanism(physics: ArmPhysics) -> Mechanism:
    return Mechanism(physics, ROBOT, lambda: [0.0] * 4)


# --- gravity and deflection, by hand ----------------------------------------------------------

@pytest.mark.parametrize("payload_kg", [0.0, 1.0, 3.0])
def test_gravity_torque_with_the_arm_stretched_out_horizontally(payload_kg: float) -> None:
    """q2 = −90° lays the upper arm along +x (DH θ2 = 0), q3 = 0 the forearm after it: each
    weight's lever about joints 2 and 3 is its horizontal distance, computed here by hand."""
    ph = exact_arm(payload_kg)
    m2, m3, m4 = (p.mass_kg for p in ph.joints[1:])
    f2, f3 = ph.joints[1].com_fraction, ph.joints[2].com_fraction
    a2, a3 = ROBOT.geometry.a2_m, ROBOT.geometry.a3_m
    tau = mechanism(ph).gravity_nm([0.0, -math.pi / 2, 0.0, 0.0])
    tip = m4 + payload_kg  # link 4 (d4 = 0) and the payload sit at the end of the forearm
    expect2 = -G * (m2 * f2 * a2 + m3 * (a2 + f3 * a3) + tip * (a2 + a3))
    expect3 = -G * (m3 * f3 * a3 + tip * a3)
    assert tau[1] == pytest.approx(expect2, rel=1e-12)
    assert tau[2] == pytest.approx(expect3, rel=1e-12)
    assert tau[0] == 0.0 and tau[3] == pytest.approx(0.0, abs=1e-12)  # vertical axis; roll


def test_no_gravity_torque_upright_and_sign_changes_across_the_vertical() -> None:
    mech = mechanism(exact_arm(2.0))
    assert mech.gravity_nm([0.3, 0.0, 0.0, 0.7]) == pytest.approx([0.0] * 4, abs=1e-12)
    lean_fwd, lean_back = mech.gravity_nm([0, -0.2, 0, 0]), mech.gravity_nm([0, 0.2, 0, 0])
    assert lean_fwd[1] < 0 < lean_back[1]  # gravity pulls a leaning arm further over
    assert lean_fwd[1] == pytest.approx(-lean_back[1], rel=1e-12)


def test_deflection_is_torque_over_stiffness() -> None:
    ph = exact_arm(3.0)
    mech = mechanism(ph)
    q = (0.1, -math.pi / 2, 0.0, 0.0)
    tau = mech.gravity_nm(q)
    true = mech.true_rad(q)
    for k in range(4):
        assert true[k] - q[k] == pytest.approx(tau[k] / ph.joints[k].stiffness_nm_per_rad,
                                               abs=1e-15)
    # by hand for joint 3: forearm and tip weights at their levers, over 4000 N·m/rad
    m3, tip = ph.joints[2].mass_kg, ph.joints[3].mass_kg + 3.0
    a3 = ROBOT.geometry.a3_m
    by_hand = -G * (m3 * 0.5 * a3 + tip * a3) / ph.joints[2].stiffness_nm_per_rad
    assert true[2] - q[2] == pytest.approx(by_hand, rel=1e-12)


def _frames(theta: np.ndarray, physics: ArmPhysics) -> list[np.ndarray]:
    """Frames 0..4 by the DH product of ``drivers.kinematics.dh_parameters`` (independent of the
    emulator's unrolled version)."""
    table = dh_parameters(physics.actual_settings(ROBOT).geometry)
    t = np.eye(4)
    out = [t]
    for k in range(4):
        a, alpha, d = table[k]
        ct, st_, ca, sa = math.cos(theta[k]), math.sin(theta[k]), math.cos(alpha), math.sin(alpha)
        t = t @ np.array([[ct, -st_ * ca, st_ * sa, a * ct], [st_, ct * ca, -ct * sa, a * st_],
                          [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]])
        out.append(t)
    return out


def _potential_j(q: list[float], physics: ArmPhysics) -> float:
    actual = physics.actual_settings(ROBOT)
    theta = np.array([j.to_dh(v) for j, v in zip(actual.joints, q, strict=True)])
    frames = _frames(theta, physics)
    u = physics.payload_kg * physics.gravity_m_s2 * frames[4][2, 3]
    for k, p in enumerate(physics.joints):
        z0, z1 = frames[k][2, 3], frames[k + 1][2, 3]
        u += p.mass_kg * physics.gravity_m_s2 * (z0 + p.com_fraction * (z1 - z0))
    return float(u)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1.5, 1.5), min_size=4, max_size=4), st.floats(0.0, 3.0))
def test_gravity_torque_is_minus_the_gradient_of_the_potential_energy(
        q: list[float], payload_kg: float) -> None:
    """τ = −∂U/∂q for the arm with its kinematic errors, any pose and payload."""
    ph = replace(DEFAULT_ARM, payload_kg=payload_kg)
    tau = Mechanism(ph, ROBOT, lambda: [0.0] * 4).gravity_nm(q)
    h = 1e-6
    for k in range(4):
        up, down = list(q), list(q)
        up[k] += h
        down[k] -= h
        grad = (_potential_j(up, ph) - _potential_j(down, ph)) / (2 * h)
        assert tau[k] == pytest.approx(-grad, abs=1e-5)


def test_truth_uses_the_actual_kinematics_and_the_host_the_nominal() -> None:
    ph = DEFAULT_ARM
    actual = ph.actual_settings(ROBOT)
    assert actual.geometry.a2_m == pytest.approx(ROBOT.geometry.a2_m + 0.0008)
    assert actual.joints[1].offset_rad == pytest.approx(
        ROBOT.joints[1].offset_rad + ph.joints[1].offset_error_rad)
    q = (0.1, -0.3, -0.9, 0.0)
    shift = np.linalg.norm(tcp_position(q, actual) - tcp_position(q, ROBOT))
    assert 0.5e-3 < shift < 5e-3  # a systematic error of the order of a millimetre


# --- the joint: play on the loaded side, step loss ----------------------------------------------

J2 = DEFAULT_JOINTS[1]


def run_to(model: JointModel, tick: int, target_rad: float, duty: int = 99) -> int:
    """Command ``target_rad`` at ``tick``; the tick at which the joint has stopped."""
    model.set_reference(tick, round(target_rad * J2.counts_per_rad), duty)
    while True:
        nxt = model.next_event_tick()
        if nxt is None:
            return tick
        tick = nxt
        model.advance(tick)
        if model.motion == "stopped":
            return tick


def physical_joint(load: Any, **kw: Any) -> JointModel:
    physics = ideal_joint(backlash_rad=math.radians(0.5), hold_nm=0.5, **kw)
    return JointModel(J2, physics=physics, load=load, seed=1)


def play_side(model: JointModel) -> float:
    """Link minus motor angle (rad): where in its play the link sits."""
    return model.true_angle_rad() - model.motor_steps / J2.steps_per_rad


def test_a_joint_crosses_its_play_when_the_gravity_torque_changes_sign() -> None:
    """An inverted pendulum (torque 20 sin q): left of the vertical the link rests on the lower
    flank, right of it on the upper; the jump between them is the whole play."""
    half = math.radians(0.5) / 2
    model = physical_joint(lambda q: 20.0 * math.sin(q))
    tick = run_to(model, 0, -0.2)
    assert play_side(model) == pytest.approx(-half)
    tick = run_to(model, tick, 0.2)
    assert play_side(model) == pytest.approx(+half)
    assert model.load_nm > 0


def test_under_load_the_approach_direction_no_longer_moves_the_link_in_its_play() -> None:
    loaded = physical_joint(lambda q: -10.0)
    tick = run_to(loaded, 0, 0.1)       # up, against gravity
    up = play_side(loaded)
    run_to(loaded, run_to(loaded, tick, 0.2), 0.1)  # down onto the same target
    assert play_side(loaded) == pytest.approx(up)
    free = physical_joint(lambda q: 0.0)  # no load: a plain play operator
    tick = run_to(free, 0, 0.1)
    from_below = play_side(free)
    run_to(free, run_to(free, tick, 0.2), 0.1)
    assert play_side(free) == pytest.approx(-from_below)


def test_step_loss_by_hand_up_against_gravity_at_full_duty_and_not_down() -> None:
    """15 N·m at 50:1 and η = 0.35 needs 0.857 N·m; the stepper gives 1.3 / (1 + 6250/8000)
    = 0.730 N·m at duty 99: 14.8 % of the pulses are lost going up (exactly the share of the
    deficit: S steps cost S / (1 − p) pulses, the fraction carried); going down needs
    15 × (1/0.35 − 2) / 50 = 0.257 N·m: none."""
    ph = ideal_joint(pullout_nm=1.3, corner_steps_per_s=8000.0, efficiency=0.35)
    rate = 1.0 / (2 * CYCLE_S)
    have = 1.3 / (1 + rate / 8000.0)
    p = 1 - have / (15 / (50 * 0.35))
    assert ph.loss_fraction(-15.0, +1, 50.0, rate, 1600) == pytest.approx(p, rel=1e-12)
    assert ph.loss_fraction(-15.0, -1, 50.0, rate, 1600) == 0.0
    assert ph.required_nm(-15.0, -1, 50.0, rate, 1600) == pytest.approx(
        15 * (1 / 0.35 - 2) / 50)
    up = physical_joint(lambda q: -15.0, pullout_nm=1.3)
    run_to(up, 0, 0.5)
    assert up.steps_missed / up.pulses == pytest.approx(0.148, abs=0.02)
    assert up.steps_missed == math.floor(up.steps_taken * p / (1 - p))
    assert up.counter == pytest.approx(round(0.5 * J2.counts_per_rad), abs=1)  # made up
    down = physical_joint(lambda q: -15.0, pullout_nm=1.3)
    run_to(down, 0, -0.5)
    assert down.steps_missed == 0
    slow = physical_joint(lambda q: -15.0, pullout_nm=1.3)
    run_to(slow, 0, 0.5, duty=81)  # a tenth of the rate: 1.21 N·m available
    assert slow.steps_missed == 0


def test_the_same_move_under_the_same_load_loses_the_same_steps() -> None:
    """Step loss is a function of the torque deficit, not a draw: other seeds, the same lost
    pulses and the same stop tick; a lift repeated loses the same again (within the one pulse
    the error diffusion carries), and many short lifts lose what one long lift does."""
    ends = []
    for seed in (1, 2, 3):
        physics = ideal_joint(backlash_rad=math.radians(0.5), pullout_nm=1.3)
        m = JointModel(J2, physics=physics, load=lambda q: -15.0, seed=seed)
        ends.append((run_to(m, 0, 0.4), m.steps_missed, m.counter))
    assert ends[0] == ends[1] == ends[2]
    m = physical_joint(lambda q: -15.0, pullout_nm=1.3)
    tick = run_to(m, 0, 0.4)
    first = m.steps_missed
    run_to(m, run_to(m, tick + 100, 0.0), 0.4)  # down (no loss), then up again
    assert abs((m.steps_missed - first) - first) <= 1
    short = physical_joint(lambda q: -15.0, pullout_nm=1.3)
    tick = 0
    for k in range(1, 41):
        tick = run_to(short, tick + 100, 0.01 * k)
    assert abs(short.steps_missed - first) <= 1  # carried: not 40 × a fraction lost


@settings(max_examples=40, deadline=None)
@given(st.floats(-40.0, 40.0), st.integers(60, 99), st.sampled_from([1, -1]))
def test_lost_share_is_the_torque_deficit(load_nm: float, duty: int, direction: int) -> None:
    """Whatever the load and rate, a single move loses ⌊S p / (1 − p)⌋ pulses for S steps, p
    being ``loss_fraction``; lowering loses no more than lifting against the same torque."""
    physics = ideal_joint(pullout_nm=1.3)
    rate = 1.0 / ((101 - duty) * CYCLE_S)
    p = physics.loss_fraction(load_nm, direction, 50.0, rate, 1600)
    m = JointModel(J2, physics=physics, load=lambda q: load_nm, seed=5)
    run_to(m, 0, 0.3 * direction, duty)
    assert m.steps_missed == math.floor(m.steps_taken * p / (1 - p))
    assert physics.loss_fraction(-abs(load_nm), -1, 50.0, rate, 1600) <= physics.loss_fraction(
        -abs(load_nm), +1, 50.0, rate, 1600)


def test_loss_jitter_is_seeded_and_a_spurious_count_does_not_change_the_loss() -> None:
    """``loss_jitter`` scatters the lost fraction per run, the same with the same seed; a spurious
    encoder count in the middle of a lift does not re-read the load (the loss stays the
    motion's), so the lift loses what it would have lost without it, but for the count."""
    lost = []
    for seed in (1, 1, 2):
        physics = ideal_joint(pullout_nm=1.3, loss_jitter=0.03)
        m = JointModel(J2, physics=physics, load=lambda q: -15.0, seed=seed)
        run_to(m, 0, 0.4)
        lost.append(m.steps_missed)
    assert lost[0] == lost[1] != lost[2]
    assert TWIN["loss_jitter"].low <= DEFAULT_JOINT_PHYSICS[1].loss_jitter

    def lift(noise: float) -> JointModel:
        physics = ideal_joint(pullout_nm=1.3)
        m = JointModel(J2, physics=physics, load=lambda q: -15.0 - 20.0 * q, seed=4,
                       noise_per_count=noise)
        run_to(m, 0, 0.4)
        return m

    clean, noisy = lift(0.0), lift(1e-3)
    assert noisy.spurious_counts >= 1
    assert abs(noisy.steps_missed - clean.steps_missed) <= noisy.spurious_counts + 1


@settings(max_examples=50, deadline=None)
@given(st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_the_stick_slip_band_never_shrinks_with_speed(a: float, b: float) -> None:
    """Slower approaches are never less repeatable than faster ones."""
    for p in DEFAULT_JOINT_PHYSICS:
        slow, fast = sorted((a, b))
        assert p.stick_band_rad(slow) <= p.stick_band_rad(fast)
        assert p.stick_band_rad(0.0) > 0.0


# --- profiles, settings, URL --------------------------------------------------------------------

def test_ideal_profile_has_no_physics_and_the_default_is_physical() -> None:
    assert emulator_settings(ROBOT).physics == DEFAULT_ARM
    assert emulator_settings(ROBOT, profile="ideal").physics is None
    arm = ArmEmulator(ROBOT, emulator_settings(ROBOT, profile="ideal"))
    assert arm.mechanism is None and arm.actual_settings is ROBOT


def test_fake_url_profile_and_payload() -> None:
    robot, _, _ = parse_fake_url("fake://?profile=ideal")
    assert emulator_settings(robot).physics is None
    robot, _, _ = parse_fake_url("fake://?payload=2.5")
    physics = emulator_settings(robot).physics
    assert physics is not None and physics.payload_kg == 2.5
    with pytest.raises(SettingsError, match=r"payload: 4.0 must be in \[0, 3\] kg"):
        parse_fake_url("fake://?payload=4")
    with pytest.raises(SettingsError, match=r"profile.*'exact'"):
        parse_fake_url("fake://?profile=exact")


def test_physics_settings_are_checked_and_named() -> None:
    s = emulator_settings(ROBOT, physics={"payload_kg": 1, "j2": {"backlash_deg": 0.5},
                                          "geometry_error": {"a2_m": 0.001}})
    assert s.physics is not None
    assert s.physics.joints[1].backlash_rad == pytest.approx(math.radians(0.5))
    assert s.physics.geometry_error.a2_m == 0.001
    with pytest.raises(SettingsError, match=r"emulator\.physics\.j3\.stiffness"):
        emulator_settings(ROBOT, physics={"j3": {"stiffness_nm_per_rad": -1}})
    with pytest.raises(SettingsError, match=r"emulator\.physics\.j1\.colour"):
        emulator_settings(ROBOT, physics={"j1": {"colour": 1}})
    with pytest.raises(SettingsError, match=r"emulator\.profile"):
        emulator_settings(ROBOT, profile="toy")


# --- whole arm -----------------------------------------------------------------------------------

def session(**kwargs: Any) -> tuple[list[Any], list[tuple[float, ...]], list[int]]:
    """Replies, truth and missed steps of three moves on virtual time."""
    async def main() -> tuple[list[Any], list[tuple[float, ...]], list[int]]:
        arm = ArmEmulator(ROBOT, emulator_settings(ROBOT, **kwargs))
        replies: list[bytes] = []
        arm.attach_host(replies.append)
        await arm.start()
        await asyncio.sleep(0.2)
        for q in ([0.2, -0.5, 0.3, 0.1], [0.0, 0.0, 0.0, 0.0], [-0.1, 0.2, -0.6, 0.0]):
            arm.host_write(Command.from_rad(q, 99).encode())
            await asyncio.sleep(1.8)
        truth = [tuple(s.true_rad) + s.firmware_rad for s in arm.truth]
        missed = [b.model.steps_missed for b in arm.boards if b.model is not None]
        await arm.close()
        return replies, truth, missed

    return run_virtual(main)


def test_same_seed_same_run_and_another_seed_another() -> None:
    loaded = {"physics": {"payload_kg": 2.0}}
    a, b, c = session(seed=7, **loaded), session(seed=7, **loaded), session(seed=8, **loaded)
    assert a == b
    assert a[1] != c[1]
    assert sum(a[2]) > 0  # lifting at full duty lost steps


def test_ideal_profile_board_joints_equal_the_cycle_by_cycle_reference() -> None:
    """The joint models the boards build in the ideal profile are step-exact: the same as the
    reference loop on a scripted session."""
    async def boot() -> list[JointModel]:
        arm = ArmEmulator(ROBOT, emulator_settings(ROBOT, profile="ideal"))
        await arm.start()
        await asyncio.sleep(0.2)
        models = [copy.deepcopy(b.model) for b in arm.boards]
        await arm.close()
        return [m for m in models if m is not None]

    for joint, model in zip(ROBOT.joints, run_virtual(boot), strict=True):
        ref = ReferenceJoint(joint, counter=model.counter, tick=model.tick)
        tick = model.tick
        for dt, target, duty in ((0, 900, 99), (700, -400, 60), (2_500, -400, 0),
                                 (50, 1200, 97), (9_000, 0, 99)):
            tick += dt
            model.advance(tick)
            ref.advance(tick)
            assert snapshot(model) == snapshot(ref)
            model.set_reference(tick, target, duty)
            ref.set_reference(tick, target, duty)
        model.advance(tick + 30_000)
        ref.advance(tick + 30_000)
        assert snapshot(model) == snapshot(ref)
        assert model.true_angle_rad() == model.motor_steps / joint.steps_per_rad


def test_belief_error_grows_with_the_payload_on_the_accuracy_square() -> None:
    """The firmware's belief against the truth, one paper-style lap: the sag the encoders cannot
    see grows with the payload."""
    from test_suites import run_fake

    from armbench.bench.suites.accuracy import AccuracySuite

    belief = [run_fake(AccuracySuite(), {"laps": 1, "styles": ["paper"]},
                       port=f"fake://?payload={kg}")[1]["accuracy.paper.belief_mean_mm"].value
              for kg in (0, 3)]
    assert belief[1] > belief[0] + 0.5
