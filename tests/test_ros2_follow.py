"""A ``FollowJointTrajectory`` goal checked whole and judged, without ROS
(:mod:`armbench.frontends.ros2_node.follow`): the result codes of what is refused, the tolerances
in force (the goal's, the defaults, -1 erased), where the trajectory says the joints are, and a
stalled arm's execution ending ``PATH_TOLERANCE_VIOLATED`` with the arm held (the driver on
``fake://``, a drive too weak to lift)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from armbench.drivers.host.arm import Arm
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.clock.vclock import run_virtual
from armbench.frontends.ros2_node.follow import (
    DEFAULT_PATH_TOLERANCE_RAD,
    INVALID_GOAL,
    INVALID_JOINTS,
    OLD_HEADER_TIMESTAMP,
    PATH_TOLERANCE_VIOLATED,
    SUCCESSFUL,
    Goal,
    GoalRefused,
    check_goal,
    copy_goal,
)
from armbench.frontends.ros2_node.follow_action import execute

S = RobotSettings()
NAMES = tuple(j.name for j in S.joints)
TOL = (3e-4,) * 4


def _goal(**more: Any) -> Goal:
    fields: dict[str, Any] = {"names": NAMES, "positions": ((0.1, 0.0, 0.0, 0.0),
                                                            (0.2, 0.1, 0.0, 0.0)),
                              "times_s": (1.0, 2.0), "points": 2, **more}
    return Goal(**fields)


@pytest.mark.parametrize(("goal", "code", "text"), [
    (_goal(names=("j1", "j2", "j3", "x")), INVALID_JOINTS, "joint_names"),
    (_goal(names=("j1", "j1", "j2", "j3")), INVALID_JOINTS, "each once"),
    (_goal(multi_dof=1), INVALID_JOINTS, "multi-DOF"),
    (_goal(path_tolerance=(("x", 0.1),)), INVALID_JOINTS, "path_tolerance"),
    (_goal(goal_tolerance=(("j1", -0.5),)), INVALID_GOAL, "-1 (not checked)"),
    (_goal(positions=(), times_s=(), points=0), INVALID_GOAL, "no points"),
    (_goal(positions=((0.1, 9.0, 0.0, 0.0), (0.2, 0.1, 0.0, 0.0))), INVALID_GOAL, "j2"),
    (_goal(times_s=(1.0, 0.5)), INVALID_GOAL, "after the previous"),
    (_goal(goal_time_tolerance_s=-1.0), INVALID_GOAL, "goal_time_tolerance"),
    (_goal(stamp_s=1.0), OLD_HEADER_TIMESTAMP, "ended before now"),
    (_goal(stamp_s=100_000.0), INVALID_GOAL, "in the future"),
])
def test_a_goal_refused_has_its_code(goal: Goal, code: int, text: str) -> None:
    with pytest.raises(GoalRefused) as caught:
        check_goal(goal, S, (0.0,) * 4, 10.0, TOL)
    assert caught.value.code == code and text in caught.value.reason, caught.value.reason


def test_tolerances_are_the_goals_the_defaults_or_erased() -> None:
    accepted = check_goal(_goal(path_tolerance=(("j2", 0.05), ("j3", -1.0), ("j4", 0.0)),
                                goal_tolerance=(("j1", 0.01),), stamp_s=10.5), S, (0.0,) * 4,
                          10.0, TOL)
    assert accepted.path_rad == (DEFAULT_PATH_TOLERANCE_RAD, 0.05, None,
                                 DEFAULT_PATH_TOLERANCE_RAD)
    assert accepted.goal_rad == (0.01, *TOL[1:])
    assert accepted.start_delay_s == pytest.approx(0.5)
    assert accepted.goal_time_s > 1.0  # the driver's slack for a move of this length


def test_desired_is_linear_between_the_points() -> None:
    accepted = check_goal(_goal(), S, (0.0,) * 4, 0.0, TOL)
    q, v, index = accepted.desired(1.5)
    assert q == pytest.approx([0.15, 0.05, 0.0, 0.0], abs=1e-4)
    assert v == pytest.approx([0.1, 0.1, 0.0, 0.0], abs=1e-3) and index == 1
    assert accepted.desired(5.0)[0] == pytest.approx([0.2, 0.1, 0.0, 0.0], abs=1e-4)
    assert accepted.path_violation(NAMES, 1.5, (0.15, 0.05, 0.0, 0.0)) is None
    off = accepted.path_violation(NAMES, 1.5, (0.15, 0.3, 0.0, 0.0))
    assert off is not None and "joint j2" in off and "path tolerance" in off


def test_a_goal_message_is_copied_into_plain_values() -> None:
    def t(s: float) -> SimpleNamespace:
        return SimpleNamespace(sec=int(s), nanosec=round((s % 1) * 1e9))

    point = SimpleNamespace(positions=[0.1, 0.0, 0.0, 0.0], time_from_start=t(1.5))
    msg = SimpleNamespace(
        trajectory=SimpleNamespace(joint_names=list(NAMES), points=[point],
                                   header=SimpleNamespace(stamp=t(2.25))),
        multi_dof_trajectory=SimpleNamespace(points=[], joint_names=[]),
        path_tolerance=[SimpleNamespace(name="j1", position=0.2)], goal_tolerance=[],
        component_path_tolerance=[], component_goal_tolerance=[], goal_time_tolerance=t(0.5))
    goal = copy_goal(msg)
    assert goal == Goal(NAMES, ((0.1, 0.0, 0.0, 0.0),), (1.5,), 2.25, (("j1", 0.2),), (), 0.5,
                        0, 1)


def test_a_stalled_joint_violates_the_path_tolerance_and_is_held(tmp_path: Path) -> None:
    weak = tmp_path / "weak.toml"
    weak.write_text('[emulator.physics.j2]\npullout_nm = 0.3\nloss_law = "stall"\n')

    async def main(port: str) -> tuple[int, str, int, tuple[float, ...]]:
        async with Arm(port, S) as arm:
            accepted = check_goal(_goal(positions=((0.0, 0.8, 0.0, 0.0),), times_s=(4.0,),
                                        points=1), S, arm.state.q_rad, 0.0,
                                  arm.default_tolerance_rad())
            feedback: list[int] = []
            outcome = await execute(arm, accepted, 0.01, lambda *a: feedback.append(a[4]))
            held, t_held = arm.state.q_rad, arm.state.t_s
            await arm.wait_state(lambda s: s.t_s > t_held + 1.0)  # a second later
            # held where it stopped (a stalled rotor settles by a few counts at most)
            assert max(abs(a - b) for a, b in zip(arm.state.q_rad, held, strict=True)) < 0.01
            return outcome.code, outcome.text, len(feedback), held

    code, text, feedback, held = run_virtual(main(f"fake://?settings={weak}"))
    assert code == PATH_TOLERANCE_VIOLATED and "joint j2" in text, text
    assert feedback > 0 and held[1] < 0.8 - 0.1  # short of the goal
    # the same goal on the default arm is followed
    code, text, _, _ = run_virtual(main("fake://"))
    assert code == SUCCESSFUL, text
