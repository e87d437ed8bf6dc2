"""Driver figures: the full stack over ``fake://`` on virtual time, and the reply rate over a pty.

* ``driver.fake_realtime_factor`` — simulated seconds per wall second of a sequence of full-duty
  ``move_joints`` over ``fake://`` on the virtual-time loop (best of ``repeats``). ``bound``: the
  same for the emulator alone (``fake://`` opened, its replies dropped as they arrive, no
  driver), i.e. the most any driver could reach on this machine; ``ratio`` is the driver's share
  of it.
* ``driver.fake_roundtrips`` — command → next reply round trips per wall second over ``fake://``,
  each command issued at a random phase of the firmware's loop (seeded), so the latency is spread
  over one loop period; the note gives its percentiles in simulated ms, also reported as
  ``driver.fake_roundtrip_p50_ms`` / ``driver.fake_roundtrip_p99_ms`` (bound: the emulated
  firmware's loop period).
* ``driver.pty_reply_rate`` — replies per second the driver decodes from ``armbench emulate --pty``
  (a subprocess, real time) over ~2 s. ``bound = min(baud / (bits per byte × 25 bytes),
  1 / loop period)``, the loop period being the emulated master's I²C traffic per loop (three
  4-byte reference writes and three 2-byte position reads at ``i2c_hz``, from
  :func:`armbench.fakes.firmware.i2c.transaction_bits`) plus ``loop_overhead_s`` of
  :class:`EmulatorSettings`.
* ``driver.host_timer_late_ms`` — the latest wake-up of a bare ``select()`` sleep at the loop
  period, over as long as the pty run, in this process: the scheduling delay the host imposes on
  any process that keeps a schedule. A server delayed d ms leaves a gap of one loop period + d,
  so on a host where this exceeds one loop period ``driver.pty_max_gap_ms`` cannot meet its bound
  whatever the emulator does.
* ``driver.port_reply_rate`` — with ``--port``: the same against the user's hardware, bounded by
  the line rate and the loop period the emulator assumes for the firmware.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import math
import random
import select
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator

from armbench.cli.perf import Figure, PerfOptions
from armbench.drivers.host.arm import CONNECT_TIMEOUT_S, Arm
from armbench.drivers.model.protocol import REPLY_LEN, Command
from armbench.drivers.model.settings import RobotSettings, SerialSettings
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.emulator_settings import EmulatorSettings, emulator_settings
from armbench.fakes.firmware.i2c import transaction_bits
from armbench.fakes.firmware.i2c_messages import I2CMessage
from armbench.fakes.links.fake_transport import FakeTransport

__all__ = ["loop_period_s", "reply_rate_bound", "run", "serve_pty", "timer_lateness_s"]

#: Poses the realtime benchmark moves between at duty 99 (rad, within the default limits).
POSES = ((0.5, 0.4, 0.6, 0.8), (-0.5, -0.3, -0.6, -0.2))


def loop_period_s(emulator: EmulatorSettings, slaves: int = 3) -> float:
    """The emulated master's loop period: per slave one 4-byte reference write and one 2-byte
    position read on the I²C bus, plus the loop's CPU overhead."""
    write = transaction_bits((I2CMessage.write(0x10, b"\x01\x00\x00\x00"),))
    read = transaction_bits((I2CMessage.read(0x10, 2),))
    return slaves * (write + read) * emulator.i2c_bit_s + emulator.loop_overhead_s


def reply_rate_bound(serial: SerialSettings, emulator: EmulatorSettings) -> float:
    """Replies per second the line and the firmware's loop allow: ``min(baud / (bits per byte ×
    25), 1 / loop period)``."""
    line = serial.baudrate / (serial.bits_per_byte * REPLY_LEN)
    return min(line, 1.0 / loop_period_s(emulator))


# --- virtual time -------------------------------------------------------------------------------

async def _moves(sim_s: float) -> tuple[float, float]:
    """Full-duty moves for at least ``sim_s`` simulated seconds: (simulated s, wall s)."""
    async with Arm.connect("fake://") as arm:
        loop = asyncio.get_running_loop()
        t0, w0 = loop.time(), time.perf_counter()
        k = 0
        while loop.time() - t0 < sim_s:
            await arm.move_joints(POSES[k % 2], 99)
            k += 1
        return loop.time() - t0, time.perf_counter() - w0


