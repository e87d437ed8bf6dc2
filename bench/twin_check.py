"""``armbench twin-check``: how well the twin predicts an arm, measured on the arm's own traffic,
and judged against what a perfect twin would score on the same capture.

The commands of a capture are replayed, at their recorded times, into the emulator built from the
given settings (the twin), on virtual time, starting from the capture's first reported pose (the
twin's replies count from its first one at that pose: what it reports while still booting is not
the model's). The two reply streams are then compared timing-robustly
(:mod:`armbench.bench.twin_align`): the twin's stream read as a trajectory at the arm's reply
times, each move from rest aligned at its start:

* per joint, the RMS and largest divergence of the reported angle (rad and encoder counts), and
  the RMS difference of where each move settled (the last reply before the next command);
* per move, the difference of the arrival times (twin − arm, after the start alignment) where
  both arrive;
* the TCP divergence where the capture has the truth: the arm's true TCP (a tracker's, or the
  truth joints of an MCAP capture of ``fake://`` through the twin's actual model: joint truth
  says nothing of link lengths) against the twin's true TCP at the same instants.

Each comparison has a floor computed from the capture (the link's timing scatter times the
twin's speed, the angle's quantisation; :func:`armbench.bench.twin_align.floor_rad`): what a
perfect twin would score. The verdict allows ``k × floor + abs`` (per joint in counts, for the
arrivals in s, for the TCP in mm; ``k`` and ``abs`` in the config's ``[suites."twin-check"]``
table, else :class:`Allowance`'s defaults): each ``*.rms_per_allowed`` figure is the RMS over
its allowance, judged against the limits of a bench config (``--config``, else the packaged
``twin_check.toml``, ``high = 1``). The verdict is ``pass`` when every judged figure is within,
else ``fail``. :mod:`armbench.bench.twin_record` writes a check as a run record.

A capture of several sessions (a run's capture holds one emulator per trial, a foreign arm
restarts at each connection) is cut where the replies jump further than the joints can move, or
fall silent; each session is replayed into a fresh twin from its own first pose, with the command
that was in flight at the cut written first.
"""

from __future__ import annotations

import asyncio
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from armbench.bench.calibrate.capture import CaptureData
from armbench.bench.limits import LimitsConfig, load_limits
from armbench.bench.record import Measurement, judge
from armbench.bench.suites.contract import TWIN_CHECK
from armbench.bench.twin_align import (
    TICK_RAD,
    Track,
    command_shifts,
    floor_rad,
    interval_floor_s,
    move_shifts,
    timing_scatter_s,
)
from armbench.drivers.capture_read import read_joint_states
from armbench.drivers.kinematics import tcp_position
from armbench.drivers.motion import joint_speed_rad_s
from armbench.drivers.protocol import MAX_DUTY, AngleDecoder, Command, Framer, Reply
from armbench.drivers.settings import RobotSettings, SettingsError
from armbench.fakes.arm import ArmEmulator
from armbench.fakes.settings import actual_robot, emulator_settings

__all__ = ["DEFAULT_CONFIG", "Aligned", "Allowance", "Session", "TwinCheck", "compare",
           "replay_twin", "sessions", "tcp_divergence", "twin_check"]

DEFAULT_CONFIG: Final = Path(__file__).resolve().with_name("twin_check.toml")
#: A move counts as arrived when every joint is this close to its target (rad): the driver's
#: default arrival tolerance.
ARRIVAL_TOLERANCE_RAD: Final = 3e-4
#: A reply further than this (rad) beyond what full speed allows since the previous one starts a
#: new session (the capture of another emulator, or an arm moved by hand while off).
JUMP_SLACK_RAD: Final = 0.005
#: Longest stall of the master's loop between two replies (s): the EEPROM records of four joints
#: changing state at once (4 × 5 bytes × 3.3 ms); a reply may show that much more motion.
STALL_S: Final = 0.07
#: A silence longer than this (s) starts a new session: a power cut, a new emulator (its boot
#: takes 0.1 s); longer than any stall of the loop.
SILENCE_S: Final = 0.09
#: Times closer than this (s) count as the same instant: a capture stores them to the nanosecond.
TIME_SLACK_S: Final = 1e-6
#: A reply followed by another within this (s) was read in one go with it: after a stall of the
#: host (a loaded machine), its stamp is when the host woke, not when it came. Such replies are
#: left out of the comparison, and the silence before them does not cut the capture.
BURST_S: Final = 2e-4
#: An arrival seen after a gap of more than this many median reply intervals is not compared.
SEEN_LATE: Final = 5.0
#: The twin has booted when it reports the session's first pose within this many ticks on every
#: joint (its first replies, before the joint boards answer, report them at 0).
BOOT_TICKS: Final = 3.0
#: Longest wait for the twin to report that pose (s, virtual).
BOOT_TIMEOUT_S: Final = 2.0

