"""The link's outages: every loss of the connection to the arm (when, how long, why, what it
cost), and the reconnection policy that may end one.

An outage begins at the last valid reply before the loss (the last moment the link was known
good) and ends at the first valid reply after it. Two kinds:

- ``"port lost"``: the transport reported the loss (EOF, connection reset, pty closed, I/O
  error). With a :class:`ReconnectPolicy` the reader reopens the port with back-off until
  ``give_up_after_s`` has passed since the last reply (or its attempts run out), then the link
  fails with :class:`~armbench.drivers.model.errors.LinkLostError`; without one the loss is final.
- ``"reply silence"``: the port stayed open but no valid reply came for longer than the link's
  reply timeout. Waits raise :class:`~armbench.drivers.model.errors.ReplyTimeoutError` as before;
  the gap is recorded here once replies come back (or shown as ongoing).

What was lost: ``commands_unacknowledged`` counts the commands written after the last reply
before the loss (the far end may never have read them) and the writes refused while the link was
down. Times are the event loop's; :meth:`LinkOutage.to_json` counts them from an origin (the
runner's: the trial's start).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, replace
from typing import Any, Final, Literal

from armbench.drivers.model.bounds import Bound, check, check_whole, option_refused

__all__ = ["OUTAGES_KEPT", "LinkOutage", "OutageKind", "OutageLog", "ReconnectPolicy"]

#: The most outages a link keeps (the oldest are forgotten; ``OutageLog.count`` counts all).
OUTAGES_KEPT: Final = 1000

OutageKind = Literal["port lost", "reply silence"]


#: The bounds of a :class:`ReconnectPolicy`'s numbers.
_DELAY_S: Final = Bound(0.0, math.inf, "s")
_FACTOR: Final = Bound(1.0, math.inf)
_ATTEMPTS: Final = Bound(1, math.inf, whole=True, why="or None: no limit")
_GIVE_UP_S: Final = Bound(0.0, math.inf, "s", low_open=True, why="or None: no limit")


@dataclass(frozen=True, slots=True)
class ReconnectPolicy:
    """Exponential back-off of the reader's reconnection after a lost port: wait
    ``initial_delay_s``, then ``factor`` times longer each attempt up to ``max_delay_s``; give up
    after ``max_attempts`` (None: no limit) or once ``give_up_after_s`` has passed since the last
    reply (None: no limit), whichever comes first, and surface
    :class:`~armbench.drivers.model.errors.LinkLostError`."""

    initial_delay_s: float = 0.05
    factor: float = 2.0
    max_delay_s: float = 1.0
    max_attempts: int | None = 20
    give_up_after_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("initial_delay_s", "max_delay_s"):
            check(f"reconnect.{name}", getattr(self, name), _DELAY_S, option_refused)
        check("reconnect.factor", self.factor, _FACTOR, option_refused)
        if self.max_attempts is not None:
            check_whole("reconnect.max_attempts", self.max_attempts, _ATTEMPTS, option_refused)
        if self.give_up_after_s is not None:
            check("reconnect.give_up_after_s", self.give_up_after_s, _GIVE_UP_S, option_refused)

    def delays(self) -> Iterator[float]:
        """The waits before each attempt."""
        delay = self.initial_delay_s
        n = 0
        while self.max_attempts is None or n < self.max_attempts:
            yield delay
            n += 1
            delay = min(delay * self.factor, self.max_delay_s)


@dataclass(frozen=True, slots=True)
class LinkOutage:
    """One outage: its ``kind`` and ``cause``, ``started_s`` (the last valid reply before it, or
    when the link was opened), ``detected_s`` (when the driver noticed), ``ended_s`` (the first
    valid reply after it; None while it lasts, or for good), the reconnect attempts that failed
    and the commands it may have swallowed. Loop times (s)."""

    kind: OutageKind
    cause: str
    started_s: float
    detected_s: float
    ended_s: float | None = None
    reconnect_attempts: int = 0
    commands_unacknowledged: int = 0

    def duration_s(self, now_s: float) -> float:
        """How long the link was silent: to its end, or to ``now_s`` while it lasts."""
        return (self.ended_s if self.ended_s is not None else now_s) - self.started_s

    def overlap_s(self, t0_s: float, t1_s: float) -> float:
        """How much of loop times [t0_s, t1_s] it covers (an ongoing one up to ``t1_s``)."""
        end = self.ended_s if self.ended_s is not None else t1_s
        return max(0.0, min(end, t1_s) - max(self.started_s, t0_s))

    def to_json(self, now_s: float, origin_s: float = 0.0) -> dict[str, Any]:
        """The outage as a record event: its times in seconds from loop time ``origin_s``
        (``start_t_s`` < 0: it began before), its duration up to ``now_s`` if it still lasts."""
        return {
            "event": "link outage",
            "kind": self.kind,
            "cause": self.cause,
            "start_t_s": self.started_s - origin_s,
            "detected_t_s": self.detected_s - origin_s,
            "end_t_s": None if self.ended_s is None else self.ended_s - origin_s,
            "duration_s": self.duration_s(now_s),
            "ongoing": self.ended_s is None,
            "reconnect_attempts": self.reconnect_attempts,
            "commands_unacknowledged": self.commands_unacknowledged,
        }


class OutageLog:
    """The outages of one link: the one going on (:attr:`current`) and the last
    :data:`OUTAGES_KEPT` that ended. ``silence_s``: a gap between replies longer than this is a
    ``"reply silence"`` outage (the link's reply timeout)."""

    def __init__(self, silence_s: float, kept: int = OUTAGES_KEPT) -> None:
        self.silence_s = silence_s
        self.current: LinkOutage | None = None
        """The ``"port lost"`` outage going on, if any."""
        self.count = 0
        """Outages so far, forgotten ones included."""
        self._ended: deque[LinkOutage] = deque(maxlen=kept)

    def lost(self, now_s: float, cause: str, last_reply_s: float, unacknowledged: int) -> None:
        """The transport reported the port lost at ``now_s``; a loss during an outage adds
        nothing."""
        if self.current is None:
            self.count += 1
            self.current = LinkOutage("port lost", cause, last_reply_s, now_s,
                                      commands_unacknowledged=unacknowledged)

    def attempt_failed(self) -> None:
        """A reconnect attempt of the current outage failed."""
        if self.current is not None:
            self.current = replace(self.current,
                                   reconnect_attempts=self.current.reconnect_attempts + 1)

    def command_lost(self) -> None:
        """A command could not be written because the link was down."""
        if self.current is not None:
            self.current = replace(
                self.current, commands_unacknowledged=self.current.commands_unacknowledged + 1)

    def reply(self, now_s: float, last_reply_s: float) -> None:
        """A valid reply at ``now_s`` after a gap (the previous one at ``last_reply_s``): ends
        the current outage, or records the gap as a silence if it was longer than
        ``silence_s``. The link calls this only after such a gap or during an outage."""
        current = self.current
        if current is not None:
            self.current = None
            self._ended.append(replace(current, ended_s=now_s))
        elif math.isfinite(last_reply_s) and now_s - last_reply_s >= self.silence_s:
            self.count += 1
            self._ended.append(LinkOutage("reply silence", f"no reply for "
                                          f"{now_s - last_reply_s:.3f} s", last_reply_s,
                                          last_reply_s + self.silence_s, ended_s=now_s))

    def ongoing(self, now_s: float, last_reply_s: float) -> LinkOutage | None:
        """The outage going on at ``now_s``: the lost port, or a silence longer than
        ``silence_s`` since ``last_reply_s``."""
        if self.current is not None:
            return self.current
        if math.isfinite(last_reply_s) and now_s - last_reply_s >= self.silence_s:
            return LinkOutage("reply silence", f"no reply for {now_s - last_reply_s:.3f} s so far",
                              last_reply_s, last_reply_s + self.silence_s)
        return None

    def between(self, t0_s: float, now_s: float, last_reply_s: float) -> list[LinkOutage]:
        """The outages that overlap loop times [t0_s, now_s], oldest first, the ongoing one
        last."""
        out: list[LinkOutage] = []
        for o in reversed(self._ended):  # in the order they ended
            if o.ended_s is None or o.ended_s < t0_s:
                break
            out.append(o)
        out.reverse()
        ongoing = self.ongoing(now_s, last_reply_s)
        if ongoing is not None:
            out.append(ongoing)
        return out

    def down_s(self, t0_s: float, now_s: float, last_reply_s: float) -> float:
        """Seconds of [t0_s, now_s] during which the port was lost (silences not counted: they
        raise a reply timeout in any wait)."""
        return sum(o.overlap_s(t0_s, now_s) for o in self.between(t0_s, now_s, last_reply_s)
                   if o.kind == "port lost")