def _drop(data: bytes) -> None:
    """A receiver that throws the replies away."""


async def _emulator_alone(sim_s: float) -> tuple[float, float]:
    """The emulator over ``fake://`` with no driver, its replies handed to a receiver that drops
    them (as the driver receives them: ``FakeTransport.set_receiver``): (simulated s, wall s)."""
    transport = FakeTransport("fake://", SerialSettings())
    await transport.open()
    transport.set_receiver(_drop)
    loop = asyncio.get_running_loop()
    try:
        t0, w0 = loop.time(), time.perf_counter()
        await asyncio.sleep(sim_s)
        return loop.time() - t0, time.perf_counter() - w0
    finally:
        await transport.close()


async def _roundtrips(count: int, period_s: float) -> tuple[int, float, list[float]]:
    """``count`` hold commands, each issued at a random phase of the firmware's loop (seeded)
    and followed by the wait for the next reply: (count, wall s, latencies in simulated s)."""
    rng = random.Random(0)
    async with Arm.connect("fake://") as arm:
        loop = asyncio.get_running_loop()
        hold = Command.from_rad(arm.state.q_rad, 0)
        latencies = []
        w0 = time.perf_counter()
        for _ in range(count):
            await asyncio.sleep(rng.uniform(0.0, period_s))
            seq = arm.state.seq
            t0 = await arm.send(hold)
            await arm.wait_state(lambda s, seq=seq: s.seq > seq)  # type: ignore[misc]
            latencies.append(loop.time() - t0)
        return count, time.perf_counter() - w0, latencies


def _percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, round(q * (len(ordered) - 1))))]


# --- real time ----------------------------------------------------------------------------------