Vec4 = tuple[float, float, float, float]
Vec3 = tuple[float, float, float]
FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Allowance:
    """How far above its floor a twin may score: ``k × floor + abs`` per joint (counts), for the
    arrival times (s) and the TCP (mm). Read from the config's ``[suites."twin-check"]``."""

    floor_factor: float = 3.0
    abs_counts: float = 2.0
    arrival_factor: float = 3.0
    arrival_abs_s: float = 0.01
    tcp_factor: float = 3.0
    tcp_abs_mm: float = 1.5

    @classmethod
    def of(cls, table: Mapping[str, Any]) -> Allowance:
        """From a config table; unknown keys and values that are not numbers >= 0 raise
        :class:`SettingsError` naming the key."""
        known = {f.name for f in fields(cls)}
        out: dict[str, float] = {}
        for key, value in table.items():
            where = f'suites."twin-check".{key}'
            if key not in known:
                raise SettingsError(where, value, "is not a known setting")
            if isinstance(value, bool) or not isinstance(value, int | float) or not (
                    math.isfinite(value) and value >= 0):
                raise SettingsError(where, value, "is not a number >= 0")
            out[key] = float(value)
        return cls(**out)


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
class Session:
    """A stretch of a capture recorded from one arm without a break, and the command that was in
    flight when it began (None for the first)."""

    data: CaptureData
    in_flight: Command | None = None


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
    series: Aligned | None = None
    arrivals: list[tuple[float, float | None, float | None]] = field(default_factory=list)
    floor_counts: list[float] = field(default_factory=list)
    allowed_counts: list[float] = field(default_factory=list)
    settled_counts: list[float] = field(default_factory=list)
    scatter_s: float = 0.0
    reaction_scatter_s: float = 0.0
    shifts_s: list[float] = field(default_factory=list)
    joint_shifts_s: FloatArray | None = None

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
            "sessions": self.sessions,
            "measurements": [{"name": m.name, "value": m.value, "unit": m.unit,
                              "limit": m.limit.describe() if m.limit else None,
                              "outcome": m.outcome} for m in self.measurements],
            "verdict": self.verdict,
        }


@dataclass(frozen=True, slots=True)
class TwinTruth:
    """The twin's truth at each of its replies: times (capture clock), true joint angles (rad)
    and true TCP (m, through its actual model)."""

    t_s: list[float] = field(default_factory=list)
    q_rad: list[Vec4] = field(default_factory=list)
    tcp_m: list[Vec3] = field(default_factory=list)


async def replay_twin(data: CaptureData, settings: RobotSettings,
                      truth: TwinTruth | None = None,
                      in_flight: Command | None = None) -> list[tuple[float, Vec4]]:
    """Replay ``data``'s commands into a twin built from ``settings`` on the running loop; the
    twin's replies from the first one at the session's first pose, on the capture's clock (that
    reply aligned with the capture's first). ``in_flight`` is written first, at once. With
    ``truth`` given, the twin's truth at each of its replies is appended to it."""
    loop = asyncio.get_running_loop()
    q0 = data.replies[0][1]
    emulator = ArmEmulator(settings, emulator_settings(settings), initial_q_rad=q0)
    framer = Framer("reply")
    decode = AngleDecoder(settings.lower_rad, settings.upper_rad)
    out: list[tuple[float, Vec4]] = []
    booted = False
    near = BOOT_TICKS * TICK_RAD

    def sink(chunk: bytes) -> None:
        nonlocal booted
        now = loop.time()
        for event in framer.feed(chunk):
            if not isinstance(event, Reply):
                continue
            q = decode(event)
            booted = booted or all(abs(a - b) <= near for a, b in zip(q, q0, strict=True))
            if not booted:
                continue
            out.append((now, q))
            if truth is not None:
                a = emulator.true_angles_rad()
                truth.t_s.append(now)
                truth.q_rad.append((a[0], a[1], a[2], a[3]))
                truth.tcp_m.append(emulator.true_position_m())

    emulator.attach_host(sink)
    await emulator.start()
    try:
        give_up = loop.time() + BOOT_TIMEOUT_S
        while not out:
            if loop.time() > give_up:
                raise RuntimeError("the twin never reported the session's first pose")
            await asyncio.sleep(0.001)
        offset = out[0][0] - data.replies[0][0]
        if in_flight is not None:
            emulator.host_write(in_flight.encode())
        for t_s, command in data.commands:
            delay = t_s + offset - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            emulator.host_write(command.encode())
        end = data.replies[-1][0] + offset
        await asyncio.sleep(max(0.0, end - loop.time()) + 0.01)
    finally:
        await emulator.close()
    if truth is not None:
        n = len(truth.t_s) - len(out)
        truth.t_s[n:] = [t - offset for t in truth.t_s[n:]]
    return [(t - offset, q) for t, q in out]


