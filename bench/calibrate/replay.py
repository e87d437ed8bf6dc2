"""The replay half of ``armbench twin-check``: a capture cut into sessions (one arm each, without
a break), and each session's commands written into a twin (the emulator built from the settings)
on the running loop at their recorded times, optionally each moved by an offset (the floor's
perturbed replay, :func:`armbench.bench.twin_check.check.replay_floor`)."""

from __future__ import annotations

import asyncio
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np
import numpy.typing as npt

from armbench.bench.calibrate.align import TICK_RAD
from armbench.bench.calibrate.capture_data import CaptureData
from armbench.drivers.host.motion import joint_speed_rad_s
from armbench.drivers.model.kinematics import tcp_position
from armbench.drivers.model.protocol import MAX_DUTY, AngleDecoder, Command, Framer, Reply
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.firmware.emulator_settings import emulator_settings

__all__ = ["BURST_S", "SILENCE_S", "TIME_SLACK_S", "Counters", "Session", "TwinTruth",
           "closer_counters", "replay_sessions", "replay_twin", "sessions"]

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
#: The twin has booted when it reports the session's first pose within this many ticks on every
#: joint (its first replies, before the joint boards answer, report them at 0).
BOOT_TICKS: Final = 3.0
#: Longest wait for the twin to report that pose (s, virtual).
BOOT_TIMEOUT_S: Final = 2.0
#: Longest wait for a resumed twin to leave its pose on the command in flight (s, virtual).
LEAVE_TIMEOUT_S: Final = 0.3

Vec4 = tuple[float, float, float, float]
Vec3 = tuple[float, float, float]
#: How the twin's counters start: as its Hall sensors set them (True) or as a new arm's (False),
#: for the whole arm or per joint.
Counters = bool | tuple[bool, ...]


def closer_counters(new_arm: Sequence[float], by_hall: Sequence[float]) -> tuple[bool, ...]:
    """Per joint, whether the twin replayed with Hall-set counters came closer to the arm than
    the one with a new arm's (``new_arm``, ``by_hall``: a divergence per joint; a tie keeps the
    new arm's). Each joint's sensor sets its own counter once the joint has passed it, so the
    choice is the joint's: a joint the twin models badly, whose divergence dwarfs the others',
    does not choose for them."""
    return tuple(float(b) < float(a) for a, b in zip(new_arm, by_hall, strict=True))


@dataclass(frozen=True, slots=True)
class Session:
    """A stretch of a capture recorded from one arm without a break, and the command that was in
    flight when it began (None for the first)."""

    data: CaptureData
    in_flight: Command | None = None


@dataclass(frozen=True, slots=True)
class TwinTruth:
    """The twin's truth at each of its replies: times (capture clock), true joint angles (rad)
    and true TCP (m, through its actual model)."""

    t_s: list[float] = field(default_factory=list)
    q_rad: list[Vec4] = field(default_factory=list)
    tcp_m: list[Vec3] = field(default_factory=list)


async def replay_twin(data: CaptureData, settings: RobotSettings,
                      truth: TwinTruth | None = None, in_flight: Command | None = None,
                      offsets_s: Sequence[float] | None = None,
                      hall_counters: Counters = False) -> list[tuple[float, Vec4]]:
    """Replay ``data``'s commands into a twin built from ``settings`` on the running loop; the
    twin's replies from the first one at the session's first pose, on the capture's clock (that
    reply aligned with the capture's first). ``in_flight`` is written first, at once; with
    ``offsets_s``, each command that much later (earlier when negative; never before the one
    before it). With ``truth`` given, the twin's truth at each of its replies is appended to
    it. ``hall_counters``: the twin's counters as its Hall sensors set them (an arm that ran
    before, ``ArmEmulator(resumed=True)``); else as a new arm's, true at power-up; per joint
    when a sequence (:func:`closer_counters`)."""
    loop = asyncio.get_running_loop()
    q0 = data.replies[0][1]
    emulator = ArmEmulator(settings, emulator_settings(settings), initial_q_rad=q0,
                           resumed=hall_counters)
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
            if _moving(data):
                # the arm was moving when the session began; the twin starts from rest when it
                # reads the command: its clock starts where it leaves the pose
                left = await _left_pose(out, loop)
                offset = offset if left is None else left - data.replies[0][0]
        shifted = [c[0] + (0.0 if offsets_s is None else offsets_s[k])
                   for k, c in enumerate(data.commands)]
        for t_s, (_, command) in zip(itertools.accumulate(shifted, max), data.commands,
                                     strict=True):
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
        # the true TCP of those true joints through the actual model, in one vectorised call
        # (one per reply was a third of a check's time)
        tcp = tcp_position(np.asarray(truth.q_rad[n:]).reshape(-1, 4), emulator.actual_settings)
        truth.tcp_m.extend((p[0], p[1], p[2]) for p in tcp.tolist())
    return [(t - offset, q) for t, q in out]


