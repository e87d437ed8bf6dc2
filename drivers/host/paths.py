"""Path following: a Cartesian path cut into waypoints, solved on one IK branch, and streamed to
the arm one waypoint ahead of its arrival.

:meth:`~armbench.drivers.host.arm.Arm.follow_path` checks the options, plans with :func:`plan_path`
and :func:`path_commands` (no I/O), moves to the start and hands over to :func:`stream_path`, which
sends each waypoint and waits with the shared
:class:`~armbench.drivers.host.arrival.ArrivalTracker`. What it did comes back as a
:class:`PathRun`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final, NamedTuple

import numpy as np
import numpy.typing as npt

from armbench.drivers.host.arrival import (
    HOLD_ON,
    MOVE_TIMEOUT_MARGIN,
    MOVE_TIMEOUT_SLACK_S,
    ArrivalTracker,
)
from armbench.drivers.host.link import ArmLink
from armbench.drivers.host.motion import (
    Path,
    PathError,
    point_to_polyline_m,
    polyline,
    segment_duties,
)
from armbench.drivers.host.move_targets import Duties, wire_command
from armbench.drivers.host.state import JointState
from armbench.drivers.model.kinematics import Vec4, ik_best, tcp_position
from armbench.drivers.model.protocol import JOINTS, Command
from armbench.drivers.model.settings import RobotSettings

__all__ = [
    "CORNER_RAD",
    "LOOKAHEAD_S",
    "MAX_WAYPOINT_JUMP_RAD",
    "PathRun",
    "SentWaypoint",
    "path_commands",
    "plan_path",
    "stream_path",
]

#: ``follow_path`` sends the next waypoint when every joint is this close (in time, at its duty)
#: to the current one: about the latency from a reply being sampled to a command taking effect.
LOOKAHEAD_S: Final = 0.010
#: ``follow_path`` stops at a waypoint where the path turns by more than this (a corner).
CORNER_RAD: Final = math.radians(10.0)
#: ``follow_path`` refuses a path whose IK jumps by more than this between two waypoints.
MAX_WAYPOINT_JUMP_RAD: Final = 0.5

FloatArray = npt.NDArray[np.float64]


class SentWaypoint(NamedTuple):
    """A path command as sent: loop time, target (rad, as on the wire), duties, TCP target (m)."""

    t_s: float
    q_rad: Vec4
    duties: Duties
    xyz_m: tuple[float, float, float]


@dataclass
class PathRun:
    """What :meth:`Arm.follow_path` did: the reference waypoints (N, 3, metres), every command
    sent, and every state received from the first path command to the arrival at the end."""

    reference_m: FloatArray
    waypoints: list[SentWaypoint] = field(default_factory=list)
    states: list[JointState] = field(default_factory=list)
    t_start_s: float = 0.0
    t_end_s: float = 0.0
    resends: int = 0

    @property
    def duration_s(self) -> float:
        """Seconds from the first path command to the arrival at the last waypoint."""
        return self.t_end_s - self.t_start_s

    def samples(self) -> list[tuple[float, Vec4]]:
        """``(t_s, q_rad)`` of every recorded state."""
        return [(s.t_s, s.q_rad) for s in self.states]

    def joint_angles(self) -> FloatArray:
        """Recorded joint angles, (M, 4) rad."""
        return np.array([s.q_rad for s in self.states], dtype=np.float64).reshape(-1, 4)

    def tcp_m(self, settings: RobotSettings) -> FloatArray:
        """TCP positions of the recorded states by forward kinematics, (M, 3) metres."""
        if not self.states:
            return np.zeros((0, 3))
        out: FloatArray = tcp_position(self.joint_angles(), settings)
        return out

    def path_errors_m(self, settings: RobotSettings) -> FloatArray:
        """Distance of each recorded TCP position to the reference polyline, (M,) metres."""
        return point_to_polyline_m(self.tcp_m(settings), self.reference_m)

    def mean_error_m(self, settings: RobotSettings) -> float:
        """Mean distance of the recorded TCP positions to the reference (the paper's figure of
        merit: 12.4 mm on its square), metres."""
        e = self.path_errors_m(settings)
        return float(e.mean()) if len(e) else 0.0


def plan_path(path: Path | Sequence[Sequence[float]] | npt.ArrayLike, settings: RobotSettings,
              near_rad: Vec4, *, roll_rad: float = 0.0, spacing_m: float = 0.005,
              branch: str | None = None) -> tuple[FloatArray, list[Vec4]]:
    """The waypoints (N, 3, metres) of ``path`` at most ``spacing_m`` apart and their IK
    solutions on one branch (``branch``, else the one closest to ``near_rad``).

    Raises the kinematics errors for an unreachable or out-of-limits waypoint and
    :class:`~armbench.drivers.host.motion.PathError` if the IK jumps between neighbouring
    waypoints."""
    p = path if isinstance(path, Path) else polyline(list(np.asarray(path, dtype=np.float64)))
    pts = p.waypoints(spacing_m)
    first = ik_best(pts[0], settings, roll=roll_rad, branch=branch, near=near_rad)
    chosen = branch or first.branch
    qs: list[Vec4] = [first.q_protocol]
    for k in range(1, len(pts)):
        sol = ik_best(pts[k], settings, roll=roll_rad, branch=chosen, near=qs[-1])
        jump = max(abs(a - b) for a, b in zip(sol.q_protocol, qs[-1], strict=True))
        if jump > MAX_WAYPOINT_JUMP_RAD:
            raise PathError(f"IK jumps by {jump:.3f} rad between waypoints {k - 1} and {k} "
                            f"({pts[k - 1].tolist()} → {pts[k].tolist()} m): the path "
                            "passes a singularity or a branch boundary")
        qs.append(sol.q_protocol)
    return pts, qs


def path_commands(pts: FloatArray, qs: Sequence[Vec4], speed_m_s: float, max_duty: int,
                  approach_duty: int, settings: RobotSettings) -> tuple[list[Command], float]:
    """The command of each waypoint (the first at ``approach_duty`` on all joints, the others
    with the duties that make the joints arrive together at ``speed_m_s``, never above
    ``max_duty``) and the planned duration of the streamed part (s)."""
    cmds: list[Command] = [wire_command(qs[0], (approach_duty,) * JOINTS, settings)]
    planned = 0.0
    for k in range(1, len(qs)):
        seg_s = float(np.linalg.norm(pts[k] - pts[k - 1])) / speed_m_s
        duties, dur = segment_duties(qs[k - 1], qs[k], seg_s, settings, max_duty)
        cmds.append(wire_command(qs[k], duties, settings))
        planned += dur
    return cmds, planned


async def stream_path(link: ArmLink, pts: FloatArray, cmds: Sequence[Command], planned_s: float,
                      tol: Vec4, lookahead_s: float, timeout_s: float | None) -> PathRun:
    """Stream the waypoints ``cmds[1:]`` (the arm is at ``cmds[0]``): send each, wait until every
    joint is within ``lookahead_s`` of it at its duty (within ``tol`` at corners and at the end),
    then send the next. ``timeout_s`` (default: from ``planned_s`` as for a move) bounds the
    whole stream; a hold is sent when it is exceeded or the wait is cancelled."""
    run = PathRun(reference_m=pts)
    if len(cmds) == 1:
        return run
    if timeout_s is None:
        timeout_s = link.move_timeout_scale * (MOVE_TIMEOUT_MARGIN * planned_s
                                               + MOVE_TIMEOUT_SLACK_S)
    corners = _corners(pts)
    gen = link._supersede()
    resends0 = link.resends
    last = len(cmds) - 1
    try:
        with link._recording(run.states):
            k = 1
            t = await link._send(cmds[k])
            run.t_start_s = t
            tracker = ArrivalTracker(link, tol, t + timeout_s, timeout_s, gen, since=t)
            while True:
                goal = cmds[k].angles_rad(link._lower, link._upper)
                run.waypoints.append(_sent(t, goal, cmds[k], pts[k]))
                tracker.aim(cmds[k], goal, t, 0.0 if (k == last or k in corners) else lookahead_s)
                state = await tracker.arrive()
                if k == last:
                    run.t_end_s = state.t_s
                    return run
                k += 1
                t = await link._send(cmds[k])
    except HOLD_ON:
        await link._hold_best_effort()
        raise
    finally:
        run.resends = link.resends - resends0


def _sent(t: float, goal: Vec4, cmd: Command, xyz: FloatArray) -> SentWaypoint:
    return SentWaypoint(t, goal, cmd.duties, (float(xyz[0]), float(xyz[1]), float(xyz[2])))


def _corners(pts: FloatArray) -> set[int]:
    """Indices of interior waypoints where the path turns by more than ``CORNER_RAD``."""
    out: set[int] = set()
    for k in range(1, len(pts) - 1):
        a, b = pts[k] - pts[k - 1], pts[k + 1] - pts[k]
        na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
        if na == 0 or nb == 0:
            continue
        c = float(np.dot(a, b)) / (na * nb)
        if math.acos(max(-1.0, min(1.0, c))) > CORNER_RAD:
            out.add(k)
    return out