def tcp_divergence(arm_tcp: Sequence[tuple[float, Sequence[float]]], twin: TwinTruth,
                   shift_at: Any, scatter_s: float) -> dict[str, float] | None:
    """RMS and largest distance (mm) between the arm's true TCP (m, at its truth times) and the
    twin's true TCP at the aligned instants (its truth read as a trajectory), and the floor
    (mm): the timing scatter (``scatter_s``: replies and reactions) times the TCP's speed. None
    without truth on both sides, or none inside the twin's replay."""
    if not arm_tcp or len(twin.t_s) < 2:
        return None
    track = Track(np.asarray(twin.t_s), np.column_stack([np.asarray(twin.tcp_m),
                                                         np.zeros(len(twin.t_s))]))
    rows = [(t, p) for t, p in arm_tcp if track.t_s[0] <= t <= track.t_s[-1]]
    if not rows:
        return None
    t = np.asarray([r[0] for r in rows])
    at = t - shift_at(t)
    twin_p = track.at(at)[:, :3]
    d_mm = 1e3 * np.linalg.norm(np.asarray([r[1] for r in rows]) - twin_p, axis=1)
    v = track.speed_at(at)[:, :3]
    floor_mm = 1e3 * math.sqrt(scatter_s ** 2 * float(np.mean(np.sum(v * v, axis=1))))
    return {"rms_mm": float(np.sqrt(np.mean(d_mm * d_mm))), "max_mm": float(d_mm.max()),
            "floor_mm": floor_mm, "samples": float(len(rows))}


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
    """Per command after which the arm came to rest (its last two replies before the next
    command equal within a tick), arm minus twin (rad) at the last of them: where the move
    settled (``(m, 4)``)."""
    ends = [*times[1:], math.inf]
    rows = []
    for k, (t0, t1) in enumerate(zip(times, ends, strict=True)):
        i = int(np.searchsorted(arm.t_s, t1 - TIME_SLACK_S)) - 1
        if i >= 1 and arm.t_s[i - 1] >= t0 and np.all(
                np.abs(arm.q_rad[i] - arm.q_rad[i - 1]) <= TICK_RAD * 1.5):
            twin_q = [twin.at(np.asarray([arm.t_s[i] - shifts[k, j]]))[0, j] for j in range(4)]
            rows.append(arm.q_rad[i] - np.asarray(twin_q))
    return np.asarray(rows).reshape(-1, 4)


def _timed(replies: Sequence[tuple[float, Vec4]]) -> list[tuple[float, Vec4]]:
    """The replies whose stamp is their time: not read in one go with the next one."""
    t = np.asarray([r[0] for r in replies])
    keep = np.append(np.diff(t) >= BURST_S, True)
    return [r for r, k in zip(replies, keep, strict=True) if k]


