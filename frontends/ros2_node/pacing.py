"""How the node holds virtual time back for ROS, without making the loop deaf to a signal.

Two holds: ``--realtime-factor`` (:class:`RealtimePacer`: at most X virtual seconds per real
second) and ``--slow-subscriber pace`` (:class:`SubscriberPacer`: every half history, until every
reliable subscriber of ``/joint_states`` has acknowledged). Each waits on a thread of the loop's
executor (:func:`hold`): on virtual time the clock does not jump while an executor job is under
way (:class:`~armbench.fakes.clock.vclock.VirtualTimeLoop`), so virtual time stands still as it
would in a blocking sleep, but the loop still runs its signal handlers (SIGTERM) and the hold ends
as soon
as its task is cancelled (a blocking ``time.sleep`` held a node at ``--realtime-factor 1e-5`` for
~240 s per reply, deaf to SIGTERM). Real seconds are ``time.perf_counter``: these holds are about
real time.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import threading
import time
from collections.abc import Callable
from typing import Any, Final, TypeVar

__all__ = ["HOLD_STEP_S", "MAX_HOLD_S", "RealtimePacer", "SubscriberPacer", "hold"]

log = logging.getLogger("armbench.ros2")

T = TypeVar("T")

#: The loop is held once it is at least this far ahead of real time: fewer, longer holds.
HOLD_STEP_S: Final = 0.005
#: The longest single hold (s): a hold is a real-time wait on a thread, re-armed until done.
MAX_HOLD_S: Final = 1.0
#: Slices of the wait for acknowledgements (s): how soon a cancelled wait's thread is free.
_ACK_SLICE_S: Final = 0.1


async def hold(wait: Callable[[threading.Event], T]) -> T:
    """``wait(stop)`` on a thread of the loop's executor; when the awaiting task is cancelled,
    ``stop`` is set so that the thread returns at once."""
    stop = threading.Event()
    try:
        return await asyncio.get_running_loop().run_in_executor(None, wait, stop)
    finally:
        stop.set()


def _sleep(seconds: float, stop: threading.Event) -> bool:
    """Sleep ``seconds``, or less once ``stop`` is set."""
    return stop.wait(seconds)


class RealtimePacer:
    """Virtual time at most ``factor`` times real time, counted from the first :meth:`pace`."""

    def __init__(self, factor: float) -> None:
        self.factor = factor
        self._start: tuple[float, float] | None = None

    async def pace(self, virtual_s: float) -> None:
        """Hold until virtual time ``virtual_s`` is no longer ahead of real time."""
        now = time.perf_counter()
        if self._start is None:
            self._start = (virtual_s, now)
            return
        v0, r0 = self._start
        ahead = (virtual_s - v0) / self.factor - (now - r0)
        while ahead >= HOLD_STEP_S:
            step = min(ahead, MAX_HOLD_S)
            await hold(functools.partial(_sleep, step))
            ahead -= step


class SubscriberPacer:
    """``pace``: every ``every`` messages offered on ``publisher``, hold until every reliable
    subscriber has acknowledged all; one that acknowledges nothing for ``timeout_s`` is no longer
    waited for (``event("subscriber_stalled")``) until all is acknowledged again
    (``subscriber_back``)."""

    def __init__(self, publisher: Any, every: int, timeout_s: float, history_depth: int,
                 event: Callable[..., None]) -> None:
        self._publisher = publisher
        self._every = every
        self._timeout_s = timeout_s
        self._history_depth = history_depth
        self._event = event
        self._checked = 0
        self.stalled = False
        self.paced_s = 0.0
        """Real seconds held."""
        self.stalls = 0
        """Times a subscriber acknowledged nothing for ``timeout_s``."""

    async def check(self, offered: int) -> None:
        """After ``offered`` messages in all: hold if due (see the class doc)."""
        if offered - self._checked < self._every:
            return
        self._checked = offered
        if self._acked(0.0):  # no wait: all caught up
            if self.stalled:
                self.stalled = False
                log.warning("/joint_states: every subscriber keeps up again: pacing again")
                self._event("subscriber_back")
            return
        if self.stalled:
            return
        t0 = time.perf_counter()
        acked = await hold(self._wait)
        self.paced_s += time.perf_counter() - t0
        if not acked:
            self.stalled = True
            self.stalls += 1
            log.warning("/joint_states: a subscriber acknowledged nothing for %.3g s: no longer "
                        "waiting for it; it loses the oldest beyond the history of %d",
                        self._timeout_s, self._history_depth)
            self._event("subscriber_stalled", timeout_s=self._timeout_s,
                        history_depth=self._history_depth)

    def _acked(self, wait_s: float) -> bool:
        from rclpy.duration import Duration

        return bool(self._publisher.wait_for_all_acked(Duration(nanoseconds=round(wait_s * 1e9))))

    def _wait(self, stop: threading.Event) -> bool:
        """On the executor's thread: wait for every acknowledgement, at most ``timeout_s``, in
        slices, returning early once ``stop`` is set."""
        end = time.perf_counter() + self._timeout_s
        while not stop.is_set():
            left = end - time.perf_counter()
            if left <= 0:
                return False
            if self._acked(min(left, _ACK_SLICE_S)):
                return True
        return False
