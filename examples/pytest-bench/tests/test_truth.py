"""Where the tool really is, against where the firmware believes it is: needs ground truth (the
emulator's, or an instrument's); skipped, with the reason, on an arm without it."""

from armbench.drivers.model.kinematics import tcp_position


async def test_the_tcp_is_where_the_firmware_believes(arm, truth, record_measurement):
    state = await arm.move_joints([0.3, 0.2, -0.2, 0.0], 80)
    believed_m = tcp_position(state.q_rad, arm.settings)
    true_m = truth.true_position_m()
    error_mm = 1000 * sum((b - t) ** 2 for b, t in zip(believed_m, true_m, strict=True)) ** 0.5
    record_measurement("lab.tcp.belief_error_mm", error_mm, "mm")