def compare(data: CaptureData, twin: Sequence[tuple[float, Vec4]], settings: RobotSettings,
            limits: LimitsConfig | None, allowance: Allowance | None = None) -> TwinCheck:
    """Compare the capture's replies with the twin's (see the module doc)."""
    allow = allowance or Allowance()
    twin_track = Track.of(twin)
    timed = _timed(data.replies)
    untimed = len(data.replies) - len(timed)
    data = CaptureData(data.path, data.commands, timed, data.bad_in_frames)
    whole = Track.of(data.replies)
    times = [c[0] for c in data.commands]
    measured = move_shifts(whole, twin_track, data.commands, settings)
    shifts = measured.per_joint_s
    start = times[0]
    rows = [(t, q) for t, q in data.replies if t >= start and t >= twin_track.t_s[0]]
    arm = Track.of(rows)
    k_of = np.clip(np.searchsorted(np.asarray(times), arm.t_s + TIME_SLACK_S, side="right") - 1,
                   0, len(times) - 1)
    at = arm.t_s[:, None] - shifts[k_of]            # per reply and joint, on the twin's clock
    q_twin = np.column_stack([twin_track.at(at[:, j])[:, j] for j in range(4)])
    speed = np.column_stack([twin_track.speed_at(at[:, j])[:, j] for j in range(4)])
    counts = np.asarray([j.counts_per_rad for j in settings.joints])
    aligned = Aligned(arm.t_s, arm.q_rad, q_twin, counts)
    diff = arm.q_rad - q_twin
    rms = np.sqrt(np.mean(diff * diff, axis=0))
    peak = np.max(np.abs(diff), axis=0)
    scatter = timing_scatter_s(whole, times)
    reaction = measured.scatter_s()
    command_scatter = scatter if reaction is None else max(scatter, reaction)
    floor = floor_rad(speed, scatter, command_scatter, counts)
    allowed = allow.floor_factor * floor * counts + allow.abs_counts
    per_command = command_shifts(shifts, data.commands, whole, settings)
    settled = _settled(arm, twin_track, times, shifts)
    settled_rms = np.sqrt(np.mean(settled * settled, axis=0)) if len(settled) else np.zeros(4)
    arm_arrivals = _arrivals(data.replies, data, settings)
    twin_arrivals = [a for a, _ in _arrivals(twin, data, settings, per_command)]
    pairs = [(a, b) for (a, _), b in zip(arm_arrivals, twin_arrivals, strict=True)]
    # an arrival seen only after a gap in the arm's replies (a host stall) is not timed
    seen_late = SEEN_LATE * float(np.median(np.diff(whole.t_s))) if len(whole.t_s) > 1 else 0.0
    dts = [b - a for (a, gap), b in zip(arm_arrivals, twin_arrivals, strict=True)
           if a is not None and b is not None and gap <= seen_late]
    arm_only = sum(a is not None and b is None for a, b in pairs)
    twin_only = sum(a is None and b is not None for a, b in pairs)
    dt_floor = interval_floor_s(whole, twin_track, scatter, command_scatter)
    n = TWIN_CHECK
    measurements = _joint_measurements(rms, peak, counts, floor, allowed, settled_rms, limits)
    measurements += _arrival_measurements(dts, dt_floor, allow, limits)
    for figure, value, unit, what in (
            (n.scatter, scatter, "s", "timing scatter of the link, from the arm's replies"),
            (n.reaction, command_scatter, "s",
             "scatter of the arm's reaction to commands, from the start shifts"),
            (n.shift_mean, float(np.mean(per_command)), "s", "mean start shift, arm - twin"),
            (n.shift_max, float(np.max(np.abs(shifts))), "s", "largest |start shift|"),
            (n.moves, len(data.commands), "", "commands replayed"),
            (n.compared, len(dts), "", "moves both streams arrived at"),
            (n.arm_only, arm_only, "", "moves only the arm arrived at"),
            (n.twin_only, twin_only, "", "moves only the twin arrived at"),
            (n.replies, len(rows), "", "replies of the capture compared"),
            (n.untimed, untimed, "", "replies left out: read in a burst after a host stall")):
        m = judge(n.metric(figure), float(value), unit, limits, description=what)
        measurements.append(replace(m, better=None) if figure == n.shift_mean else m)
    return TwinCheck(
        [float(v) for v in rms], [float(v) for v in peak], [float(v) for v in rms * counts],
        [float(v) for v in peak * counts], dts, len(data.commands), arm_only, twin_only,
        len(rows), measurements, _verdict(measurements), list(twin), series=aligned,
        arrivals=[(c[0], a, b) for c, (a, b) in zip(data.commands, pairs, strict=True)],
        floor_counts=[float(v) for v in floor * counts],
        allowed_counts=[float(v) for v in allowed],
        settled_counts=[float(v) for v in settled_rms * counts], scatter_s=scatter,
        reaction_scatter_s=command_scatter,
        shifts_s=[float(v) for v in per_command], joint_shifts_s=shifts)


