"""Progress of a run on the operator's terminal: one line per trial with k of n, elapsed and
remaining time (:class:`ProgressPrinter`)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import IO

__all__ = ["ProgressPrinter"]


def _clock(seconds: float) -> str:
    s = max(0, round(seconds))
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class ProgressPrinter:
    """One line per trial on ``stream`` (stderr): suite, trial k of n, elapsed and an estimate of
    the remaining time; rewritten in place on a terminal.

    Elapsed and remaining are the operator's time (the wall clock, ``time.perf_counter``): on
    ``fake://`` the robot's simulated time runs much faster and is shown beside it as ``robot``.
    The estimate is each suite's mean trial time so far (the run's mean for a suite that has not
    measured a trial yet) times the trials left.
    """

    def __init__(self, stream: IO[str] | None, total_trials: int, *,
                 robot_clock: Callable[[], float] | None = None) -> None:
        self.stream = stream
        self.total = total_trials
        self.done = 0
        self.robot_clock = robot_clock
        self._tty = bool(stream is not None and getattr(stream, "isatty", lambda: False)())
        self._t0 = time.perf_counter()
        self._durations: dict[str, list[float]] = {}
        self._remaining: dict[str, int] = {}
        self._pending_s = 0.0
        self._open_line = False
        self.lines: list[str] = []
        """Every line shown (for tests and logs)."""

    def plan(self, suite: str, remaining: int) -> None:
        """Declare how many trials of ``suite`` are left."""
        self._remaining[suite] = remaining

    def estimate_s(self) -> float | None:
        """Seconds (wall) the remaining trials should take, None before any trial ended."""
        everything = [d for ds in self._durations.values() for d in ds]
        if not everything:
            return None
        overall = sum(everything) / len(everything)
        total = 0.0
        for suite, left in self._remaining.items():
            ds = self._durations.get(suite)
            total += left * (sum(ds) / len(ds) if ds else overall)
        return total

    def trial(self, suite: str, k: int, n: int, status: str, wall_s: float, *,
              retry: bool = False) -> None:
        """Trial ``k`` (1-based) of ``n`` of ``suite`` ended with ``status``; with ``retry`` it
        is measured again, so it is not counted as finished yet (its time is added to the
        attempt that finishes it)."""
        self._pending_s += wall_s
        if not retry:
            self.done += 1
            self._durations.setdefault(suite, []).append(self._pending_s)
            self._pending_s = 0.0
            self._remaining[suite] = max(0, self._remaining.get(suite, 1) - 1)
        elapsed = time.perf_counter() - self._t0
        est = self.estimate_s()
        parts = [f"[{suite}] trial {k}/{n} {status}", f"run {self.done}/{self.total}",
                 f"elapsed {_clock(elapsed)}",
                 f"remaining ~{_clock(est)}" if est is not None else "remaining ?"]
        if self.robot_clock is not None:
            parts.append(f"robot time {_clock(self.robot_clock())}")
        self._show("  ".join(parts), in_place=True)

    def message(self, text: str) -> None:
        """A line that stays (suite start and end, warnings)."""
        self._show(text, in_place=False)

    def finish(self) -> None:
        """End an in-place line."""
        if self._open_line and self.stream is not None:
            self.stream.write("\n")
            self.stream.flush()
        self._open_line = False

    def _show(self, line: str, *, in_place: bool) -> None:
        self.lines.append(line)
        stream = self.stream
        if stream is None:
            return
        if self._tty and in_place:
            stream.write("\r\x1b[K" + line)
            self._open_line = True
        else:
            if self._open_line:
                stream.write("\n")
                self._open_line = False
            stream.write(line + "\n")
        stream.flush()
