"""The block of a capture part being filled: its records as three columns, and the reply the
driver's per-reply path writes into it.

Compiled (``cli/perf/hot_modules.py``): a link on ``fake://`` hands its part hundreds of
replies a second and a campaign millions, and compiled a reply costs three list appends and a
comparison in C. What a block is on disk, and when one is due, is
:class:`~armbench.drivers.capture.part.PartWriter`'s.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

__all__ = ["IN_FLAG", "OpenBlock"]

#: Flag of a record from the arm to the host (the other bits are the writer's).
IN_FLAG: Final = 1


class OpenBlock:
    """The records of the open block, oldest first: times (seconds since ``t0_s``), flags and
    frames. A reply at or after :attr:`due_s`, or one that fills the block to ``batch_records``,
    is handed to ``due`` with its loop time (a new truth slot, a block to write)."""

    def __init__(self, t0_s: float, batch_records: int, due: Callable[[float], None]) -> None:
        self.t0_s = t0_s
        self.batch_records = batch_records
        self.due = due
        self.due_s = float("-inf")
        """Loop time from which a reply calls ``due``."""
        self.times: list[float] = []
        self.flags: list[int] = []
        self.frames: list[bytes] = []

    def reply(self, t_s: float, data: bytes) -> None:
        """A valid reply ``data``, read at loop time ``t_s``."""
        self.times.append(t_s - self.t0_s)
        self.frames.append(data)
        self.flags.append(IN_FLAG)
        if t_s >= self.due_s or len(self.frames) >= self.batch_records:
            self.due(t_s)

    def add(self, t_s: float, flag: int, data: bytes) -> None:
        """Any other record: ``data`` at loop time ``t_s`` with ``flag``."""
        self.times.append(t_s - self.t0_s)
        self.frames.append(data)
        self.flags.append(flag)

    def take(self) -> tuple[list[float], list[int], list[bytes]]:
        """The records so far (times, flags, frames); the block starts empty again."""
        columns = self.times, self.flags, self.frames
        self.times, self.flags, self.frames = [], [], []
        return columns
