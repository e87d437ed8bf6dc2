"""Progress of a run on the operator's terminal or in a CI log (:class:`ProgressPrinter`).

How much is shown is the stream's to say (:class:`ProgressStream`, what ``armbench run`` hands
the runner; ``-v``/``-q`` on the command line):

- **per suite** (the command line's default): one line per suite — trials measured of those
  planned, a bar, the robot time, the elapsed wall time and the time left — rewritten in place
  on a terminal; where the stream is no terminal (a CI log) the same line is written when the
  suite begins, every :data:`LOG_INTERVAL_S` while it runs and when it ends. The suite's own
  messages (``[suite] ...``: what a trial is doing, its summary) become the end of its line;
  any other message (a warning, the capture stopping) and a trial that did not end ``done`` (an
  error, a retry, a lost link) is a line of its own;
- **per trial** (``-v``, and any plain stream given to the runner's API): one line per trial
  and every message, as a line of its own (a trial's line rewritten in place on a terminal).

The hand-written carriage-return line needs no dependency: ``rich`` or ``tqdm`` would add a
package to every lab PC for one line, and the runner already rewrote its line in place.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import IO

__all__ = ["LOG_INTERVAL_S", "PER_SUITE", "PER_TRIAL", "ProgressPrinter", "ProgressStream",
           "verbosity_of"]

#: Verbosity of a progress stream: one live line per suite.
PER_SUITE = 0
#: Verbosity of a progress stream: one line per trial and every message.
PER_TRIAL = 1
#: Seconds (wall) between two lines of a running suite where the stream is no terminal.
LOG_INTERVAL_S = 60.0
#: Characters of the bar of a suite's line.
_BAR_CHARS = 16
#: The width assumed for a terminal that does not say its own.
_DEFAULT_COLUMNS = 100


class ProgressStream:
    """A progress stream (stderr) with how much the runner shows on it: ``verbosity``
    :data:`PER_SUITE` or :data:`PER_TRIAL`; ``interval_s`` between two lines of a running suite
    when ``stream`` is no terminal."""

    def __init__(self, stream: IO[str], verbosity: int = PER_SUITE, *,
                 interval_s: float = LOG_INTERVAL_S) -> None:
        self.stream = stream
        self.verbosity = verbosity
        self.interval_s = interval_s

    def write(self, text: str) -> int:
        return self.stream.write(text)

    def flush(self) -> None:
        self.stream.flush()

    def isatty(self) -> bool:
        return bool(getattr(self.stream, "isatty", lambda: False)())

    def columns(self) -> int:
        """The terminal's width in characters (:data:`_DEFAULT_COLUMNS` when it says none)."""
        try:
            return os.get_terminal_size(self.stream.fileno()).columns or _DEFAULT_COLUMNS
        except (AttributeError, OSError, ValueError):
            return _DEFAULT_COLUMNS


def verbosity_of(stream: object) -> int:
    """How much ``stream`` asks to be shown: a :class:`ProgressStream`'s (or a wrapper's that
    carries one's ``verbosity``), else :data:`PER_TRIAL`, what the runner always showed on a
    plain stream."""
    value = getattr(stream, "verbosity", PER_TRIAL)
    return value if isinstance(value, int) else PER_TRIAL


def _clock(seconds: float) -> str:
    s = max(0, round(seconds))
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


@dataclass(slots=True)
class _SuiteLine:
    """The line of the suite running now."""

    name: str
    planned: int
    started_wall_s: float
    started_robot_s: float | None
    measured: int = 0
    note: str = ""
    shown_wall_s: float = -1e300


