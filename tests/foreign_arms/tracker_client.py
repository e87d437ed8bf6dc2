"""The tracker of ``tracker_arm.py`` read from the host: a reference instrument beside the serial
link. Its lines (``T t_s x_m y_m z_m q1 q2 q3 q4``, ``t_s`` on CLOCK_MONOTONIC, the clock of the
host's asyncio loop) are collected while the block runs::

    async with TrackerStream(host, port) as tracker:
        ...
    tracker.samples     # [(t_s, x_m, y_m, z_m, q1, q2, q3, q4), ...]
"""

from __future__ import annotations

import asyncio
import contextlib
from types import TracebackType

Sample = tuple[float, float, float, float, float, float, float, float]


class TrackerStream:
    """Collect the tracker's lines in the background (malformed lines are counted, not kept)."""

    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self.samples: list[Sample] = []
        self.malformed = 0
        self._task: asyncio.Task[None] | None = None
        self._writer: asyncio.StreamWriter | None = None

    async def __aenter__(self) -> TrackerStream:
        reader, self._writer = await asyncio.open_connection(self.host, self.port)
        self._task = asyncio.create_task(self._read(reader))
        while not self.samples and not self._task.done():
            await asyncio.sleep(0.005)
        return self

    async def _read(self, reader: asyncio.StreamReader) -> None:
        while line := await reader.readline():
            fields = line.split()
            if len(fields) != 9 or fields[0] != b"T":
                self.malformed += 1
                continue
            v = [float(f) for f in fields[1:]]
            self.samples.append((v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7]))

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        if self._writer is not None:
            self._writer.close()
