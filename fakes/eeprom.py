"""A board's EEPROM: survives power cuts, counts writes and wear per cell.

The firmware stores its joint's motion state and encoder counter on every change among stopped /
moving CW / moving CCW (paper §5.2). Record layout (our choice; the paper gives none), at address 0:
``state`` (uint8: 0 stopped, 1 CW, 2 CCW; 0xFF blank) then ``counter`` (int32, little-endian).
Writes use ``EEPROM.put`` semantics: only cells whose value changes are written (and worn).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Literal

__all__ = ["RATED_CYCLES", "RECORD_ACCESS_ORDER", "Eeprom", "EepromRecord", "Motion",
           "RecordWrites", "record_write_times"]

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


#: The order in which the firmware's record store reads each cell of the record and writes it if
#: it changed: the state, then the counter from its high byte down (``eeprom_update_byte``, then
#: avr-libc's ``eeprom_update_dword``; firmware/joint.c).
RECORD_ACCESS_ORDER = (0, 4, 3, 2, 1)


def record_write_times(written: tuple[int, ...], start_s: float, busy_until_s: float,
                       s_per_byte: float) -> tuple[float, float]:
    """When the firmware's record store started at ``start_s`` returns, and until when the EEPROM
    stays busy, for a record whose cells ``written`` changed (ATmega328P: a byte write runs in
    the background for ``s_per_byte``; every access, read or write, first waits until no write
    runs, EECR.EEPE). So n changed cells stall the code (n − 1) writes when the last cell it
    touches is one of them, n otherwise, and the last write goes on after it returns."""
    t, busy = start_s, busy_until_s
    for address in RECORD_ACCESS_ORDER:
        t = max(t, busy)
        if address in written:
            busy = t + s_per_byte
    return t, busy


class RecordWrites:
    """The records a main loop stored whose write time it has not paid yet (stored by the model
    as they happen; the firmware writes them at its loop's store), and until when the EEPROM is
    busy with the last byte write, which the next record's first access waits for."""

    def __init__(self, s_per_byte: float) -> None:
        self.s_per_byte = s_per_byte
        self.pending: list[tuple[int, ...]] = []
        self.busy_until_s = -math.inf

    def add(self, written: tuple[int, ...]) -> None:
        """A record whose cells ``written`` changed."""
        self.pending.append(written)

    def pay(self, t_s: float) -> float:
        """The loop's record store at ``t_s`` for the pending records: when the loop goes on."""
        for written in self.pending:
            t_s, self.busy_until_s = record_write_times(written, t_s, self.busy_until_s,
                                                        self.s_per_byte)
        self.pending.clear()
        return t_s
