"""The tasks waiting for a state, and the one alarm that wakes them at their deadlines.

The reader offers each new state to :class:`Waiters`, which evaluates the waiting predicates in
place (no task switch per reply) and resolves the futures of those satisfied. One loop timer
serves all deadlines instead of one timer per wait: a wait that ends with a reply (most do,
hundreds per second) leaves no cancelled timer behind in the loop's heap.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable

from armbench.drivers.host.state import JointState

__all__ = ["Waiter", "Waiters", "any_state", "never"]


def any_state(state: JointState) -> bool:
    """A predicate every state satisfies."""
    return True


def never(state: JointState) -> bool:
    """A predicate no state satisfies (wait for a wake-up only)."""
    return False


class Waiter:
    """A task waiting for a state that satisfies ``predicate``: resolved with the first state that
    does, or with None at loop time ``wake_at`` (``inf``: never) or by :meth:`Waiters.wake_all`,
    which marks it ``woken`` so that the waiting task returns to re-check its conditions."""

    __slots__ = ("future", "predicate", "wake_at", "woken")

    def __init__(self, predicate: Callable[[JointState], bool],
                 future: asyncio.Future[JointState | None], wake_at: float) -> None:
        self.predicate = predicate
        self.future = future
        self.wake_at = wake_at
        self.woken = False

    def wake(self) -> None:
        self.woken = True
        if not self.future.done():
            self.future.set_result(None)


class Waiters:
    """The waiters of one connection, and their shared alarm (on the loop they wait on)."""

    __slots__ = ("_alarm", "_alarm_at", "_loop", "_waiters")

    def __init__(self) -> None:
        self._loop: asyncio.AbstractEventLoop | None = None
        self._waiters: list[Waiter] = []
        self._alarm: asyncio.TimerHandle | None = None
        self._alarm_at = math.inf

    def __bool__(self) -> bool:
        return bool(self._waiters)

    def add(self, predicate: Callable[[JointState], bool], wake_at: float) -> Waiter:
        """A new waiter for ``predicate``, woken with None at loop time ``wake_at`` at the
        latest; whoever resolves it drops it from the set."""
        self._loop = loop = asyncio.get_running_loop()
        fut: asyncio.Future[JointState | None] = loop.create_future()
        waiter = Waiter(predicate, fut, wake_at)
        self._waiters.append(waiter)
        if wake_at < self._alarm_at:
            self._set_alarm(wake_at)
        return waiter

    def offer(self, state: JointState) -> None:
        """Resolve the waiters whose predicate the new state satisfies; drop the resolved ones
        (and those whose task was cancelled). A predicate that raises resolves its waiter with
        the exception."""
        done = False
        for w in self._waiters:
            fut = w.future
            if fut.done():
                done = True
                continue
            try:
                hit = w.predicate(state)
            except Exception as exc:  # a user predicate failed: its waiter raises it
                fut.set_exception(exc)
                done = True
                continue
            if hit:
                fut.set_result(state)
                done = True
        if done:
            self._waiters = [w for w in self._waiters if not w.future.done()]

    def wake_all(self) -> None:
        """Wake every waiter to re-check (closed, failed, reconnecting, superseded)."""
        waiters, self._waiters = self._waiters, []
        for w in waiters:
            w.wake()

    def close(self) -> None:
        """Wake every waiter and cancel the alarm."""
        self.wake_all()
        if self._alarm is not None:
            self._alarm.cancel()
            self._alarm = None

    def _set_alarm(self, when: float) -> None:
        """Wake :meth:`_on_alarm` at loop time ``when`` (instead of a later alarm)."""
        assert self._loop is not None
        if self._alarm is not None:
            self._alarm.cancel()
        self._alarm_at = when
        self._alarm = self._loop.call_at(when, self._on_alarm)

    def _on_alarm(self) -> None:
        """Expire the waiters due at the alarm's time, then set it for the next one due."""
        due = self._alarm_at
        self._alarm, self._alarm_at = None, math.inf
        keep: list[Waiter] = []
        nxt = math.inf
        for w in self._waiters:
            fut = w.future
            if fut.done():
                continue
            if w.wake_at <= due:
                fut.set_result(None)
                continue
            keep.append(w)
            nxt = min(nxt, w.wake_at)
        self._waiters = keep
        if nxt < math.inf:
            self._set_alarm(nxt)
