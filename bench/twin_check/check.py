"""``armbench twin-check``: how well the twin predicts an arm, measured on the arm's own traffic,
and judged against what a perfect twin would score on the same capture.

The commands of a capture are replayed, at their recorded times, into the emulator built from the
given settings (the twin), on virtual time, starting from the capture's first reported pose (the
twin's replies count from its first one at that pose: what it reports while still booting is not
the model's). The two reply streams are then compared timing-robustly
(:mod:`armbench.bench.calibrate.align`): the twin's stream read as a trajectory at the arm's reply
times, each move from rest aligned at its start:

* per joint, the RMS and largest divergence of the reported angle (rad and encoder counts), and
  the RMS difference of where each move settled (the last reply before the next command);
* per move, the difference of the arrival times (twin − arm, after the start alignment) where
  both arrive;
* the TCP divergence where the capture has the truth: the arm's true TCP (a tracker's, or the
  truth joints of an MCAP capture of ``fake://`` through the actual model of the arm its record
  names) against the twin's true TCP at the same instants.

Each comparison has a floor computed from the capture: what a perfect twin would score. The
link's timing scatter (the RMS of the replies' timing residuals, their tail too) times the twin's
speed and the angle's quantisation (:func:`armbench.bench.calibrate.align.floor_rad`), the
uncertainty of each move's start as the arm's own replies tell it times the speed
(:func:`armbench.bench.calibrate.align.onset_floor_rad`), and the arm's reaction scatter (the
spread of the measured start shifts) by replay: the twin replayed with each command moved by ± its
RMS,
compared with itself as the arm is (:func:`replay_floor`). The verdict allows
``k × floor + abs`` (per joint in counts, for the arrivals in s, for the TCP in mm; ``k`` and
``abs`` in the config's ``[suites."twin-check"]``
table, else :class:`Allowance`'s defaults): each ``*.rms_per_allowed`` figure is the RMS over
its allowance, judged against the limits of a bench config (``--config``, else the packaged
``twin_check.toml``, ``high = 1``). Where moves settled and where the twin rests no timing
enters: there the floor is the quantisation alone (``settled_per_allowed``, and the TCP at rest
against ``tcp_abs_mm``). The verdict is ``pass`` when every judged figure is within, else
``fail`` (the figures judged in :mod:`armbench.bench.twin_check.figures`). Each failing joint gets a
diagnosis: what its divergence looks like and what to do
(:mod:`armbench.bench.twin_check.diagnosis`). :mod:`armbench.bench.twin_check.twin_record` writes a
check as a run record.

A capture of several sessions (a run's capture holds one emulator per trial, a foreign arm
restarts at each connection) is cut where the replies jump further than the joints can move, or
fall silent; each session is replayed into a fresh twin from its own first pose, with the command
that was in flight at the cut written first.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from armbench.bench.calibrate.align import (
    SEEN_LATE,
    TICK_RAD,
    Track,
    command_shifts,
    interval_floor_s,
    move_shifts,
    stamped_late_s,
)
from armbench.bench.calibrate.capture_data import CaptureData
from armbench.bench.calibrate.divergence import (
    diverge,
    read_aligned,
    read_late,
    timed,
)
from armbench.bench.calibrate.replay import (
    TIME_SLACK_S,
    Session,
    TwinTruth,
    closer_counters,
    replay_sessions,
    replay_twin,
    sessions,
)
from armbench.bench.suites.twin_check_contract import TWIN_CHECK
from armbench.bench.twin_check.diagnosis import Diagnosis, diagnose_joints, failing_joints
from armbench.bench.twin_check.figures import (
    Allowance,
    arrival_measurements,
    joint_measurements,
    part_measurements,
    tcp_measurements,
    verdict_of,
)
from armbench.bench.twin_check.parts import Part, part_figures
from armbench.bench.twin_check.tool_point import arm_tcp_from_capture, tcp_divergence
from armbench.bench.twin_check.where import factors_of, growth
from armbench.drivers.model.settings import RobotSettings
from armbench.record import Measurement, judge
from armbench.record.limits import LimitsConfig, load_limits

__all__ = ["DEFAULT_CONFIG", "Aligned", "Allowance", "Session", "TwinCheck", "compare",
           "replay_floor", "replay_twin", "sessions", "tcp_divergence", "twin_check"]

DEFAULT_CONFIG: Final = Path(__file__).resolve().with_name("twin_check.toml")
#: A move counts as arrived when every joint is this close to its target (rad): the driver's
#: default arrival tolerance.
ARRIVAL_TOLERANCE_RAD: Final = 3e-4
#: A start shift further than this (s) from its joint's median is a start timed badly (a stale
#: or late-read reply), not a reaction: the draws take it as this much.
MAX_REACTION_S: Final = 0.02
#: Seed of the reaction draws of the floor's replays, and how many replays it averages.
REACTION_SEED: Final = 0
REACTION_REPLAYS: Final = 4
Vec4 = tuple[float, float, float, float]
Vec3 = tuple[float, float, float]
FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Aligned:
    """The two reply streams side by side: at each compared reply of the capture (``t_s``, s on
    the capture's clock) the arm's reported angles and the twin's at the aligned instant
    (``(n, 4)``, rad), and each joint's encoder counts per rad."""

    t_s: FloatArray
    arm_rad: FloatArray
    twin_rad: FloatArray
    counts_per_rad: FloatArray

    @property
    def divergence_counts(self) -> FloatArray:
        """Arm minus twin, per joint, in encoder counts (``(n, 4)``)."""
        return (self.arm_rad - self.twin_rad) * self.counts_per_rad


@dataclass(frozen=True, slots=True)
class TwinCheck:
    """The comparison of an arm's capture with its twin's replay. ``arrivals`` holds, per
    command, its time and the arrival time in the arm's and the twin's stream (the twin's on the
    arm's clock after the start alignment; None: never arrived before the next command)."""

    rms_rad: list[float]
    max_rad: list[float]
    rms_counts: list[float]
    max_counts: list[float]
    arrival_dt_s: list[float]
    moves: int
    arrived_arm_only: int
    arrived_twin_only: int
    replies_compared: int
    measurements: list[Measurement]
    verdict: str
    twin_replies: list[tuple[float, Vec4]]
    tcp: dict[str, float] | None = None
    sessions: int = 1
    hall_counters: tuple[bool, ...] = (False, False, False, False)
    """Per joint, whether the twin's counters were as its Hall sensors set them (else a new
    arm's)."""
    series: Aligned | None = None
    arrivals: list[tuple[float, float | None, float | None]] = field(default_factory=list)
    floor_counts: list[float] = field(default_factory=list)
    allowed_counts: list[float] = field(default_factory=list)
    settled_counts: list[float] = field(default_factory=list)
    scatter_s: float = 0.0
    reaction_scatter_s: float = 0.0
    shifts_s: list[float] = field(default_factory=list)
    joint_shifts_s: FloatArray | None = None
    shift_deviations_s: list[float] = field(default_factory=list)
    arm_lag_s: FloatArray | None = None
    diagnoses: list[Diagnosis | None] = field(default_factory=lambda: [None] * 4)
    """Per joint, what its divergence looks like and what to do (where the joint failed)."""
    parts: list[Part] = field(default_factory=list)
    """The parts of the capture judged one by one (:mod:`armbench.bench.twin_check.parts`)."""
    speed_rad_s: FloatArray | None = None
    """The twin's speed at each compared reply (``(n, 4)``), beside :attr:`series`."""

    def to_json(self) -> dict[str, Any]:
        """The ``--json`` object."""
        dt = np.asarray(self.arrival_dt_s) if self.arrival_dt_s else None
        return {
            "rms_rad": self.rms_rad, "max_rad": self.max_rad, "rms_counts": self.rms_counts,
            "max_counts": self.max_counts, "floor_counts": self.floor_counts,
            "allowed_counts": self.allowed_counts, "settled_counts": self.settled_counts,
            "timing_scatter_s": self.scatter_s, "reaction_scatter_s": self.reaction_scatter_s,
            "arrival": {"moves": self.moves, "compared": len(self.arrival_dt_s),
                        "arm_only": self.arrived_arm_only, "twin_only": self.arrived_twin_only,
                        "mean_dt_s": None if dt is None else float(dt.mean()),
                        "max_abs_dt_s": None if dt is None else float(np.abs(dt).max())},
            "tcp": self.tcp, "replies_compared": self.replies_compared,
            "sessions": self.sessions, "hall_counters": list(self.hall_counters),
            "measurements": [{"name": m.name, "value": m.value, "unit": m.unit,
                              "limit": m.limit.describe() if m.limit else None,
                              "outcome": m.outcome} for m in self.measurements],
            "verdict": self.verdict,
            "parts": [p.to_json() for p in self.parts],
            "diagnosis": [None if d is None else d.to_json() for d in self.diagnoses],
        }


def _arrivals(replies: Sequence[tuple[float, Vec4]], data: CaptureData,
              settings: RobotSettings, shifts: FloatArray | None = None
              ) -> list[tuple[float | None, float]]:
    """Per command, the first reply time after it (before the next one) within the arrival
    tolerance of its target on every joint, or None; and how long before it the previous reply
    came (how late the arrival may have been seen). With ``shifts`` (the twin's stream), the
    command's window is shifted by them and the arrival mapped onto the arm's clock."""
    t = np.asarray([r[0] for r in replies])
    q = np.asarray([r[1] for r in replies])
    times = [c[0] for c in data.commands] + [math.inf]
    out: list[tuple[float | None, float]] = []
    for k, (tc, cmd) in enumerate(data.commands):
        s = 0.0 if shifts is None else float(shifts[k])
        goal = np.asarray(cmd.angles_rad(settings.lower_rad, settings.upper_rad))
        i0 = int(np.searchsorted(t, tc - s - TIME_SLACK_S))
        i1 = int(np.searchsorted(t, times[k + 1] - s - TIME_SLACK_S))
        close = np.all(np.abs(q[i0:i1] - goal) <= ARRIVAL_TOLERANCE_RAD, axis=1)
        if not close.any():
            out.append((None, 0.0))
            continue
        i = i0 + int(np.argmax(close))
        out.append((float(t[i]) + s, float(t[i] - t[i - 1]) if i > 0 else 0.0))
    return out


def _settled(arm: Track, twin: Track, times: Sequence[float], shifts: FloatArray
             ) -> FloatArray:
    """Per command after which both came to rest (the arm's last three replies before the next
    command equal within 1.5 ticks, the twin still over the same aligned instants), arm minus
    twin (rad) at the last of them: where the move settled (``(m, 4)``)."""
    ends = [*times[1:], math.inf]
    rows = []
    for k, (t0, t1) in enumerate(zip(times, ends, strict=True)):
        i = int(np.searchsorted(arm.t_s, t1 - TIME_SLACK_S)) - 1
        if i < 2 or arm.t_s[i - 2] < t0:
            continue
        if np.any(np.abs(np.diff(arm.q_rad[i - 2:i + 1], axis=0)) > 1.5 * TICK_RAD):
            continue
        at = arm.t_s[i - 2:i + 1, None] - shifts[k][None, :]
        twin_q = np.column_stack([twin.at(at[:, j])[:, j] for j in range(4)])
        if np.any(np.abs(np.diff(twin_q, axis=0)) > 1.5 * TICK_RAD):
            continue
        rows.append(arm.q_rad[i] - twin_q[-1])
    return np.asarray(rows).reshape(-1, 4)


@dataclass(frozen=True, slots=True)
class ReplayFloor:
    """How far the twin diverges from itself replayed with each command moved by a draw of the
    arm's reaction scatter (the measured start shifts about their joint's median), compared as
    the arm is: per joint RMS (rad), the arrival times' RMS difference (s), the TCP's RMS
    distance (mm; None without truth)."""

    rad: FloatArray
    dt_s: float
    tcp_mm: float | None = None
    #: The compared times (s) and the squared divergence there (``(m, 4)``, rad²): a part of
    #: the capture takes its mean over its span.
    per_reply: tuple[FloatArray, FloatArray] | None = None


def _shift_at(times: Sequence[float], per_command: Sequence[float] | FloatArray) -> Any:
    """The start shift (s) in force at each of the times ``t`` (the newest command's)."""
    ct = np.asarray(times)
    shifts = np.asarray(per_command, dtype=np.float64)

    def at(t: FloatArray) -> FloatArray:
        k = np.clip(np.searchsorted(ct, t + TIME_SLACK_S, side="right") - 1, 0, len(ct) - 1)
        return np.asarray(shifts[k], dtype=np.float64)
    return at


def replay_floor(data: CaptureData, twin: Sequence[tuple[float, Vec4]],
                 perturbed: Sequence[tuple[float, Vec4]], settings: RobotSettings,
                 truth: tuple[TwinTruth, TwinTruth, Sequence[float]] | None = None
                 ) -> ReplayFloor:
    """The :class:`ReplayFloor` of the twin's replay ``twin`` against its perturbed replay,
    read at the capture's (timed) reply times; with ``truth`` (the two replays' truths and the
    arm's truth times) the TCP's too."""
    reference, base = Track.of(perturbed), Track.of(twin)
    times = [c[0] for c in data.commands]
    measured = move_shifts(reference, base, data.commands, settings)
    shifts = measured.per_joint_s
    kept = Track.of(timed(data.replies))
    t = kept.t_s[~read_late(kept, times)]
    t = t[(t >= times[0]) & (t >= base.t_s[0])]
    q_base, _, blind = read_aligned(t, times, base, shifts)
    seen = ~(blind | reference.blind(t, SEEN_LATE))
    diff = (reference.at(t) - q_base)[seen]
    per_command = command_shifts(shifts, data.commands, reference, settings)
    a = _arrivals(perturbed, data, settings)
    b = _arrivals(twin, data, settings, per_command)
    dts = np.asarray([y - x for (x, _), (y, _) in zip(a, b, strict=True)
                      if x is not None and y is not None])
    tcp_mm = None
    if truth is not None and len(truth[1].t_s) > 1:
        moved = Track(np.asarray(truth[1].t_s), np.column_stack(
            [np.asarray(truth[1].tcp_m), np.zeros(len(truth[1].t_s))]))
        at = np.asarray(truth[2], dtype=np.float64)
        samples = [(float(x), tuple(p[:3])) for x, p in zip(at, moved.at(at), strict=True)]
        tcp = tcp_divergence(samples, truth[0], _shift_at(times, per_command), 0.0)
        tcp_mm = None if tcp is None else tcp["rms_mm"]
    return ReplayFloor(np.sqrt(np.mean(diff * diff, axis=0)),
                       float(np.sqrt(np.mean(dts * dts))) if len(dts) else 0.0, tcp_mm,
                       (t[seen], diff * diff))


def compare(data: CaptureData, twin: Sequence[tuple[float, Vec4]], settings: RobotSettings,
            limits: LimitsConfig | None, allowance: Allowance | None = None,
            floor_by_replay: ReplayFloor | None = None) -> TwinCheck:
    """Compare the capture's replies with the twin's (see the module doc). The floor's
    reaction part is ``floor_by_replay`` where given (what :func:`twin_check` passes), else the
    reaction scatter times the twin's speed."""
    allow = allowance or Allowance()
    div = diverge(data, twin, settings)
    data, whole, twin_track, times = div.data, div.whole, div.twin, div.times
    shifts = div.shifts.per_joint_s
    counts = div.counts_per_rad
    arm = Track(div.t_s, div.arm_rad)
    aligned = Aligned(div.t_s, div.arm_rad, div.twin_rad, counts)
    diff = div.diff_rad
    rms = div.rms_rad()
    peak = np.max(np.abs(diff), axis=0) if len(diff) else np.zeros(4)
    floor2 = div.floor2_rad2(reaction=floor_by_replay is None)
    floor = np.sqrt(np.mean(floor2, axis=0) + (
        0.0 if floor_by_replay is None else floor_by_replay.rad ** 2))
    allowed = allow.floor_factor * floor * counts + allow.abs_counts
    parts = part_figures(div.t_s, diff, floor2, counts, (allow.part_factor, allow.abs_counts),
                         times,
                         None if floor_by_replay is None else floor_by_replay.per_reply)
    per_command = command_shifts(shifts, data.commands, whole, settings)
    settled = _settled(arm, twin_track, times, shifts)
    settled_rms = np.sqrt(np.mean(settled * settled, axis=0)) if len(settled) else np.zeros(4)
    # where moves settled no timing enters: the floor there is the quantisation alone
    settled_allowed = allow.floor_factor * div.floor_rad(rows=np.zeros(len(div.t_s), bool)) \
        * counts + allow.abs_counts
    arm_arrivals = _arrivals(data.replies, data, settings)
    twin_arrivals = [a for a, _ in _arrivals(twin, data, settings, per_command)]
    pairs = [(a, b) for (a, _), b in zip(arm_arrivals, twin_arrivals, strict=True)]
    # an arrival seen only after a gap in the arm's replies (a host stall) is not timed
    seen_late = SEEN_LATE * float(np.median(np.diff(whole.t_s))) if len(whole.t_s) > 1 else 0.0
    dts = [b - a for (a, gap), b in zip(arm_arrivals, twin_arrivals, strict=True)
           if a is not None and b is not None and gap <= seen_late]
    arm_only = sum(a is not None and b is None for a, b in pairs)
    twin_only = sum(a is None and b is not None for a, b in pairs)
    if floor_by_replay is None:
        dt_floor = interval_floor_s(whole, twin_track, div.scatter_s, div.reaction_s)
    else:
        dt_floor = math.hypot(interval_floor_s(whole, twin_track, div.scatter_s, 0.0),
                              floor_by_replay.dt_s)
    n = TWIN_CHECK
    measurements = joint_measurements(rms, peak, counts, floor, allowed, settled_rms,
                                      settled_allowed if len(settled) else None, limits)
    measurements += part_measurements(parts, limits)
    measurements += arrival_measurements(dts, dt_floor, allow, limits)
    for figure, value, unit, what in (
            (n.scatter, div.scatter_s, "s", "timing scatter of the link, from the arm's replies"),
            (n.reaction, div.reaction_s, "s",
             "scatter of the arm's reaction to commands, from the start shifts"),
            (n.shift_mean, float(np.mean(per_command)), "s", "mean start shift, arm - twin"),
            (n.shift_max, float(np.max(np.abs(shifts))), "s", "largest |start shift|"),
            (n.moves, len(data.commands), "", "commands replayed"),
            (n.compared, len(dts), "", "moves both streams arrived at"),
            (n.arm_only, arm_only, "", "moves only the arm arrived at"),
            (n.twin_only, twin_only, "", "moves only the twin arrived at"),
            (n.replies, len(div.t_s), "", "replies of the capture compared"),
            (n.untimed, div.untimed, "", "replies left out: read in a burst or late (a host "
                                         "stall)")):
        m = judge(n.metric(figure), float(value), unit, limits, description=what)
        measurements.append(replace(m, better=None) if figure == n.shift_mean else m)
    return TwinCheck(
        [float(v) for v in rms], [float(v) for v in peak], [float(v) for v in rms * counts],
        [float(v) for v in peak * counts], dts, len(data.commands), arm_only, twin_only,
        len(div.t_s), measurements, verdict_of(measurements), list(twin), series=aligned,
        arrivals=[(c[0], a, b) for c, (a, b) in zip(data.commands, pairs, strict=True)],
        floor_counts=[float(v) for v in floor * counts],
        allowed_counts=[float(v) for v in allowed],
        settled_counts=[float(v) for v in settled_rms * counts], scatter_s=div.scatter_s,
        reaction_scatter_s=div.reaction_s,
        shifts_s=[float(v) for v in per_command], joint_shifts_s=shifts,
        shift_deviations_s=div.shifts.deviations_s(), arm_lag_s=div.shifts.arm_lag_s,
        parts=parts, speed_rad_s=div.speed_rad_s)


def _mean_floor(floors: Sequence[ReplayFloor]) -> ReplayFloor:
    """The RMS over several replays' floors."""
    tcp = [f.tcp_mm for f in floors if f.tcp_mm is not None]
    rows = [f.per_reply for f in floors if f.per_reply is not None]
    per_reply = None if not rows else (np.concatenate([r[0] for r in rows]),
                                       np.concatenate([r[1] for r in rows]))
    return ReplayFloor(
        np.sqrt(np.mean([f.rad ** 2 for f in floors], axis=0)),
        math.sqrt(sum(f.dt_s ** 2 for f in floors) / len(floors)),
        math.sqrt(sum(v ** 2 for v in tcp) / len(tcp)) if tcp else None, per_reply)


def _reaction_draws(result: TwinCheck, n: int, rng: np.random.Generator) -> FloatArray:
    """Per command, ± the RMS (s) of the start shifts' deviations from their joint's median
    (within ±:data:`MAX_REACTION_S`; without three, the reply timing scatter), seeded signs: a
    draw's mean square, without the floor hanging on which moves drew the largest deviations."""
    if len(result.shift_deviations_s) >= 3:
        pool = np.clip(result.shift_deviations_s, -MAX_REACTION_S, MAX_REACTION_S)
        size = math.sqrt(float(np.mean(pool * pool)))
    else:
        size = result.scatter_s
    return size * rng.choice(np.array([-1.0, 1.0]), size=n)


def _where(diagnoses: Sequence[Diagnosis | None], result: TwinCheck, data: CaptureData,
           session_starts_s: Sequence[float], settings: RobotSettings, allow: Allowance
           ) -> list[Diagnosis | None]:
    """Each diagnosis with where its joint's divergence grows and its worst part
    (:mod:`armbench.bench.twin_check.where`, :mod:`armbench.bench.twin_check.parts`)."""
    series = result.series
    assert series is not None and result.speed_rad_s is not None
    factors = factors_of(series.t_s, series.arm_rad, result.speed_rad_s, series.counts_per_rad,
                         data.commands, session_starts_s, settings, TICK_RAD)
    residual = -series.divergence_counts            # twin - arm
    out: list[Diagnosis | None] = []
    for j, d in enumerate(diagnoses):
        if d is None:
            out.append(None)
            continue
        worst = max(result.parts, key=lambda p: p.per_allowed(j), default=None)
        out.append(replace(d, grows=tuple(growth(series.t_s, residual[:, j], factors[j],
                                                 allow.abs_counts)),
                           worst_part=None if worst is None else (
                               worst.start_s, worst.end_s, worst.per_allowed(j))))
    return out


def twin_check(data: CaptureData, settings: RobotSettings,
               config: str | Path | None = None,
               arm_tcp: Sequence[tuple[float, Sequence[float]]] | None = None) -> TwinCheck:
    """Replay each session on a virtual-time loop and compare (see the module doc; commands
    stamped late, :func:`armbench.bench.calibrate.align.stamped_late_s`, when the arm got them);
    then again with each command moved by a draw of the arm's reaction scatter, for the floor
    (:func:`replay_floor`). ``arm_tcp``: the arm's true TCP (capture clock s, m) from a
    reference instrument; without it, the truth joints of an MCAP capture, if any."""
    limits = load_limits(config if config is not None else DEFAULT_CONFIG)
    allow = Allowance.of(limits.suite_params(TWIN_CHECK.suite))
    parts = sessions(data, settings)
    truth_tcp = list(arm_tcp) if arm_tcp is not None else arm_tcp_from_capture(data.path, settings)
    # the twin's truth only where the arm's is: reading it syncs the joint boards, which a
    # replay without it does not do (the replies stay bit-identical)
    twin_truth = TwinTruth() if truth_tcp else None
    merged = CaptureData(data.path, [c for p in parts for c in p.data.commands],
                         [r for p in parts for r in p.data.replies], data.bad_in_frames)

    # the twin's counters as a new arm's or as its Hall sensors set them (they differ after the
    # twin passes a Hall sensor whose position error its settings give): joint by joint, the
    # closer replay; replayed once more when the joints choose differently
    tried = {}
    for ran in (False, True):
        truth = TwinTruth() if truth_tcp else None
        twin = replay_sessions(parts, settings, None, truth, ran)
        tried[ran] = (compare(merged, twin, settings, limits, allow), twin, truth)
    hall = closer_counters(tried[False][0].rms_counts, tried[True][0].rms_counts)
    if len(set(hall)) == 1:
        first, twin, twin_truth = tried[hall[0]]
    else:
        twin_truth = TwinTruth() if truth_tcp else None
        twin = replay_sessions(parts, settings, None, twin_truth, hall)
        first = compare(merged, twin, settings, limits, allow)
    # commands the host stamped late are replayed when the arm got them
    late = stamped_late_s(first.arm_lag_s, [c[0] for c in merged.commands], MAX_REACTION_S)
    if late is not None:
        twin_truth = TwinTruth() if truth_tcp else None
        twin = replay_sessions(parts, settings, late, twin_truth, hall)
        first = compare(merged, twin, settings, limits, allow)
    base = np.zeros(len(merged.commands)) if late is None else late
    floors = []
    rng = np.random.default_rng(REACTION_SEED)
    for _ in range(REACTION_REPLAYS):
        draws = base + _reaction_draws(first, len(merged.commands), rng)
        moved_truth = TwinTruth() if truth_tcp else None
        moved = replay_sessions(parts, settings, draws, moved_truth, hall)
        truths = None if twin_truth is None or moved_truth is None else (
            twin_truth, moved_truth, [t for t, _ in truth_tcp])
        floors.append(replay_floor(merged, twin, moved, settings, truths))
    floor = _mean_floor(floors)
    result = compare(merged, twin, settings, limits, allow, floor)
    shift_at = _shift_at([c[0] for c in merged.commands], result.shifts_s)
    tcp = None if twin_truth is None else tcp_divergence(truth_tcp, twin_truth, shift_at,
                                                         result.scatter_s)
    if tcp is not None and floor.tcp_mm is not None:
        tcp["floor_mm"] = math.hypot(tcp["floor_mm"], floor.tcp_mm)
    count = judge(TWIN_CHECK.metric(TWIN_CHECK.sessions), float(len(parts)), "", limits,
                  description="sessions replayed, each into a fresh twin")
    measurements = [*result.measurements, count, *tcp_measurements(tcp, allow, limits)]
    series = result.series
    failing = failing_joints(measurements)
    diagnoses = result.diagnoses if series is None else diagnose_joints(
        series.t_s, series.arm_rad, series.twin_rad, series.counts_per_rad,
        [c[0] for c in merged.commands], TICK_RAD, failing)
    if series is not None and result.speed_rad_s is not None and failing:
        diagnoses = _where(diagnoses, result, merged, [p.data.replies[0][0] for p in parts],
                           settings, allow)
    return replace(result, tcp=tcp, sessions=len(parts), measurements=measurements,
                   verdict=verdict_of(measurements), hall_counters=hall, diagnoses=diagnoses)
