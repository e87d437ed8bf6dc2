"""What a failing twin's divergence looks like, and what to do about it.

Per joint, the residual ``r`` (twin minus arm, encoder counts, at the compared replies of
:class:`armbench.bench.twin_check.check.Aligned`) is fitted by the signature of each known effect,
and
each gets the share of the residual's mean square it explains (``1 − SSR / Σ r²``):

* **offset** — a constant: ``r = c``;
* **play** — the sign of the joint's last motion (held through rests): ``r = a · dir``, flipping
  at every reversal, of about constant size;
* **timing** — the joint's speed: ``r = −τ · v`` (a lag ``τ``: the twin's stream shifted in
  time);
* **gear/scale** — the joint's travel since the command in force, while both streams move: a
  speed off by a share ``e`` (another gear ratio) diverges by ``e`` × the travel, and the closed
  loop lands both on the target, so it is back to 0 on arrival (not linear in the position: a
  divergence that stays where a joint stopped short is a stall);
* **step loss** — the scale's ramp with a slope of its own per move and one sign for all (the
  lossy stream is always behind along the motion, in the moves that lift or run at a high duty,
  not in the others), the level the move before left while both move, and the level a move
  leaves while both rest after it (a stalled joint stays short of its target until the next
  command). Its fit has three parameters per move, so it is taken only when it explains
  :data:`STEP_GAIN` more than the best one-parameter effect; its columns are nonzero in one
  move each, so its non-negative least squares falls apart into a small fit per move.

Where one stream has arrived and the other is still on its way, the closed loop decides the
divergence (it lands both on the target), whatever the effect: those replies are left out of
every fit and of the mean square. The kind that explains the most is named when it explains at
least :data:`EXPLAINS`; otherwise none of the known effects explains the divergence: the model
has an effect the evidence did not support. The replies a move's window holds run from its
command to the next; a window in which the joint does not move joins the one before.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from armbench.bench.suites.twin_check_contract import TWIN_CHECK
from armbench.bench.twin_check.where import Growth, direction_of, resembles
from armbench.record import Measurement

__all__ = ["EXPLAINS", "KINDS", "STEP_GAIN", "Diagnosis", "diagnose", "diagnose_joints",
           "failing_joints"]

FloatArray = npt.NDArray[np.float64]

#: The effects a divergence is fitted by, and what the text calls them.
KINDS: Final = {"timing": "timing", "scale": "gear/scale", "step_loss": "step loss",
                "play": "play", "offset": "offset"}
#: A kind names the divergence when it explains at least this share of its mean square.
EXPLAINS: Final = 0.5
#: The step-loss fit (two parameters per command) is taken over the best one-parameter effect
#: only when it explains this much more of the mean square.
STEP_GAIN: Final = 0.25
#: A stream has arrived in a command's window from where it stays within this many wire ticks of
#: where it ends.
SETTLED_TICKS: Final = 3.0
#: The speed is the slope over this many replies either side (the wire's rounding averaged out).
SPEED_REPLIES: Final = 3
#: The span reported holds the replies around the largest divergence within this share of it.
SPAN_SHARE: Final = 0.5

_NEXT: Final = {
    "timing": "check the link (its latency and jitter) and the capture's time base (a fake:// "
              "arm served at a --realtime-factor), or re-run armbench calibrate with a longer "
              "--budget-s (its timing phase measures the reply period and latency)",
    "scale": "calibrate the gear ratio: re-run armbench calibrate with a longer --budget-s (its "
             "ladder's speed runs fit joints.jN.gear_ratio)",
    "step_loss": "calibrate the stall and duty structures: re-run armbench calibrate with a "
                 "--budget-s long enough for the duty ladder (its speed runs choose jN.loss_law "
                 "and fit the pull-out torque)",
    "play": "measure the link side: armbench calibrate --tracker MODULE:CLASS (a reference "
            "instrument; without one the play and stick-slip are the prior's)",
    "offset": "measure the link side: armbench calibrate --tracker MODULE:CLASS (a reference "
              "instrument; without one the offsets and Hall positions are the prior's)",
    "unexplained": "the twin has a model the evidence did not support: look at the arm-vs-twin "
                   "overlay of that span (in the report of twin-check --out)",
}


@dataclass(frozen=True, slots=True)
class Diagnosis:
    """One joint's divergence: the ``kind`` that explains it (a key of :data:`KINDS`, or
    ``unexplained``), the share of its mean square it explains, every kind's share, the span
    (s, capture clock) around its largest divergence, and what it looks like (a sentence with
    the fitted size: the offset, the play, the lag, the speed error)."""

    joint: int
    kind: str
    explained: float
    fractions: dict[str, float]
    span_s: tuple[float, float]
    looks: str
    #: Where the divergence grows (:mod:`armbench.bench.twin_check.where`), the strongest first.
    grows: tuple[Growth, ...] = ()
    #: The part of the capture where it is furthest over its allowance: its span (s) and its RMS
    #: over the allowance there.
    worst_part: tuple[float, float, float] | None = None

    @property
    def label(self) -> str:
        """What the text calls the kind."""
        return KINDS.get(self.kind, "none of the known effects")

    @property
    def next_step(self) -> str:
        """What to do about it."""
        return _NEXT[self.kind].replace("jN", f"j{self.joint}")

    def lines(self) -> list[str]:
        """The diagnosis for a terminal: what it looks like, how much that explains, where it is
        largest, what to do."""
        a, b = self.span_s
        what = (self.looks if self.kind == "unexplained" else
                f"{self.label}: {self.looks}; explains {self.explained:.0%} of the mean square")
        out = [f"diagnosis: {what}, largest at {a:.2f}..{b:.2f} s"]
        if self.worst_part is not None:
            a, b, ratio = self.worst_part
            out.append(f"worst part: {a:.2f}..{b:.2f} s, {ratio:.2f} x its allowance")
        out += [f"where: {g.line()}" for g in self.grows]
        out += [f"resembles: {text}" for text in resembles(self.grows)]
        return [*out, f"next: {self.next_step}"]

    def to_json(self) -> dict[str, Any]:
        """The ``--json`` object."""
        return {"joint": self.joint, "kind": self.kind, "label": self.label,
                "explained": self.explained, "fractions": self.fractions,
                "span_s": list(self.span_s), "looks": self.looks, "next_step": self.next_step,
                "worst_part": None if self.worst_part is None else {
                    "span_s": list(self.worst_part[:2]), "per_allowed": self.worst_part[2]},
                "grows": [g.to_json() for g in self.grows],
                "resembles": resembles(self.grows)}


def failing_joints(measurements: Iterable[Measurement]) -> list[int]:
    """The joints (1..4) with a judged figure (``twin.jN.*``) outside its limit."""
    return sorted({j for m in measurements for j in range(1, 5)
                   if m.outcome == "fail" and m.name.startswith(TWIN_CHECK.joint_metric(j, ""))})


def diagnose_joints(t_s: FloatArray, arm_rad: FloatArray, twin_rad: FloatArray,
                    counts_per_rad: FloatArray, command_times_s: Sequence[float],
                    tick_rad: float, joints: Iterable[int]) -> list[Diagnosis | None]:
    """Per joint (4), the diagnosis of the ``joints`` given (1..4; None for the others), from
    the aligned streams (``(n, 4)`` rad at the times ``t_s``)."""
    out: list[Diagnosis | None] = [None] * 4
    for j in joints:
        c = float(counts_per_rad[j - 1])
        out[j - 1] = diagnose(j, t_s, arm_rad[:, j - 1] * c, twin_rad[:, j - 1] * c,
                              command_times_s, tick_rad * c)
    return out


def _share(x: FloatArray, r: FloatArray, total: float) -> tuple[float, float]:
    """The least-squares coefficient of ``r`` on ``x`` and the share of ``total`` (Σ r²) it
    explains."""
    xx = float(np.dot(x, x))
    if xx <= 0.0 or total <= 0.0:
        return 0.0, 0.0
    xr = float(np.dot(x, r))
    return xr / xx, xr * xr / xx / total


def _settled_from(q: FloatArray, tol: float) -> int:
    """The first index from which ``q`` stays within ``tol`` of its last value."""
    away = np.flatnonzero(np.abs(q - q[-1]) > tol)
    return 0 if not len(away) else int(away[-1]) + 1


def _moves(t: FloatArray, q: FloatArray, command_times_s: Sequence[float], tol: float
           ) -> list[tuple[int, int]]:
    """The compared replies ``[a, b)`` of each command's window, from its time to the next; a
    window in which the joint does not move (by more than ``tol``) joins the one before (what
    a move left stays through it)."""
    edges = np.searchsorted(t, np.asarray(command_times_s, dtype=np.float64))
    edges = np.unique(np.clip(np.append(edges, len(t)), 0, len(t)))
    out: list[tuple[int, int]] = []
    for a, b in itertools.pairwise(int(e) for e in edges):
        start = q[a - 1] if a > 0 else q[a]
        if out and not np.any(np.abs(q[a:b] - start) > tol):
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    return out


@dataclass(frozen=True, slots=True)
class _Move:
    """One move's compared replies ``[a, b)``: both streams move until ``first`` (where one
    has arrived: it stays within the tolerance of where it ends), both rest from ``both``;
    where it started and its way (counts, the mean of both streams)."""

    a: int
    first: int
    both: int
    b: int
    start: float
    way: float


def _phases(q: FloatArray, arm: FloatArray, twin: FloatArray,
            windows: Sequence[tuple[int, int]], tol: float) -> list[_Move]:
    """Each move's phases (:class:`_Move`)."""
    out = []
    for a, b in windows:
        start = float(q[a - 1] if a > 0 else q[a])
        arrived = sorted((_settled_from(arm[a:b], tol), _settled_from(twin[a:b], tol)))
        out.append(_Move(a, a + arrived[0], a + arrived[1], b, start, float(q[b - 1] - start)))
    return out