def replay_sessions(parts: Sequence[Session], settings: RobotSettings,
                    offsets: Sequence[float] | npt.NDArray[np.float64] | None,
                    truth: TwinTruth | None,
                    hall_counters: Counters) -> list[tuple[float, Vec4]]:
    """Replay each session into a twin of its own, each on a virtual-time loop of its own, the
    replies in order; ``offsets`` moves the commands of all sessions, in order (see
    :func:`replay_twin`)."""
    from armbench.fakes.clock.vclock import run_virtual

    out: list[tuple[float, Vec4]] = []
    k = 0
    for part in parts:
        n, k = len(part.data.commands), k + len(part.data.commands)
        moved = None if offsets is None else [float(v) for v in offsets[k - n:k]]
        out.extend(run_virtual(replay_twin(part.data, settings, truth, part.in_flight,
                                           offsets_s=moved, hall_counters=hall_counters)))
    return out


def _moving(data: CaptureData) -> bool:
    """Whether the arm moved between the session's first two replies (by more than a tick)."""
    if len(data.replies) < 2:
        return False
    return any(abs(a - b) > 1.5 * TICK_RAD for a, b in zip(data.replies[0][1],
                                                           data.replies[1][1], strict=True))


async def _left_pose(out: list[tuple[float, Vec4]], loop: asyncio.AbstractEventLoop
                     ) -> float | None:
    """The time of the twin's last reply at its first reply's pose (within 1.5 ticks) before
    one that left it, as its replies come in (``out``); None when it has not left within
    :data:`LEAVE_TIMEOUT_S`."""
    give_up = loop.time() + LEAVE_TIMEOUT_S
    while loop.time() < give_up:
        for k in range(1, len(out)):
            if any(abs(a - b) > 1.5 * TICK_RAD for a, b in zip(out[k][1], out[0][1],
                                                               strict=True)):
                return out[k - 1][0]
        await asyncio.sleep(0.001)
    return None


def sessions(data: CaptureData, settings: RobotSettings) -> list[Session]:
    """The capture cut where the arm it recorded was another one: a reply that jumps further
    than the joints can move at full speed in the time since the previous one (and a stall of the
    loop), or a silence longer than :data:`SILENCE_S` (a run's capture holds one emulator per
    trial, each booting at its own pose) with the arm at rest on both sides, that does not end in
    a burst (:data:`BURST_S`: then the host was silent, not the arm). Each session after a
    silence carries the command in flight at its start; sessions without commands are left
    out."""
    t = np.asarray([r[0] for r in data.replies])
    q = np.asarray([r[1] for r in data.replies])
    if len(t) < 2:
        return [Session(data)]
    dt = np.diff(t)
    speed = np.asarray([joint_speed_rad_s(MAX_DUTY, j.steps_per_rad) for j in settings.joints])
    reach = 1.5 * speed * (dt[:, None] + STALL_S) + JUMP_SLACK_RAD
    jump = np.abs(np.diff(q, axis=0)) > reach
    burst = np.append(dt < BURST_S, False)          # per reply: read together with the next
    # at rest on both sides of it (the last two replies before, the first two after): an arm
    # that moved through a silence is the same arm going on, and its twin goes on with it
    still = np.append(np.all(np.abs(np.diff(q, axis=0)) <= 1.5 * TICK_RAD, axis=1), True)
    rest_before = np.insert(still[:-1], 0, True)[:-1]
    silent = (dt > SILENCE_S) & ~burst[1:] & rest_before & still[1:]
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


