"""The node's trajectory planning (no ROS needed): what is refused, and what is sent."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest
from conftest import cli, one_line_error
from hypothesis import given, settings
from hypothesis import strategies as st

from armbench.drivers.host.motion import joint_times_s
from armbench.drivers.model.protocol import MAX_DUTY
from armbench.drivers.model.settings import RobotSettings
from armbench.frontends.ros2_node.trajectory import TrajectoryError, plan_trajectory

S = RobotSettings()
NAMES = [j.name for j in S.joints]
HOME = (0.0, 0.0, 0.0, 0.0)


def test_a_trajectory_becomes_one_command_per_point_from_where_the_arm_is() -> None:
    plan = plan_trajectory(NAMES, [[0.1, 0.0, 0.0, 0.0], [0.1, 0.1, 0.0, 0.0]], [2.0, 4.0], S,
                           HOME)
    assert plan.points == 2 and len(plan.commands) == 3
    assert plan.targets_rad[1] == pytest.approx((0.1, 0.1, 0.0, 0.0))
    assert plan.tcp_m.shape == (3, 3)
    assert plan.planned_s == pytest.approx(4.0, rel=0.02)
    # slow segments: the moving joint's duty is below the maximum
    assert plan.commands[1].duties[0] < MAX_DUTY


def test_joint_names_in_any_order_are_mapped_to_the_arm() -> None:
    names = list(reversed(NAMES))
    plan = plan_trajectory(names, [[0.0, 0.0, 0.2, 0.1]], [3.0], S, HOME)
    assert plan.targets_rad[0] == pytest.approx((0.1, 0.2, 0.0, 0.0))


@pytest.mark.parametrize(("names", "points", "times", "expected"), [
    (NAMES, [], [], "has no points"),
    (NAMES[:3], [[0.0] * 3], [1.0], "must be the arm's joints"),
    ([*NAMES[:3], "j1"], [[0.0] * 4], [1.0], "must be the arm's joints"),
    (NAMES, [[0.0] * 3], [1.0], "point 0: has 3 positions"),
    (NAMES, [[math.nan, 0.0, 0.0, 0.0]], [1.0], "point 0"),
    (NAMES, [[0.0, 0.0, 0.0, 50.0]], [1.0], "point 0"),
    (NAMES, [[0.0] * 4, [0.1, 0, 0, 0]], [1.0, 1.0], "point 1: time_from_start 1.0 s must be"),
    (NAMES, [[0.0] * 4], [-1.0], "point 0: time_from_start -1.0 s must be finite"),
    (NAMES, [[0.0] * 4], [math.inf], "must be finite"),
    (NAMES, [[1.0, 0.0, 0.0, 0.0]], [0.01], "point 0: reaching it 0.01 s after"),
])
def test_invalid_trajectories_are_refused_naming_the_point(
        names: list[str], points: list[list[float]], times: list[float], expected: str) -> None:
    with pytest.raises(TrajectoryError) as exc:
        plan_trajectory(names, points, times, S, HOME)
    assert expected in str(exc.value)


def test_a_joint_outside_its_limits_is_named() -> None:
    upper = S.joints[2].upper_rad
    with pytest.raises(TrajectoryError) as exc:
        plan_trajectory(NAMES, [[0.0, 0.0, upper + 0.1, 0.0]], [30.0], S, HOME)
    assert "point 0" in str(exc.value) and S.joints[2].name in str(exc.value)


def test_max_duty_is_a_speed_limit() -> None:
    target = [0.3, 0.0, 0.0, 0.0]
    fastest = joint_times_s(HOME, target, (MAX_DUTY,) * 4, S)[0]
    plan_trajectory(NAMES, [target], [fastest * 1.01], S, HOME)
    with pytest.raises(TrajectoryError, match="at duty 50"):
        plan_trajectory(NAMES, [target], [fastest * 1.01], S, HOME, max_duty=50)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(*[st.floats(-0.5, 0.5)] * 4), min_size=1, max_size=6),
       st.floats(0.05, 5.0))
def test_every_accepted_segment_is_within_its_time_and_the_duty_limit(
        qs: list[tuple[float, float, float, float]], step_s: float) -> None:
    times = [step_s * (k + 1) for k in range(len(qs))]
    try:
        plan = plan_trajectory(NAMES, [list(q) for q in qs], times, S, HOME)
    except TrajectoryError as exc:
        assert "reaching it" in str(exc)  # only speed can refuse these in-range points
        return
    previous = HOME
    for cmd, q in zip(plan.commands[1:], plan.targets_rad, strict=True):
        assert all(1 <= d <= MAX_DUTY for d in cmd.duties)
        slowest = max(joint_times_s(previous, q, cmd.duties, S))
        # the duty quantisation may lengthen a segment a little, never by a factor
        assert slowest <= step_s * 1.2 + 0.01 or max(cmd.duties) == 1
        previous = q


def test_without_the_extra_the_command_says_so_in_one_line() -> None:
    probe = ("import sys\nsys.modules['rclpy'] = None  # as where the extra is not installed\n"
             "from armbench.cli.main import main\nsys.exit(main(['ros2', '--duration', '1']))\n")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120, check=False)
    one_line_error(done.returncode, done.stderr, "armbench ros2: error:", "armbench[ros2]")


@pytest.mark.parametrize(("args", "expected"), [
    (["--duration", "-1"], "--duration"),
    (["--domain-id", "999"], "--domain-id: 999 must be a whole number in [0, 232]"),
    (["--max-duty", "0"], "--max-duty"),
    (["--realtime-factor", "nan"], "--realtime-factor"),
    (["--connect-timeout", "0"], "--connect-timeout"),
    (["--history-depth", "1"], "--history-depth: 1 must be a whole number in [2, 1e+06]"),
    (["--namespace", "arm 1"], "--namespace"),
    (["--pace-timeout", "inf"], "--pace-timeout"),
    (["--pace-timeout", "1e300"], "--pace-timeout: 1e+300 must be in (0, 86400] s"),
    (["--realtime-factor", "1e-300"], "--realtime-factor: 1e-300 must be in [0.001, 1e+06]"),
    (["--realtime-factor", "1e-5"], "--realtime-factor: 1e-05 must be in [0.001, 1e+06]"),
    (["--reply-timeout", "1e-300"], "--reply-timeout: 1e-300 must be in [0.01, 3600] s"),
    (["--node-name", "bad-name"], "--node-name: 'bad-name' must be a ROS node name"),
    (["--node-name", ""], "--node-name: '' must be a ROS node name"),
    (["--node-name", "1abc"], "--node-name: '1abc' must be a ROS node name"),
    (["--namespace", "/" + "a" * 220], "at most 220 characters"),
])
def test_bad_options_are_one_line_errors_before_anything_starts(
        capsys: pytest.CaptureFixture[str], args: list[str], expected: str) -> None:
    status, _, err = cli(capsys, "ros2", *args)
    one_line_error(status, err, expected)
