"""atheris harness: arbitrary bytes on the emulated master's UART, then one valid command.

Each input runs a fresh ``ArmEmulator`` on a fresh virtual-time loop
(``armbench.fakes.clock.vclock``),
so a
crash reproduces from the input alone; about 0.2 s of robot time, a few ms of wall time.

Input layout (``atheris.FuzzedDataProvider``: integers from the end, bytes from the front)::

    <bytes for the UART, at most 1024> <(size, gap) pairs> <n pairs = b % 16> <setup byte>

``size`` is 1 + b % 128 bytes per write, ``gap`` b % 11 ms of virtual time after it (pairs used
cyclically; gaps stop after 80 ms in total). n = 0 writes everything at once. Setup bits pick
the firmware variant: 0 blocking receive, 1 CR LF after replies, 2 400 kHz I²C, 3 a small
receive buffer of 40 bytes (just above a command); bit 4 starts the noise while the boards are
still booting (``emulator.boot_s``: those bytes are lost, as on the real board).

Invariants (any violation is a crash):

* every board boots (runs ``setup()``) within ``boot_s`` + 0.5 s, noise or not;
* no board task ends while the arm has power — an exception inside the firmware is re-raised here
  with its own traceback;
* after the noise, the line drains and the master takes the next valid command: within 100 ms
  (the master's loop may be stalled by EEPROM writes, 16.5 ms per record) all four joints'
  references become the command's; the command is resent at most twice, and only when the
  receive buffer overflowed meanwhile (which loses bytes on a real ATmega328P too);
* the master's loop is still running: a polling master prints another reply within 100 ms;
* the master's framer never discards more bytes than the UART delivered.

Run: ``python fuzz/fuzz_emulator_uart.py -max_total_time=60 -rss_limit_mb=512
fuzz/corpus/emulator_uart``
"""

from __future__ import annotations

import asyncio

import atheris
from _harness import fuzz_main

with atheris.instrument_imports(include=["drivers", "fakes"]):
    from armbench.drivers.model.protocol import Command
    from armbench.drivers.model.settings import RobotSettings
    from armbench.fakes.clock.vclock import run_virtual
    from armbench.fakes.firmware.arm_emulator import ArmEmulator
    from armbench.fakes.firmware.emulator_settings import EmulatorSettings, emulator_settings

MAX_BYTES = 1024
MAX_PAIRS = 15
MAX_GAPS_S = 0.08
SETTLE_S = 0.01
OBEY_S = 0.1  # > the longest EEPROM stall of the master's loop seen (2 records, 33 ms)
POLL_S = 0.005
TRIES = 3

ROBOT = RobotSettings()
#: The command sent after the noise; every joint's target inside its limits, all different.
COMMAND = Command((1234, 2000, 60000, 1500), (60, 45, 30, 99))
COMMAND_WIRE = COMMAND.encode()


def _variant(setup: int) -> EmulatorSettings:
    return emulator_settings(
        ROBOT,
        uart_receive="blocking" if setup & 1 else "polling",
        reply_line_end="\r\n" if setup & 2 else "",
        i2c_hz=400_000 if setup & 4 else 100_000,
        rx_buffer_bytes=40 if setup & 8 else 64,
    )


VARIANTS = [_variant(s) for s in range(16)]


def _raise_task_errors(arm: ArmEmulator) -> None:
    """Re-raise the first board task's exception (retrieving all: no asyncio log noise)."""
    errors = [t.exception() for b in arm.boards
              if (t := b._task) is not None and t.done() and not t.cancelled()]
    for exc in errors:
        if exc is not None:
            raise exc


def _alive(arm: ArmEmulator) -> None:
    for board in arm.boards:
        task = board._task
        assert board.powered and task is not None, f"board {board.number} lost its task"
        if task.done():
            _raise_task_errors(arm)
            raise AssertionError(f"board {board.number}'s task ended")


