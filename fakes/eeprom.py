"""A board's EEPROM: survives power cuts, counts writes and wear per cell.

The firmware stores its joint's motion state and encoder counter on every change among stopped /
moving CW / moving CCW (paper §5.2). Record layout (our choice; the paper gives none), at address 0:
``state`` (uint8: 0 stopped, 1 CW, 2 CCW; 0xFF blank) then ``counter`` (int32, little-endian).
Writes use ``EEPROM.put`` semantics: only cells whose value changes are written (and worn).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Literal

__all__ = ["RATED_CYCLES", "Eeprom", "EepromRecord", "Motion"]

#: ATmega328P data sheet: 100 000 write/erase cycles per EEPROM cell.
RATED_CYCLES = 100_000

Motion = Literal["stopped", "cw", "ccw"]
_STATE_CODE: dict[Motion, int] = {"stopped": 0, "cw": 1, "ccw": 2}
_CODE_STATE: dict[int, Motion] = {v: k for k, v in _STATE_CODE.items()}
_RECORD = struct.Struct("<Bi")


@dataclass(frozen=True, slots=True)
class EepromRecord:
    """What the firmware finds at power-up; ``None`` fields mean a blank EEPROM."""

    motion: Motion
    counter: int


class Eeprom:
    """1 KiB of cells (ATmega328P), 0xFF when new."""

    def __init__(self, cells: int = 1024) -> None:
        self._cells = bytearray(b"\xff" * cells)
        self._wear = [0] * cells
        self.record_writes = 0
        """How many times the firmware stored its record (one per motion change)."""
        self.cell_writes = 0
        """Cell writes actually performed (changed bytes only)."""
        self.last_written: tuple[int, ...] = ()
        """Addresses of the cells the last :meth:`store` wrote."""

    def store(self, motion: Motion, counter: int) -> int:
        """Store the record; returns how many cells were written (what costs time and wear)."""
        data = _RECORD.pack(_STATE_CODE[motion], max(-(2**31), min(2**31 - 1, counter)))
        written = []
        for i, b in enumerate(data):
            if self._cells[i] != b:
                self._cells[i] = b
                self._wear[i] += 1
                written.append(i)
        self.last_written = tuple(written)
        self.record_writes += 1
        self.cell_writes += len(written)
        return len(written)

    def load(self) -> EepromRecord | None:
        """The stored record, or ``None`` for a blank or unreadable one."""
        code, counter = _RECORD.unpack_from(self._cells, 0)
        motion = _CODE_STATE.get(code)
        return None if motion is None else EepromRecord(motion, counter)

    @property
    def max_cell_wear(self) -> int:
        """Writes endured by the most-worn cell."""
        return max(self._wear)

    def erase(self) -> None:
        """Back to a blank EEPROM (a new board)."""
        n = len(self._cells)
        self._cells[:] = b"\xff" * n
