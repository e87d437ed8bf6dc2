"""``armbench twin-check``: how well the twin predicts an arm, measured on the arm's own traffic.

The commands of a capture are replayed, at their recorded times, into the emulator built from the
given settings (the twin), on virtual time, starting from the capture's first reported pose. The
two reply streams are then compared at the capture's reply times (the twin's newest reply then,
as a host would see it):

* per joint, the RMS and largest divergence of the reported angle (rad and encoder counts);
* per move (each command), the difference of the arrival times (twin − arm) where both arrive;
* the TCP divergence where the capture has the truth beside its replies (``/joint_states/true``
  of an MCAP capture of ``fake://``: the arm's true TCP against the twin's at the same instants,
  both through the twin's actual DH model; a JSON Lines capture or a real arm's has none:
  reported as absent).

A capture of several sessions (a run's capture holds one emulator per trial) is cut where the
replies jump further than the joints can move, or fall silent; each session is replayed into a
fresh twin from its own first pose.

Every figure is a measurement named by the suite contract (``TWIN_CHECK``) and judged against
the limits of a bench config (``--config``, else the packaged ``twin_check.toml``, which limits
``twin.jN.rms_counts`` to 3 counts): the verdict is ``pass`` when every judged figure is within,
else ``fail``. :mod:`armbench.bench.twin_record` writes a check as a run record.
"""

from __future__ import annotations

import asyncio
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from armbench.bench.calibrate.capture import CaptureData
from armbench.bench.limits import LimitsConfig, load_limits
from armbench.bench.record import Measurement, judge
from armbench.bench.suites.contract import TWIN_CHECK
from armbench.drivers.capture_read import read_joint_states
from armbench.drivers.kinematics import tcp_position
from armbench.drivers.motion import joint_speed_rad_s
from armbench.drivers.protocol import MAX_DUTY, AngleDecoder, Framer, Reply
from armbench.drivers.settings import RobotSettings
from armbench.fakes.arm import ArmEmulator
from armbench.fakes.settings import actual_robot, emulator_settings

__all__ = ["DEFAULT_CONFIG", "Aligned", "TwinCheck", "compare", "replay_twin", "sessions",
           "tcp_divergence", "twin_check"]

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

