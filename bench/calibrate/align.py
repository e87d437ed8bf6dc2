"""Timing-robust comparison of two reply streams (an arm's capture and its twin's replay), and
the floor of that comparison: what a perfect twin would score on this capture.

A real-time capture stamps each reply when the host read it and each command when the host wrote
it; the arm acts on a command a little later, and reports its pose a little before the stamp. None
of that is the model's doing. So:

* the twin's stream is a trajectory (its replies joined by straight lines), read at the time of
  each of the arm's replies, not its newest reply then (which would be up to one reply interval
  stale); where the twin's replies pause (its firmware writing EEPROM records after a command)
  its trajectory is unknown, and the arm's replies then are not compared;
* a reply the host read late (a loaded host wakes some milliseconds after it came: its angle is
  behind the line of its neighbours, along the motion) is found from the arm's stream alone,
  with no model in it (:func:`late_stamps`), and is neither compared nor used to time a start;
* each move that starts from rest is aligned at its start: the time the arm's joint left its
  pose (its first replies beyond :data:`ONSET_TICKS`, traced back along the joint's nominal speed)
  against the twin's; that pose, and whether the joint rested, from every reply read before the
  command, those left out for their stamps too (a stamp can be late, never early); commands
  sent while the arm moves (a streamed path) keep the shift of the move they continue; an arm
  silent across a command (its loop stalled) may start as much later as it was silent, and the
  commands that came meanwhile reached it together. A twin that is too slow or loses steps
  still diverges: only the start is aligned, not the motion;
* the floor comes from the capture itself. The arm's own replies, where a joint moves steadily,
  scatter around the straight line through their neighbours by the link's timing scatter times
  the joint's speed: that scatter (s; a robust spread of those residuals in time units finds the
  replies read late, their RMS is what a perfect twin meets) times the twin's speed, plus the
  quantisation of the wire angle and of the encoder on both sides, is the part of the per-joint
  floor (RMS, rad) the replies give; a move's start, timed from the arm's first replies, is as
  uncertain as those replies disagree on it, and the whole move is aligned by it (its standard
  error times the twin's speed: :func:`onset_floor_rad`); the start shifts' spread is the arm's
  reaction scatter, which :mod:`armbench.bench.twin_check.check` turns into the rest of the floor by
  replaying the twin with its commands moved by draws of it. A perfect twin scores about the
  floor; the verdict allows ``k × floor + abs``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
from numpy.lib.stride_tricks import sliding_window_view

from armbench.drivers.host.motion import joint_speed_rad_s
from armbench.drivers.model.protocol import TICKS_PER_RAD, Command
from armbench.drivers.model.settings import RobotSettings

__all__ = ["ONSET_TICKS", "SEEN_LATE", "Shifts", "Track", "command_shifts", "floor_rad",
           "interval_floor_s", "late_stamps", "move_shifts", "onset_floor_rad", "silent_s",
           "stamped_late_s", "timing_rms_s", "timing_scatter_s"]

FloatArray = npt.NDArray[np.float64]

#: Times closer than this (s) are the same instant (a capture stores them to the nanosecond): a
#: reply at a command's instant shows the pose before it.
SAME_INSTANT_S: Final = 1e-6
#: One wire tick (rad): the resolution of a reported angle.
TICK_RAD: Final = 1.0 / TICKS_PER_RAD
#: A joint has left its pose when it is this many ticks from it: beyond the quantisation and
#: the scatter of a pose at rest.
ONSET_TICKS: Final = 4.0
#: Replies a move's start is traced back from.
ONSET_REPLIES: Final = 5
#: Replies the speed a start is traced back with is measured on (every two of them).
SPEED_REPLIES: Final = 10
#: The speed a start is traced back with: the stream's own, when within this band of the
#: nominal one (times the nominal).
SPEED_BAND: Final = (0.3, 1.5)
#: A joint whose move is shorter than this (ticks) does not time a move's start.
MIN_WAY_TICKS: Final = 30.0
#: The arm is at rest at a command when its last replies before it differ by at most this.
REST_TICKS: Final = 1.5
#: The largest start shift taken (s): a twin that starts later than this is not a timing matter,
#: unless the arm was silent meanwhile (:func:`silent_s`).
MAX_SHIFT_S: Final = 0.06
#: Where a stream's replies pause for more than this many median intervals its motion is not
#: known (and an arrival first seen after such a gap is not timed), and its sender was silent.
SEEN_LATE: Final = 5.0
#: Steady motion for the timing scatter: the two neighbours of a reply this many ticks apart.
STEADY_TICKS: Final = 20.0
#: The timing RMS takes a reply where the joint's speeds just outside its neighbours agree
#: within this share of the larger (away from where it starts or stops).
OUTER_SPEED_BAND: Final = 0.3
#: Fewer residuals than this: the timing scatter is taken from the reply intervals instead.
MIN_RESIDUALS: Final = 20
#: A reply is stamped late when its angle is behind the straight line through its neighbours
#: by more than this many timing scatters (in time, along the joint's motion) ...
LATE_SIGMAS: Final = 5.0
#: ... and by more than this many wire ticks (the quantisation of a slow joint).
LATE_TICKS: Final = 3.0
#: A joint tells a late reply where its two neighbours are this many ticks apart: twice the
#: late limit (a slow joint moves only a few ticks between two replies read close together).
LATE_WAY_TICKS: Final = 2.0 * LATE_TICKS
#: Rounds of :func:`late_stamps` (each round on the replies the rounds before kept; a few, so
#: that what a round drops stays local to a host stall).
LATE_ROUNDS: Final = 3
#: Robust standard deviation from the median absolute value of a centred normal sample.
MAD_TO_SIGMA: Final = 1.4826
#: Variance of a sample's median over that of its mean (a normal sample): π / 2.
MEDIAN_EFFICIENCY: Final = math.pi / 2.0


@dataclass(frozen=True, slots=True)
class Track:
    """A reply stream: times (s, increasing) and the reported angles (``(n, 4)`` rad)."""

    t_s: FloatArray
    q_rad: FloatArray

    @classmethod
    def of(cls, replies: Sequence[tuple[float, Sequence[float]]]) -> Track:
        return cls(np.asarray([r[0] for r in replies], dtype=np.float64),
                   np.asarray([r[1] for r in replies], dtype=np.float64).reshape(-1, 4))

    def at(self, t_s: FloatArray) -> FloatArray:
        """The stream read as a trajectory (straight lines between replies, held beyond its
        ends; a reply's own value at its instant) at the times ``t_s``: ``(len(t_s), 4)``."""
        cols = [np.interp(t_s, self.t_s, self.q_rad[:, j]) for j in range(self.q_rad.shape[1])]
        out = np.column_stack(cols) if cols else np.zeros((len(t_s), 0))
        # at a reply's own instant, its value as it is (no rounding of the interpolation)
        i = np.clip(np.searchsorted(self.t_s, t_s - SAME_INSTANT_S), 0, len(self.t_s) - 1)
        same = np.abs(self.t_s[i] - t_s) <= SAME_INSTANT_S
        out[same] = self.q_rad[i[same]]
        return out

    def blind(self, t_s: FloatArray, gap_factor: float) -> npt.NDArray[np.bool_]:
        """Where the stream does not show its motion: within a gap of more than ``gap_factor``
        median intervals between two replies (its sender's loop stalled: an emulated firmware
        writing its EEPROM records, a starved process), up to the second reply after it (the
        first was composed before the gap ended, its angles older than its stamp)."""
        out = np.zeros(len(t_s), dtype=bool)
        if len(self.t_s) < 3:
            return out
        dt = np.diff(self.t_s)
        for i in np.flatnonzero(dt > gap_factor * float(np.median(dt))):
            begin, end = float(self.t_s[i]), float(self.t_s[min(int(i) + 2, len(self.t_s) - 1)])
            out |= (t_s > begin) & (t_s < end)
        return out

    def speed_at(self, t_s: FloatArray) -> FloatArray:
        """The trajectory's speed (rad/s, per joint) at the times ``t_s``: the slope of the line
        the time falls on."""
        if len(self.t_s) < 2:
            return np.zeros((len(t_s), self.q_rad.shape[1]))
        dt = np.diff(self.t_s)
        slope = np.diff(self.q_rad, axis=0) / np.where(dt > 0, dt, np.inf)[:, None]
        i = np.clip(np.searchsorted(self.t_s, t_s, side="right") - 1, 0, len(dt) - 1)
        inside = (t_s >= self.t_s[0]) & (t_s <= self.t_s[-1])
        return np.where(inside[:, None], slope[i], 0.0)


def _onset_s(track: Track, t0_s: float, t1_s: float, joint: int, speed_rad_s: float,
             pose_rad: float, target_rad: float | None = None) -> tuple[float, float] | None:
    """When ``joint`` left its pose ``pose_rad`` after a command at ``t0_s`` (before ``t1_s``),
    and the standard error of that time (s): each of the first :data:`ONSET_REPLIES` replies
    :data:`ONSET_TICKS` or more away from the pose at the command, traced back at the speed
    they show (the median slope between every two of the first :data:`SPEED_REPLIES` that have
    not arrived at ``target_rad``; ``speed_rad_s``, the nominal one, if that is outside
    :data:`SPEED_BAND`); their median (a reply composed before a stall of the sender's loop
    and sent after it is stale: one such reply does not move the median). Its standard error
    is that of a median of their spread, less the wire angle's quantisation (already in the
    floor): how much the replies disagree on the start, which a host that read them late by
    different amounts shows. None when it did not leave."""
    t, q = track.t_s, track.q_rad[:, joint]
    i0 = int(np.searchsorted(t, t0_s + SAME_INSTANT_S))
    i1 = int(np.searchsorted(t, t1_s + SAME_INSTANT_S))
    if i1 <= i0:
        return None
    away = np.abs(q[i0:i1] - pose_rad)
    moved = np.flatnonzero(away > ONSET_TICKS * TICK_RAD)[:ONSET_REPLIES]
    if len(moved) == 0:
        return None
    k = i0 + moved
    # the stream's own speed there (a joint that loses steps is slower than its law): the
    # median of the slopes between every two of its first replies (one stale reply does not
    # move it; pairs further apart than neighbours keep the wire's rounding of a slow joint
    # out of it; not those that arrived, a short move's end); the nominal one when they do
    # not say
    m = i0 + np.flatnonzero(away > ONSET_TICKS * TICK_RAD)[:SPEED_REPLIES]
    if target_rad is not None:
        going = m[np.abs(q[m] - target_rad) > ONSET_TICKS * TICK_RAD]
        m = going if len(going) >= len(k) else k
    a, b = np.triu_indices(len(m), 1)
    dt = t[m[b]] - t[m[a]]
    slopes = np.abs(q[m[b]] - q[m[a]])[dt > 0] / dt[dt > 0]
    speed = float(np.median(slopes)) if len(slopes) else speed_rad_s
    if not SPEED_BAND[0] * speed_rad_s <= speed <= SPEED_BAND[1] * speed_rad_s:
        speed = speed_rad_s
    starts = t[k] - np.abs(q[k] - pose_rad) / speed
    start = float(np.median(starts))
    if len(starts) < 2:
        return start, 0.0
    spread2 = float(np.sum((starts - start) ** 2)) / (len(starts) - 1)
    quant2 = 2.0 * (TICK_RAD / speed) ** 2 / 12.0      # the reply's and the pose's
    return start, math.sqrt(max(0.0, spread2 - quant2) * MEDIAN_EFFICIENCY / len(starts))


def silent_s(track: Track, t0_s: float, t1_s: float, interval_s: float) -> float:
    """How long (s) of ``t0_s`` to ``t1_s`` the stream was silent: where the span from its last
    reply before ``t0_s`` to ``t1_s``, less the replies it holds there (a median ``interval_s``
    each, and one for the reply that ends it), is more than :data:`SEEN_LATE` intervals (less
    is a sender's jitter), that much, at most ``t1_s − t0_s``; else 0. A sender whose loop
    stalled (a starved process on a loaded machine, a firmware busy) sent none meanwhile; a
    host that stalled read them late but read them all (a burst), which is no silence."""
    i0 = int(np.searchsorted(track.t_s, t0_s, side="right"))
    since = float(track.t_s[i0 - 1]) if i0 > 0 else t0_s
    n = int(np.searchsorted(track.t_s, t1_s)) - i0
    missing = (t1_s - since) - (n + 1) * interval_s
    return min(missing, t1_s - t0_s) if missing > SEEN_LATE * interval_s else 0.0


def _pose_at(track: Track, t_s: float) -> tuple[FloatArray, npt.NDArray[np.bool_]] | None:
    """The angles of the stream's newest reply before ``t_s`` and, per joint, whether its last
    two replies then show no motion (one reply alone: at rest); None when there is none."""
    i = int(np.searchsorted(track.t_s, t_s + SAME_INSTANT_S))
    if i == 0:
        return None
    q = track.q_rad
    rest = np.full(q.shape[1], True) if i == 1 else np.abs(q[i - 1] - q[i - 2]) <= \
        REST_TICKS * TICK_RAD
    return q[i - 1], np.asarray(rest)


def _heard_until(arm: Track, times: Sequence[float], k: int) -> float:
    """Until when command ``k``'s start is looked for: the next command the arm sent a reply
    before (``times``: the commands' and a last ``inf``). Commands that came while it was
    silent since command ``k`` (its loop stalled) reached it together when it woke, and its
    start then answers the first of them."""
    heard = int(np.searchsorted(arm.t_s, times[k], side="right"))  # replies by command k
    end = k + 1
    while end < len(times) - 1 and int(np.searchsorted(arm.t_s, times[end], side="right")) == heard:
        end += 1
    return times[end]


@dataclass(frozen=True, slots=True)
class Shifts:
    """The start shifts: per command and joint (``(n, 4)``, s), and the measured ones
    (joint, s; not those of an arm silent before its start: its reaction scatter is that of an
    arm awake, which the commands it met awake may meet); per command and joint, the standard
    error (s) of the arm's start the shift was measured at (``(n, 4)``, carried with the
    shift: 0 where none was measured)."""

    per_joint_s: FloatArray
    measured: list[tuple[int, float]]
    onset_se_s: FloatArray | None = None
    #: Per command, the earliest of the arm's measured starts after it less its stamp (s; nan
    #: where none was measured): the arm's reaction time as the capture's stamps show it, from
    #: the arm's replies alone (every joint that rested and has the way, whatever the twin did).
    arm_lag_s: FloatArray | None = None

    def deviations_s(self) -> list[float]:
        """Each measured shift minus its joint's median (s)."""
        out: list[float] = []
        for j in sorted({j for j, _ in self.measured}):
            values = np.asarray([v for i, v in self.measured if i == j])
            out.extend(float(v) for v in values - np.median(values))
        return out

    def scatter_s(self) -> float | None:
        """The spread (s, RMS) of the measured shifts about each joint's median: how much the
        arm's reaction to a command varies against the twin's, which the shifts of commands sent
        while moving (not measurable) may be off by. Not a robust spread: the odd late reaction
        (a starved process on a loaded machine, two commands queued on the wire) is exactly what
        such a command may meet. None with fewer than three."""
        if len(self.measured) < 3:
            return None
        return float(np.sqrt(np.mean(np.square(self.deviations_s()))))


def move_shifts(arm: Track, twin: Track, commands: Sequence[tuple[float, Command]],
                settings: RobotSettings, poses: tuple[Track, Track] | None = None) -> Shifts:
    """Per command and joint (``(n, 4)``), the time (s) the arm's joint started moving after the
    twin's (arm − twin): measured, at each command, on each joint that was at rest (in both
    streams) and has a way of :data:`MIN_WAY_TICKS` or more (the firmware passes a command on to
    each joint's board in turn: each joint has its own delay); carried over from the move before
    otherwise (0 before the first measured start, or when a stream did not move). Within
    ±:data:`MAX_SHIFT_S`, the arm later by as much more as it was silent between the command and
    its start (:func:`silent_s`: an arm whose loop stalled acts on the command when it wakes,
    which is a timing matter too; the commands that came while it was silent reached it
    together, and its start answers the first). ``poses``: the two streams with every reply,
    those left out of ``arm`` and ``twin`` for their stamps too (read in a burst or late): where
    a joint was and whether it rested at a command comes from them, since a stamp may be late
    but never early (after a host stall the newest timed reply before a command can be from
    before the move that ended at it, and a start traced back from there came before the
    command)."""
    out = np.zeros((len(commands), 4))
    onset_se = np.zeros((len(commands), 4))
    lag = np.full(len(commands), np.nan)
    shift, se = np.zeros(4), np.zeros(4)
    measured: list[tuple[int, float]] = []
    times = [c[0] for c in commands] + [math.inf]
    lower, upper = settings.lower_rad, settings.upper_rad
    arm_poses, twin_poses = (arm, twin) if poses is None else poses
    interval_s = float(np.median(np.diff(arm_poses.t_s))) if len(arm_poses.t_s) > 1 else 0.0
    for k, (t_c, cmd) in enumerate(commands):
        arm_at, twin_at = _pose_at(arm_poses, t_c), _pose_at(twin_poses, t_c)
        until = _heard_until(arm_poses, times, k)
        if arm_at is not None:
            arm_pose, arm_rest = arm_at
            goals = np.asarray(cmd.angles_rad(lower, upper))
            way = np.abs(goals - arm_pose)
            # the arm's start is the arm's (its lag too, whatever the twin did); a shift needs
            # the twin's start as well
            for j in np.flatnonzero((way >= MIN_WAY_TICKS * TICK_RAD)
                                    & (np.asarray(cmd.duties) > 0) & arm_rest):
                speed = joint_speed_rad_s(cmd.duties[j], settings.joints[j].steps_per_rad)
                goal = float(goals[j])
                a = _onset_s(arm, t_c, until, int(j), speed, float(arm_pose[j]), goal)
                if a is None:
                    continue
                lag[k] = np.fmin(lag[k], a[0] - t_c)
                if twin_at is None:
                    continue
                twin_pose, twin_rest = twin_at
                if not twin_rest[j]:
                    continue
                b = _onset_s(twin, t_c, until, int(j), speed, float(twin_pose[j]), goal)
                if b is not None:
                    silence_s = silent_s(arm_poses, t_c, a[0], interval_s)
                    shift[j] = float(np.clip(a[0] - b[0], -MAX_SHIFT_S, MAX_SHIFT_S + silence_s))
                    se[j] = a[1]
                    if silence_s == 0.0:  # how late an arm wakes is no reaction of it
                        measured.append((int(j), float(shift[j])))
        out[k], onset_se[k] = shift, se
    return Shifts(out, measured, onset_se, lag)


def stamped_late_s(arm_lag_s: FloatArray | None, command_times: Sequence[float],
                   limit_s: float) -> FloatArray | None:
    """Per command, how much earlier (s, <= 0) the arm acted on it than its stamp says, where
    its own replies show it left more than ``limit_s`` before the stamp (``arm_lag_s``:
    :attr:`Shifts.arm_lag_s`; a host stalled while writing the command stamped it late): by
    that and the arm's median reaction time; the commands stamped between that instant and it
    are moved alike (they keep their order). None when no command was."""
    lag = arm_lag_s
    if lag is None or int(np.isfinite(lag).sum()) < 3:
        return None
    early = np.isfinite(lag) & (lag < -limit_s)
    if not early.any():
        return None
    out = np.where(early, lag - float(np.nanmedian(lag)), 0.0)
    t = np.asarray(command_times)
    for k in np.flatnonzero(early)[::-1]:
        before = (t < t[k]) & (t > t[k] + out[k])
        out[before] = np.minimum(out[before], out[k])
    return np.asarray(out, dtype=np.float64)


def command_shifts(shifts: FloatArray, commands: Sequence[tuple[float, Command]],
                   arm: Track, settings: RobotSettings) -> FloatArray:
    """Per command, the start shift of its joint with the longest way (the one that decides
    when the move arrives)."""
    out = np.zeros(len(commands))
    for k, (t_c, cmd) in enumerate(commands):
        i = max(0, int(np.searchsorted(arm.t_s, t_c + SAME_INSTANT_S)) - 1)
        way = np.abs(np.asarray(cmd.angles_rad(settings.lower_rad, settings.upper_rad))
                     - arm.q_rad[i])
        out[k] = shifts[k, int(np.argmax(way))]
    return out


def _steady_residuals_s(arm: Track, command_times: Sequence[float], outer: bool = False
                        ) -> FloatArray:
    """Where a joint moves steadily (its two neighbouring replies at least
    :data:`STEADY_TICKS` apart, no command between them), each reply's distance from the
    straight line through its neighbours in time units (divided by the speed, scaled for the
    neighbours' own scatter), pooled over the joints. With ``outer``, only where the joint's
    speed before the neighbours and after them (the next replies out) agrees within
    :data:`OUTER_SPEED_BAND` (no command between those either): a reply next to where the
    joint starts or stops (a knee in its motion, not a timing matter) is left out."""
    t, q = arm.t_s, arm.q_rad
    if len(t) < 3:
        return np.zeros(0)
    span = t[2:] - t[:-2]
    ok_t = span > 0
    w = np.where(ok_t, (t[1:-1] - t[:-2]) / np.where(ok_t, span, 1.0), 0.5)
    ct = np.asarray(sorted(command_times))
    # no command between the outer neighbours (the arm may change course there)
    same = np.searchsorted(ct, t[:-2], side="right") == np.searchsorted(ct, t[2:], side="right")
    scale = np.sqrt(1.0 + w * w + (1.0 - w) ** 2)
    pooled = []
    for j in range(q.shape[1]):
        dq = q[2:, j] - q[:-2, j]
        steady = ok_t & same & (np.abs(dq) >= STEADY_TICKS * TICK_RAD)
        if not steady.any():
            continue
        if outer:
            steady &= _outer_steady(t, q[:, j], ct)
        v = dq[steady] / span[steady]
        r = q[1:-1, j][steady] - (q[:-2, j][steady] + w[steady] * dq[steady])
        pooled.append(r / v / scale[steady])
    return np.concatenate(pooled) if pooled else np.zeros(0)


def _outer_steady(t: FloatArray, q: FloatArray, command_times: FloatArray
                  ) -> npt.NDArray[np.bool_]:
    """Per inner reply (``n - 2``) of one joint: whether the speed from the reply two before to
    the one before and from the one after to the one two after agree (same sign, within
    :data:`OUTER_SPEED_BAND` of the larger), with no command from the first to the last."""
    out = np.zeros(max(0, len(t) - 2), dtype=bool)
    if len(t) < 5:
        return out
    dt_l, dt_r = t[1:-3] - t[:-4], t[4:] - t[3:-1]
    ok = (dt_l > 0) & (dt_r > 0)
    v_l = (q[1:-3] - q[:-4]) / np.where(ok, dt_l, 1.0)
    v_r = (q[4:] - q[3:-1]) / np.where(ok, dt_r, 1.0)
    top = np.maximum(np.abs(v_l), np.abs(v_r))
    same = np.searchsorted(command_times, t[:-4], side="right") == np.searchsorted(
        command_times, t[4:], side="right")
    out[1:-1] = ok & same & (v_l * v_r > 0) & (np.abs(v_l - v_r) <= OUTER_SPEED_BAND * top)
    return out


def timing_rms_s(arm: Track, command_times: Sequence[float]) -> float | None:
    """The RMS of the timing residuals of :func:`timing_scatter_s` (s): every timing scatter
    the replies show, its tail too (a loaded host reading some replies a little late, a sender
    whose loop time varies), which a perfect twin's RMS divergence meets in full. None with
    fewer than :data:`MIN_RESIDUALS` of them."""
    e = _steady_residuals_s(arm, command_times, outer=True)
    if len(e) < MIN_RESIDUALS:
        return None
    return float(np.sqrt(np.mean(e * e)))


def timing_scatter_s(arm: Track, command_times: Sequence[float]) -> float:
    """The link's timing scatter (s, a standard deviation) as the capture shows it: where a
    joint moves steadily (its two neighbouring replies at least :data:`STEADY_TICKS` apart, no
    command between them), the reply's distance from the straight line through its neighbours,
    in time units (divided by the speed, scaled for the neighbours' own scatter); a robust
    spread of all of them. With too few, the spread of the reply intervals over √2 (a steady
    reply rate assumed: an overestimate otherwise)."""
    t = arm.t_s
    if len(t) < 3:
        return 0.0
    e = _steady_residuals_s(arm, command_times)
    if len(e) >= MIN_RESIDUALS:
        return float(MAD_TO_SIGMA * np.median(np.abs(e)))
    gaps = np.diff(t)
    return float(MAD_TO_SIGMA * np.median(np.abs(gaps - np.median(gaps))) / math.sqrt(2.0))


def floor_rad(speed_rad_s: FloatArray, reply_scatter_s: float, command_scatter_s: float,
              counts_per_rad: FloatArray) -> FloatArray:
    """Per joint, the RMS divergence (rad) a perfect twin would show on this capture: the timing
    scatter of the replies and of the arm's reaction to commands, times the twin's speed at the
    compared replies (``(n, 4)`` rad/s), and the quantisation of the wire angle and of the
    encoder, on both streams."""
    mean_v2 = np.mean(speed_rad_s * speed_rad_s, axis=0) if len(speed_rad_s) else 0.0
    quant = 2.0 * (TICK_RAD ** 2 + (1.0 / counts_per_rad) ** 2) / 12.0
    timing2 = reply_scatter_s ** 2 + command_scatter_s ** 2
    return np.asarray(np.sqrt(timing2 * mean_v2 + quant), dtype=np.float64)


def onset_floor_rad(shifts: Shifts, t_s: FloatArray, command_times: Sequence[float],
                    speed_rad_s: FloatArray) -> FloatArray:
    """Per joint, the RMS divergence (rad) a perfect twin shows from the uncertainty of the
    arm's starts the shifts were measured at: at each compared reply (times ``t_s``), the
    standard error of its move's start (:attr:`Shifts.onset_se_s`, from the arm's own replies)
    times the twin's speed there (``(n, 4)`` rad/s). A host that read a start's replies late by
    different amounts aligns the whole move by a start that much off."""
    if shifts.onset_se_s is None or not len(t_s) or not len(command_times):
        return np.zeros(4)
    k = np.clip(np.searchsorted(np.asarray(command_times), t_s + SAME_INSTANT_S, side="right")
                - 1, 0, len(command_times) - 1)
    se = shifts.onset_se_s[k]
    return np.asarray(np.sqrt(np.mean((se * speed_rad_s) ** 2, axis=0)), dtype=np.float64)


def interval_floor_s(arm: Track, twin: Track, reply_scatter_s: float,
                     command_scatter_s: float) -> float:
    """The RMS difference (s) of two arrival times a perfect twin would show: an arrival is
    seen at the first reply after it (late by up to one reply interval, uniform), on both
    streams, plus the timing scatter of the replies and of the reaction to commands."""
    def interval(track: Track) -> float:
        gaps = np.diff(track.t_s)
        return float(np.percentile(gaps, 95)) if len(gaps) else 0.0
    return math.sqrt((interval(arm) ** 2 + interval(twin) ** 2) / 12.0 + reply_scatter_s ** 2
                     + command_scatter_s ** 2)


def _residuals(t: FloatArray, q: FloatArray, command_times: Sequence[float]
               ) -> tuple[FloatArray, FloatArray, npt.NDArray[np.bool_]]:
    """Per inner reply and joint (``(n - 2, 4)``): its angle minus the straight line through
    its two neighbours (rad), the speed of that line (rad/s), and whether the joint moves
    there (neighbours :data:`LATE_WAY_TICKS` apart, no command between them)."""
    span = t[2:] - t[:-2]
    ok_t = span > 0
    w = np.where(ok_t, (t[1:-1] - t[:-2]) / np.where(ok_t, span, 1.0), 0.5)
    ct = np.asarray(sorted(command_times)) + SAME_INSTANT_S
    same = np.searchsorted(ct, t[:-2]) == np.searchsorted(ct, t[2:])
    dq = q[2:] - q[:-2]
    steady = (ok_t & same)[:, None] & (np.abs(dq) >= LATE_WAY_TICKS * TICK_RAD)
    v = dq / np.where(ok_t, span, np.inf)[:, None]
    return q[1:-1] - (q[:-2] + w[:, None] * dq), v, steady


def _stale_at_start(t: FloatArray, q: FloatArray, command_times: Sequence[float],
                    scatter_s: float) -> npt.NDArray[np.bool_]:
    """Per inner reply (``n - 2``): whether it still shows the pose of the reply before it
    while the joint had left it by the late limit at its stamp, as the next
    :data:`ONSET_REPLIES` replies traced back at their own speed (medians: one of them may be
    late too) say: a reply composed before the joint left, read after (the line through two
    neighbours does not see it: a command lies between them). Vectorised over the replies and
    joints (the candidates narrowed first): a capture holds some 10⁵ replies."""
    n = ONSET_REPLIES
    out = np.zeros(max(0, len(t) - 2), dtype=bool)
    m = len(t) - n - 1                      # replies i = 1 .. m, each with n replies after it
    if m <= 0:
        return out
    i = np.arange(1, m + 1)
    ct = np.asarray(sorted(command_times)) + SAME_INSTANT_S   # a reply at a command's instant
    t_next = sliding_window_view(t[2:], n)[:m]                 # is before it; (m, n)
    dt = np.diff(t_next, axis=1)
    ok = (np.searchsorted(ct, t[i]) == np.searchsorted(ct, t[i + n])) & np.all(dt > 0, axis=1)
    way_last = q[i + n] - q[i]                                 # (m, joints)
    ok = (ok[:, None] & (np.abs(q[i] - q[i - 1]) <= REST_TICKS * TICK_RAD)
          & (np.abs(way_last) >= STEADY_TICKS * TICK_RAD))
    r, j = np.nonzero(ok)
    q_next = sliding_window_view(q[2:], n, axis=0)[:m][r, j]  # (candidates, n)
    way = q_next - q[i[r], j][:, None]
    one_way = ~np.any(way * way_last[r, j][:, None] < 0, axis=1)
    r, way = r[one_way], way[one_way]
    speed = np.median(np.abs(np.diff(q_next[one_way], axis=1)) / dt[r], axis=1)
    moving = speed > 0
    r, way, speed = r[moving], way[moving], speed[moving]
    left = np.median(t_next[r] - np.abs(way) / speed[:, None], axis=1)
    limit = np.maximum(LATE_SIGMAS * scatter_s * speed, LATE_TICKS * TICK_RAD)
    out[r[(t[i[r]] - left) * speed > limit]] = True
    return out


def late_stamps(arm: Track, command_times: Sequence[float], scatter_s: float
                ) -> npt.NDArray[np.bool_]:
    """Per reply, whether its stamp is later than its angle shows (the host read it late: a
    loaded machine reading a serial port or a socket; a reply may come late, never early): on a
    joint that moves steadily, its angle is behind the straight line through its neighbours,
    along the motion, by more than :data:`LATE_SIGMAS` timing scatters ``scatter_s`` and
    :data:`LATE_TICKS` ticks. Found from the arm's stream alone (no model enters: a wrong twin
    cannot excuse itself), repeated on the replies kept (a late neighbour bends the line)."""
    late = np.zeros(len(arm.t_s), dtype=bool)
    for _ in range(LATE_ROUNDS):
        keep = np.flatnonzero(~late)
        if len(keep) < 3:
            break
        r, v, steady = _residuals(arm.t_s[keep], arm.q_rad[keep], command_times)
        behind = -r * np.sign(v)
        limit = np.maximum(LATE_SIGMAS * scatter_s * np.abs(v), LATE_TICKS * TICK_RAD)
        new = np.any(steady & (behind > limit), axis=1)
        new |= _stale_at_start(arm.t_s[keep], arm.q_rad[keep], command_times, scatter_s)
        if not new.any():
            break
        late[keep[1:-1][new]] = True
    return late
