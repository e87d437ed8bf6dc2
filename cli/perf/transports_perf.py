"""Serial transport throughput over a pty: pyserial-asyncio-fast (0.16) vs pyserial-asyncio (0.6).

A round trip is what the driver does every control cycle: write one 37-byte command, wait for the
25-byte reply. The far end of the pty is an echo peer in a child process (blocking ``os.read`` /
``os.write``), so ``time.process_time`` of this process is the host side's CPU alone.

Figures (``unit`` round trips per second, best of ``repeats``):

* ``transport.pty_roundtrips_fast`` — ``serial_asyncio_fast.open_serial_connection``
* ``transport.pty_roundtrips_classic`` — ``serial_asyncio.open_serial_connection`` (left out
  when pyserial-asyncio, a test extra, is not installed)

``bound`` is the same round trip with blocking ``os.write``/``os.read`` on the pty slave (no
asyncio, no pyserial): the ceiling a transport could reach on this machine. Each figure's note
gives the CPU time per round trip in µs (lower is better), measured in the same best run.
"""

from __future__ import annotations

import asyncio
import contextlib
import importlib
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from armbench.cli.perf import Figure, PerfOptions
from armbench.drivers.model.protocol import Command, Reply

__all__ = ["PACKAGES", "RoundTripRate", "echo_pty", "measure_bare", "measure_package", "run"]

#: Figure suffix → module providing ``open_serial_connection``.
PACKAGES: dict[str, str] = {"fast": "serial_asyncio_fast", "classic": "serial_asyncio"}

COMMAND = Command.from_rad([0.1, 0.2, 0.3, 0.4], 50).encode()
REPLY = Reply.from_rad([0.1, 0.2, 0.3, 0.4]).encode()

_PEER = r"""
import os, sys
fd, need, reply = int(sys.argv[1]), int(sys.argv[2]), bytes.fromhex(sys.argv[3])
pending = 0
while True:
    try:
        chunk = os.read(fd, 4096)
    except OSError:
        break
    if not chunk:
        break
    pending += len(chunk)
    while pending >= need:
        pending -= need
        os.write(fd, reply)
"""


@dataclass(frozen=True, slots=True)
class RoundTripRate:
    """One timed run: round trips per second (wall clock) and CPU µs per round trip."""

    rate_per_s: float
    cpu_us: float


@contextlib.contextmanager
def echo_pty() -> Iterator[str]:
    """A pty whose master is served by an echo peer process: every 37 bytes written to the slave
    are answered with one 25-byte reply. Yields the slave's path (POSIX only)."""
    import tty  # POSIX: imported by the figure that needs a pty

    master, slave = os.openpty()
    tty.setraw(slave)
    proc = subprocess.Popen(
        [sys.executable, "-c", _PEER, str(master), str(len(COMMAND)), REPLY.hex()],
        pass_fds=(master,))
    os.close(master)
    try:
        yield os.ttyname(slave)  # ``slave`` stays open so the peer never sees EIO between runs
    finally:
        proc.kill()
        proc.wait()
        os.close(slave)


async def _roundtrips(reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                      count: int) -> None:
    need = len(REPLY)
    for _ in range(count):
        writer.write(COMMAND)
        await writer.drain()
        got = 0
        while got < need:
            chunk = await reader.read(4096)
            if not chunk:
                raise ConnectionError("pty closed during the benchmark")
            got += len(chunk)


async def _measure_async(module: Any, path: str, count: int) -> RoundTripRate:
    loop = asyncio.get_running_loop()
    reader, writer = await module.open_serial_connection(loop=loop, url=path, baudrate=115200)
    try:
        await _roundtrips(reader, writer, max(10, count // 20))  # warm up
        cpu0, t0 = time.process_time(), loop.time()
        await _roundtrips(reader, writer, count)
        wall, cpu = loop.time() - t0, time.process_time() - cpu0
    finally:
        writer.close()
        with contextlib.suppress(OSError, TimeoutError):
            async with asyncio.timeout(2.0):
                await writer.wait_closed()
    return RoundTripRate(count / wall, cpu / count * 1e6)


def measure_package(module_name: str, path: str, count: int) -> RoundTripRate:
    """``count`` round trips through ``module_name.open_serial_connection`` on ``path``."""
    module = importlib.import_module(module_name)
    return asyncio.run(_measure_async(module, path, count))


def measure_bare(path: str, count: int) -> RoundTripRate:
    """``count`` round trips with blocking ``os.write``/``os.read`` on ``path`` (the bound)."""
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
    try:
        need = len(REPLY)
        for timed in (False, True):
            n = count if timed else max(10, count // 20)
            cpu0, t0 = time.process_time(), time.perf_counter()
            for _ in range(n):
                os.write(fd, COMMAND)
                got = 0
                while got < need:
                    got += len(os.read(fd, 4096))
            wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    finally:
        os.close(fd)
    return RoundTripRate(count / wall, cpu / count * 1e6)


def _available(module_name: str) -> bool:
    try:
        importlib.import_module(module_name)
    except ImportError:
        return False
    return True


def run(options: PerfOptions) -> list[Figure]:
    """Measure ``transport.pty_roundtrips_fast`` and ``transport.pty_roundtrips_classic``."""
    count = 400 if options.quick else 3000
    names = [name for name, module in PACKAGES.items() if _available(module)]
    best: dict[str, RoundTripRate] = {}

    def keep(key: str, m: RoundTripRate) -> None:
        if key not in best or m.rate_per_s > best[key].rate_per_s:
            best[key] = m

    with echo_pty() as path:
        for _ in range(options.repeats):  # interleave so all see the same machine load
            keep("bare", measure_bare(path, count))
            for name in names:
                keep(name, measure_package(PACKAGES[name], path, count))
    bare = best["bare"]
    figures = []
    for name in PACKAGES:
        fig_name = f"transport.pty_roundtrips_{name}"
        if name not in best:  # pyserial-asyncio is a test extra; no figure rather than a 0
            continue
        m = best[name]
        figures.append(Figure(
            fig_name, m.rate_per_s, "roundtrips/s", bare.rate_per_s, m.rate_per_s / bare.rate_per_s,
            note=f"{m.cpu_us:.1f} µs CPU per round trip; blocking os.read/os.write "
                 f"{bare.cpu_us:.1f} µs"))
    return figures