@contextlib.contextmanager
def serve_pty(timeout_s: float = 120.0) -> Iterator[str]:
    """``armbench emulate --pty`` in a subprocess; yields the pty device it printed. Starting
    Python and the emulator takes seconds of CPU, far more on a loaded machine: ``timeout_s``
    bounds a start that hangs, not a slow one."""
    proc = subprocess.Popen([sys.executable, "-m", "armbench", "emulate", "--pty"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], timeout_s)
        line = proc.stdout.readline() if ready else ""
        if " on " not in line:
            raise RuntimeError(f"armbench emulate --pty did not start: {line!r}")
        yield line.rsplit(" on ", 1)[1].split()[0]
    finally:
        proc.terminate()
        try:
            proc.wait(5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


async def _reply_rate(port: str, seconds: float, settings: RobotSettings,
                      patience_s: float | None = None) -> tuple[float, float]:
    """Replies per second decoded from ``port`` over ``seconds`` (after a short warm-up), and
    the longest gap (s) between two replies as the client received them. ``patience_s``: the
    connection and reply timeouts instead of the driver's defaults (for the emulator this module
    starts: its rate is measured, not required, and a loaded machine may keep it waiting)."""
    connect_s = CONNECT_TIMEOUT_S if patience_s is None else patience_s
    reply_s = 0.5 if patience_s is None else patience_s
    async with Arm.connect(port, settings, connect_timeout_s=connect_s,
                           reply_timeout_s=reply_s) as arm:
        loop = asyncio.get_running_loop()
        await asyncio.sleep(0.2)
        n0, t0 = arm.frames_received, loop.time()
        with arm.record_states() as states:
            await asyncio.sleep(seconds)
        rate = (arm.frames_received - n0) / (loop.time() - t0)
        times = [t0] + [s.t_s for s in states]
        return rate, max(b - a for a, b in itertools.pairwise(times))


def timer_lateness_s(seconds: float, period_s: float) -> float:
    """The latest a bare ``select()`` sleep woke after its deadline, sleeping every
    ``period_s`` for ``seconds`` of real time: the scheduling delay the host imposes on any
    process that keeps a schedule, the emulator serving a pty included."""
    deadline = time.monotonic() + period_s
    end = deadline + seconds
    worst = 0.0
    while deadline < end:
        wait_s = deadline - time.monotonic()
        if wait_s > 0:
            select.select([], [], [], wait_s)
        worst = max(worst, time.monotonic() - deadline)
        deadline += period_s
    return worst


# --- figures ------------------------------------------------------------------------------------

def run(options: PerfOptions) -> list[Figure]:
    """Measure the driver figures (see the module docstring)."""
    robot = RobotSettings()
    emu = emulator_settings(robot)
    sim_s = 5.0 if options.quick else 20.0
    best_driver = best_alone = 0.0
    for _ in range(options.repeats):
        sim, wall = run_virtual(_moves(sim_s))
        best_driver = max(best_driver, sim / wall)
        sim, wall = run_virtual(_emulator_alone(sim_s))
        best_alone = max(best_alone, sim / wall)
    figures = [Figure(
        "driver.fake_realtime_factor", best_driver, "sim s/wall s", best_alone,
        best_driver / best_alone,
        note=f"full-duty move_joints over fake:// for {sim_s:g} simulated s; bound = the "
             "emulator alone; target 100")]

    count = 300 if options.quick else 2000
    period_s = loop_period_s(emu)
    best_rate, best_lat = 0.0, [0.0]
    for _ in range(options.repeats):
        n, wall, lat = run_virtual(_roundtrips(count, period_s))
        if n / wall > best_rate:
            best_rate, best_lat = n / wall, lat
    p50, p99 = _percentile(best_lat, 0.5) * 1e3, _percentile(best_lat, 0.99) * 1e3
    period_ms = period_s * 1e3
    figures += [
        Figure("driver.fake_roundtrips", best_rate, "roundtrips/s",
               note=f"command at a random loop phase → next reply; latency p50 {p50:.2f} ms, "
                    f"p99 {p99:.2f} ms (simulated), "
                    f"mean {statistics.fmean(best_lat) * 1e3:.2f} ms"),
        Figure("driver.fake_roundtrip_p50_ms", p50, "ms", period_ms, p50 / period_ms,
               note="simulated; bound = emulated firmware loop period"),
        Figure("driver.fake_roundtrip_p99_ms", p99, "ms", period_ms, p99 / period_ms,
               note="simulated; bound = emulated firmware loop period"),
    ]

    bound = reply_rate_bound(robot.serial, emu)
    seconds = 1.0 if options.quick else 2.0
    runs = 1 if options.quick else min(options.repeats, 2)
    best, best_gap = 0.0, math.inf
    with serve_pty() as path:
        for _ in range(runs):
            rate, gap = asyncio.run(_reply_rate(path, seconds, robot, patience_s=30.0))
            best, best_gap = max(best, rate), min(best_gap, gap)
    figures.append(Figure(
        "driver.pty_reply_rate", best, "replies/s", bound, best / bound,
        note=f"armbench emulate --pty, {seconds:g} s; bound = min(line "
             f"{robot.serial.baudrate / (robot.serial.bits_per_byte * REPLY_LEN):.1f}/s, loop "
             f"{1 / loop_period_s(emu):.1f}/s); target ratio 0.9"))
    two_loops_ms = 2e3 * period_s
    late_s = timer_lateness_s(seconds, period_s)
    figures.append(Figure(
        "driver.pty_max_gap_ms", best_gap * 1e3, "ms", two_loops_ms,
        best_gap * 1e3 / two_loops_ms,
        note="the emulator serving in real time: longest gap between two replies of armbench "
             "emulate --pty as the driver received them; bound = two firmware loop periods"))
    figures.append(Figure(
        "driver.host_timer_late_ms", late_s * 1e3, "ms", period_s * 1e3, late_s / period_s,
        note=f"what the host allows: the latest wake-up of a bare select() sleep every loop "
             f"period for {seconds:g} s, in this process; a pty gap exceeds one loop period by "
             f"at least any such delay of the server's (bound = one loop period)"))

    if options.port is not None:
        rate, _gap = asyncio.run(_reply_rate(options.port, seconds, robot))
        figures.append(Figure(
            "driver.port_reply_rate", rate, "replies/s", bound, rate / bound,
            note=f"{options.port}, {seconds:g} s; bound as driver.pty_reply_rate (the firmware "
                 "loop period is the emulator's model of it)"))
    return figures