def _nonneg_explained(columns: Sequence[FloatArray], y: FloatArray) -> float:
    """The sum of squares of ``y`` that ``columns`` (a few) explain with coefficients >= 0: the
    best least-squares fit over the subsets whose coefficients all are."""
    cols = [c for c in columns if np.any(c)]
    best = 0.0
    for n in range(1, len(cols) + 1):
        for subset in itertools.combinations(cols, n):
            x = np.column_stack(subset)
            beta = np.linalg.lstsq(x, y, rcond=None)[0]
            if np.all(beta >= 0.0):
                fitted = x @ beta
                best = max(best, float(np.dot(fitted, fitted)))
    return best


def _loss_explained(q: FloatArray, r: FloatArray, moves: Sequence[_Move]) -> dict[float, float]:
    """Per sign of the lossy stream's lag along the motion, the sum of squares of ``r`` the
    step-loss fit explains: per move, a ramp along its travel and the level the move before
    left (while both move), and the level of its way (while both rest after it), each with
    its own coefficient of that sign."""
    explained = {1.0: 0.0, -1.0: 0.0}
    left = 0.0
    for m in moves:
        for sign in explained:
            explained[sign] += _nonneg_explained(
                [sign * (q[m.a:m.first] - m.start), np.full(m.first - m.a, sign * left)],
                r[m.a:m.first])
            explained[sign] += _nonneg_explained([np.full(m.b - m.both, sign * m.way)],
                                                 r[m.both:m.b])
        left = m.way
    return explained


