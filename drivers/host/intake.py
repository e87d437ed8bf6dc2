"""The link's per-reply path: a chunk from the transport to the newest state, the recorders, the
capture and the waiters.

A link receives hundreds of replies a second, and on ``fake://`` a campaign receives millions,
so this path is one compiled object (``cli/perf/hot_modules.py``) instead of a chain of the link's
methods: :meth:`ReplyIntake.take` handles a chunk that is exactly one reply (how ``fake://`` and a
quiet line deliver them) and hands any other chunk to the link's general path, which calls
:meth:`ReplyIntake.took` with the newest state it completed. The intake owns what each reply
changes (``state``, ``last_rx_s``, ``tx_since_rx``); the link reads them here.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from armbench.drivers.capture.jsonl import ReplySink
from armbench.drivers.host.link_outages import OutageLog
from armbench.drivers.host.replies import ReplyStream
from armbench.drivers.host.state import JointState
from armbench.drivers.host.waiters import Waiters

__all__ = ["ReplyIntake"]


class ReplyIntake:
    """The per-reply path of one link (one for the link's life: reconnections keep it).

    ``clock`` gives the loop time a chunk is read at; ``general`` takes a chunk that is not
    exactly one reply (with that time); ``failed`` takes an exception a pushed chunk raised
    (a bug: the link shows it to its waiters, as its reader does)."""

    __slots__ = ("capture", "clock", "failed", "general", "last_rx_s", "live", "outages",
                 "recorders", "replies", "reply_timeout_s", "state", "tx_since_rx", "waiters")

    def __init__(self, replies: ReplyStream, waiters: Waiters, outages: OutageLog,
                 reply_timeout_s: float, general: Callable[[bytes, float], None],
                 failed: Callable[[Exception], None]) -> None:
        self.replies = replies
        self.waiters = waiters
        self.outages = outages
        self.reply_timeout_s = reply_timeout_s
        self.general = general
        self.failed = failed
        self.clock: Callable[[], float] = _no_clock
        """The loop's time (set when the link opens)."""
        self.capture: ReplySink | None = None
        self.recorders: list[list[JointState]] = []
        """Lists every new state is appended to (``ArmLink.record_states``)."""
        self.state: JointState | None = None
        """The newest state."""
        self.last_rx_s = -math.inf
        """Loop time of the newest state."""
        self.tx_since_rx = 0
        """Commands sent since the newest state."""
        self.live = True
        """False once the link is closed or failed: a pushed chunk is then dropped, as the
        reader, stopped by then, would."""

    def push(self, data: bytes) -> None:
        """A chunk a transport hands over as it arrives (``set_receiver``, ``fake://``)."""
        if not self.live:
            return
        try:
            self.take(data)
        except Exception as exc:  # a bug: the link shows it to the waiters, as the reader does
            self.failed(exc)

    def take(self, data: bytes) -> None:
        """A chunk read now: a single reply here, anything else by the link's general path."""
        t = self.clock()
        one = self.replies.one(data, t)
        if one is None:
            self.general(data, t)
            return
        for r in self.recorders:
            r.append(one)
        capture = self.capture
        if capture is not None:
            capture.reply(t, data)
        self.took(one, t)

    def took(self, state: JointState, t: float) -> None:
        """``state``, read at loop time ``t``, is the newest: it ends an outage or a silence
        and goes to the waiters."""
        self.state = state
        if t - self.last_rx_s >= self.reply_timeout_s or self.outages.current is not None:
            self.outages.reply(t, self.last_rx_s)
        self.last_rx_s = t
        self.tx_since_rx = 0
        self.waiters.offer(state)


def _no_clock() -> float:
    raise RuntimeError("the link is not open")
