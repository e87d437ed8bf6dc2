"""Judging a start-up recovery reply by reply: :class:`RecoveryJudge` takes in each reply after
power-on, as the driver takes it in, and tells when the arm is back (within tolerance and still).
It is asked once a reply for the whole watch (compiled in the release build:
``docs/performance.md``); :func:`armbench.bench.suites.startup_watch.await_recovery` runs it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, Final

import numpy as np

from armbench.bench.suites._common import rad_list
from armbench.bench.suites.startup_contract import STARTUP
from armbench.bench.suites.truth_probe import TruthProbe
from armbench.drivers.host.state import JointState
from armbench.drivers.model.settings import RobotSettings

__all__ = ["STILL_RAD", "TRACE_PERIOD_S", "RecoveryJudge"]

#: Two replies whose joints differ by no more than this (rad, 1.5 wire ticks) show a still arm.
STILL_RAD: Final = 1.5e-4
#: Interval (s) of the recovery trace kept in the samples.
TRACE_PERIOD_S: Final = 0.1


class RecoveryJudge:
    """The replies after power-on (loop time ``t_on``) judged against the truth where ``probe``
    has it (the motor side, as the firmware's counters should say; else the TCP within
    ``tolerance_m``), else against ``expected_rad`` (within ``tolerance_rad``). The arm is back
    when it has been within tolerance and still for ``still_s``. Replies up to number ``seen``
    are not looked at; ``log(event=..., **data)`` keeps the trace and the events.

    What it saw so far: the first reply's time from power-on (``first_reply_s``), when the
    final within-tolerance window began (``recovered_s``, None until the arm is back), the last
    reply judged (``last``) with its error (``error_rad``: rad, or m against the TCP) and what it
    was compared with (``compared_with``: ``truth_rad``, ``truth_m`` or ``expected_rad``)."""

    def __init__(self, probe: TruthProbe, expected_rad: Sequence[float], tolerance_rad: float,
                 tolerance_m: float, settings: RobotSettings, t_on: float, still_s: float,
                 seen: int, log: Callable[..., Any]) -> None:
        self._probe = probe
        self._expected = tuple(expected_rad)
        self._tol_rad = tolerance_rad
        self._tol_m = tolerance_m
        self._settings = settings
        self.t_on = t_on
        self._still_s = still_s
        self._seen = seen
        self._log = log
        self._window: JointState | None = None
        self._last_trace = -math.inf
        self.first_reply_s: float | None = None
        self.recovered_s: float | None = None
        self.error_rad: float | None = None
        self.compared_with: str | None = None
        self.last: JointState | None = None

    def error(self, state: JointState) -> tuple[float, bool, str]:
        """(error, within tolerance, what it was compared with) of ``state``."""
        if self._probe.available:
            q = self._probe.joints(state, motor=True)
            if q is not None:
                return self._within(_largest_difference(state.q_rad, q), "truth_rad")
            pos = self._probe.position(state)
            if pos is not None:
                e = float(np.linalg.norm(np.subtract(state.tcp_m(self._settings), pos)))
                return e, e <= self._tol_m, "truth_m"
        return self._within(_largest_difference(state.q_rad, self._expected), "expected_rad")

    def _within(self, e: float, what: str) -> tuple[float, bool, str]:
        return e, e <= self._tol_rad, what

    def take(self, state: JointState) -> bool:
        """Take in ``state`` (once); True when it ends the watch: the arm is back."""
        if state.seq <= self._seen:
            return False
        self._seen = state.seq
        t_on = self.t_on
        if state.t_s < t_on:
            return False
        e, within, what = self.error(state)
        self.last, self.error_rad, self.compared_with = state, e, what
        log = self._log
        if self.first_reply_s is None:
            self.first_reply_s = round(state.t_s - t_on, 6)
            log(event=STARTUP.ev_ready, first_reply_s=self.first_reply_s,
                q_rad=rad_list(state.q_rad))
        if state.t_s - self._last_trace >= TRACE_PERIOD_S:
            self._last_trace = state.t_s
            log(event=STARTUP.ev_position_check, q_rad=rad_list(state.q_rad),
                error_mrad=round(e * 1e3, 4), within=within)
        if not within:
            self._window = None
            return False
        window = self._window
        if window is None or _largest_difference(state.q_rad, window.q_rad) > STILL_RAD:
            self._window = window = state
        if state.t_s - window.t_s >= self._still_s:
            self.recovered_s = round(window.t_s - t_on, 6)
            log(event=STARTUP.ev_recovered, recovery_s=self.recovered_s,
                error_mrad=round(e * 1e3, 4))
            return True
        return False


def _largest_difference(a: Sequence[float], b: Sequence[float]) -> float:
    """The largest of ``|a[i] - b[i]|`` (rad) over the joints, as ``max`` picks it."""
    if len(a) == len(b) == 4:
        largest = abs(a[0] - b[0])
        for i in (1, 2, 3):
            d = abs(a[i] - b[i])
            if d > largest:
                largest = d
        return largest
    return max(abs(x - y) for x, y in zip(a, b, strict=True))