def _speed(t: FloatArray, q: FloatArray) -> FloatArray:
    """The joint's speed (counts/s): the slope over :data:`SPEED_REPLIES` replies either side."""
    k = SPEED_REPLIES
    i = np.arange(len(q))
    lo, hi = np.maximum(i - k, 0), np.minimum(i + k, len(q) - 1)
    dt = t[hi] - t[lo]
    return np.where(dt > 0, (q[hi] - q[lo]) / np.where(dt > 0, dt, 1.0), 0.0)


def _span(t: FloatArray, r: FloatArray) -> tuple[float, float]:
    """The span (s) of the replies around the largest |r| within :data:`SPAN_SHARE` of it."""
    size = np.abs(r)
    peak = int(np.argmax(size))
    low = np.flatnonzero(size < SPAN_SHARE * size[peak])
    a = low[low < peak]
    b = low[low > peak]
    first = int(a[-1]) + 1 if len(a) else 0
    last = int(b[0]) - 1 if len(b) else len(r) - 1
    return float(t[first]), float(t[last])


def diagnose(joint: int, t_s: FloatArray, arm_counts: FloatArray, twin_counts: FloatArray,
             command_times_s: Sequence[float], tick_counts: float) -> Diagnosis:
    """The diagnosis of one joint (1..4) from its two streams (counts) at the compared replies
    (times ``t_s``, capture clock), the commands' times and the wire's tick (counts)."""
    t = np.asarray(t_s, dtype=np.float64)
    arm = np.asarray(arm_counts, dtype=np.float64)
    twin = np.asarray(twin_counts, dtype=np.float64)
    r = twin - arm
    total = float(np.dot(r, r))
    if len(r) < 3 or total <= 0.0:
        span = (float(t[0]), float(t[-1])) if len(t) else (0.0, 0.0)
        return Diagnosis(joint, "unexplained", 0.0, dict.fromkeys(KINDS, 0.0), span,
                         "no divergence")
    q = 0.5 * (arm + twin)
    tol = SETTLED_TICKS * tick_counts
    moves = _phases(q, arm, twin, _moves(t, q, command_times_s, tol), tol)
    # where one stream has arrived and the other is still on its way, the closed loop decides
    # the divergence (it lands both on the target), not the effect: left out of every fit
    kept = np.ones(len(r), dtype=bool)
    travel = np.zeros(len(r))
    for m in moves:
        kept[m.first:m.both] = False
        travel[m.a:m.first] = q[m.a:m.first] - m.start
    total = float(np.dot(r[kept], r[kept]))
    fits = {"timing": _share(_speed(t, q)[kept], r[kept], total),
            "scale": _share(travel[kept], r[kept], total),
            "play": _share(direction_of(q, tick_counts)[kept], r[kept], total),
            "offset": _share(np.ones(int(kept.sum())), r[kept], total)}
    fractions = {k: f[1] for k, f in fits.items()}
    # the lossy stream is behind along the motion: one sign for every move
    loss = _loss_explained(q, r, moves)
    sign = max(loss, key=lambda s: loss[s])
    fractions["step_loss"] = min(1.0, loss[sign] / total) if total > 0.0 else 0.0
    kind = max(fits, key=lambda k: fractions[k])
    if fractions["step_loss"] >= fractions[kind] + STEP_GAIN:
        kind = "step_loss"
    if fractions[kind] < EXPLAINS:
        best = max(fractions, key=lambda k: fractions[k])
        looks = (f"none of the known effects explains it (the best, {KINDS[best]}, explains "
                 f"{fractions[best]:.0%} of the mean square)")
        return Diagnosis(joint, "unexplained", fractions[kind], fractions, _span(t, r), looks)
    if kind == "step_loss":
        looks = ("grows in some moves only, always one way: the "
                 + ("arm behind along the motion (it loses steps the twin does not)" if sign > 0
                    else "twin behind along the motion (it loses steps the arm does not)"))
    else:
        looks = _looks(kind, fits[kind][0])
    return Diagnosis(joint, kind, fractions[kind], fractions, _span(t, r), looks)


def _scale_error(coefficient: float) -> float:
    """The twin's speed over the arm's, less 1, from the coefficient of ``r`` on the mean of
    both streams' travel (``r = e ×`` the arm's travel is ``2e / (2 + e)`` × the mean's)."""
    return 2.0 * coefficient / (2.0 - coefficient) if coefficient < 2.0 else math.inf


def _looks(kind: str, coefficient: float) -> str:
    """What a one-parameter effect of fitted ``coefficient`` looks like."""
    if kind == "timing":                      # r = −τ v
        return (f"follows the joint's speed: the twin {'behind' if coefficient < 0 else 'ahead'}"
                f" by {abs(coefficient) * 1e3:.1f} ms")
    if kind == "scale":
        e = _scale_error(coefficient)
        return (f"grows with the joint's travel since each command: the twin moves "
                f"{abs(e):.1%} {'faster' if e > 0 else 'slower'} than the arm")
    if kind == "play":
        return (f"flips sign with the joint's direction, about ±{abs(coefficient):.1f} counts: "
                f"the {'arm' if coefficient > 0 else 'twin'} lags the other after each reversal")
    return f"a constant {coefficient:+.1f} counts (twin - arm)"
