"""A ``FollowJointTrajectory`` goal checked whole, and how the arm's replies are judged against it.

Pure functions, no ROS import (the goal is copied into a :class:`Goal` of plain values on the
executor thread): :func:`check_goal` refuses what the arm cannot execute faithfully with the
control_msgs result code (:class:`GoalRefused`: ``INVALID_JOINTS``, ``INVALID_GOAL``,
``OLD_HEADER_TIMESTAMP``) and otherwise returns the plan of
:func:`armbench.frontends.ros2_node.trajectory.plan_trajectory` with the tolerances in force;
:meth:`Accepted.desired` is where the trajectory says the joints are at a time after its start
(linear between the points, as the arm drives each segment at constant speed) and
:meth:`Accepted.path_violation` / :meth:`Accepted.goal_violation` say which joint is out of which
tolerance by how much.

Tolerances follow control_msgs: per joint, 0 (or none given) is the default, -1 "erased" (not
checked), anything else positive the tolerance; only the positions are judged (the replies carry
positions only). Defaults: :data:`DEFAULT_PATH_TOLERANCE_RAD` on the path, the driver's arrival
tolerance at the goal, and as ``goal_time_tolerance`` the slack the driver gives a move of that
duration (:data:`armbench.drivers.host.arrival` margins).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

from armbench.drivers.host.arrival import MOVE_TIMEOUT_MARGIN, MOVE_TIMEOUT_SLACK_S
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.kinematics import Vec4
from armbench.drivers.model.peer_text import peer_repr
from armbench.drivers.model.protocol import MAX_DUTY
from armbench.drivers.model.settings import RobotSettings
from armbench.frontends.ros2_node.intake import MAX_POINTS
from armbench.frontends.ros2_node.trajectory import TrajectoryError, TrajectoryPlan, plan_trajectory

__all__ = ["DEFAULT_PATH_TOLERANCE_RAD", "GOAL_TOLERANCE_VIOLATED", "INVALID_GOAL",
           "INVALID_JOINTS", "MAX_START_DELAY_S", "OLD_HEADER_TIMESTAMP",
           "PATH_TOLERANCE_VIOLATED", "SUCCESSFUL", "Accepted", "Goal", "GoalRefused",
           "check_goal", "copy_goal"]

#: ``control_msgs/action/FollowJointTrajectory`` result codes (the action's constants).
SUCCESSFUL: Final = 0
INVALID_GOAL: Final = -1
INVALID_JOINTS: Final = -2
OLD_HEADER_TIMESTAMP: Final = -3
PATH_TOLERANCE_VIOLATED: Final = -4
GOAL_TOLERANCE_VIOLATED: Final = -5

#: How far (rad) a joint may be from where the trajectory says it is at that time when the goal
#: gives no path tolerance: well above the lag of law (12)'s duty steps and the streaming's
#: look-ahead on a trajectory the arm can follow, well below what a stalled joint falls behind
#: within a fraction of a second at speed.
DEFAULT_PATH_TOLERANCE_RAD: Final = 0.1
#: A goal stamped further in the future than this (s) is refused (``INVALID_GOAL``).
MAX_START_DELAY_S: Final = 3600.0


class GoalRefused(ArmbenchError, ValueError):
    """A goal refused before anything moved: its result ``code`` and why."""

    def __init__(self, code: int, reason: str) -> None:
        self.code = code
        self.reason = reason
        super().__init__(reason)


@dataclass(frozen=True)
class Goal:
    """A goal's fields as plain values: the trajectory's joint names, each point's positions
    (rad) and ``time_from_start`` (s), its ``header.stamp`` (s; 0: start on arrival), the path
    and goal tolerances as ``(joint, position)``, ``goal_time_tolerance`` (s), and the counts
    of what the arm has no use for (multi-DOF points and component tolerances); ``points``: the
    trajectory's point count (beyond :data:`MAX_POINTS` nothing else is copied)."""

    names: tuple[str, ...]
    positions: tuple[tuple[float, ...], ...]
    times_s: tuple[float, ...]
    stamp_s: float = 0.0
    path_tolerance: tuple[tuple[str, float], ...] = ()
    goal_tolerance: tuple[tuple[str, float], ...] = ()
    goal_time_tolerance_s: float = 0.0
    multi_dof: int = 0
    points: int = 0