def _verdict(measurements: Sequence[Measurement]) -> str:
    """``fail`` when a figure is outside its limit, else ``pass``."""
    return "fail" if any(m.outcome == "fail" for m in measurements) else "pass"


def _joint_measurements(rms: FloatArray, peak: FloatArray, counts: FloatArray,
                        floor: FloatArray, allowed: FloatArray, settled: FloatArray,
                        limits: LimitsConfig | None) -> list[Measurement]:
    """Per joint: the RMS and largest divergence (counts, rad), the floor and the allowance
    (counts), the RMS over its allowance (the judged figure), where moves settled (counts)."""
    n = TWIN_CHECK
    out = []
    for j in range(4):
        for figure, value, unit, what in (
                (n.rms_counts, rms[j] * counts[j], "counts", "RMS divergence"),
                (n.max_counts, peak[j] * counts[j], "counts", "largest divergence"),
                (n.rms_rad, rms[j], "rad", "RMS divergence"),
                (n.max_rad, peak[j], "rad", "largest divergence"),
                (n.floor_counts, floor[j] * counts[j], "counts", "floor (a perfect twin's RMS)"),
                (n.allowed_counts, allowed[j], "counts", "allowed RMS: k x floor + abs"),
                (n.per_allowed, rms[j] * counts[j] / allowed[j], "", "RMS over allowed RMS"),
                (n.settled_counts, settled[j] * counts[j], "counts",
                 "RMS divergence where the moves settled")):
            out.append(judge(n.joint_metric(j + 1, figure), float(value), unit, limits,
                             better="lower", description=f"{what} of the reported angle"))
    return out


def _arrival_measurements(dts: Sequence[float], floor_s: float, allow: Allowance,
                          limits: LimitsConfig | None) -> list[Measurement]:
    """The arrival-time differences: mean, largest, RMS, its floor and RMS over allowance."""
    if not dts:
        return []
    n = TWIN_CHECK
    dt = np.asarray(dts)
    rms = float(np.sqrt(np.mean(dt * dt)))
    allowed = allow.arrival_factor * floor_s + allow.arrival_abs_s
    return [
        replace(judge(n.metric(n.mean_dt), float(dt.mean()), "s", limits,
                      description="mean arrival-time difference, twin - arm"), better=None),
        judge(n.metric(n.max_abs_dt), float(np.abs(dt).max()), "s", limits,
              description="largest arrival-time difference, |twin - arm|"),
        judge(n.metric(n.rms_dt), rms, "s", limits, better="lower",
              description="RMS arrival-time difference"),
        judge(n.metric(n.floor_dt), floor_s, "s", limits,
              description="floor of the arrival-time difference (a perfect twin's RMS)"),
        judge(n.metric(n.arrival_per_allowed), rms / allowed, "", limits, better="lower",
              description="RMS arrival-time difference over its allowance"),
    ]


def sessions(data: CaptureData, settings: RobotSettings) -> list[Session]:
    """The capture cut where the arm it recorded was another one: a reply that jumps further
    than the joints can move at full speed in the time since the previous one (and a stall of the
    loop), or a silence longer than :data:`SILENCE_S` (a run's capture holds one emulator per
    trial, each booting at its own pose) that does not end in a burst (:data:`BURST_S`: then the
    host was silent, not the arm). Each session after the first carries the command in
    flight at its start; sessions without commands are left out."""
    t = np.asarray([r[0] for r in data.replies])
    q = np.asarray([r[1] for r in data.replies])
    if len(t) < 2:
        return [Session(data)]
    dt = np.diff(t)
    speed = np.asarray([joint_speed_rad_s(MAX_DUTY, j.steps_per_rad) for j in settings.joints])
    reach = 1.5 * speed * (dt[:, None] + STALL_S) + JUMP_SLACK_RAD
    jump = np.abs(np.diff(q, axis=0)) > reach
    burst = np.append(dt < BURST_S, False)          # per reply: read together with the next
    silent = (dt > SILENCE_S) & ~burst[1:]
    cuts = [0, *(np.flatnonzero(jump.any(axis=1) | silent) + 1), len(t)]
    out = []
    for a, b in itertools.pairwise(cuts):
        t0, t1 = t[a], (t[b] if b < len(t) else math.inf)
        commands = [c for c in data.commands if t0 <= c[0] < t1]
        before = [c for c in data.commands if c[0] < t0]
        # a silence is the same arm resuming; a jump is another one, which got no command yet
        resumed = a > 0 and not jump[a - 1].any()
        in_flight = before[-1][1] if before and resumed else None
        if commands:
            out.append(Session(CaptureData(data.path, commands, data.replies[a:b], 0),
                               in_flight))
    return out


