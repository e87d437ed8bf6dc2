"""Log lines a peer can cause once per event (a refused connection, a note from a server), at a
bounded rate: a client storm of 2 000 connections a second must not write 2 000 lines a second
to the log.

:class:`LogLimit` lets :data:`DEFAULT_LINES` lines of one kind through per
:data:`DEFAULT_INTERVAL_S`, counts the rest, and says how many it held back in one line when the
interval is over (at the next event of that kind, or at :meth:`LogLimit.flush`). Time comes from
the running event loop (virtual seconds on a virtual loop), or a clock the caller gives.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Final

__all__ = ["DEFAULT_INTERVAL_S", "DEFAULT_LINES", "LogLimit"]

#: Lines of one kind let through per interval.
DEFAULT_LINES: Final = 5
#: The interval, seconds.
DEFAULT_INTERVAL_S: Final = 10.0


def _loop_time() -> float:
    return asyncio.get_running_loop().time()


class LogLimit:
    """At most ``lines`` log lines per ``interval_s`` of ``clock`` (default: the running event
    loop's) through ``logger`` at ``level``; the ones held back are counted and told in one line
    (``… N more WHAT suppressed``)."""

    def __init__(self, logger: logging.Logger, level: int, what: str,
                 clock: Callable[[], float] | None = None, *, lines: int = DEFAULT_LINES,
                 interval_s: float = DEFAULT_INTERVAL_S) -> None:
        if lines < 1 or not interval_s > 0:
            raise ValueError(f"lines {lines} must be >= 1 and interval_s {interval_s} > 0")
        self._log = logger
        self._level = level
        self._what = what
        self._clock = clock if clock is not None else _loop_time
        self._lines = lines
        self._interval_s = interval_s
        self._start_s: float | None = None
        self._sent = 0
        self.suppressed = 0
        """Lines held back since the last summary line."""
        self.suppressed_total = 0
        """Lines held back in all."""

    def __call__(self, msg: str, *args: object) -> None:
        """Log ``msg % args`` unless this interval's lines are used up (then count it)."""
        now = self._clock()
        if self._start_s is None or now - self._start_s >= self._interval_s:
            self.flush()
            self._start_s = now
            self._sent = 0
        if self._sent < self._lines:
            self._sent += 1
            self._log.log(self._level, msg, *args)
        else:
            self.suppressed += 1
            self.suppressed_total += 1

    def flush(self) -> None:
        """Say how many lines were held back since the last time, if any (one line)."""
        if self.suppressed:
            self._log.log(self._level, "… %d more %s suppressed (at most %d every %g s)",
                          self.suppressed, self._what, self._lines, self._interval_s)
            self.suppressed = 0