Vec4 = tuple[float, float, float, float]
FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class Aligned:
    """The two reply streams side by side: at each compared reply of the capture (``t_s``, s on
    the capture's clock) the arm's reported angles and the twin's newest ones (``(n, 4)``, rad),
    and each joint's encoder counts per rad."""

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
    command, its time and the arrival time in the arm's and the twin's stream (None: never
    arrived before the next command)."""

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

    def to_json(self) -> dict[str, Any]:
        """The ``--json`` object."""
        dt = np.asarray(self.arrival_dt_s) if self.arrival_dt_s else None
        return {
            "rms_rad": self.rms_rad, "max_rad": self.max_rad, "rms_counts": self.rms_counts,
            "max_counts": self.max_counts,
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


async def replay_twin(data: CaptureData, settings: RobotSettings,
                      truth: list[tuple[float, Vec4]] | None = None) -> list[tuple[float, Vec4]]:
    """Replay ``data``'s commands into a twin built from ``settings`` on the running loop; the
    twin's replies, on the capture's clock (its first reply aligned with the capture's). With
    ``truth`` given, the twin's true joint angles at each of its replies are appended to it."""
    loop = asyncio.get_running_loop()
    emulator = ArmEmulator(settings, emulator_settings(settings),
                           initial_q_rad=data.replies[0][1])
    framer = Framer("reply")
    decode = AngleDecoder(settings.lower_rad, settings.upper_rad)
    out: list[tuple[float, Vec4]] = []
    true_at: list[tuple[float, Vec4]] = []

    def sink(chunk: bytes) -> None:
        now = loop.time()
        for event in framer.feed(chunk):
            if isinstance(event, Reply):
                out.append((now, decode(event)))
                if truth is not None:
                    q = emulator.true_angles_rad()
                    true_at.append((now, (q[0], q[1], q[2], q[3])))

    emulator.attach_host(sink)
    await emulator.start()
    try:
        while not out:
            await asyncio.sleep(0.001)
        offset = out[0][0] - data.replies[0][0]
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
        truth.extend((t - offset, q) for t, q in true_at)
    return [(t - offset, q) for t, q in out]


def tcp_divergence(arm_truth: Sequence[tuple[float, Sequence[float]]],
                   twin_truth: Sequence[tuple[float, Vec4]],
                   geometry: RobotSettings) -> dict[str, float] | None:
    """RMS and largest distance (mm) between the arm's true TCP (the capture's truth samples)
    and the twin's at the same instants (its newest truth then), both through ``geometry`` (the
    twin's actual DH model: the arm's own is what a calibration estimates). None without truth
    on both sides."""
    if not arm_truth or not twin_truth:
        return None
    t_twin = np.asarray([r[0] for r in twin_truth])
    rows = [(t, q) for t, q in arm_truth if t >= t_twin[0]]
    if not rows:
        return None
    idx = np.searchsorted(t_twin, np.asarray([r[0] for r in rows]) + TIME_SLACK_S,
                          side="right") - 1
    arm_tcp = tcp_position(np.asarray([r[1] for r in rows]), geometry)
    twin_tcp = tcp_position(np.asarray([twin_truth[i][1] for i in idx]), geometry)
    d_mm = 1e3 * np.linalg.norm(arm_tcp - twin_tcp, axis=1)
    return {"rms_mm": float(np.sqrt(np.mean(d_mm * d_mm))), "max_mm": float(d_mm.max()),
            "samples": float(len(rows))}


def _arrivals(replies: Sequence[tuple[float, Vec4]], data: CaptureData,
              settings: RobotSettings) -> list[float | None]:
    """Per command, the first reply time after it (before the next one) within the arrival
    tolerance of its target on every joint, or None."""
    t = np.asarray([r[0] for r in replies])
    q = np.asarray([r[1] for r in replies])
    times = [c[0] for c in data.commands] + [math.inf]
    out: list[float | None] = []
    for k, (tc, cmd) in enumerate(data.commands):
        goal = np.asarray(cmd.angles_rad(settings.lower_rad, settings.upper_rad))
        i0 = int(np.searchsorted(t, tc - TIME_SLACK_S))
        i1 = int(np.searchsorted(t, times[k + 1] - TIME_SLACK_S))
        close = np.all(np.abs(q[i0:i1] - goal) <= ARRIVAL_TOLERANCE_RAD, axis=1)
        out.append(float(t[i0 + int(np.argmax(close))]) if close.any() else None)
    return out


def compare(data: CaptureData, twin: Sequence[tuple[float, Vec4]], settings: RobotSettings,
            limits: LimitsConfig | None) -> TwinCheck:
    """Compare the capture's replies with the twin's (see the module doc)."""
    t_twin = np.asarray([r[0] for r in twin])
    q_twin = np.asarray([r[1] for r in twin])
    start = data.commands[0][0]
    rows = [(t, q) for t, q in data.replies if t >= start and t >= t_twin[0]]
    t_arm = np.asarray([r[0] for r in rows])
    q_arm = np.asarray([r[1] for r in rows])
    # the newest twin reply at each capture reply (the capture's times carry 1 ns of rounding)
    idx = np.searchsorted(t_twin, t_arm + TIME_SLACK_S, side="right") - 1
    counts = np.asarray([j.counts_per_rad for j in settings.joints])
    aligned = Aligned(t_arm, q_arm, q_twin[idx], counts)
    diff = q_arm - q_twin[idx]
    rms = np.sqrt(np.mean(diff * diff, axis=0))
    peak = np.max(np.abs(diff), axis=0)
    arm_arrivals = _arrivals(data.replies, data, settings)
    twin_arrivals = _arrivals(twin, data, settings)
    pairs = list(zip(arm_arrivals, twin_arrivals, strict=True))
    dts = [b - a for a, b in pairs if a is not None and b is not None]
    arm_only = sum(a is not None and b is None for a, b in pairs)
    twin_only = sum(a is None and b is not None for a, b in pairs)
    measurements = _measurements(rms, peak, counts, dts, len(data.commands), arm_only,
                                 twin_only, len(rows), limits)
    return TwinCheck(
        [float(v) for v in rms], [float(v) for v in peak], [float(v) for v in rms * counts],
        [float(v) for v in peak * counts], dts, len(data.commands), arm_only, twin_only,
        len(rows), measurements, _verdict(measurements), list(twin), series=aligned,
        arrivals=[(c[0], a, b) for c, (a, b) in zip(data.commands, pairs, strict=True)])


def _verdict(measurements: Sequence[Measurement]) -> str:
    """``fail`` when a figure is outside its limit, else ``pass``."""
    return "fail" if any(m.outcome == "fail" for m in measurements) else "pass"


def _measurements(rms: FloatArray, peak: FloatArray, counts: FloatArray, dts: Sequence[float],
                  moves: int, arm_only: int, twin_only: int, replies: int,
                  limits: LimitsConfig | None) -> list[Measurement]:
    """The figures of a check, named by the suite contract and judged against ``limits``: per
    joint the RMS and largest divergence (counts, rad), the arrival-time differences, the counts
    of what was compared."""
    n = TWIN_CHECK
    out = []
    for j in range(4):
        for figure, value, unit, what in (
                (n.rms_counts, rms[j] * counts[j], "counts", "RMS divergence"),
                (n.max_counts, peak[j] * counts[j], "counts", "largest divergence"),
                (n.rms_rad, rms[j], "rad", "RMS divergence"),
                (n.max_rad, peak[j], "rad", "largest divergence")):
            out.append(judge(n.joint_metric(j + 1, figure), float(value), unit, limits,
                             better="lower", description=f"{what} of the reported angle"))
    if dts:
        dt = np.asarray(dts)
        out.append(replace(judge(n.metric(n.mean_dt), float(dt.mean()), "s", limits,
                                 description="mean arrival-time difference, twin - arm"),
                           better=None))
        out.append(judge(n.metric(n.max_abs_dt), float(np.abs(dt).max()), "s", limits,
                         description="largest arrival-time difference, |twin - arm|"))
    for figure, value, what in (
            (n.moves, moves, "commands replayed"),
            (n.compared, len(dts), "moves both streams arrived at"),
            (n.arm_only, arm_only, "moves only the arm arrived at"),
            (n.twin_only, twin_only, "moves only the twin arrived at"),
            (n.replies, replies, "replies of the capture compared")):
        out.append(judge(n.metric(figure), float(value), "", limits, description=what))
    return out


def sessions(data: CaptureData, settings: RobotSettings) -> list[CaptureData]:
    """The capture cut where the arm it recorded was another one: a reply that jumps further
    than the joints can move at full speed in the time since the previous one (and a stall of the
    loop), or a silence longer than :data:`SILENCE_S` (a run's capture holds one emulator per
    trial, each booting at its own pose). Sessions without commands are left out."""
    t = np.asarray([r[0] for r in data.replies])
    q = np.asarray([r[1] for r in data.replies])
    if len(t) < 2:
        return [data]
    dt = np.diff(t)
    speed = np.asarray([joint_speed_rad_s(MAX_DUTY, j.steps_per_rad) for j in settings.joints])
    reach = 1.5 * speed * (dt[:, None] + STALL_S) + JUMP_SLACK_RAD
    jump = np.abs(np.diff(q, axis=0)) > reach
    cuts = [0, *(np.flatnonzero(jump.any(axis=1) | (dt > SILENCE_S)) + 1), len(t)]
    out = []
    for a, b in itertools.pairwise(cuts):
        t0, t1 = t[a], (t[b] if b < len(t) else math.inf)
        commands = [c for c in data.commands if t0 <= c[0] < t1]
        if commands:
            out.append(CaptureData(data.path, commands, data.replies[a:b], 0))
    return out


def _tcp(tcp: dict[str, float] | None, limits: LimitsConfig) -> list[Measurement]:
    """The TCP divergence as measurements, where the capture had truth (``rms_mm``,
    ``max_mm``)."""
    n = TWIN_CHECK
    tcp = tcp or {}
    return [judge(n.metric(name), tcp[key], "mm", limits, better="lower",
                  description=f"{what} of the TCP, arm against twin")
            for name, key, what in ((n.tcp_rms, "rms_mm", "RMS divergence"),
                                    (n.tcp_max, "max_mm", "largest divergence"))
            if key in tcp]


def twin_check(data: CaptureData, settings: RobotSettings,
               config: str | Path | None = None) -> TwinCheck:
    """Replay each session on a virtual-time loop and compare (see the module doc)."""
    from armbench.fakes.vclock import run_virtual

    limits = load_limits(config if config is not None else DEFAULT_CONFIG)
    parts = sessions(data, settings)
    arm_truth = read_joint_states(data.path)
    twin_truth: list[tuple[float, Vec4]] | None = [] if arm_truth else None
    twin: list[tuple[float, Vec4]] = []
    for part in parts:
        twin.extend(run_virtual(replay_twin(part, settings, twin_truth)))
    merged = CaptureData(data.path, [c for p in parts for c in p.commands],
                         [r for p in parts for r in p.replies], data.bad_in_frames)
    result = compare(merged, twin, settings, limits)
    if twin_truth:
        result = replace(result, tcp=tcp_divergence(arm_truth, twin_truth,
                                                     actual_robot(settings)))
    count = judge(TWIN_CHECK.metric(TWIN_CHECK.sessions), float(len(parts)), "", limits,
                  description="sessions replayed, each into a fresh twin")
    measurements = [*result.measurements, count, *_tcp(result.tcp, limits)]
    return replace(result, sessions=len(parts), measurements=measurements,
                   verdict=_verdict(measurements))
