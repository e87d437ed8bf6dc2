"""The held-out blocks of ``armbench calibrate --port``: the motions the suites make, recorded
and never fitted, on which the calibration judges its fitted structures against the prior
(:mod:`armbench.bench.calibrate.held_out`).

A block is the accuracy suite's lap, shortened to what its share of the budget holds: the
approach to the square's first corner, each joint's own moves there (the joints suite's style:
joints 1 and 4 move in no square's corners, so they come first, before a short budget runs out),
the square's first edge streamed (a stream is judged however short the budget: a stop rule
shows itself differently there), the square's other corners at full duty with one duty for
every joint (the paper's style), then its edges streamed with per-joint duties at the suite's speed
(armbench's coordinated style: the duties a path uses, well below full). The same block is made
twice: right after the approaches, and at the end of the session (an arm whose behaviour moves
during the session is then not judged by what it did at the start only). A stalled corner is
held and sent again slower, as every move of the procedure; a path that times out is held, and
the block goes on.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from typing import Final

from armbench.bench.calibrate.model import ArmDoesNotMoveError, HeldOut
from armbench.bench.suites.workspace import DEFAULT_SQUARE_CENTRE_M, DEFAULT_SQUARE_SIDE_M
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.kinematics import ik_best
from armbench.drivers.model.protocol import MAX_DUTY
from armbench.metrics import square_yz

__all__ = ["BLOCK_SHARE", "EDGE_S", "EDGE_SPEED_M_S", "Segment", "SuiteBlock",
           "corner_targets", "plan_block", "run_block"]

#: Share of the budget each held-out block may take (two blocks: the suite's motions after the
#: approaches and again at the end).
BLOCK_SHARE: Final = 0.15
#: The accuracy suite's streaming speed (m/s) and its waypoint spacing (m).
EDGE_SPEED_M_S: Final = 0.05
EDGE_SPACING_M: Final = 0.005
#: The branch of the square's IK solutions (the accuracy suite's).
BRANCH: Final = "front-up"
#: Rest after a block (s): its last replies show where the arm settled; and before it: its
#: first replies show the pose it starts from at rest (longer than the replies of its window
#: before its first command, ``held_out.LEAD_S``).
SETTLE_S: Final = 0.3
REST_BEFORE_S: Final = 0.2
#: Room for the arrival of each streamed edge beyond its law time (s).
EDGE_SLACK_S: Final = 0.5
CORNERS: Final = square_yz(DEFAULT_SQUARE_CENTRE_M, DEFAULT_SQUARE_SIDE_M)
#: Robot time (s) an edge of the square takes streamed, with room for its arrival.
EDGE_S: Final = DEFAULT_SQUARE_SIDE_M / EDGE_SPEED_M_S + EDGE_SLACK_S


#: Each joint's own moves in a block (the joints suite's style, one joint at a time): this far
#: (rad) at full duty and back at the repeatability suite's half speed (duty 97).
JOINT_WAY_RAD: Final = 0.3
JOINT_DUTIES: Final = (MAX_DUTY, 97)


@dataclass(frozen=True, slots=True)
class Segment:
    """One part of a block: the move to corner ``index`` of the square (0..3; the first is the
    approach), joint ``index``'s own moves (0-based), or the square's first ``index`` edges
    streamed; ``estimate_s``: its robot time as planned."""

    kind: str
    index: int
    estimate_s: float


@dataclass(frozen=True, slots=True)
class SuiteBlock:
    """What a block holds, in order (:func:`plan_block`)."""

    segments: tuple[Segment, ...]

    @property
    def estimate_s(self) -> float:
        """Its robot time as planned."""
        return sum(s.estimate_s for s in self.segments)

    @property
    def edges(self) -> int:
        """How many edges of the square it streams."""
        return sum(s.index for s in self.segments if s.kind == "edge")


def corner_targets(arm: Arm) -> list[list[float]]:
    """The joint angles (protocol, rad) of the square's corners 0 to 3 on the suite's
    branch."""
    return [[float(v) for v in ik_best(CORNERS[k], arm.settings, branch=BRANCH).q_protocol]
            for k in range(4)]


def joint_target(q: Sequence[float], j: int, arm: Arm) -> list[float]:
    """``q`` with joint ``j`` :data:`JOINT_WAY_RAD` further (back the other way where its upper
    limit is nearer)."""
    spec = arm.settings.joints[j]
    out = list(q)
    up = q[j] + JOINT_WAY_RAD <= spec.upper_rad - 0.05
    out[j] = q[j] + (JOINT_WAY_RAD if up else -JOINT_WAY_RAD)
    return out


def plan_block(allot_s: float, arm: Arm, estimate: Callable[[Sequence[float],
               Sequence[float], int], float]) -> SuiteBlock | None:
    """The block that fits ``allot_s`` of robot time (``estimate``: a move's robot time from,
    to, at a duty): the approach to the square's first corner, each joint's own moves there,
    the square's first edge streamed, its other corners at full duty (the paper's style) and
    back to the first, then as many of the square's edges streamed as the rest holds
    (armbench's style; at most four: a whole lap), each part in that order while it fits; None
    when not even the approach and two joints' moves do."""
    corners = corner_targets(arm)
    plan: list[Segment] = []
    q = list(arm.state.q_rad)
    for kind, index in (("corner", 0), *(("joint", j) for j in range(4)), ("edge", 1),
                        ("corner", 2), ("corner", 3), ("corner", 0)):
        if kind == "edge":  # from the first corner to the second
            need, q_next = EDGE_S, corners[1]
        elif kind == "corner":
            need, q_next = estimate(q, corners[index], MAX_DUTY), corners[index]
        else:
            there = joint_target(q, index, arm)
            need, q_next = sum(estimate(a, b, d) for (a, b), d in zip(
                ((q, there), (there, q)), JOINT_DUTIES, strict=True)), q
        if sum(s.estimate_s for s in plan) + need > allot_s:
            break
        plan.append(Segment(kind, index, need))
        q = q_next
    if len(plan) < 3:
        return None
    if len(plan) == 9:  # every corner: back at the first, the edges may follow
        edges = min(4, int((allot_s - sum(s.estimate_s for s in plan)) // EDGE_S))
        if edges:
            plan.append(Segment("edge", edges, edges * EDGE_S))
    return SuiteBlock(tuple(plan))


async def run_block(arm: Arm, block: SuiteBlock, name: str, origin_s: float,
                    move: Callable[[Sequence[float], int], Awaitable[bool]],
                    fits: Callable[[float], bool]) -> tuple[HeldOut, ArmDoesNotMoveError | None]:
    """Make ``block`` (``move``: the procedure's move, which holds a stalled joint and sends it
    again slower; each part only while ``fits`` its estimate in the budget) and return its
    window on the capture's clock (loop time less ``origin_s``). A joint that stands at every
    duty ends the block there: its error is returned beside the window (what the block did is
    evidence all the same)."""
    await asyncio.sleep(REST_BEFORE_S)
    start = arm.state.t_s - origin_s
    failure: ArmDoesNotMoveError | None = None
    corners = corner_targets(arm)
    try:
        for seg in block.segments:
            if not fits(seg.estimate_s):
                break
            if seg.kind == "corner":
                await move(corners[seg.index], MAX_DUTY)
            elif seg.kind == "joint":
                q = list(arm.state.q_rad)
                await move(joint_target(q, seg.index, arm), JOINT_DUTIES[0])
                await move(q, JOINT_DUTIES[1])
            else:
                path = [[float(v) for v in CORNERS[k % 4]] for k in range(seg.index + 1)]
                try:
                    await arm.follow_path(path, speed_m_s=EDGE_SPEED_M_S,
                                          spacing_m=EDGE_SPACING_M, branch=BRANCH)
                except ArmbenchError:  # a path the arm cannot keep up with: held, go on
                    await arm.stop()
    except ArmDoesNotMoveError as exc:
        failure = exc
    await asyncio.sleep(SETTLE_S)
    return HeldOut(name, start, arm.state.t_s - origin_s, block.edges), failure
