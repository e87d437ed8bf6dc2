"""The conditions of a start-up recovery trial (paper §5.2): how the test joints stand or move
relative to their Hall sensor when the power is cut, and where in their room they do it."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

from armbench.bench.suites.base import SuiteContext
from armbench.drivers.model.settings import RobotSettings

__all__ = ["CONDITIONS", "LIMIT_MARGIN_RAD", "Condition", "band", "parse_condition",
           "signed_range", "targets"]

#: Every condition, in the default order (each occurs twice in the default 20 trials).
CONDITIONS: Final = (
    "stopped-near", "stopped-far",
    "cw-away-near", "cw-away-far", "cw-toward-near", "cw-toward-far",
    "ccw-away-near", "ccw-away-far", "ccw-toward-near", "ccw-toward-far",
)

#: Keep a joint this far (rad) inside its limits when placing it.
LIMIT_MARGIN_RAD: Final = 0.02


@dataclass(frozen=True, slots=True)
class Condition:
    """A parsed condition: ``motion`` (``stopped``, ``cw``, ``ccw``), ``relation`` to the Hall
    sensor (``away``, ``toward``, or None when stopped) and ``zone`` (``near``, ``far``)."""

    name: str
    motion: str
    relation: str | None
    zone: str

    @property
    def moving(self) -> bool:
        """Whether the cut happens during a motion."""
        return self.motion != "stopped"

    @property
    def expected_to_recover(self) -> bool:
        """What §5.2's procedure predicts: every case but a motion towards the Hall sensor."""
        return self.relation != "toward"


def parse_condition(name: str) -> Condition:
    """``"cw-away-near"`` → Condition; raises ValueError for an unknown name."""
    parts = name.split("-")
    if len(parts) == 2 and parts[0] == "stopped" and parts[1] in ("near", "far"):
        return Condition(name, "stopped", None, parts[1])
    if (len(parts) == 3 and parts[0] in ("cw", "ccw") and parts[1] in ("away", "toward")
            and parts[2] in ("near", "far")):
        return Condition(name, parts[0], parts[1], parts[2])
    raise ValueError(f"unknown condition {name!r} (known: {', '.join(CONDITIONS)})")


def band(params: Mapping[str, Any], zone: str) -> tuple[float, float]:
    lo, hi = params[f"{zone}_band_rad"]
    return float(lo), float(hi)


def signed_range(settings: RobotSettings, joint: int, lo: float, hi: float,
                  side: int) -> tuple[float, float]:
    """The band ``[lo, hi]`` (rad, distance from the Hall angle) on ``side`` (+1/−1) of joint
    ``joint`` (0-based), clipped inside its limits; returned as (near end, far end)."""
    j = settings.joints[joint]
    hall = j.hall_rad
    limit = (j.upper_rad if side > 0 else j.lower_rad) - side * LIMIT_MARGIN_RAD
    room = abs(limit - hall)
    near, far = min(lo, room), min(hi, room)
    return hall + side * near, hall + side * far



def targets(ctx: SuiteContext, condition: Condition,
            joints: Sequence[int]) -> tuple[list[float], list[float]]:
    """Start and end joint angles (rad) of the condition's motion (equal when stopped):
    the test joints in the condition's band and side, the others at their Hall angle."""
    p = ctx.params
    rng = ctx.rng
    start = [j.hall_rad for j in ctx.settings.joints]
    end = list(start)
    lo, hi = band(p, condition.zone)
    for j in (int(v) - 1 for v in joints):
        if not condition.moving:
            side = rng.choice((1, -1))
            a, b = signed_range(ctx.settings, j, lo, hi, side)
            start[j] = end[j] = rng.uniform(min(a, b), max(a, b))
            continue
        # CW counts up. Away from the Hall sensor: CW on the + side, CCW on the − side.
        up = condition.motion == "cw"
        side = 1 if up == (condition.relation == "away") else -1
        near, far = signed_range(ctx.settings, j, lo, hi, side)
        going_out = condition.relation == "away"
        start[j], end[j] = (near, far) if going_out else (far, near)
    return start, end

