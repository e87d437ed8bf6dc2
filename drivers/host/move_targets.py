"""What a move may ask for: joint targets, duties and tolerances checked against the robot model
before anything is sent, and the command that puts a checked target on the wire.

One rule for every way a target reaches the arm: an angle is within a joint's limits if it is at
most :data:`LIMIT_SLACK_RAD` past them, whether it comes as radians (``check_target``) or as a raw
command's wire ticks (``check_command``). Errors name the joint and the offending value.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import Final

import numpy as np
import numpy.typing as npt

from armbench.drivers.model.bounds import Bound, check, check_whole, option_refused
from armbench.drivers.model.errors import InvalidTargetError, JointRangeError
from armbench.drivers.model.kinematics import Vec4
from armbench.drivers.model.protocol import (
    JOINTS,
    MAX_DUTY,
    TICKS_PER_RAD,
    Command,
    rad_to_ticks,
    ticks_to_rad,
)
from armbench.drivers.model.settings import JointSettings, RobotSettings

__all__ = [
    "DEFAULT_TOLERANCE_RAD",
    "LIMIT_SLACK_RAD",
    "TICK_RAD",
    "Duties",
    "check_command",
    "check_duties",
    "check_duty",
    "check_limits",
    "check_target",
    "default_tolerances",
    "tolerances",
    "wire_command",
]

Duties = tuple[int, int, int, int]

#: One protocol tick: the resolution of angles on the wire (rad).
TICK_RAD: Final = 1.0 / TICKS_PER_RAD
#: How far past a joint limit a target may be and still count as within it (rad): half a tick,
#: the wire's rounding. A target on a limit can be put on the wire up to half a tick past it, so
#: a raw command built from it is accepted; and any accepted target is aimed inside the limit by
#: :func:`wire_command`'s one-tick nudge (at most half a tick of slack plus half a tick of
#: rounding), so the firmware never aims beyond a limit. ``docs/driver.md`` explains the choice.
LIMIT_SLACK_RAD: Final = 0.5 * TICK_RAD
#: Default arrival tolerance per joint (rad): a few protocol ticks (1e-4 rad) and encoder counts.
DEFAULT_TOLERANCE_RAD: Final = 3e-4
#: A duty on the wire (00 is a hold, not a speed) and an arrival tolerance.
_DUTY: Final = Bound(1, MAX_DUTY, whole=True, why="00 holds: use stop()")
_TOLERANCE_RAD: Final = Bound(0.0, math.inf, "rad", low_open=True)


def check_limits(q_rad: Sequence[float], settings: RobotSettings) -> None:
    """Raise :class:`JointRangeError` naming the first joint of ``q_rad`` more than
    :data:`LIMIT_SLACK_RAD` past its limits."""
    for i, (v, j) in enumerate(zip(q_rad, settings.joints, strict=True), 1):
        _check_joint(i, v, j)


def _check_joint(i: int, v: float, j: JointSettings) -> None:
    if v < j.lower_rad - LIMIT_SLACK_RAD:
        raise JointRangeError(i, j.name, v, j.lower_rad, "lower")
    if v > j.upper_rad + LIMIT_SLACK_RAD:
        raise JointRangeError(i, j.name, v, j.upper_rad, "upper")


def check_target(q_rad: Sequence[float] | npt.ArrayLike, settings: RobotSettings) -> Vec4:
    """Four finite joint angles (rad) within the limits, as floats; raises
    :class:`InvalidTargetError` / :class:`JointRangeError` naming the joint otherwise."""
    try:
        values = [float(v) for v in np.asarray(q_rad, dtype=np.float64).reshape(-1)]
    except (TypeError, ValueError):
        raise InvalidTargetError(None, "target", q_rad, "is not a sequence of numbers") from None
    if len(values) != JOINTS:
        raise InvalidTargetError(None, "target", q_rad,
                                 f"has {len(values)} values; the arm has {JOINTS} joints")
    for i, (v, j) in enumerate(zip(values, settings.joints, strict=True), 1):
        if not math.isfinite(v):
            raise InvalidTargetError(i, "target", v, "is not a finite angle")
        _check_joint(i, v, j)
    return (values[0], values[1], values[2], values[3])


def check_command(command: Command, settings: RobotSettings) -> None:
    """Raise :class:`JointRangeError` if a raw command aims a joint past its limits (its wire
    ticks decoded into each joint's window)."""
    check_limits(command.angles_rad(settings.lower_rad, settings.upper_rad), settings)


def check_duty(duty: object, joint: int | None = None) -> int:
    """A duty 1..99 as an int; raises :class:`InvalidTargetError` otherwise (00 is a hold)."""
    return check_whole("duty", duty, _DUTY, option_refused if joint is None
                       else functools.partial(InvalidTargetError, joint))


def check_duties(duty: int | Sequence[int]) -> Duties:
    """One duty for all joints or one per joint, checked, as four duties."""
    if isinstance(duty, (int, np.integer)) and not isinstance(duty, bool):
        d = check_duty(duty)
        return (d, d, d, d)
    if isinstance(duty, (str, bytes)) or not isinstance(duty, Sequence):
        raise InvalidTargetError(None, "duty", duty, "is not a duty or 4 duties")
    if len(duty) != JOINTS:
        raise InvalidTargetError(None, "duty", duty, f"has {len(duty)} values, not {JOINTS}")
    ds = [check_duty(v, i) for i, v in enumerate(duty, 1)]
    return (ds[0], ds[1], ds[2], ds[3])


def default_tolerances(settings: RobotSettings) -> Vec4:
    """Per-joint arrival tolerance used when none is given (rad): ``max(3e-4, 1.5 encoder counts
    + 1e-4)`` (the firmware's 1-count deadband, half a count of rounding of the target and one
    protocol tick of rounding of the reply)."""
    t = [max(DEFAULT_TOLERANCE_RAD, 1.5 / j.counts_per_rad + TICK_RAD) for j in settings.joints]
    return (t[0], t[1], t[2], t[3])


def tolerances(tolerance_rad: float | Sequence[float] | None, default: Vec4) -> Vec4:
    """One tolerance for all joints or one per joint (rad, finite, > 0); ``default`` for None."""
    if tolerance_rad is None:
        return default
    scalar = isinstance(tolerance_rad, (int, float))
    values = ([tolerance_rad] * JOINTS if isinstance(tolerance_rad, (int, float))
              else list(tolerance_rad))
    if len(values) != JOINTS:
        raise InvalidTargetError(None, "tolerance_rad", tolerance_rad,
                                 "must be one or 4 finite numbers > 0")
    t = [check("tolerance_rad", v, _TOLERANCE_RAD,
               option_refused if scalar else functools.partial(InvalidTargetError, i))
         for i, v in enumerate(values, 1)]
    return (t[0], t[1], t[2], t[3])


def wire_command(target: Sequence[float], duties: Sequence[int],
                 settings: RobotSettings) -> Command:
    """The command for a checked target; a wire value that rounds just past a limit is moved
    one tick inwards, so the firmware never aims beyond a limit."""
    cmd = Command.from_rad(target, list(duties))
    ticks = list(cmd.ticks)
    changed = False
    for i, j in enumerate(settings.joints):
        q = ticks_to_rad(ticks[i], j.lower_rad, j.upper_rad)
        if q < j.lower_rad:
            ticks[i], changed = rad_to_ticks(q + TICK_RAD), True
        elif q > j.upper_rad:
            ticks[i], changed = rad_to_ticks(q - TICK_RAD), True
    if changed:
        cmd = Command((ticks[0], ticks[1], ticks[2], ticks[3]), cmd.duties)
    return cmd
