"""The speed ladder of ``armbench calibrate --port``: its duties, the pose each joint's runs
start from and their order, and what a run's replies show (its speed over the middle of the
move, with the standard error of that slope)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Final

import numpy as np

from armbench.drivers.host.state import JointState

__all__ = ["FIRST_DUTIES", "LADDER_DUTIES", "LADDER_RANGES", "RATE_MARGIN", "UNLOADED_DUTIES",
           "ladder_order", "speed_of"]

#: Duties of the speed ladder, the most informative first: full duty (where steps are lost), the
#: lowest (a speed scale without loss: a gear ratio off the nominal), full duty again (the
#: repeated runs measure the session's scatter, the link's jitter included), then between.
LADDER_DUTIES: Final = (99, 90, 99, 95, 97, 93, 98, 96)
#: Per joint: the start pose of its ladder and the range its moves span (protocol rad): joints 2
#: and 3 tilted so that moving towards the vertical lifts the arm, joint 3 from its forearm
#: horizontal (q2 + q3 ≈ 1.6: the largest gravity torque it can meet, so a joint that loses no
#: step here loses none elsewhere at these duties); 1 and 4 carry no gravity load and get the two
#: top duties only. The joints go one after the other, in this order, each through all its
#: duties: the arm travels to each joint's pose once (a drive too weak for the arm's weight
#: lifts joint 2 slowly, and every trip back from a tilted pose costs that), and joint 2, the
#: heaviest lift, comes last: a drive that cannot lift it at any duty leaves the arm there, and
#: the others are measured first.
LADDER_RANGES: Final = {
    1: ((0.0, 0.0, 0.0, 0.0), 0.3, -0.3),
    4: ((0.0, 0.0, 0.0, 0.0), 0.3, -0.3),
    3: ((0.0, 0.6, 1.0, 0.0), 1.0, 0.7),
    2: ((0.0, 0.9, 0.0, 0.0), 0.9, 0.6),
}
UNLOADED_DUTIES: Final = (99, 95)
#: Duties of the ladder joints 3 and 2 go through alternately before each takes the rest.
FIRST_DUTIES: Final = 3
#: Share of a move at each end left out of the speed fit (start-up and arrival).
RATE_MARGIN: Final = 0.2


def ladder_order() -> list[tuple[int, int]]:
    """The ladder's ``(joint, duty)`` runs in order: joints 1 and 4 (no gravity load, at the zero
    pose) at full duty; joints 3 and 2 alternating at the first :data:`FIRST_DUTIES` of
    :data:`LADDER_DUTIES` (a budget that runs out leaves both with full duty, the lowest and the
    repeat); joints 1 and 4 at their other duty; then 3 and 2 each through the rest. The arm
    goes back to the zero pose between joint 3's and joint 2's poses once: a drive too weak for
    the arm's own weight lifts joint 2 only slowly (and one that cannot has been brought back
    there by then)."""
    top, *slower = UNLOADED_DUTIES
    out: list[tuple[int, int]] = [(1, top), (4, top)]
    first, rest = LADDER_DUTIES[:FIRST_DUTIES], LADDER_DUTIES[FIRST_DUTIES:]
    out += [(j, int(d)) for d in first for j in (3, 2)]
    out += [(j, d) for d in slower for j in (1, 4)]
    out += [(j, int(d)) for j in (3, 2) for d in rest]
    return out


def speed_of(states: Sequence[JointState], j: int, start: float,
             target: float) -> tuple[float, int, float] | None:
    """Slope (rad/s, unsigned) of joint ``j`` over the middle of a move from ``start`` to
    ``target``, fitted to the replies, the number of replies and the slope's standard error
    from their scatter about the line; None with fewer than 5 replies there."""
    span = target - start
    if span == 0:
        return None
    t, q = [], []
    for s in states:
        f = (s.q_rad[j] - start) / span
        if RATE_MARGIN <= f <= 1.0 - RATE_MARGIN:
            t.append(s.t_s)
            q.append(s.q_rad[j])
    if len(t) < 5:
        return None
    ta = np.asarray(t) - t[0]
    qa = np.asarray(q)
    slope, icept = (float(c) for c in np.polyfit(ta, qa, 1))
    resid = qa - (slope * ta + icept)
    sxx = float(((ta - ta.mean()) ** 2).sum())
    sigma = math.sqrt(float(resid @ resid) / (len(t) - 2) / sxx) if sxx > 0 else math.inf
    return abs(slope), len(t), sigma

