"""An asyncio event loop on virtual time: when nothing is ready, the clock jumps to the next timer.

Everything in armbench reads time from ``loop.time()`` and waits with asyncio, so the same code runs
in real time against hardware and on this loop against the in-process emulator, where minutes of
robot time pass in seconds. Only the selector's *waiting* is virtual: ready I/O is still served (a
real pty or socket would see the virtual clock race ahead, so use this loop with in-process peers).
A simulator in another process joins the clock as a :class:`ClockPeer` (``loop.peers``): each
jump first lets it run up to the new time, and stops where it has something for the loop (the
firmware harness of ``avr://``, ``fakes/avr/lockstep.py``).

Why a loop of our own: measured here (200 000 sequential ``asyncio.sleep(0.0027)``, best of 3 on a
busy 2-core machine) this loop costs ~9.5 µs per virtual sleep against ~24 µs for ``looptime`` 0.9
with ``noop_cycles=0``; it is ~60 lines with no pytest coupling. Its bare sleep is the bound of
``emulator.loop_cost`` in ``armbench perf``.
"""

from __future__ import annotations

import asyncio
import collections
import contextvars
import heapq
import selectors
from collections.abc import Awaitable, Callable, Coroutine, Mapping
from typing import Any, Protocol, TypeVar

__all__ = ["ClockPeer", "VirtualTimeLoop", "run_virtual", "virtual_loop_factory"]

T = TypeVar("T")

# the share of cancelled timers at which they leave the heap (asyncio's, base_events.py; asyncio
# also waits for more than 100 timers, which this loop does not: _drop_cancelled)
_MIN_CANCELLED_FRACTION = 0.5


#: With a peer and no timer, the clock still moves (the peer, a simulator, runs on): this far a
#: step (s).
PEER_IDLE_STEP_S = 0.1


class ClockPeer(Protocol):
    """A simulator in another process whose clock is the loop's (``fakes/avr/lockstep.py``): before
    the loop's clock jumps, the peer runs up to the new time, or stops earlier at an event the
    loop's callbacks must see then (a byte for the host), and the clock jumps only that far."""

    def run_until(self, t_s: float) -> float:
        """Run up to loop time ``t_s``; the time reached: earlier at an event, or ``t_s`` (a
        little past it by the peer's own time step)."""
        ...


