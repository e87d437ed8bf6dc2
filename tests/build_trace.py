"""Deterministic fake:// sessions, everything observable of them as JSON: what
``tests/test_compiled.py`` compares between the compiled build of the hot modules and their Python
source (run as a script, it prints the trace of the build its environment selects).

The sessions go through every compiled module: the codec both ways, the boards' main loops with
the bus fused and not, the joints with their physical effects, EEPROM records, power cuts with
start-up recovery (the joints' look-ahead), a noisy line and blocking receive.
"""

from __future__ import annotations

import asyncio
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

from armbench.cli.perf.hot_modules import build_name
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.protocol import Command
from armbench.drivers.model.settings import load_settings
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.arm_emulator import ArmEmulator

SETTINGS = """
[emulator]
uart_receive = "{receive}"
fused_bus = {fused}
i2c_hz = {i2c_hz}

[emulator.effects]
miss_probability = 0.02
miss_above_duty = 40

[emulator.physics]
noise_per_count = 4e-4
{faults}"""
FAULTS = """
[[faults]]
kind = "uart_corrupt"
at_s = 2.0
duration_s = 0.5
probability = 0.01

[[faults]]
kind = "i2c_nak"
joint = 3
at_s = 4.0
duration_s = 0.05
"""

MOVES = (((0.5, 0.4, -0.6, 0.8), 99), ((-0.3, 0.2, 0.5, -0.4), 60),
         ((0.1, -0.2, 0.3, 0.2), (30, 99, 70, 10)), ((0.0, 0.0, 0.0, 0.0), 90))


def every_truth(emulator: ArmEmulator) -> list[Any]:
    """Every truth sample ``emulator`` has delivered and delivers from now on: its history keeps
    only the newest (``TRUTH_HISTORY``), the trace compares them all."""
    samples = list(emulator.truth)
    deliver = emulator.uart.on_delivered
    assert deliver is not None

    def keep(sample: Any) -> None:
        samples.append(sample)
        deliver(sample)

    emulator.uart.on_delivered = keep
    return samples


async def _session(port: str) -> dict[str, Any]:
    async with Arm.connect(port) as arm:
        first = arm.emulator
        assert isinstance(first, ArmEmulator)
        every = every_truth(first)
        with arm.record_states() as states:
            for q, duty in MOVES:  # fixed times, arrived or not (missed steps may keep a joint off)
                await arm.move_joints(q, duty, wait=False)
                await asyncio.sleep(2.5)
            await arm.move_joints((0.6, -0.3, 0.4, -0.5), 99, coordinated=True, wait=False)
            await asyncio.sleep(0.4)
            emulator = arm.emulator
            assert isinstance(emulator, ArmEmulator)
            emulator.power_off()  # mid-move: start-up recovery drives to the Hall sensors
            await asyncio.sleep(0.2)
            emulator.power_on()
            await asyncio.sleep(12.0)
            await arm.stop()
        truth = [(s.t_s, s.true_rad, s.firmware_rad) for s in every]
        return {
            "states": [(s.t_s, s.ticks, s.q_rad, s.seq) for s in states],
            "truth": truth, "stats": emulator.stats().to_json(),
            "counters": (arm.frames_received, arm.frames_dropped, arm.discarded_bytes),
            "eeprom": [bytes(e._cells).hex() for e in emulator.eeproms],
        }


async def _blocking_session(settings: Path) -> dict[str, Any]:
    """The firmware reading commands with a blocking receive says nothing until it gets one: a
    host that sends a command every 20 ms, without the driver."""
    emulator = ArmEmulator(load_settings(settings))
    loop = asyncio.get_running_loop()
    replies: list[tuple[float, str]] = []
    emulator.attach_host(lambda data: replies.append((loop.time(), data.decode("latin-1"))))
    async with emulator:
        every = every_truth(emulator)
        for q, duty in MOVES:
            command = Command.from_rad(q, duty).encode()
            for _ in range(100):
                emulator.host_write(command)
                await asyncio.sleep(0.02)
        return {"replies": replies, "stats": emulator.stats().to_json(),
                "truth": [(s.t_s, s.true_rad, s.firmware_rad) for s in every]}


def trace() -> dict[str, Any]:
    """The sessions' trace (JSON types only), with the build that ran them."""
    out: dict[str, Any] = {"build": build_name(), "modules": {
        name: Path(sys.modules[name].__file__ or "").name
        for name in ("armbench.drivers.model.protocol", "armbench.fakes.firmware.boards",
        "armbench.fakes.twin.joint")}}
    with tempfile.TemporaryDirectory() as tmp:
        for receive, fused, i2c_hz, faults in (("polling", "true", 100_000, ""),
                                               ("polling", "false", 400_000, FAULTS),
                                               ("blocking", "true", 100_000, "")):
            path = Path(tmp) / f"{receive}-{fused}.toml"
            path.write_text(SETTINGS.format(receive=receive, fused=fused, i2c_hz=i2c_hz,
                                            faults=faults), encoding="utf-8")
            session = run_virtual(_blocking_session(path) if receive == "blocking"
                                  else _session(f"fake://?seed=4&settings={path}"))
            out[f"{receive} fused={fused}"] = json.loads(json.dumps(session))
    return out


if __name__ == "__main__":
    print(json.dumps(trace()))