def _s(duration: Any) -> float:
    return float(duration.sec) + float(duration.nanosec) * 1e-9


def copy_goal(msg: Any) -> Goal:
    """A ``FollowJointTrajectory.Goal`` (or anything shaped like one) copied into a
    :class:`Goal`."""
    traj = msg.trajectory
    n = len(traj.points)
    multi = (len(msg.multi_dof_trajectory.points) + len(msg.multi_dof_trajectory.joint_names)
             + len(msg.component_path_tolerance) + len(msg.component_goal_tolerance))
    tols = [tuple((str(t.name), float(t.position)) for t in ts)
            for ts in (msg.path_tolerance, msg.goal_tolerance)]
    if n > MAX_POINTS:
        return Goal(tuple(map(str, traj.joint_names)), (), (), points=n)
    return Goal(tuple(str(s) for s in traj.joint_names),
                tuple(tuple(float(v) for v in p.positions) for p in traj.points),
                tuple(_s(p.time_from_start) for p in traj.points),
                _s(traj.header.stamp), tols[0], tols[1], _s(msg.goal_time_tolerance),
                multi, n)


@dataclass(frozen=True)
class Accepted:
    """A goal accepted: its plan, the time of each point from the start (``times_s[0]`` = 0, the
    arm's position), the per-joint tolerances in force (rad, arm order; None: not checked),
    ``goal_time_s`` (how late the arm may arrive) and ``start_delay_s`` (a stamp in the
    future); ``start_rad`` / ``end_rad``: the first and last commands' targets as written
    (the wire's resolution: what the arm is judged against)."""

    plan: TrajectoryPlan
    times_s: tuple[float, ...]
    start_rad: Vec4
    end_rad: Vec4
    path_rad: tuple[float | None, ...]
    goal_rad: tuple[float | None, ...]
    goal_time_s: float
    start_delay_s: float

    @property
    def end_s(self) -> float:
        """When the trajectory ends, from its start (s)."""
        return self.times_s[-1]

    def desired(self, t_s: float) -> tuple[list[float], list[float], int]:
        """Positions (rad) and velocities (rad/s) the trajectory gives at ``t_s`` from its start,
        and the index of the point it heads for (the last once past the end)."""
        points = (self.start_rad, *self.plan.targets_rad)
        times = self.times_s
        k = next((i for i in range(1, len(times)) if t_s < times[i]), len(times) - 1)
        if t_s >= times[-1]:
            return list(points[-1]), [0.0] * len(points[-1]), k - 1
        dt = times[k] - times[k - 1]
        f = (t_s - times[k - 1]) / dt if dt > 0 else 1.0
        a, b = points[k - 1], points[k]
        return ([x + f * (y - x) for x, y in zip(a, b, strict=True)],
                [(y - x) / dt if dt > 0 else 0.0 for x, y in zip(a, b, strict=True)], k - 1)

    def path_violation(self, names: Sequence[str], t_s: float,
                       q_rad: Sequence[float]) -> str | None:
        """Which joint is out of its path tolerance at ``t_s`` (and by how much), or None."""
        want, _, _ = self.desired(t_s)
        return _violation("path", names, want, q_rad, self.path_rad, t_s)

    def goal_violation(self, names: Sequence[str], q_rad: Sequence[float]) -> str | None:
        """Which joint is out of its goal tolerance (and by how much), or None."""
        return _violation("goal", names, self.end_rad, q_rad, self.goal_rad, None)


def _violation(kind: str, names: Sequence[str], want: Sequence[float], have: Sequence[float],
               tol: Sequence[float | None], t_s: float | None) -> str | None:
    for name, w, h, e in zip(names, want, have, tol, strict=True):
        if e is not None and abs(h - w) > e:
            when = "" if t_s is None else f" at {t_s:.3f} s"
            return (f"joint {name} is {h - w:+.4f} rad from the {kind}'s {w:.4f} rad{when}, "
                    f"beyond the {kind} tolerance of {e:.4g} rad")
    return None


