"""Each joint reaches what it is told: the firmware's own report (the encoders)."""

import pytest

HOME_RAD = [0.0, 0.0, 0.0, 0.0]


@pytest.mark.parametrize("joint", [0, 1, 2])
async def test_a_joint_reaches_its_target(arm, joint, record_measurement):
    await arm.move_joints(HOME_RAD, 99)  # the shared arm is where the last test left it
    target = list(HOME_RAD)
    target[joint] = 0.3
    state = await arm.move_joints(target, 80)
    record_measurement(f"lab.j{joint + 1}.error_mrad", abs(state.q_rad[joint] - 0.3) * 1000,
                       "mrad")


async def test_the_arm_holds_still_between_tests(arm):
    first = arm.state.q_rad
    later = await arm.stop()
    assert max(abs(a - b) for a, b in zip(first, later.q_rad, strict=True)) < 1e-3
