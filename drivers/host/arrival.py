"""Waiting for the arm to arrive: one tracker for moves and paths.

The firmware latches the last command and acknowledges nothing, so arrival is watched in the
replies. An :class:`ArrivalTracker` is aimed at one command at a time (a move's, or each waypoint
of a path in turn); :meth:`ArrivalTracker.arrive` waits until every joint is within tolerance of
the goal (or, for a path, close enough in time to send the next waypoint), sends the command
again when the distance to go stops shrinking for ``resend_after_s``, and raises on a timeout or a
newer command. The policies are documented in ``docs/driver.md``.
"""

from __future__ import annotations

import asyncio
import math
from typing import Final

from armbench.drivers.host.link import ArmLink
from armbench.drivers.host.motion import CYCLE_S, period_for_duty
from armbench.drivers.host.move_targets import Duties
from armbench.drivers.host.state import JointState
from armbench.drivers.model.errors import MoveInterruptedError, MoveTimeoutError, ReplyTimeoutError
from armbench.drivers.model.kinematics import Vec4
from armbench.drivers.model.protocol import Command

__all__ = [
    "HOLD_ON",
    "MOVE_TIMEOUT_MARGIN",
    "MOVE_TIMEOUT_SLACK_S",
    "PROGRESS_RAD",
    "ArrivalTracker",
]

#: A move's default timeout is this many times the slowest joint's time by law (12) ...
MOVE_TIMEOUT_MARGIN: Final = 1.5
#: ... plus this many seconds (command on the wire, loop latency, start-up of the stepping).
MOVE_TIMEOUT_SLACK_S: Final = 1.0
#: Distance to go (sum over joints, rad) that counts as progress: one protocol tick.
PROGRESS_RAD: Final = 1e-4
#: The errors on which a waiting move or path sends a hold before they propagate.
HOLD_ON: Final = (asyncio.CancelledError, KeyboardInterrupt, MoveTimeoutError, ReplyTimeoutError)


class ArrivalTracker:
    """Arrival, progress and resend bookkeeping of one move or path on ``link``.

    ``tol``: per-joint tolerance (rad); ``deadline``: loop time at which :meth:`arrive` raises
    :class:`MoveTimeoutError` (reporting ``timeout_s``); ``gen``: the link's command generation
    the move belongs to (a newer one raises :class:`MoveInterruptedError`); ``since``: loop time
    the reply timeout is counted from (besides the last reply).
    """

    __slots__ = ("_ahead_s", "_best", "_cmd", "_duties", "_gen", "_goal", "_last_progress",
                 "_last_send", "_link", "_since", "_steps_per_rad", "deadline", "timeout_s",
                 "tol")

    def __init__(self, link: ArmLink, tol: Vec4, deadline: float, timeout_s: float, gen: int,
                 since: float) -> None:
        self._link = link
        self.tol = tol
        self.deadline = deadline
        self.timeout_s = timeout_s
        self._gen = gen
        self._since = since
        self._steps_per_rad = tuple(j.steps_per_rad for j in link.settings.joints)
        self._cmd: Command | None = None
        self._goal: Vec4 = (0.0, 0.0, 0.0, 0.0)
        self._duties: Duties = (0, 0, 0, 0)
        self._ahead_s = 0.0
        self._best = math.inf
        self._last_progress = self._last_send = since

    def aim(self, cmd: Command, goal: Vec4, t_sent: float, ahead_s: float = 0.0) -> None:
        """Track ``cmd`` (sent at loop time ``t_sent``) towards ``goal`` (its angles as on the
        wire). ``ahead_s`` > 0: a joint also counts as arrived once it is less than that long
        away at its duty (a path's look-ahead)."""
        self._cmd = cmd
        self._goal = goal
        self._duties = cmd.duties
        self._ahead_s = ahead_s
        self._best = math.inf
        self._last_progress = self._last_send = t_sent

    def reached(self, state: JointState) -> bool:
        """Evaluated by the reader on every new state: arrival, and progress bookkeeping."""
        q1, q2, q3, q4 = state.q_rad
        g1, g2, g3, g4 = self._goal
        tol1, tol2, tol3, tol4 = self.tol
        e1, e2, e3, e4 = abs(q1 - g1), abs(q2 - g2), abs(q3 - g3), abs(q4 - g4)
        if e1 <= tol1 and e2 <= tol2 and e3 <= tol3 and e4 <= tol4:
            return True
        if self._ahead_s > 0 and self._near((e1, e2, e3, e4)):
            return True
        total = e1 + e2 + e3 + e4
        if total < self._best - PROGRESS_RAD:
            self._best, self._last_progress = total, state.t_s
        return False

    def _near(self, errors: Vec4) -> bool:
        """Whether every joint is within tolerance or less than ``ahead_s`` away at its duty."""
        ahead_s = self._ahead_s
        for e, tol, steps_per_rad, duty in zip(errors, self.tol, self._steps_per_rad,
                                               self._duties, strict=True):
            if e > tol and e * steps_per_rad * period_for_duty(duty) * CYCLE_S > ahead_s:
                return False
        return True

    def _check_current(self) -> None:
        link = self._link
        if link._generation != self._gen:
            raise MoveInterruptedError(self._goal, link._intake.state)

    async def arrive(self) -> JointState:
        """The first state (the current one included) at the goal; sends the command again when
        the distance to go has not shrunk for the link's ``resend_after_s``.

        Raises :class:`MoveTimeoutError` at the deadline, :class:`MoveInterruptedError` when a
        newer command superseded this one, and what the link's waits raise. Time the port was
        lost does not count against the deadline: while the reader reconnects the move waits for
        it (the reconnect policy bounds that wait and raises
        :class:`~armbench.drivers.model.errors.LinkLostError`), and afterwards the deadline is later
        by the outage's length."""
        link = self._link
        cmd = self._cmd
        assert link._loop is not None and cmd is not None
        loop = link._loop
        resend_after = link.resend_after_s
        reached = self.reached
        while True:
            self._check_current()
            state = link.state
            if reached(state):
                return state
            if link._reconnecting:  # the port is lost: no deadline, no resend until it is back
                got = await link._wait(reached, None, since=self._since)
                if got is not None:
                    self._check_current()
                    return got
                continue
            deadline = self.deadline + link.link_down_s(self._since)
            # the very sum the wake-up below is set at: comparing differences instead can miss
            # it by one ulp on virtual time, and the loop would spin without yielding
            if loop.time() >= max(self._last_progress, self._last_send) + resend_after:
                await link._resend(cmd)
                self._last_send = self._last_progress = loop.time()
            wake = min(deadline, max(self._last_progress, self._last_send) + resend_after)
            got = await link._wait(reached, wake, since=self._since)
            self._check_current()
            if got is not None:
                return got
            if not link._reconnecting and (
                    loop.time() >= self.deadline + link.link_down_s(self._since)):
                raise MoveTimeoutError(self._goal, self.tol, self.timeout_s, link._intake.state)