def _tolerances(kind: str, given: Sequence[tuple[str, float]], names: list[str],
                default: Sequence[float]) -> tuple[float | None, ...]:
    out: list[float | None] = list(default)
    for joint, value in given:
        if joint not in names:
            raise GoalRefused(INVALID_JOINTS, f"{kind}_tolerance names joint "
                                              f"{peer_repr(joint)}, not one of the arm's {names}")
        if not math.isfinite(value) or (value < 0 and value != -1):
            raise GoalRefused(INVALID_GOAL, f"{kind}_tolerance of {joint}: position {value!r} "
                                            "must be > 0, 0 (the default) or -1 (not checked)")
        i = names.index(joint)
        out[i] = None if value == -1 else (value if value > 0 else default[i])
    return tuple(out)


def check_goal(goal: Goal, settings: RobotSettings, start_rad: Sequence[float], now_s: float,
               goal_default_rad: Sequence[float], *, max_duty: int = MAX_DUTY) -> Accepted:
    """Check ``goal`` whole against the arm at ``start_rad`` at ROS time ``now_s``; raises
    :class:`GoalRefused` with the result code (see the module doc)."""
    names = [j.name for j in settings.joints]
    if goal.multi_dof:
        raise GoalRefused(INVALID_JOINTS, f"the goal has multi-DOF joints or component "
                                          f"tolerances; the arm's joints {names} are revolute")
    if len(goal.names) != len(set(goal.names)) or sorted(goal.names) != sorted(names):
        raise GoalRefused(INVALID_JOINTS, f"joint_names {peer_repr(list(goal.names))} must be "
                                          f"the arm's joints {names}, each once, in any order")
    if goal.points > MAX_POINTS:
        raise GoalRefused(INVALID_GOAL, f"{goal.points} points, more than the {MAX_POINTS} "
                                        "accepted")
    if not goal.positions:
        raise GoalRefused(INVALID_GOAL, "the trajectory has no points")
    path = _tolerances("path", goal.path_tolerance, names,
                       [DEFAULT_PATH_TOLERANCE_RAD] * len(names))
    at_goal = _tolerances("goal", goal.goal_tolerance, names, goal_default_rad)
    slack = goal.goal_time_tolerance_s
    if not math.isfinite(slack) or slack < 0:
        raise GoalRefused(INVALID_GOAL, f"goal_time_tolerance {slack!r} s must be >= 0")
    delay = 0.0
    if goal.stamp_s > 0:
        if goal.stamp_s + goal.times_s[-1] < now_s:
            raise GoalRefused(OLD_HEADER_TIMESTAMP,
                              f"header.stamp {goal.stamp_s:.9f} s plus the trajectory's "
                              f"{goal.times_s[-1]:.4g} s ended before now ({now_s:.9f} s)")
        delay = max(0.0, goal.stamp_s - now_s)
        if delay > MAX_START_DELAY_S:
            raise GoalRefused(INVALID_GOAL, f"header.stamp is {delay:.4g} s in the future, more "
                                            f"than the {MAX_START_DELAY_S:g} s accepted")
    try:
        plan = plan_trajectory(goal.names, goal.positions, goal.times_s, settings, start_rad,
                               max_duty=max_duty)
    except TrajectoryError as exc:
        raise GoalRefused(INVALID_GOAL, str(exc)) from None
    if slack == 0:  # the driver's own slack for a move of this length
        slack = (MOVE_TIMEOUT_MARGIN - 1.0) * plan.planned_s + MOVE_TIMEOUT_SLACK_S
    start, end = (c.angles_rad(settings.lower_rad, settings.upper_rad)
                  for c in (plan.commands[0], plan.commands[-1]))
    return Accepted(plan, (0.0, *goal.times_s), start, end, path, at_goal, slack, delay)
