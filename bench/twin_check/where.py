"""Where a joint's divergence grows, and which known effects that resembles: what twin-check says
about what it could not explain.

Per joint, the squared divergence at the compared replies is split by each factor in turn at the
threshold that separates it best (a one-split regression tree on its mean): the speed of the
twin's joint, the duty of the command in force for it, how recently it reversed, how far into
the session the reply is, and the gravity torque its motion lifts against (the twin's model of
the load). A factor is named where the divergence's RMS on its high side is at least
:data:`GROWS` times that on the other (and above the allowance's absolute part), with the spans
of the capture's clock it covers there; each named factor says which known effect grows that
way (a step loss above a duty, one that grows with the load, play, a speed scale or timing,
drift: none of the twin's).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from armbench.drivers.model.protocol import Command
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.fakes.twin.physics import DEFAULT_ARM, Mechanism

__all__ = ["FACTORS", "GROWS", "Growth", "direction_of", "factors_of", "growth", "resembles",
           "since_reversal_s"]

FloatArray = npt.NDArray[np.float64]

#: A factor is named where the RMS on its high side is at least this many times the other's ...
GROWS: Final = 2.0
#: ... and its high side holds at least this share of the squared divergence.
HOLDS: Final = 0.5
#: Factors named per joint at most (the one that separates the divergence best first: the factors
#: are correlated, a lossy lift at full duty is fast too).
NAMED: Final = 3
#: Each side of a split holds at least this share of the replies (a few replies prove nothing).
MIN_SHARE: Final = 0.05
#: Thresholds tried per factor: each of its values where it has at most this many (a duty),
#: else this many quantiles of them.
SPLITS: Final = 24
#: Replies closer than this (s) belong to the same span of the capture's clock.
SPAN_GAP_S: Final = 0.25
#: Spans listed per factor (the longest).
SPANS: Final = 3
#: A reversal's effect is looked for this long after it (s).
REVERSAL_S: Final = 0.5
#: The joint's direction of motion is the sign of its motion over this many replies, when that
#: exceeds :data:`DIRECTION_TICKS` wire ticks (held otherwise).
DIRECTION_REPLIES: Final = 5
DIRECTION_TICKS: Final = 3.0
#: The load is evaluated at most at this many replies (evenly spread; the others take the
#: nearest): a gravity torque costs tens of microseconds.
LOAD_SAMPLES: Final = 2000

#: The factors, what the text calls the high side, and the known effect that grows that way.
FACTORS: Final = {
    "duty": ("duty >= {:.0f}",
             "a step loss above a duty (jN.loss_law = \"duty\"): the calibration's duty ladder "
             "and its held-out suite motions find it"),
    "load": ("lifting against >= {:.2f} N·m",
             "a step loss that grows with the lifted torque (jN.loss_law = \"torque\" or "
             "\"stall\", the pull-out torque)"),
    "speed": ("speed >= {:.0f} counts/s",
              "a speed scale (another gear ratio) or a timing error (a lag grows with the speed)"),
    "reversal": ("within {:.2f} s of a reversal",
                 "play: the twin's backlash (a reference instrument measures it)"),
    "time": ("from {:.1f} s into the session on",
             "drift: the arm changed during the session, which no effect of the twin does "
             "(calibrate again, closer to the run, or look for what warms up)"),
}


@dataclass(frozen=True, slots=True)
class Growth:
    """One factor along which a joint's divergence grows: its name (a key of :data:`FACTORS`),
    the threshold, the RMS divergence (counts) on the high side and on the other, the share of
    the compared replies on the high side, the share of the squared divergence it holds and
    the longest spans (s, capture clock) where it is at least half its RMS there."""

    factor: str
    threshold: float
    rms_counts: float
    other_counts: float
    share: float
    holds: float
    spans_s: tuple[tuple[float, float], ...]

    @property
    def where(self) -> str:
        """The high side in words (``duty >= 97``)."""
        value = -self.threshold if self.factor == "reversal" else self.threshold
        return FACTORS[self.factor][0].format(value)

    @property
    def resembles(self) -> str:
        """The known effect that grows this way."""
        return FACTORS[self.factor][1]

    def line(self) -> str:
        """One line for a terminal."""
        spans = ", ".join(f"{a:.2f}..{b:.2f} s" for a, b in self.spans_s)
        return (f"grows at {self.where}: RMS {self.rms_counts:.1f} counts against "
                f"{self.other_counts:.1f} elsewhere ({self.holds:.0%} of the squared divergence "
                f"in {self.share:.0%} of the replies; at {spans})")

    def to_json(self) -> dict[str, Any]:
        """The ``--json`` object."""
        return {"factor": self.factor, "where": self.where, "threshold": self.threshold,
                "rms_counts": self.rms_counts, "other_counts": self.other_counts,
                "share": self.share, "holds": self.holds,
                "spans_s": [list(s) for s in self.spans_s],
                "resembles": self.resembles}


def _spans(t: FloatArray) -> tuple[tuple[float, float], ...]:
    """The longest runs of the times ``t`` (sorted) without a gap over :data:`SPAN_GAP_S`."""
    if not len(t):
        return ()
    cuts = np.flatnonzero(np.diff(t) > SPAN_GAP_S) + 1
    runs = [(float(r[0]), float(r[-1])) for r in np.split(t, cuts)]
    runs.sort(key=lambda s: s[0] - s[1])
    return tuple(sorted(runs[:SPANS]))


def _split(x: FloatArray, r2: FloatArray) -> tuple[float, float, float, float] | None:
    """The threshold of ``x`` (NaN: left out; -inf: below any threshold) whose high side's mean
    of ``r2`` exceeds the low side's by the most (:func:`_separation`), each side at
    least :data:`MIN_SHARE` of the replies: threshold, high mean, low mean, high share. None
    when no split qualifies."""
    known = ~np.isnan(x)
    finite = np.isfinite(x)
    n = int(known.sum())
    if finite.sum() < 2:
        return None
    values = np.unique(x[finite])
    if len(values) > SPLITS:  # many values (a speed, a load): their quantiles
        values = np.unique(np.quantile(x[finite], np.linspace(MIN_SHARE, 1 - MIN_SHARE,
                                                              SPLITS)))
    best: tuple[float, float, float, float, float] | None = None
    for thr in values:
        high = known & (x >= thr)
        low = known & ~high
        k = int(high.sum())
        if k < MIN_SHARE * n or n - k < MIN_SHARE * n:
            continue
        m_hi, m_lo = float(r2[high].mean()), float(r2[low].mean())
        gain = _separation(m_hi, m_lo, k / n) if m_hi > m_lo else 0.0
        if best is None or gain > best[0]:
            best = (gain, float(thr), m_hi, m_lo, k / n)
    if best is None or best[0] <= 0.0:
        return None
    return best[1], best[2], best[3], best[4]


def growth(t_s: FloatArray, residual_counts: FloatArray, factors: dict[str, FloatArray],
           floor_counts: float) -> list[Growth]:
    """The factors along which ``residual_counts`` (twin − arm at the compared replies, times
    ``t_s``) grows (see the module doc), at most :data:`NAMED`, the one separating it best
    first (:func:`_separation`); ``factors`` maps each factor's name to its value at every
    reply (NaN: it says nothing there; -inf: below any threshold); a high side must be above
    ``floor_counts`` (the allowance's absolute part)."""
    r2 = residual_counts * residual_counts
    out: list[tuple[float, Growth]] = []
    for name, x in factors.items():
        values = np.asarray(x, dtype=np.float64)
        found = _split(values, r2)
        if found is None:
            continue
        thr, m_hi, m_lo, share = found
        rms_hi, rms_lo = float(np.sqrt(m_hi)), float(np.sqrt(m_lo))
        holds = share * m_hi / (share * m_hi + (1.0 - share) * m_lo)
        if rms_hi < GROWS * rms_lo or rms_hi <= floor_counts or holds < HOLDS:
            continue
        # the spans where it grows: on the high side, at least half its RMS there
        grows = ~np.isnan(values) & (values >= thr) & (r2 >= 0.25 * m_hi)
        out.append((_separation(m_hi, m_lo, share),
                    Growth(name, thr, rms_hi, rms_lo, share, holds, _spans(t_s[grows]))))
    out.sort(key=lambda sg: sg[0], reverse=True)
    return [g for _, g in out[:NAMED]]


def _separation(m_hi: float, m_lo: float, share: float) -> float:
    """How well a split separates the squared divergence (its between-group sum of squares per
    reply, as :func:`_split` chooses thresholds): the order factors are named in. Concentration
    alone (the share held over the share of replies) ties for every part of the region where
    the divergence grows, so a factor cutting out a part of it (the last seconds of a session,
    by time) could be named before the one that covers all of it; this criterion peaks at the
    whole region."""
    return share * (1.0 - share) * (m_hi - m_lo) ** 2


def direction_of(q: FloatArray, tick: float) -> FloatArray:
    """The sign of a joint's last motion (over :data:`DIRECTION_REPLIES`, beyond
    :data:`DIRECTION_TICKS` of ``tick``, in the unit of ``q``), held through rests; 0 before it
    first moves."""
    w = DIRECTION_REPLIES
    moved = np.zeros(len(q))
    moved[w:] = q[w:] - q[:-w]
    sign = np.where(np.abs(moved) > DIRECTION_TICKS * tick, np.sign(moved), 0.0)
    last = np.maximum.accumulate(np.where(sign != 0, np.arange(len(q)), -1))
    out: FloatArray = np.where(last >= 0, sign[np.maximum(last, 0)], 0.0)
    return out


def since_reversal_s(t_s: FloatArray, direction: FloatArray) -> FloatArray:
    """Per reply, how long after the joint's direction of motion (``direction``: ±1, 0 before
    it first moves) last flipped, negated (larger: more recent), within :data:`REVERSAL_S`;
    -inf before the first reversal and longer after one."""
    moving = np.flatnonzero(direction != 0)
    flips = moving[1:][direction[moving[1:]] != direction[moving[:-1]]]
    out = np.full(len(t_s), -np.inf)
    if not len(flips):
        return out
    index = np.arange(len(t_s))
    last = np.maximum.accumulate(np.where(np.isin(index, flips), index, -1))
    ago = np.where(last >= 0, t_s - t_s[np.maximum(last, 0)], np.inf)
    result: FloatArray = np.where(ago <= REVERSAL_S, -ago, -np.inf)
    return result


def _lifted_nm(q_rad: FloatArray, speed_rad_s: FloatArray, settings: RobotSettings
               ) -> FloatArray:
    """Per reply and joint, the gravity torque (N·m) the joint's motion works against in the
    twin's model (the settings' masses, payload and geometry; negative: lowering; 0 at rest)."""
    physics = emulator_settings(settings).physics or DEFAULT_ARM
    mech = Mechanism(physics, settings, lambda: [0.0] * 4)
    n = len(q_rad)
    if not n:
        return np.zeros((0, 4))
    at = np.unique(np.linspace(0, n - 1, min(n, LOAD_SAMPLES)).round().astype(int))
    tau = np.asarray([mech.gravity_nm(q_rad[i]) for i in at]).reshape(-1, 4)
    nearest = np.clip(np.searchsorted(at, np.arange(n)), 0, len(at) - 1)
    out: FloatArray = -tau[nearest] * np.sign(speed_rad_s)
    return out


def factors_of(t_s: FloatArray, arm_rad: FloatArray, speed_rad_s: FloatArray,
               counts_per_rad: FloatArray, commands: Sequence[tuple[float, Command]],
               session_starts_s: Sequence[float], settings: RobotSettings,
               tick_rad: float) -> list[dict[str, FloatArray]]:
    """Per joint, each factor's value at every compared reply (times ``t_s``, the arm's angles
    and the twin's speed ``(n, 4)``): the twin's speed (counts/s), the duty of the command in
    force, how recently the joint reversed (:func:`since_reversal_s`), the time into its
    session (s) and the torque its motion lifts against (N·m)."""
    times = np.asarray([c[0] for c in commands], dtype=np.float64)
    duty = np.zeros((len(t_s), 4))
    if len(times):
        k = np.searchsorted(times, t_s, side="right") - 1
        duties = np.asarray([c[1].duties for c in commands], dtype=np.float64).reshape(-1, 4)
        duty = np.where((k >= 0)[:, None], duties[np.clip(k, 0, None)], 0.0)
    starts = np.asarray(sorted(session_starts_s) or [float(t_s[0]) if len(t_s) else 0.0])
    into = t_s - starts[np.clip(np.searchsorted(starts, t_s, side="right") - 1, 0, None)]
    lifted = _lifted_nm(arm_rad, speed_rad_s, settings)
    out = []
    for j in range(4):
        c = float(counts_per_rad[j])
        out.append({"duty": duty[:, j], "load": lifted[:, j],
                    "speed": np.abs(speed_rad_s[:, j]) * c,
                    "reversal": since_reversal_s(t_s, direction_of(arm_rad[:, j], tick_rad)),
                    "time": into})
    return out


def resembles(growths: Sequence[Growth]) -> list[str]:
    """The known effects the named factors point to, the strongest first, once each."""
    seen: list[str] = []
    for g in growths:
        if g.resembles not in seen:
            seen.append(g.resembles)
    return seen
