"""The virtual-time event loop: clock jumps, timer order, and its own timer handles."""

from __future__ import annotations

import asyncio

from armbench.fakes.clock import vclock
from armbench.fakes.clock.vclock import VirtualTimeLoop, run_virtual


def test_an_hour_of_sleep_passes_at_once() -> None:
    async def main() -> float:
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        await asyncio.sleep(3600.0)
        return loop.time() - t0

    assert run_virtual(main) == 3600.0  # (on a real clock this test would take the hour)


def test_equal_time_timers_run_in_the_order_they_were_scheduled() -> None:
    async def main() -> list[int]:
        loop = asyncio.get_running_loop()
        seen: list[int] = []
        for k in range(200):  # cancelled and earlier timers shuffle asyncio's heap
            loop.call_at(loop.time() + 0.5 + (k % 7) * 1e-3, seen.append, -1).cancel()
        for k in range(50):
            loop.call_at(loop.time() + 1.0, seen.append, k)
        await asyncio.sleep(2.0)
        return seen

    assert run_virtual(main) == list(range(50))


def test_cancelled_timers_leave_a_small_heap_at_once() -> None:
    """A cancelled long timer does not wait in the heap for its deadline once cancelled ones are
    half of it (asyncio waits for more than 100 timers). With a timer always due sooner (as the
    UART's next byte is), a cancelled one never reaches the top to be popped; each push and pop
    would compare with all that stayed. The ticks still run in order, every 0.5 ms."""
    async def main() -> tuple[int, list[float]]:
        loop = asyncio.get_running_loop()
        ticks: list[float] = []

        def tick() -> None:
            ticks.append(loop.time())
            loop.call_at(loop.time() + 5e-4, tick)

        loop.call_soon(tick)
        biggest = 0
        for _ in range(300):  # an alarm re-set per step, as a waiter's deadline is
            loop.call_at(loop.time() + 60.0, ticks.append, -1.0).cancel()
            await asyncio.sleep(2e-3)
            biggest = max(biggest, len(loop._scheduled))  # type: ignore[attr-defined]
        return biggest, ticks

    biggest, ticks = run_virtual(main)
    assert ticks == sorted(ticks) and len(ticks) == 1201 and ticks[0] == 0.0
    assert biggest <= 3, biggest  # the tick and the sleep (asyncio's rule left 99)


def test_timer_handles_are_what_asyncio_would_build() -> None:
    """``call_at`` fills the handles' attributes itself (no ``__init__``); they must hold what
    asyncio's own constructor gives, and cancel, compare and print as asyncio's do."""
    assert vclock._FAST_HANDLES  # this CPython has the expected slots: the fast path is tested

    async def main() -> None:
        loop = asyncio.get_running_loop()
        fired: list[str] = []
        timer = loop.call_at(loop.time() + 1.0, fired.append, "a")
        reference = asyncio.TimerHandle(timer.when(), fired.append, ("a",), loop,
                                        timer._context)  # type: ignore[attr-defined]
        for name in vclock._HANDLE_SLOTS - {"__weakref__", "_scheduled"}:
            assert getattr(timer, name) == getattr(reference, name), name
        assert timer._scheduled  # type: ignore[attr-defined]
        assert repr(timer).startswith("<_OrderedTimerHandle when=")
        doomed = loop.call_at(loop.time() + 0.5, fired.append, "cancelled")
        doomed.cancel()
        assert doomed.cancelled()
        later = loop.call_later(2.0, fired.append, "b")
        assert timer < later and not later < timer
        await asyncio.sleep(3.0)
        assert fired == ["a", "b"]

    run_virtual(main)


def test_debug_mode_keeps_the_order_of_equal_time_timers() -> None:
    """Debug mode builds the handles with asyncio's constructor (creation tracebacks), still
    ordered."""

    async def main() -> list[int]:
        loop = asyncio.get_running_loop()
        seen: list[int] = []
        for k in range(5):
            loop.call_at(loop.time() + 1.0, seen.append, k)
        await asyncio.sleep(1.5)
        return seen

    with asyncio.Runner(loop_factory=VirtualTimeLoop, debug=True) as runner:
        assert runner.run(main()) == [0, 1, 2, 3, 4]


def test_a_failing_callback_goes_to_the_exception_handler_and_the_loop_goes_on() -> None:
    """The loop runs handles inline (not through ``Handle._run``): a callback's exception still
    reaches the loop's exception handler, with the message and handle asyncio gives it."""
    seen: list[dict[str, object]] = []
    ran: list[float] = []

    def boom() -> None:
        raise ValueError("boom")

    async def main() -> None:
        loop = asyncio.get_running_loop()
        loop.set_exception_handler(lambda _loop, context: seen.append(context))
        handle = loop.call_at(1.0, boom)
        loop.call_at(2.0, lambda: ran.append(loop.time()))
        await asyncio.sleep(3.0)
        assert seen[0]["handle"] is handle

    run_virtual(main)
    assert len(seen) == 1
    assert isinstance(seen[0]["exception"], ValueError)
    assert str(seen[0]["message"]).startswith("Exception in callback ")
    assert "boom" in str(seen[0]["message"])
    assert ran == [2.0]


def test_stop_ends_run_forever_before_later_callbacks() -> None:
    """Many iterations run in one ``_run_once`` call: ``stop()`` still ends ``run_forever``
    after the iteration that called it, the later timers waiting for the next run."""
    loop = VirtualTimeLoop()
    ran: list[int] = []
    try:
        loop.call_at(1.0, ran.append, 1)
        loop.call_at(2.0, loop.stop)
        loop.call_at(3.0, ran.append, 3)
        loop.run_forever()
        assert ran == [1] and loop.time() == 2.0
        loop.call_at(4.0, loop.stop)
        loop.run_forever()
        assert ran == [1, 3] and loop.time() == 4.0
    finally:
        loop.close()
