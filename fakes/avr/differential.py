"""Differential check: one command script on the Python emulator and on the compiled firmware.

Both start powered at t = 0 and get the same command frames at the same simulated times: the
emulator on a virtual-time loop, the firmware in the harness at full speed (``--script``,
``--reply-log``), so neither side sees wall-clock noise. Each firmware reply is then checked
against the emulator's replies within ``window_s`` (one loop period) of it: per joint the
firmware's position must lie within the emulator's over that window, widened by ``tol_counts``
encoder counts. :func:`compare` gives the worst excess per joint.
"""

from __future__ import annotations

import asyncio
import subprocess
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from armbench.drivers.model.protocol import Command, Framer, Reply
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.avr.harness import HARNESS_NAME, board_specs, build, find_images
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.firmware.emulator_settings import emulator_settings, with_emulator_overrides

__all__ = ["DEFAULT_SCRIPT", "DiffResult", "compare", "run_emulator", "run_firmware"]

Timed = list[tuple[float, Reply]]
TICKS_TURN = 62832
TICKS_HALF_TURN = TICKS_TURN // 2
#: The longest stall of a master's loop: an EEPROM record of five changed cells.
STALL_MAX_S = 0.025

#: Moves at full, middle and low duty, a reversal and a hold: (time s, angles rad, duty).
DEFAULT_SCRIPT: tuple[tuple[float, tuple[float, float, float, float], int], ...] = (
    (0.30, (0.30, 0.20, -0.25, 0.40), 99),
    (1.20, (-0.10, 0.35, 0.10, 0.20), 60),
    (2.40, (0.05, 0.10, -0.05, 0.30), 20),
    (3.60, (0.05, 0.10, -0.05, 0.30), 0),
)


def _frames(script: Sequence[tuple[float, Sequence[float], int]]) -> list[tuple[float, bytes]]:
    return [(t, Command.from_rad(list(q), duty).encode()) for t, q, duty in script]


def run_emulator(script: Sequence[tuple[float, Sequence[float], int]], until_s: float,
                 robot: RobotSettings | None = None) -> Timed:
    """The emulator's replies (time of their last byte, reply) for the script; by default the
    ``ideal`` profile (the firmware model alone: the harness's joints have no physics)."""
    robot = robot if robot is not None else with_emulator_overrides(RobotSettings(),
                                                                    profile="ideal")

    async def main() -> Timed:
        loop = asyncio.get_running_loop()
        framer = Framer("reply")
        out: Timed = []
        arm = ArmEmulator(robot, emulator_settings(robot))
        arm.attach_host(lambda data: out.extend(
            (loop.time(), r) for r in framer.feed(data) if isinstance(r, Reply)))
        await arm.start()
        t0 = loop.time()
        for t, frame in _frames(script):
            await asyncio.sleep(t0 + t - loop.time())
            arm.host_write(frame)
        await asyncio.sleep(t0 + until_s - loop.time())
        await arm.close()
        return [(t - t0, r) for t, r in out]

    return run_virtual(main)


def run_firmware(script: Sequence[tuple[float, Sequence[float], int]], until_s: float,
                 robot: RobotSettings | None = None, firmware: str | None = None) -> Timed:
    """The firmware's replies (time its '#' was written, reply) for the script, from the
    harness at full speed."""
    robot = robot if robot is not None else RobotSettings()
    exe = build() / HARNESS_NAME
    with tempfile.TemporaryDirectory() as tmp:
        script_file, log_file = Path(tmp, "script.txt"), Path(tmp, "replies.txt")
        script_file.write_text("".join(f"{t:.6f} {frame.decode()}\n"
                                       for t, frame in _frames(script)))
        args = [str(exe), "--speed", "max", "--seconds", str(until_s), "--script",
                str(script_file), "--reply-log", str(log_file)]
        for spec in board_specs(robot, find_images(firmware, robot)):
            args += ["--board", spec]
        subprocess.run(args, stdin=subprocess.DEVNULL, capture_output=True, check=True,
                       timeout=600)
        framer = Framer("reply")
        out: Timed = []
        for line in log_file.read_text().splitlines():
            t, _, text = line.partition(" ")
            out.extend((float(t), r) for r in framer.feed(text.encode()) if isinstance(r, Reply))
        return out


@dataclass(frozen=True)
class DiffResult:
    """Worst disagreement per joint, in encoder counts beyond the emulator's range over the
    window, with the time it happened; and how many firmware replies were compared."""

    excess_counts: tuple[float, float, float, float]
    at_s: tuple[float, float, float, float]
    compared: int


def compare(firmware: Timed, emulator: Timed, robot: RobotSettings | None = None,
            window_s: float = 3.2e-3, tol_counts: float = 0.0,
            widen_s: Callable[[float], float] | None = None,
            speed_counts_per_s: Sequence[float] | None = None,
            stall_s: float | None = None) -> DiffResult:
    """Check each firmware reply against the emulator's within ``window_s`` of it.

    ``widen_s(t)``, when given, is how far apart the two masters took the commands that may
    still be in force at t (their loops pick a command up at moments up to a loop apart): the
    window is widened by it, and the tolerance by that time at each joint's
    ``speed_counts_per_s`` (a hold taken that much later stops the joint that much further on,
    for good). ``stall_s``, when given: a firmware reply more than that after the one before
    followed a stall of its loop (an EEPROM record) and carries a position sampled before it;
    its window reaches back to the reply before (the stall's length depends on how many bytes
    of the record changed, which a few counts' difference at a byte boundary changes); likewise
    an emulator reply after a stall of its own brings the next one into the window."""
    robot = robot if robot is not None else RobotSettings()
    per_tick = [j.counts_per_rad / 1e4 for j in robot.joints]  # counts per wire tick
    lo = 0
    worst = [0.0] * 4
    at = [0.0] * 4
    compared = 0
    previous = -float("inf")
    for t, reply in firmware:
        w = window_s + (widen_s(t) if widen_s is not None else 0.0)
        begin = t - w
        if stall_s is not None and t - previous > stall_s:
            # sampled before the stall, which may be longer on one side (no further back than
            # the longest stall: not across a power cut)
            begin = max(previous, t - STALL_MAX_S) - w
        previous = t
        while lo > 0 and emulator[lo - 1][0] >= begin:
            lo -= 1
        while lo < len(emulator) and emulator[lo][0] < begin:
            lo += 1
        window = []
        k = lo
        while k < len(emulator) and emulator[k][0] <= t + w:
            window.append(emulator[k][1])
            if (stall_s is not None and k > 0 and k + 1 < len(emulator)
                    and emulator[k][0] - emulator[k - 1][0] > stall_s
                    and emulator[k + 1][0] > t + w):
                # the emulator's reply after its own stall is old too: its next one is the
                # first sampled after the stall
                window.append(emulator[k + 1][1])
            k += 1
        if not window:
            continue
        compared += 1
        for j in range(4):
            v = reply[j]   # compared on the circle: 62832 and 0 are neighbours
            values = [v + (r[j] - v + TICKS_HALF_TURN) % TICKS_TURN - TICKS_HALF_TURN
                      for r in window]
            excess_ticks = max(min(values) - v, v - max(values), 0)
            extra = 0.0
            if widen_s is not None and speed_counts_per_s is not None:
                extra = widen_s(t) * speed_counts_per_s[j]
            excess = excess_ticks * per_tick[j] - tol_counts - extra
            if excess > worst[j]:
                worst[j], at[j] = excess, t
    return DiffResult((worst[0], worst[1], worst[2], worst[3]), (at[0], at[1], at[2], at[3]),
                      compared)
