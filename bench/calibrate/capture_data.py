"""A capture as calibration and twin-check read it: the commands and the replies with their times,
checked against the robot model, and what the traffic alone shows (reply period, latency, effective
speed against duty and direction).

The capture is read with :func:`armbench.drivers.capture.read.open_capture` (MCAP or JSON
Lines), so every capture format it reads works here. Problems are :class:`CaptureContentError`
naming the file and the problem: a truncated capture, replies that this robot model cannot have
produced, a capture without commands.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np

from armbench.bench.calibrate.ladder import speed_of
from armbench.bench.calibrate.model import CaptureContentError, Observations, SpeedRun
from armbench.drivers.capture.jsonl import CaptureError
from armbench.drivers.capture.read import is_mcap, mcap_layout, open_capture
from armbench.drivers.host.motion import joint_speed_rad_s
from armbench.drivers.host.state import JointState
from armbench.drivers.model.protocol import AngleDecoder, Command, Framer, Reply
from armbench.drivers.model.settings import RobotSettings

__all__ = ["CaptureData", "load_capture", "observations_from_capture"]

#: How far (rad) a reply may lie outside the joint limits before the capture counts as another
#: robot model's (the firmware never drives beyond its limits; a few ticks of rounding remain).
LIMIT_SLACK_RAD: Final = 0.02
#: Smallest move (rad) the capture fit takes a speed from.
MIN_MOVE_RAD: Final = 0.05

Vec4 = tuple[float, float, float, float]


@dataclass(frozen=True, slots=True)
class CaptureData:
    """The commands (capture seconds, command) and replies (capture seconds, joint angles rad)."""

    path: str
    commands: list[tuple[float, Command]]
    replies: list[tuple[float, Vec4]]
    bad_in_frames: int


def _line_count(path: Path) -> int | None:
    try:
        with path.open("rb") as fh:
            return sum(1 for _ in fh)
    except OSError:
        return None


def _no_traffic(path: Path) -> str:
    """Why a capture without a frame has none: a killed run's MCAP file holds no complete chunk
    (its frames were still in memory), any other holds no traffic."""
    if is_mcap(path) or path.suffix.lower() == ".mcap":
        layout = mcap_layout(path)
        if not layout.closed and layout.chunks == 0:
            return ("holds no complete chunk: the run was killed before the first flush; "
                    "nothing to replay")
    return "holds no traffic"


def load_capture(path: str | Path, settings: RobotSettings) -> CaptureData:
    """Read and check a capture; raises :class:`CaptureContentError` (or the reader's
    ``CaptureError`` for a file that is not a capture at all, a damaged one, times that run
    backwards)."""
    p = Path(path)
    decode = AngleDecoder(settings.lower_rad, settings.upper_rad)
    commands: list[tuple[float, Command]] = []
    replies: list[tuple[float, Vec4]] = []
    bad = 0
    one_reply = Framer("reply").one_reply  # holds nothing between calls: a reply or None
    try:
        for rec in open_capture(p):
            if rec.error is not None:
                bad += rec.dir == "in"
                continue
            data = rec.frame.encode("ascii", "backslashreplace")
            reply = one_reply(data) if rec.dir == "in" else None
            if reply is not None:
                replies.append((rec.t_s, decode(reply)))
                continue
            events = Framer("command" if rec.dir == "out" else "reply").feed(data)
            if rec.dir == "out":
                if len(events) == 1 and isinstance(events[0], Command):
                    commands.append((rec.t_s, events[0]))
                continue
            if len(events) == 1 and isinstance(events[0], Reply):
                replies.append((rec.t_s, decode(events[0])))
            else:
                bad += 1
    except CaptureError as exc:
        if (exc.line is not None and exc.reason.startswith("is not JSON")
                and exc.line == _line_count(p)):
            raise CaptureContentError(str(p), f"truncated: the last record (line {exc.line}) "
                                              f"is incomplete ({exc.reason})") from exc
        raise
    if not replies:
        if not commands and not bad:
            raise CaptureContentError(str(p), _no_traffic(p))
        if not bad:
            raise CaptureContentError(str(p), f"no replies: {len(commands)} commands and not "
                                              "one reply (the arm never answered)")
        raise CaptureContentError(str(p), f"another robot model: {bad} reply frames that are "
                                          "not this protocol's 4-joint replies, and no other")
    if bad > 0.5 * (bad + len(replies)):
        raise CaptureContentError(str(p), f"another robot model: {bad} of "
                                          f"{bad + len(replies)} reply frames are not "
                                          "this protocol's 4-joint replies")
    q = np.array([r[1] for r in replies])
    inside = ((q >= np.array(settings.lower_rad) - LIMIT_SLACK_RAD)
              & (q <= np.array(settings.upper_rad) + LIMIT_SLACK_RAD))
    if not inside.all():
        k, j = (int(i) for i in np.argwhere(~inside)[0])  # the first reply outside, its joint
        spec = settings.joints[j]
        raise CaptureContentError(
            str(p), f"another robot model: at {replies[k][0]:.3f} s joint {j + 1} reports "
                    f"{replies[k][1][j]:+.4f} rad, outside its limits {spec.lower_rad:+.4f}.."
                    f"{spec.upper_rad:+.4f} rad in these settings")
    if not commands:
        raise CaptureContentError(str(p), "no commands: the capture has replies only (a "
                                          "monitor session?), nothing to replay or fit")
    return CaptureData(str(p), commands, replies, bad)


def _states(replies: Sequence[tuple[float, Vec4]]) -> list[JointState]:
    return [JointState(t, q, (0, 0, 0, 0), k) for k, (t, q) in enumerate(replies, 1)]


def observations_from_capture(data: CaptureData, settings: RobotSettings) -> Observations:
    """What the traffic shows: reply period, latency of commands that started a joint from rest,
    and the effective speed of every complete single move of at least :data:`MIN_MOVE_RAD`."""
    obs = Observations(source=data.path)
    t = np.asarray([r[0] for r in data.replies])
    q = np.asarray([r[1] for r in data.replies])
    dt = np.diff(t)
    if len(dt):
        typical = float(np.median(dt))
        obs.reply_dt_s = [float(x) for x in dt if x <= 10 * typical]
    lower, upper = settings.lower_rad, settings.upper_rad
    times = [c[0] for c in data.commands] + [math.inf]
    for k, (tc, cmd) in enumerate(data.commands):
        i0 = int(np.searchsorted(t, tc))
        i1 = int(np.searchsorted(t, times[k + 1]))
        if i0 == 0 or i0 >= len(t):
            continue
        start = q[i0 - 1]
        goal = cmd.angles_rad(lower, upper)
        window = q[i0:i1]
        if len(window) == 0:
            continue
        moved = np.any(window != start, axis=1)
        at_rest = i0 >= 2 and bool(np.all(q[i0 - 2:i0] == start))
        if at_rest and moved.any():
            obs.latency_s.append(float(t[i0 + int(np.argmax(moved))] - tc))
        for j, spec in enumerate(settings.joints):
            duty = cmd.duties[j]
            span = goal[j] - start[j]
            if duty == 0 or abs(span) < MIN_MOVE_RAD:
                continue
            arrived = np.abs(window[:, j] - goal[j]) < 3e-4
            if not arrived.any():
                continue
            states = _states(data.replies[i0:i0 + int(np.argmax(arrived)) + 1])
            run = speed_of(states, j, float(start[j]), float(goal[j]))
            if run is None:
                continue
            obs.speeds.append(SpeedRun(j + 1, duty, 1 if span > 0 else -1,
                                       [float(v) for v in start],
                                       joint_speed_rad_s(duty, spec.steps_per_rad), run[0],
                                       run[1], abs(span) * spec.steps_per_rad, run[2]))
    obs.phases_done = ["capture"]
    obs.robot_time_s = float(t[-1] - t[0]) if len(t) else 0.0
    return obs