class ProgressPrinter:
    """Shows a run's progress on ``stream`` (stderr), as much as the stream asks
    (:func:`verbosity_of`; the module docstring).

    Elapsed and remaining are the operator's time (the wall clock, ``wall_clock``:
    ``time.perf_counter``): on ``fake://`` the robot's simulated time runs much faster and is
    shown beside it as ``robot``. The estimate is each suite's mean trial time so far (the run's
    mean for a suite that has not measured a trial yet) times the trials left.
    """

    def __init__(self, stream: IO[str] | ProgressStream | None, total_trials: int, *,
                 robot_clock: Callable[[], float] | None = None,
                 wall_clock: Callable[[], float] = time.perf_counter) -> None:
        self.stream = stream
        self.total = total_trials
        self.done = 0
        self.robot_clock = robot_clock
        self.per_trial = verbosity_of(stream) >= PER_TRIAL
        interval = getattr(stream, "interval_s", LOG_INTERVAL_S)
        self.interval_s = float(interval) if isinstance(interval, (int, float)) else LOG_INTERVAL_S
        self._tty = bool(stream is not None and getattr(stream, "isatty", lambda: False)())
        self._wall = wall_clock
        self._t0 = wall_clock()
        self._durations: dict[str, tuple[float, int]] = {}
        """Per suite, its finished trials' wall seconds added up, and their number."""
        self._remaining: dict[str, int] = {}
        self._planned: dict[str, int] = {}
        self._pending_s = 0.0
        self._open_line = False
        self._suite: _SuiteLine | None = None
        self.lines: list[str] = []
        """Every line shown, a live line at each of its renderings (for tests and logs)."""

    def plan(self, suite: str, remaining: int) -> None:
        """Declare how many trials of ``suite`` are left."""
        self._remaining[suite] = remaining
        self._planned[suite] = remaining

    def estimate_s(self) -> float | None:
        """Seconds (wall) the remaining trials should take, None before any trial ended."""
        count = sum(n for _, n in self._durations.values())
        if not count:
            return None
        overall = sum(total_s for total_s, _ in self._durations.values()) / count
        total = 0.0
        for suite, left in self._remaining.items():
            total_s, n = self._durations.get(suite, (0.0, 0))
            total += left * (total_s / n if n else overall)
        return total

    def trial(self, suite: str, k: int, n: int, status: str, wall_s: float, *,
              retry: bool = False) -> None:
        """Trial ``k`` (1-based) of ``n`` of ``suite`` ended with ``status``; with ``retry`` it
        is measured again, so it is not counted as finished yet (its time is added to the
        attempt that finishes it)."""
        self._pending_s += wall_s
        if not retry:
            self.done += 1
            total_s, count = self._durations.get(suite, (0.0, 0))
            self._durations[suite] = (total_s + self._pending_s, count + 1)
            self._pending_s = 0.0
            self._remaining[suite] = max(0, self._remaining.get(suite, 1) - 1)
        if self.per_trial:
            self._show(self._trial_text(suite, k, n, status), in_place=True)
            return
        line = self._enter(suite)
        if not retry:
            line.measured += 1
        if status != "done":  # an error, a retry, a lost link: a line that stays
            self._say(f"[{suite}] trial {k}/{n} {status}")
        self._update(line)

    def message(self, text: str) -> None:
        """A line that stays (suite start and end, warnings); per suite, a suite's own message
        (``[suite] ...``) ends that suite's line instead."""
        if self.per_trial:
            self._show(text, in_place=False)
            return
        suite, _, note = text[1:].partition("] ") if text.startswith("[") else ("", "", "")
        if suite not in self._planned:
            self._say(text)
            return
        line = self._enter(suite)
        line.note = note
        self._update(line)

    def finish(self) -> None:
        """End the suite's line and an in-place line."""
        if self._suite is not None:
            self._close(self._suite)
        if self._open_line and self.stream is not None:
            self.stream.write("\n")
            self.stream.flush()
        self._open_line = False

    # -- per trial ------------------------------------------------------------------------------

    def _trial_text(self, suite: str, k: int, n: int, status: str) -> str:
        est = self.estimate_s()
        parts = [f"[{suite}] trial {k}/{n} {status}", f"run {self.done}/{self.total}",
                 f"elapsed {_clock(self._wall() - self._t0)}",
                 f"remaining ~{_clock(est)}" if est is not None else "remaining ?"]
        if self.robot_clock is not None:
            parts.append(f"robot time {_clock(self.robot_clock())}")
        return "  ".join(parts)

    # -- per suite ------------------------------------------------------------------------------

    def _enter(self, suite: str) -> _SuiteLine:
        """The line of ``suite``, begun now if another suite's was showing (which ends)."""
        line = self._suite
        if line is not None and line.name == suite:
            return line
        if line is not None:
            self._close(line)
        robot = self.robot_clock() if self.robot_clock is not None else None
        line = self._suite = _SuiteLine(suite, self._planned.get(suite, 0), self._wall(), robot)
        return line

    def _status(self, line: _SuiteLine) -> str:
        """The suite's line: bar, trials, robot time, elapsed, time left, its last message."""
        now = self._wall()
        filled = (_BAR_CHARS * line.measured // line.planned if line.planned
                  else _BAR_CHARS)
        parts = [f"[{line.name}] [{'#' * filled}{'-' * (_BAR_CHARS - filled)}] "
                 f"{line.measured}/{line.planned} trials"]
        if self.robot_clock is not None and line.started_robot_s is not None:
            parts.append(f"robot {_clock(self.robot_clock() - line.started_robot_s)}")
        parts.append(f"elapsed {_clock(now - line.started_wall_s)}")
        left = self._remaining.get(line.name, 0)
        total_s, n = self._durations.get(line.name, (0.0, 0))
        if left and n:
            run = self.estimate_s()
            parts.append(f"left ~{_clock(left * total_s / n)}"
                         + (f" (run ~{_clock(run)})" if run is not None else ""))
        if line.note:
            parts.append(line.note)
        return "  ".join(parts)

    def _update(self, line: _SuiteLine) -> None:
        """Show the suite's line again: at once on a terminal, else when the interval passed."""
        now = self._wall()
        if self._tty:
            self._show(self._fit(self._status(line)), in_place=True)
        elif now - line.shown_wall_s >= self.interval_s:
            line.shown_wall_s = now
            self._show(self._status(line), in_place=False)

    def _close(self, line: _SuiteLine) -> None:
        """The suite's last line, which stays."""
        self._suite = None
        if self._tty:  # whole: no later rewrite needs it within one line
            self._show(self._status(line), in_place=True)
            self._end_line()
        else:
            self._show(self._status(line), in_place=False)

    def _say(self, text: str) -> None:
        """A line that stays above the live line (drawn again below it on a terminal)."""
        self._show(text, in_place=False)
        if self._tty and self._suite is not None:
            self._show(self._fit(self._status(self._suite)), in_place=True)

    def _fit(self, text: str) -> str:
        """``text`` cut to the terminal's width: a line that wraps cannot be rewritten."""
        columns = (self.stream.columns() if isinstance(self.stream, ProgressStream)
                   else _DEFAULT_COLUMNS)
        return text if len(text) < columns else text[:max(1, columns - 2)] + "…"

    # -- output ---------------------------------------------------------------------------------

    def _end_line(self) -> None:
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
                stream.write("\r\x1b[K" if not self.per_trial else "\n")
                self._open_line = False
            stream.write(line + "\n")
        stream.flush()
