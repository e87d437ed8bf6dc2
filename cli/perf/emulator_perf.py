"""Emulator throughput on virtual time: simulated seconds per wall second, and cost per main loop.

The workload is the emulator alone with default settings (115200 baud, 100 kHz I²C), four boards,
the arm moving at full duty between two far-apart poses (every joint moving most of the time), and
every main loop and reply frame the firmware would produce. The bound of ``emulator.loop_cost`` is
one bare ``asyncio.sleep`` on the same virtual-time loop, measured in the same run.
``emulator.cpu_realtime_factor`` is the same run per CPU second of its thread (on a busy machine
the wall time measures the other processes as much as the emulator).
``emulator.bus_realtime_factor`` is the same workload with ``emulator.fused_bus = false`` (every
transaction of every loop through the bus, see ``docs/emulator.md``), beside the default.
"""

from __future__ import annotations

import asyncio
import time

from armbench.cli.perf import Figure, PerfOptions
from armbench.drivers.model.protocol import Command
from armbench.drivers.model.settings import RobotSettings, SerialSettings
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.fakes.twin.joint import CYCLE_S

__all__ = ["emulate", "run"]

POSES = ([1.2, 0.9, -1.2, 1.5], [-1.2, -0.6, 0.8, -0.4])
#: A low baud rate where each reply takes ~26 ms on the line: the master's prints block.
SLOW_BAUD = 9600


async def emulate(sim_s: float, moving: bool, baudrate: int = 115200,
                   fused_bus: bool = True, cpu: list[float] | None = None) -> tuple[float, int]:
    """Wall seconds and main loops for ``sim_s`` simulated seconds (the CPU seconds of this
    thread appended to ``cpu`` when given)."""
    robot = RobotSettings(serial=SerialSettings(baudrate=baudrate))
    arm = ArmEmulator(robot, emulator_settings(robot, fused_bus=fused_bus))
    arm.attach_host(lambda data: None)
    await arm.start()
    wall = time.perf_counter()
    thread = time.thread_time()
    elapsed = 0.0
    k = 0
    while elapsed < sim_s:
        if moving:
            arm.host_write(Command.from_rad(POSES[k % 2], 99).encode())
            k += 1
        step = min(5.0, sim_s - elapsed)
        await asyncio.sleep(step)
        elapsed += step
    wall = time.perf_counter() - wall
    if cpu is not None:
        cpu.append(time.thread_time() - thread)
    loops = arm.stats().loops
    await arm.close()
    return wall, loops


def _cycle_loop_s(sim_s: float) -> float:
    """Wall seconds of the issue's yardstick for ``sim_s`` simulated seconds: a plain Python
    loop stepping the 80 µs cycle of four joints through the STOP / PWM_HIGH / PWM_LOW machine
    at duty 99, with no I²C, UART or event loop at all."""
    state, count, steps = [1] * 4, [0] * 4, [0] * 4
    duty = 99
    low_cycles = 100 - duty
    wall = time.perf_counter()
    for _ in range(round(sim_s / CYCLE_S)):
        for j in range(4):
            if state[j] == 1:  # PWM_HIGH: one step, then the low cycles
                steps[j] += 1
                state[j], count[j] = 2, low_cycles
            elif state[j] == 2:  # PWM_LOW
                count[j] -= 1
                if count[j] <= 0:
                    state[j] = 1
    return time.perf_counter() - wall


async def _bare_sleep_s(n: int, dt_s: float) -> float:
    wall = time.perf_counter()
    for _ in range(n):
        await asyncio.sleep(dt_s)
    return (time.perf_counter() - wall) / n


def run(options: PerfOptions) -> list[Figure]:
    """Measure the ``emulator.*`` figures."""
    sim_s = 10.0 if options.quick else 40.0
    repeats = max(1, min(options.repeats, 3))
    best_factor = best_idle = best_cycle = best_cpu_factor = 0.0
    cycle_s = 2.0 if options.quick else 5.0
    best_loop = best_sleep = float("inf")
    best_slow = best_unfused = 0.0
    for _ in range(repeats):  # interleaved, best of each: a busy machine only ever slows a run
        cpu: list[float] = []
        wall, loops = run_virtual(emulate(sim_s, moving=True, cpu=cpu))
        best_factor = max(best_factor, sim_s / wall)
        best_cpu_factor = max(best_cpu_factor, sim_s / cpu[0])
        unfused_wall, _ = run_virtual(emulate(sim_s, moving=True, fused_bus=False))
        best_unfused = max(best_unfused, sim_s / unfused_wall)
        slow_wall, _ = run_virtual(emulate(sim_s, moving=True, baudrate=SLOW_BAUD))
        best_slow = max(best_slow, sim_s / slow_wall)
        best_loop = min(best_loop, wall / loops)
        best_sleep = min(best_sleep, run_virtual(_bare_sleep_s(20_000, 2.4e-3)))
        idle_wall, _ = run_virtual(emulate(sim_s, moving=False))
        best_idle = max(best_idle, sim_s / idle_wall)
        best_cycle = max(best_cycle, cycle_s / _cycle_loop_s(cycle_s))
    return [
        Figure("emulator.realtime_factor", best_factor, "sim s/wall s",
               note="four boards, full duty, 115200 baud, 100 kHz I²C, virtual time"),
        Figure("emulator.cpu_realtime_factor", best_cpu_factor, "sim s/CPU s",
               note="the same run per CPU second of its thread: what a busy machine "
                    "stretches less"),
        Figure("emulator.loop_cost", best_loop * 1e6, "µs/loop", best_sleep * 1e6,
               best_loop / best_sleep, note="bound: one bare virtual-time asyncio.sleep"),
        Figure("emulator.bus_realtime_factor", best_unfused, "sim s/wall s",
               note="same with emulator.fused_bus = false: every I²C transaction of every loop "
                    "through I2CBus.i2c_rdwr"),
        Figure("emulator.idle_realtime_factor", best_idle, "sim s/wall s",
               note="same, arm holding still: cost follows events, not 80 µs cycles"),
        Figure("emulator.slow_line_realtime_factor", best_slow, "sim s/wall s",
               note=f"same at {SLOW_BAUD} baud: the loop waits for the line, so fewer events "
                    f"per simulated second; {best_slow / best_cycle:.0f}× the yardstick below"),
        Figure("emulator.cycle_loop_factor", best_cycle, "sim s/wall s",
               note=f"yardstick of the issue: a plain loop stepping the 80 µs cycle of four "
                    f"joints, no I²C, no UART; the emulator runs at "
                    f"{best_factor / best_cycle:.2f} of it"),
    ]