async def _booted(arm: ArmEmulator, settings: EmulatorSettings) -> None:
    """Wait until every board has run ``setup()`` (bytes sent while the master boots are lost, as
    on the real board); the boot takes ``emulator.boot_s``."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + getattr(settings, "boot_s", 0.0) + 0.5
    while any(b.model is None for b in arm.boards):
        assert loop.time() < deadline, "a board never finished booting"
        await asyncio.sleep(POLL_S)
        _alive(arm)


def _obeyed(arm: ArmEmulator) -> bool:
    refs = [b.reference for b in arm.boards]
    return refs == [(t, d) for t, d in zip(COMMAND.ticks, COMMAND.duties, strict=True)]


async def scenario(settings: EmulatorSettings, writes: list[tuple[bytes, float]],
                   early: bool = False) -> None:
    """Noise (from power-up when ``early``, else once booted), then the command; assert the
    invariants."""
    loop = asyncio.get_running_loop()
    arm = ArmEmulator(ROBOT, settings)
    replies: list[bytes] = []
    arm.attach_host(replies.append)
    await arm.start()
    try:
        if not early:
            await _booted(arm, settings)
        for chunk, gap in writes:
            arm.host_write(chunk)
            if gap > 0:
                await asyncio.sleep(gap)
                _alive(arm)
        await _booted(arm, settings)
        await asyncio.sleep(max(0.0, arm.uart.rx_line_free_s - loop.time()) + SETTLE_S)
        _alive(arm)
        for _ in range(TRIES):
            overflow = arm.uart.rx_overflow_bytes
            arm.host_write(COMMAND_WIRE)
            deadline = loop.time() + OBEY_S
            while not _obeyed(arm) and loop.time() < deadline:
                await asyncio.sleep(POLL_S)
                _alive(arm)
            if _obeyed(arm):
                break
            assert arm.uart.rx_overflow_bytes > overflow, (
                f"the master ignored a valid command without losing bytes: references "
                f"{[b.reference for b in arm.boards]}, {arm.stats()}")
        else:
            raise AssertionError(f"command lost {TRIES} times to receive-buffer overflow")
        if settings.uart_receive == "polling":  # a blocking master replies only to commands
            seen = len(replies)
            deadline = loop.time() + OBEY_S  # an EEPROM write may stall the loop meanwhile
            while len(replies) == seen:
                assert loop.time() < deadline, "the master stopped replying"
                await asyncio.sleep(POLL_S)
                _alive(arm)
        framer = arm.master.framer
        assert framer.discarded_bytes <= arm.uart.rx_bytes, (framer.discarded_bytes,
                                                            arm.uart.rx_bytes)
    finally:
        await arm.close()


def plan(data: bytes) -> tuple[EmulatorSettings, list[tuple[bytes, float]], bool]:
    """The firmware variant, the timed writes and the early flag an input stands for."""
    fdp = atheris.FuzzedDataProvider(data)
    setup = fdp.ConsumeIntInRange(0, 31)
    settings, early = VARIANTS[setup & 15], bool(setup & 16)
    n = fdp.ConsumeIntInRange(0, MAX_PAIRS)
    pairs = [(fdp.ConsumeIntInRange(1, 128), fdp.ConsumeIntInRange(0, 10) / 1000)
             for _ in range(n)]
    stream = fdp.ConsumeBytes(min(fdp.remaining_bytes(), MAX_BYTES))
    if not pairs:
        return settings, [(stream, 0.0)] if stream else [], early
    writes: list[tuple[bytes, float]] = []
    pos = k = 0
    budget = MAX_GAPS_S
    while pos < len(stream):
        size, gap = pairs[k % len(pairs)]
        gap = min(gap, budget)
        budget -= gap
        writes.append((stream[pos:pos + size], gap))
        pos += size
        k += 1
    return settings, writes, early


def test_one_input(data: bytes) -> None:
    settings, writes, early = plan(data)
    run_virtual(scenario(settings, writes, early))


if __name__ == "__main__":
    fuzz_main("emulator_uart", test_one_input)
