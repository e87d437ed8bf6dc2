"""The firmware in the loop, measured: the harness's speed and the firmware's own timing.

The workload: the reference firmware on four simulated ATmega328P at full harness speed for
``SIM_S`` simulated seconds, the arm moving (all four joints at duty 99 towards far poses, then
back), the master replying every loop. Figures (``docs/firmware.md``):

- ``firmware.realtime_factor``: simulated seconds per wall second (must stay above 1 to serve a
  client in real time; the bound is 1);
- ``firmware.isr_worst_cycles``: the 80 µs interrupt's worst case over the four boards, against
  its 1 280-cycle budget at 16 MHz;
- ``firmware.loop_period_ms``: the master's main-loop period (mean; max in the note);
- ``firmware.i2c_transaction_us``: mean I²C transaction time (min and max in the note);
- ``firmware.uart_rx_overflows``: bytes the firmware's 64-byte receive buffer dropped.
"""

from __future__ import annotations

import json
import logging
import subprocess
import tempfile
import time
from pathlib import Path

from armbench.cli.perf import Figure, PerfOptions
from armbench.drivers.model.protocol import Command
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.avr.harness import HARNESS_NAME, FirmwareError, board_specs, build, find_images

__all__ = ["run"]

log = logging.getLogger("armbench.perf")

SIM_S = 6.0
POSES = ([1.2, 0.9, -1.2, 1.5], [-1.2, -0.6, 0.8, -0.4])
CYCLE_BUDGET = 1280


def _measure(sim_s: float) -> tuple[float, dict[str, object]]:
    folder = build()
    robot = RobotSettings()
    with tempfile.TemporaryDirectory() as tmp:
        script = Path(tmp, "script.txt")
        script.write_text(f"0.2 {Command.from_rad(POSES[0], 99).encode().decode()}\n"
                          f"{sim_s / 2:.3f} {Command.from_rad(POSES[1], 99).encode().decode()}\n")
        args = [str(folder / HARNESS_NAME), "--speed", "max", "--seconds", str(sim_s),
                "--script", str(script)]
        for spec in board_specs(robot, find_images(None)):
            args += ["--board", spec]
        start = time.perf_counter()
        out = subprocess.run(args, stdin=subprocess.DEVNULL, capture_output=True, text=True,
                             check=True, timeout=600).stdout
        wall = time.perf_counter() - start
    line = next(x for x in out.splitlines() if x.startswith("stats "))
    stats: dict[str, object] = json.loads(line[6:])
    return wall, stats


def run(options: PerfOptions) -> list[Figure]:
    """The figures above, best realtime factor of ``options.repeats`` runs (1 when quick)."""
    try:
        build()
    except FirmwareError as exc:
        log.warning("firmware figures skipped: %s", exc)
        return []
    sim_s = 2.0 if options.quick else SIM_S
    best_wall, stats = _measure(sim_s)
    for _ in range(1 if options.quick else max(0, options.repeats - 1)):
        wall, s = _measure(sim_s)
        if wall < best_wall:
            best_wall, stats = wall, s
    boards = stats["boards"]
    uart = stats["uart"]
    i2c = stats["i2c"]
    assert isinstance(boards, list) and isinstance(uart, dict) and isinstance(i2c, dict)
    worst = max(int(b["isr_worst_cycles"]) for b in boards)
    steps = sum(int(b["steps"]) for b in boards)
    fw = boards[0].get("fw", {})
    return [
        Figure("firmware.realtime_factor", sim_s / best_wall, "sim s/s", bound=1.0,
               ratio=sim_s / best_wall,
               note=f"4 boards, arm moving ({steps} steps in {sim_s:g} s)"),
        Figure("firmware.isr_worst_cycles", worst, "cycles", bound=CYCLE_BUDGET,
               ratio=worst / CYCLE_BUDGET, note="80 µs control interrupt, worst of 4 boards"),
        Figure("firmware.loop_period_ms", float(uart["period_us_mean"]) / 1e3, "ms",
               note=f"max {float(uart['period_us_max']) / 1e3:.2f} ms (EEPROM records)"),
        Figure("firmware.i2c_transaction_us", float(i2c["us_mean"]), "µs",
               note=f"min {i2c['us_min']}, max {i2c['us_max']}, {i2c['transactions']} "
                    f"transactions, {i2c['naks']} NAKs"),
        Figure("firmware.uart_rx_overflows", float(fw.get("rx_overflows", 0)), "bytes",
               note="the firmware's 64-byte receive buffer"),
    ]
