"""The touch-off procedure of ``armbench calibrate --port PORT --touch-off plate.toml``: for each
known point of a plate the arm brings its tool :data:`LIFT_M` above the point (through the
nominal model), every joint arriving from a side of its own beyond the widest play (so the
play starts taken up on a known flank, each joint from both over the points), the operator
jogs it onto the point, and the driver records the joint readings and every reading the jogs
left on the way (the path the play operator replays in the fit,
``bench/calibrate/reference.py``).

The operator is anything with ``touch(point, jog)`` (:class:`Operator`): a person at a terminal
(``cli/commands/touch_operator.py``) or a script. :class:`Jog` is what they move the arm with:
a joint by an angle, the tool by a step in the base frame (solved through the nominal model, so
it lands near where asked, not on it: the operator looks and jogs again), each a move at
:data:`JOG_DUTY`, slow as an operator's jog.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Sequence
from typing import Final, Protocol

import numpy as np

from armbench.bench.calibrate.model import APPROACH_OFFSET_RAD, ReferencePose
from armbench.bench.calibrate.reference import Plate, PlatePoint
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.kinematics import ik_best, tcp_position

__all__ = ["JOG_DUTY", "LIFT_M", "Jog", "Operator", "touch_off"]

#: How far above each point (m, along the base's z) the arm brings the tool.
LIFT_M: Final = 0.01
#: Duty of the move above a point and of every jog.
APPROACH_DUTY: Final = 95
JOG_DUTY: Final = 70
#: Rest before a reading is taken (s).
SETTLE_S: Final = 0.3


class Jog:
    """Moves the arm for an operator, recording the reported angles after each move."""

    def __init__(self, arm: Arm) -> None:
        self.arm = arm
        self.history: list[list[float]] = [list(arm.state.q_rad)]

    @property
    def q_rad(self) -> tuple[float, ...]:
        """The reported joint angles now (rad)."""
        return tuple(self.arm.state.q_rad)

    async def joints(self, delta_rad: Sequence[float]) -> None:
        """Move the joints by ``delta_rad`` (rad, four; within the limits)."""
        target = [min(max(q + d, s.lower_rad), s.upper_rad) for q, d, s in zip(
            self.arm.state.q_rad, delta_rad, self.arm.settings.joints, strict=True)]
        await self.arm.move_joints(target, JOG_DUTY)
        await asyncio.sleep(SETTLE_S)
        self.history.append(list(self.arm.state.q_rad))

    async def tool(self, delta_m: Sequence[float]) -> None:
        """Move the tool by ``delta_m`` (m, base frame) as the nominal model has it."""
        q = np.asarray(self.arm.state.q_rad)
        there = tcp_position(q, self.arm.settings) + np.asarray(delta_m, dtype=np.float64)
        sol = ik_best(there, self.arm.settings, near=q)
        await self.joints([float(a - b) for a, b in zip(sol.q_protocol, q, strict=True)])


class Operator(Protocol):
    """Whoever jogs the tool onto the plate's points."""

    async def touch(self, point: PlatePoint, jog: Jog) -> bool:
        """Jog the tool onto ``point`` (it is :data:`LIFT_M` above it); True when it is on it,
        False to leave the point out."""
        ...


async def touch_off(arm: Arm, plate: Plate, operator: Operator,
                    progress: Callable[[str], None] = lambda message: None
                    ) -> list[ReferencePose]:
    """Touch each point of ``plate`` (see the module doc): one reference pose per point the
    operator touched, with the plate's and the touch's standard error."""
    out = []
    for k, point in enumerate(plate.points):
        above = np.asarray(point.xyz_m) + np.asarray([0.0, 0.0, LIFT_M])
        target = ik_best(above, arm.settings, near=arm.state.q_rad).q_protocol
        # each joint from its side: the bits of the point's index, so both over the points
        approach = [1 if (k >> j) & 1 else -1 for j in range(4)]
        await arm.move_joints([min(max(v - a * APPROACH_OFFSET_RAD, s.lower_rad), s.upper_rad)
                               for v, a, s in zip(target, approach, arm.settings.joints,
                                                  strict=True)], APPROACH_DUTY)
        await arm.move_joints(target, APPROACH_DUTY)
        await asyncio.sleep(SETTLE_S)
        progress(f"touch-off: point {point.name} at {tuple(round(v * 1e3, 2) for v in point.xyz_m)}"
                 " mm")
        jog = Jog(arm)
        if not await operator.touch(point, jog):
            progress(f"touch-off: point {point.name} left out")
            continue
        await asyncio.sleep(SETTLE_S)
        q = list(arm.state.q_rad)
        out.append(ReferencePose(q, list(point.xyz_m), plate.point_sigma_m, approach,
                                 [*jog.history, q], source=f"plate point {point.name}"))
        await jog.tool([0.0, 0.0, LIFT_M])  # off the plate before the next point
    return out
