"""A ``trajectory_msgs/JointTrajectory`` checked whole and turned into the driver's path commands.

Pure functions, no ROS import: the node (:mod:`armbench.frontends.ros2_node.node`) hands over the
message's fields, :func:`plan_trajectory` refuses anything it cannot execute faithfully (with a
:class:`TrajectoryError` naming the point and the value) and otherwise returns the commands that
:func:`armbench.drivers.host.paths.stream_path` streams: the arm's current position first, then one
command per point with the per-joint duties that make every joint arrive together after the
point's ``time_from_start`` minus the previous one's
(:func:`armbench.drivers.host.motion.segment_duties`).

What is refused, before anything moves: joint names that are not exactly the arm's (any order),
a point whose positions are not one finite number per joint, a position outside the joint limits,
times that are negative, not finite or not increasing, and a segment faster than ``max_duty``
allows (law (12)). Velocities, accelerations and efforts in the points are not used: the firmware
takes a target and a duty per joint, so the speed of each segment follows from its duration.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from armbench.drivers.host.motion import CYCLE_S, segment_duties
from armbench.drivers.host.move_targets import check_target, wire_command
from armbench.drivers.model.errors import ArmbenchError, InvalidTargetError
from armbench.drivers.model.kinematics import Vec4, tcp_position
from armbench.drivers.model.peer_text import peer_repr
from armbench.drivers.model.protocol import JOINTS, MAX_DUTY, Command
from armbench.drivers.model.settings import RobotSettings

__all__ = ["DURATION_SLACK", "TrajectoryError", "TrajectoryPlan", "plan_trajectory"]

#: A segment may need up to this fraction more time than asked at ``max_duty`` (the firmware's
#: duty steps) before it is refused as too fast; beyond it the arm would lag the trajectory.
DURATION_SLACK: Final = 0.02

FloatArray = npt.NDArray[np.float64]


class TrajectoryError(ArmbenchError, ValueError):
    """A trajectory the node refuses: ``point`` (None for the whole message) and why."""

    def __init__(self, point: int | None, reason: str) -> None:
        self.point = point
        self.reason = reason
        where = "trajectory" if point is None else f"trajectory point {point}"
        super().__init__(f"{where}: {reason}")


@dataclass(frozen=True)
class TrajectoryPlan:
    """What :func:`plan_trajectory` made of a trajectory: the commands (``commands[0]``: where
    the arm is), each point's joint targets (rad, URDF order), TCP positions (m) of the start and
    the points, and the planned duration of the motion (s)."""

    commands: tuple[Command, ...]
    targets_rad: tuple[Vec4, ...]
    tcp_m: FloatArray
    planned_s: float

    @property
    def points(self) -> int:
        """Points of the trajectory (the start excluded)."""
        return len(self.targets_rad)


def _order(names: Sequence[str], settings: RobotSettings) -> list[int]:
    """For each of the arm's joints, its index in ``names``."""
    arm = [j.name for j in settings.joints]
    if len(names) != len(set(names)) or sorted(names) != sorted(arm):
        raise TrajectoryError(None, f"joint_names {peer_repr(list(names))} must be the arm's "
                                    f"joints {arm!r}, each once, in any order")
    return [list(names).index(n) for n in arm]


def _time(point: int, t_s: float, previous_s: float) -> float:
    if not math.isfinite(t_s) or t_s < 0:
        raise TrajectoryError(point, f"time_from_start {t_s!r} s must be finite and >= 0")
    if point > 0 and t_s <= previous_s:
        raise TrajectoryError(point, f"time_from_start {t_s!r} s must be after the previous "
                                     f"point's ({previous_s!r} s)")
    return t_s


def _target(point: int, positions: Sequence[float], order: list[int],
            settings: RobotSettings) -> Vec4:
    if len(positions) != JOINTS:
        raise TrajectoryError(point, f"has {len(positions)} positions, the arm has {JOINTS} "
                                     "joints")
    try:
        return check_target([float(positions[i]) for i in order], settings)
    except InvalidTargetError as exc:
        raise TrajectoryError(point, str(exc)) from exc


def plan_trajectory(names: Sequence[str], positions: Sequence[Sequence[float]],
                    times_s: Sequence[float], settings: RobotSettings, start_rad: Sequence[float],
                    *, max_duty: int = MAX_DUTY) -> TrajectoryPlan:
    """Check a trajectory (``names``: its ``joint_names``; per point its ``positions`` (rad) and
    ``time_from_start`` (s)) from the arm's current joints ``start_rad`` and plan it; raises
    :class:`TrajectoryError` for anything refused (see the module doc). An empty trajectory is
    refused too: the node treats it as "stop" before planning."""
    if not positions:
        raise TrajectoryError(None, "has no points")
    if len(times_s) != len(positions):
        raise TrajectoryError(None, f"{len(positions)} points but {len(times_s)} times")
    if not 1 <= max_duty <= MAX_DUTY:
        raise TrajectoryError(None, f"max_duty {max_duty!r} must be 1..{MAX_DUTY}")
    order = _order(names, settings)
    start: Vec4 = check_target(start_rad, settings)
    commands = [wire_command(start, (0,) * JOINTS, settings)]
    targets: list[Vec4] = []
    planned = 0.0
    previous_t, previous_q = 0.0, start
    for k, (pos, t) in enumerate(zip(positions, times_s, strict=True)):
        t_s = _time(k, float(t), previous_t)
        q = _target(k, pos, order, settings)
        dt = t_s - previous_t
        duties, needed_s = segment_duties(previous_q, q, dt, settings, max_duty)
        if needed_s > dt * (1.0 + DURATION_SLACK) + CYCLE_S:
            raise TrajectoryError(k, f"reaching it {dt:.4g} s after the previous point needs "
                                     f"{needed_s:.4g} s at duty {max_duty} (joint limits of "
                                     "speed): give it a later time_from_start")
        commands.append(wire_command(q, duties, settings))
        targets.append(q)
        planned += max(dt, needed_s)
        previous_t, previous_q = t_s, q
    tcp = tcp_position(np.array([start, *targets], dtype=np.float64), settings)
    return TrajectoryPlan(tuple(commands), tuple(targets),
                          np.asarray(tcp, dtype=np.float64).reshape(-1, 3), planned)
