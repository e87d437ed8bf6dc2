"""A twin's replay against an arm's capture, compared timing-robustly
(:mod:`armbench.bench.calibrate.align`): per joint, the divergence of the reported angle at the
arm's compared replies, and per reply what a perfect twin would score there from the capture's
own timing (the parts of the floor the replies give). ``armbench twin-check`` judges it
(:mod:`armbench.bench.twin_check.check`); a calibration chooses with it, on its held-out
blocks, which of its fitted structures replaces the prior
(:mod:`armbench.bench.calibrate.held_out`).

The replies the host read in one go after a stall (several within :data:`BURST_S`) or late one by
one (:func:`~armbench.bench.calibrate.align.late_stamps`, from the arm's stream alone) are left
out; each move from rest is aligned at its start; where the twin's replies pause its motion is
not known and the arm's replies then are not compared.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from armbench.bench.calibrate.align import (
    SAME_INSTANT_S,
    SEEN_LATE,
    TICK_RAD,
    Shifts,
    Track,
    late_stamps,
    move_shifts,
    timing_rms_s,
    timing_scatter_s,
)
from armbench.bench.calibrate.capture_data import CaptureData
from armbench.bench.calibrate.replay import BURST_S, TIME_SLACK_S
from armbench.drivers.model.settings import RobotSettings

__all__ = ["ArmSide", "Divergence", "arm_side", "diverge", "read_aligned",
           "read_late", "timed"]

FloatArray = npt.NDArray[np.float64]
Vec4 = tuple[float, float, float, float]

def timed(replies: Sequence[tuple[float, Vec4]], start_s: float = -math.inf
          ) -> list[tuple[float, Vec4]]:
    """The replies whose stamp is their time: not read in one go with the one before or after
    (the last of a burst too was stamped when the host woke); and those stamped before
    ``start_s`` (the first command: the arm rests before it, so their stamps do not matter,
    and they hold the pose the first move starts from)."""
    t = np.asarray([r[0] for r in replies])
    apart = np.diff(t) >= BURST_S
    keep = (np.append(apart, True) & np.insert(apart, 0, True)) | (t < start_s)
    return [r for r, k in zip(replies, keep, strict=True) if k]


def read_late(arm: Track, command_times: Sequence[float], scatter_s: float | None = None
              ) -> npt.NDArray[np.bool_]:
    """Per reply of ``arm`` (timed ones), whether the host read it late
    (:func:`armbench.bench.calibrate.align.late_stamps`: a loaded host reads the replies some
    milliseconds after they came, not always in one go), against the timing scatter
    ``scatter_s`` (else the stream's own). Such a reply is neither compared nor used to time a
    move's start."""
    if len(arm.t_s) < 3:
        return np.zeros(len(arm.t_s), dtype=bool)
    if scatter_s is None:
        scatter_s = timing_scatter_s(arm, command_times)
    return late_stamps(arm, command_times, scatter_s)


def read_aligned(t_s: FloatArray, times: Sequence[float], twin: Track, shifts: FloatArray
                 ) -> tuple[FloatArray, FloatArray, npt.NDArray[np.bool_]]:
    """The twin's angles and speeds (``(n, 4)``) at the times ``t_s``, each joint read at its
    start shift's instant, and whether a joint's instant falls where the twin's replies pause
    (:meth:`Track.blind`: its motion there is not known)."""
    k_of = np.clip(np.searchsorted(np.asarray(times), t_s + TIME_SLACK_S, side="right") - 1,
                   0, len(times) - 1)
    at = t_s[:, None] - shifts[k_of]            # per reply and joint, on the twin's clock
    q = np.column_stack([twin.at(at[:, j])[:, j] for j in range(4)])
    v = np.column_stack([twin.speed_at(at[:, j])[:, j] for j in range(4)])
    blind = np.any(np.column_stack([twin.blind(at[:, j], SEEN_LATE) for j in range(4)]), axis=1)
    return q, v, blind


@dataclass(frozen=True, slots=True)
class Divergence:
    """The arm's capture and the twin's replay side by side. ``data``: the capture with its
    timed replies only; ``whole``: those replies as a track, ``late`` which of them the host
    read late; ``twin``: the twin's stream; ``shifts``: the start alignment. At each compared
    reply (``t_s``, capture clock): the arm's angles, the twin's at the aligned instant and its
    speed there (``(n, 4)``, rad and rad/s). ``scatter_s``: the link's timing scatter (robust),
    ``spread_s``: the RMS of the replies' timing residuals (at least the scatter),
    ``reaction_s``: the scatter of the arm's reaction to commands (the start shifts' spread, at
    least the timing scatter); ``untimed``: replies left out (read in a burst or late)."""

    data: CaptureData
    whole: Track
    late: npt.NDArray[np.bool_]
    twin: Track
    shifts: Shifts
    t_s: FloatArray
    arm_rad: FloatArray
    twin_rad: FloatArray
    speed_rad_s: FloatArray
    counts_per_rad: FloatArray
    scatter_s: float
    spread_s: float
    reaction_s: float
    untimed: int

    @property
    def times(self) -> list[float]:
        """The commands' times (capture clock)."""
        return [c[0] for c in self.data.commands]

    @property
    def diff_rad(self) -> FloatArray:
        """Arm minus twin at each compared reply (``(n, 4)``, rad)."""
        out: FloatArray = self.arm_rad - self.twin_rad
        return out

    def rms_rad(self, rows: npt.NDArray[np.bool_] | None = None) -> FloatArray:
        """Per joint, the RMS divergence (rad) over the compared replies (``rows`` of them)."""
        d = self.diff_rad if rows is None else self.diff_rad[rows]
        return np.sqrt(np.mean(d * d, axis=0)) if len(d) else np.zeros(4)

    def floor2_rad2(self, reaction: bool) -> FloatArray:
        """Per compared reply and joint (``(n, 4)``, rad²), what a perfect twin's squared
        divergence is there from the capture's timing: the replies' timing spread and, with
        ``reaction``, the arm's reaction scatter (:attr:`reaction_s`; without it the caller adds
        the reaction part by replay), times the twin's speed; the standard error of the move's
        start the alignment took (:attr:`Shifts.onset_se_s`) times the speed; the quantisation
        of the wire angle and the encoder on both streams."""
        v2 = self.speed_rad_s * self.speed_rad_s
        timing2 = self.spread_s ** 2 + (self.reaction_s ** 2 if reaction else 0.0)
        quant = 2.0 * (TICK_RAD ** 2 + (1.0 / self.counts_per_rad) ** 2) / 12.0
        onset = np.zeros_like(v2)
        times = self.times
        if self.shifts.onset_se_s is not None and len(self.t_s) and times:
            k = np.clip(np.searchsorted(np.asarray(times), self.t_s + SAME_INSTANT_S,
                                        side="right") - 1, 0, len(times) - 1)
            onset = (self.shifts.onset_se_s[k] ** 2) * v2
        out: FloatArray = timing2 * v2 + quant[None, :] + onset
        return out

    def floor_rad(self, reaction: bool = True,
                  rows: npt.NDArray[np.bool_] | None = None) -> FloatArray:
        """Per joint, the RMS of :meth:`floor2_rad2` over the compared replies (``rows`` of
        them): the floor a perfect twin would score there (the quantisation alone where
        nothing is compared)."""
        f2 = self.floor2_rad2(reaction)
        if rows is not None:
            f2 = f2[rows]
        if not len(f2):
            return np.sqrt(2.0 * (TICK_RAD ** 2 + (1.0 / self.counts_per_rad) ** 2) / 12.0)
        return np.asarray(np.sqrt(np.mean(f2, axis=0)), dtype=np.float64)


@dataclass(frozen=True, slots=True)
class ArmSide:
    """What the arm's capture alone says, the same against every twin: the capture with its
    timed replies only, those replies as a track, which of them the host read late, the
    link's timing scatter and spread, how many replies were left out, and every reply as the
    host read it (``received``: where the arm was at a command, whatever the stamps)."""

    data: CaptureData
    whole: Track
    late: npt.NDArray[np.bool_]
    scatter_s: float
    spread_s: float
    untimed: int
    received: Track


def arm_side(data: CaptureData) -> ArmSide:
    """The :class:`ArmSide` of a capture."""
    times = [c[0] for c in data.commands]
    kept = timed(data.replies, times[0] - TIME_SLACK_S if times else -math.inf)
    scatter = timing_scatter_s(Track.of(kept), times)
    late = read_late(Track.of(kept), times, scatter)
    untimed = len(data.replies) - len(kept) + int(late.sum())
    whole = Track.of(kept)
    spread = timing_rms_s(Track(whole.t_s[~late], whole.q_rad[~late]), times)
    return ArmSide(CaptureData(data.path, data.commands, kept, data.bad_in_frames), whole, late,
                   scatter, scatter if spread is None else max(scatter, spread), untimed,
                   Track.of(data.replies))


def diverge(data: CaptureData, twin: Sequence[tuple[float, Vec4]],
            settings: RobotSettings, arm: ArmSide | None = None) -> Divergence:
    """Compare the capture's replies with the twin's (see the module doc); ``arm``: the
    capture's :class:`ArmSide` where it was found before (several twins on one capture)."""
    side = arm_side(data) if arm is None else arm
    data, whole, late, scatter = side.data, side.whole, side.late, side.scatter_s
    twin_track = Track.of(twin)
    times = [c[0] for c in data.commands]
    # the starts are timed on the replies read on time, the twin's alike (its own stale
    # replies, after its firmware's pauses, are left out by the same rule)
    twin_late = read_late(twin_track, times, scatter)
    measured = move_shifts(Track(whole.t_s[~late], whole.q_rad[~late]),
                           Track(twin_track.t_s[~twin_late], twin_track.q_rad[~twin_late]),
                           data.commands, settings, (side.received, twin_track))
    start = times[0] if times else -math.inf
    rows = [(t, q) for (t, q), x in zip(data.replies, late, strict=True)
            if t >= start and len(twin_track.t_s) and t >= twin_track.t_s[0] and not x]
    compared = Track.of(rows)
    if times and len(compared.t_s):
        q_twin, speed, blind = read_aligned(compared.t_s, times, twin_track,
                                            measured.per_joint_s)
    else:
        n = len(compared.t_s)
        q_twin, speed, blind = np.zeros((n, 4)), np.zeros((n, 4)), np.zeros(n, dtype=bool)
    reaction = measured.scatter_s()
    counts = np.asarray([j.counts_per_rad for j in settings.joints])
    return Divergence(
        data, whole, late, twin_track, measured, compared.t_s[~blind], compared.q_rad[~blind],
        q_twin[~blind], speed[~blind], counts, scatter, side.spread_s,
        scatter if reaction is None else max(scatter, reaction), side.untimed)