def _judge_tcp(tcp: dict[str, float] | None, allow: Allowance,
               limits: LimitsConfig) -> list[Measurement]:
    """The TCP divergence as measurements, where the capture had truth."""
    if not tcp:
        return []
    n = TWIN_CHECK
    allowed = allow.tcp_factor * tcp["floor_mm"] + allow.tcp_abs_mm
    out = [judge(n.metric(name), tcp[key], "mm", limits, better="lower",
                 description=f"{what} of the TCP, arm against twin")
           for name, key, what in ((n.tcp_rms, "rms_mm", "RMS divergence"),
                                   (n.tcp_max, "max_mm", "largest divergence"),
                                   (n.tcp_floor, "floor_mm", "floor of the RMS divergence"))]
    out.append(judge(n.metric(n.tcp_per_allowed), tcp["rms_mm"] / allowed, "", limits,
                     better="lower", description="RMS TCP divergence over its allowance"))
    out.append(judge(n.metric(n.tcp_samples), tcp["samples"], "", limits,
                     description="truth samples compared"))
    return out


def _arm_tcp(path: str, settings: RobotSettings) -> list[tuple[float, Vec3]]:
    """The arm's true TCP from an MCAP capture's truth joints, through the twin's actual
    model (the capture does not hold the arm's)."""
    truth = read_joint_states(path)
    if not truth:
        return []
    p = tcp_position(np.asarray([q for _, q in truth]), actual_robot(settings))
    return [(t, (float(x), float(y), float(z))) for (t, _), (x, y, z) in zip(truth, p,
                                                                              strict=True)]


def twin_check(data: CaptureData, settings: RobotSettings,
               config: str | Path | None = None,
               arm_tcp: Sequence[tuple[float, Sequence[float]]] | None = None) -> TwinCheck:
    """Replay each session on a virtual-time loop and compare (see the module doc).
    ``arm_tcp``: the arm's true TCP (capture clock s, m) from a reference instrument; without
    it, the truth joints of an MCAP capture, if any."""
    from armbench.fakes.vclock import run_virtual

    limits = load_limits(config if config is not None else DEFAULT_CONFIG)
    allow = Allowance.of(limits.suite_params(TWIN_CHECK.suite))
    parts = sessions(data, settings)
    truth_tcp = list(arm_tcp) if arm_tcp is not None else _arm_tcp(data.path, settings)
    # the twin's truth only when there is the arm's to compare it with: reading it syncs the
    # joint boards, which a replay without it does not do (the replies stay bit-identical)
    twin_truth = TwinTruth() if truth_tcp else None
    twin: list[tuple[float, Vec4]] = []
    for part in parts:
        twin.extend(run_virtual(replay_twin(part.data, settings, twin_truth, part.in_flight)))
    merged = CaptureData(data.path, [c for p in parts for c in p.data.commands],
                         [r for p in parts for r in p.data.replies], data.bad_in_frames)
    result = compare(merged, twin, settings, limits, allow)
    times = np.asarray([c[0] for c in merged.commands])
    shifts = np.asarray(result.shifts_s)   # per command (its longest-way joint)

    def shift_at(t: FloatArray) -> FloatArray:
        k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 1)
        return np.asarray(shifts[k], dtype=np.float64)

    tcp = None if twin_truth is None else tcp_divergence(truth_tcp, twin_truth, shift_at,
                         math.hypot(result.scatter_s, result.reaction_scatter_s))
    count = judge(TWIN_CHECK.metric(TWIN_CHECK.sessions), float(len(parts)), "", limits,
                  description="sessions replayed, each into a fresh twin")
    measurements = [*result.measurements, count, *_judge_tcp(tcp, allow, limits)]
    return replace(result, tcp=tcp, sessions=len(parts), measurements=measurements,
                   verdict=_verdict(measurements))