class _VirtualSelector(selectors.BaseSelector):
    """Wraps a real selector; a wait with a timeout becomes a jump of the virtual clock.

    With nothing registered but the loop's own self-pipe no peer can be ready, so the real
    selector is asked only now and then (to drain the self-pipe of thread wake-ups, whose
    callbacks are already queued): no system call per loop iteration.
    """

    POLL_EVERY = 256

    def __init__(self, real: selectors.BaseSelector, loop: VirtualTimeLoop) -> None:
        self._real = real
        self._loop = loop
        self._registered = 0
        self._skipped = 0

    def register(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        key = self._real.register(fileobj, events, data)
        self._registered += 1
        return key

    def unregister(self, fileobj: Any) -> selectors.SelectorKey:
        key = self._real.unregister(fileobj)
        self._registered -= 1
        return key

    def modify(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        return self._real.modify(fileobj, events, data)

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        if timeout is None and self._loop.peers and not self._loop.external_jobs:
            timeout = PEER_IDLE_STEP_S
        if timeout is None or (timeout > 0 and self._loop.external_jobs):
            # nothing scheduled, or work in an executor (real time) that the clock must wait
            # for: only real I/O or another thread can wake us
            return self._real.select(None)
        if self._registered > 1:
            events = self._real.select(0)
        else:
            self._skipped += 1
            if self._skipped < self.POLL_EVERY:
                events = []
            else:
                self._skipped = 0
                events = self._real.select(0)
        if not events and timeout > 0:
            self._loop.advance(timeout)
        return events

    def close(self) -> None:
        self._real.close()

    def get_map(self) -> Mapping[Any, selectors.SelectorKey]:
        return self._real.get_map()


#: The attributes asyncio's ``Handle`` and ``TimerHandle`` have (CPython 3.11 to 3.13): where they
#: are exactly these, :meth:`VirtualTimeLoop.call_at` fills them itself instead of running the two
#: ``__init__`` (a call to ``loop.get_debug()`` and a traceback check each), once per reply.
_HANDLE_SLOTS = frozenset(("_callback", "_args", "_cancelled", "_loop", "_source_traceback",
                           "_repr", "__weakref__", "_context", "_scheduled", "_when"))
_FAST_HANDLES = (frozenset(asyncio.Handle.__slots__) | frozenset(asyncio.TimerHandle.__slots__)
                 == _HANDLE_SLOTS)
_new_object = object.__new__


class _OrderedTimerHandle(asyncio.TimerHandle):
    """A timer that runs after every timer scheduled before it for the same time. asyncio's heap
    orders timers by time only, so equal times run in an order that depends on whatever else is
    in the heap (say, cancelled timers of an earlier trial on the same loop); on virtual time,
    where equal times are common, that made a run depend on its history."""

    __slots__ = ("_seq",)
    _seq: int

    def __lt__(self, other: object) -> bool:
        if type(other) is _OrderedTimerHandle:
            when, other_when = self._when, other._when  # type: ignore[attr-defined]
            return when < other_when or (when == other_when and self._seq < other._seq)
        return super().__lt__(other)  # type: ignore[operator]


class VirtualTimeLoop(asyncio.SelectorEventLoop):
    """A selector event loop whose ``time()`` is virtual and starts at ``start_s``."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._virtual_now = start_s
        self._timer_seq = 0
        self.external_jobs = 0
        """Executor jobs under way: the clock does not jump while one runs."""
        self.peers: list[ClockPeer] = []
        """Simulators on this clock (:class:`ClockPeer`): each jump waits for them."""
        super().__init__(_VirtualSelector(selectors.DefaultSelector(), self))

    def run_in_executor(  # type: ignore[override]  # same behaviour, a looser signature
            self, executor: Any, func: Callable[..., T], *args: Any) -> asyncio.Future[T]:
        """As asyncio's, but work in an executor (a thread, another process) runs in real
        time: while it is under way the virtual clock waits for it instead of jumping to the
        next timer (a timeout would otherwise fire before the work could finish)."""
        future = super().run_in_executor(executor, func, *args)
        self.external_jobs += 1
        future.add_done_callback(self._external_done)
        return future

    def _external_done(self, _future: asyncio.Future[Any]) -> None:
        self.external_jobs -= 1

    def time(self) -> float:
        """Virtual seconds."""
        return self._virtual_now

    def call_at(  # type: ignore[override]  # same behaviour, a looser signature
            self, when: float, callback: Callable[..., object], *args: Any,
            context: contextvars.Context | None = None) -> asyncio.TimerHandle:
        """As asyncio's, with timers for the same time run in the order they were scheduled
        (:class:`_OrderedTimerHandle`)."""
        base: Any = self
        if when is None:
            raise TypeError("when cannot be None")
        if base._closed:  # _check_closed, inline
            raise RuntimeError("Event loop is closed")
        if base._debug:  # asyncio's checks; its constructor keeps the creation traceback
            base._check_thread()
            base._check_callback(callback, "call_at")
        timer: Any
        if _FAST_HANDLES and not base._debug:  # what the two __init__ do then
            timer = _new_object(_OrderedTimerHandle)
            timer._callback = callback
            timer._args = args
            timer._cancelled = False
            timer._loop = self
            timer._source_traceback = None
            timer._repr = None
            timer._context = contextvars.copy_context() if context is None else context
            timer._when = when
        else:
            timer = _OrderedTimerHandle(when, callback, args, self, context)
        timer._seq = self._timer_seq = self._timer_seq + 1
        heapq.heappush(base._scheduled, timer)
        timer._scheduled = True
        return timer  # type: ignore[no-any-return]

    def _run_once(self) -> None:
        """Iterations of asyncio's loop (same order of callbacks, same selector calls) until
        ``stop()`` is called, minus what virtual time does not need.

        ``run_forever`` does nothing between two iterations but look at ``_stopping``, so this
        method runs iterations until that is set, in one call: one Python frame for thousands
        of iterations instead of one each. Per iteration: the clock is an attribute, not a call;
        no cap of a day on a jump; no event processing without events; the selector's skipped
        polls (:class:`_VirtualSelector`) and each handle's ``_run`` are done inline (no frame
        per call). Cancelled timers go as soon as they are half the heap (:func:`_drop_cancelled`).
        Debug mode takes asyncio's own iteration (whose private state this shares:
        ``_scheduled``, ``_ready``, ... are the same in CPython 3.11 to 3.13)."""
        base: Any = self
        scheduled: list[Any] = base._scheduled
        ready: collections.deque[Any] = base._ready
        selector: _VirtualSelector = base._selector
        poll_every = selector.POLL_EVERY
        resolution: float = base._clock_resolution
        heappop = heapq.heappop
        while True:
            if base._debug:
                base_run_once: Callable[[], None] = super()._run_once  # type: ignore[misc]
                base_run_once()
                return
            if base._timer_cancelled_count > len(scheduled) * _MIN_CANCELLED_FRACTION:
                _drop_cancelled(base, scheduled)
            while scheduled and scheduled[0]._cancelled:
                base._timer_cancelled_count -= 1
                heappop(scheduled)._scheduled = False
            timeout: float | None
            if ready or base._stopping:
                timeout = 0.0
            elif scheduled:
                timeout = scheduled[0]._when - self._virtual_now
                if timeout < 0.0:
                    timeout = 0.0
            else:
                timeout = None
            if (timeout is not None and selector._registered <= 1
                    and selector._skipped + 1 < poll_every and not self.peers
                    and not (timeout > 0 and self.external_jobs)):
                selector._skipped += 1  # _VirtualSelector.select, inline: a skipped poll
                if timeout > 0:
                    self._virtual_now += timeout
            else:
                events = selector.select(timeout)
                if events:
                    base._process_events(events)
            end_time = self._virtual_now + resolution
            while scheduled and scheduled[0]._when < end_time:
                handle = heappop(scheduled)
                handle._scheduled = False
                ready.append(handle)
            for _ in range(len(ready)):
                handle = ready.popleft()
                if handle._cancelled:
                    continue
                try:  # Handle._run, inline
                    handle._context.run(handle._callback, *handle._args)
                except (SystemExit, KeyboardInterrupt):
                    raise
                except BaseException as exc:
                    _report(handle, exc)
            handle = None  # breaks a cycle through an exception's traceback, as asyncio does
            if base._stopping:
                return

    def advance(self, dt_s: float) -> None:
        """Move the virtual clock forward by ``dt_s`` seconds (also usable from tests); with
        :attr:`peers`, only as far as the earliest of them ran."""
        if dt_s > 0:
            if not self.peers:
                self._virtual_now += dt_s
                return
            target = self._virtual_now + dt_s
            reached = min(peer.run_until(target) for peer in list(self.peers))
            self._virtual_now = max(self._virtual_now, reached)


def _drop_cancelled(loop: Any, scheduled: list[Any]) -> None:
    """Take the cancelled timers out of the loop's heap ``scheduled``, in place. asyncio does so
    only beyond 100 timers; on virtual time the heap is a few live timers, and a cancelled one
    waits for its deadline beneath a timer always due sooner (the UART's next byte), so every push
    and pop would compare with it (a Python ``__lt__``). Timers are ordered by time, then by
    scheduling sequence: no live timer moves."""
    live: list[Any] = []
    for handle in scheduled:
        if handle._cancelled:
            handle._scheduled = False
        else:
            live.append(handle)
    heapq.heapify(live)
    scheduled[:] = live
    loop._timer_cancelled_count = 0


def _report(handle: Any, exc: BaseException) -> None:
    """What ``Handle._run`` does with the exception of a callback: the loop's exception
    handler gets it with the callback's source."""
    from asyncio import format_helpers

    context: dict[str, Any] = {
        "message": "Exception in callback "
                   f"{format_helpers._format_callback_source(handle._callback, handle._args)}",
        "exception": exc,
        "handle": handle,
    }
    if handle._source_traceback:
        context["source_traceback"] = handle._source_traceback
    handle._loop.call_exception_handler(context)


def virtual_loop_factory() -> asyncio.AbstractEventLoop:
    """A fresh virtual-time loop (for ``asyncio.Runner(loop_factory=...)`` and pytest-asyncio)."""
    return VirtualTimeLoop()


def run_virtual(main: Callable[[], Coroutine[Any, Any, T]] | Awaitable[T]) -> T:
    """Run a coroutine to completion on a new virtual-time loop."""
    coro = main() if callable(main) else main
    with asyncio.Runner(loop_factory=virtual_loop_factory) as runner:
        return runner.run(coro)  # type: ignore[arg-type]
