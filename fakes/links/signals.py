"""Ctrl-C and SIGTERM end a real-time server cleanly, on every system.

``loop.add_signal_handler`` exists only on Unix event loops; Windows' loops raise
``NotImplementedError`` (and have no SIGTERM to speak of). There the handler is installed with
:func:`signal.signal` and hands the stop to the loop thread-safely.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import signal
from collections.abc import Callable, Iterator

__all__ = ["stop_on_signals"]


@contextlib.contextmanager
def stop_on_signals(stop: asyncio.Event) -> Iterator[None]:
    """Set ``stop`` on SIGINT or SIGTERM (where the system has it) while the block runs, in the
    running loop; the previous handlers come back afterwards."""
    loop = asyncio.get_running_loop()
    signals = [s for s in (signal.SIGINT, getattr(signal, "SIGTERM", None)) if s is not None]
    undo: list[Callable[[], object]] = []
    for sig in signals:
        previous = signal.getsignal(sig)
        try:
            loop.add_signal_handler(sig, stop.set)
            undo.append(functools.partial(loop.remove_signal_handler, sig))
        except (NotImplementedError, RuntimeError):  # Windows' loops; not the main thread
            signal.signal(sig, lambda _signum, _frame: loop.call_soon_threadsafe(stop.set))
        if previous is not None:  # None: a handler not installed from Python
            undo.append(functools.partial(signal.signal, sig, previous))
    try:
        yield
    finally:
        for restore in undo:
            restore()
