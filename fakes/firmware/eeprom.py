"""A board's EEPROM: survives power cuts, counts writes and wear per cell.

The firmware stores its joint's motion state and encoder counter on every change among stopped /
moving CW / moving CCW (paper §5.2). Record layout (our choice; the paper gives none), at address 0:
``state`` (uint8: 0 stopped, 1 CW, 2 CCW; 0xFF blank) then ``counter`` (int32, little-endian).
Writes use ``EEPROM.put`` semantics: only cells whose value changes are written (and worn).

The firmware writes a record cell by cell, 3.3 ms a changed byte, so a power cut in the middle of
a record leaves it torn: the cells written before the cut hold the new record, the others the old
one. The model stores a record at once and keeps, for each cell it changed, the time the
firmware's write of it starts (:func:`record_write_times`, given when known); :meth:`Eeprom.cut`
takes back every cell whose write starts after the cut.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Literal

__all__ = ["RATED_CYCLES", "RECORD_ACCESS_ORDER", "RECORD_BYTES", "Eeprom", "EepromRecord",
           "Motion", "RecordWrites", "decode_record", "record_write_times"]

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


#: The record's size in cells, from address 0.
RECORD_BYTES = _RECORD.size


def decode_record(cells: bytes | bytearray) -> EepromRecord | None:
    """The record at the start of ``cells``, or ``None`` for a blank or unreadable one (the
    firmware's start-up takes a state beyond CCW for a blank EEPROM)."""
    code, counter = _RECORD.unpack_from(cells, 0)
    motion = _CODE_STATE.get(code)
    return None if motion is None else EepromRecord(motion, counter)


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
        self._unlanded: list[list[float]] = []
        """The cells stored whose write may start after a power cut, oldest first: [start time
        (``inf`` until :meth:`land` gives it), address, value before, value written]."""
        self.write_log: list[tuple[float, int, int]] | None = None
        """If a list: each cell write as :meth:`land` times it, (start time, address, value),
        also those a power cut then takes back (what the differential check compares)."""

    def store(self, motion: Motion, counter: int) -> int:
        """Store the record; returns how many cells were written (what costs time and wear)."""
        data = _RECORD.pack(_STATE_CODE[motion], max(-(2**31), min(2**31 - 1, counter)))
        written = []
        unlanded = self._unlanded
        for i in RECORD_ACCESS_ORDER:
            b = data[i]
            if self._cells[i] != b:
                unlanded.append([math.inf, i, self._cells[i], b])
                self._cells[i] = b
                self._wear[i] += 1
                written.append(i)
        if len(unlanded) > 2 * _UNLANDED_KEPT:
            del unlanded[:-_UNLANDED_KEPT]
        self.last_written = tuple(written)
        self.record_writes += 1
        self.cell_writes += len(written)
        return len(written)

    def land(self, starts_s: list[float]) -> None:
        """The times the writes of the oldest stored cells without one start, in their order."""
        k = 0
        log = self.write_log
        for entry in self._unlanded:
            if k == len(starts_s):
                break
            if entry[0] == math.inf:
                entry[0] = starts_s[k]
                k += 1
                if log is not None:
                    log.append((entry[0], int(entry[1]), int(entry[3])))

    def cut(self, t_s: float) -> int:
        """Power cut at ``t_s``: every stored cell whose write would start later (or has no time
        yet) is taken back, newest first, and neither written nor worn; returns how many."""
        unlanded = self._unlanded
        undone = 0
        while unlanded:
            start_s, address, before, _ = unlanded.pop()
            if start_s > t_s:
                i = int(address)
                self._cells[i] = int(before)
                self._wear[i] -= 1
                self.cell_writes -= 1
                undone += 1
        return undone

    def read(self, address: int, n: int) -> bytes:
        """``n`` cells from ``address``, as they are."""
        return bytes(self._cells[address:address + n])

    def load(self) -> EepromRecord | None:
        """The stored record, or ``None`` for a blank or unreadable one."""
        return decode_record(self._cells)

    @property
    def max_cell_wear(self) -> int:
        """Writes endured by the most-worn cell."""
        return max(self._wear)

    def erase(self) -> None:
        """Back to a blank EEPROM (a new board)."""
        n = len(self._cells)
        self._cells[:] = b"\xff" * n
        self._unlanded.clear()


#: The order in which the firmware's record store reads each cell of the record and writes it if
#: it changed: the state, then the counter from its high byte down (``eeprom_update_byte``, then
#: avr-libc's ``eeprom_update_dword``; firmware/joint.c).
RECORD_ACCESS_ORDER = (0, 4, 3, 2, 1)

#: The newest cells kept for :meth:`Eeprom.cut`: one after the other at 3.3 ms a cell, 32 cells
#: reach further ahead of the older ones than the model runs ahead of the time of a power cut.
_UNLANDED_KEPT = 32


def record_write_times(written: tuple[int, ...], start_s: float, busy_until_s: float,
                       s_per_byte: float,
                       starts_s: list[float] | None = None) -> tuple[float, float]:
    """When the firmware's record store started at ``start_s`` returns, and until when the EEPROM
    stays busy, for a record whose cells ``written`` changed (ATmega328P: a byte write runs in
    the background for ``s_per_byte``; every access, read or write, first waits until no write
    runs, EECR.EEPE). So n changed cells stall the code (n − 1) writes when the last cell it
    touches is one of them, n otherwise, and the last write goes on after it returns. The time
    each write starts (when the chip takes the byte), in the access order, is appended to
    ``starts_s`` if given."""
    t, busy = start_s, busy_until_s
    for address in RECORD_ACCESS_ORDER:
        t = max(t, busy)
        if address in written:
            busy = t + s_per_byte
            if starts_s is not None:
                starts_s.append(t)
    return t, busy


class RecordWrites:
    """The records a main loop stored whose write time it has not paid yet (stored by the model
    as they happen; the firmware writes them at its loop's store), and until when the EEPROM is
    busy with the last byte write, which the next record's first access waits for. Paying gives
    ``eeprom`` the times its cells are written (:meth:`Eeprom.land`), save for records added as
    already landed (written before the main loop ran, their stall still paid by its first
    store)."""

    def __init__(self, s_per_byte: float, eeprom: Eeprom | None = None) -> None:
        self.s_per_byte = s_per_byte
        self.eeprom = eeprom
        self.pending: list[tuple[tuple[int, ...], bool]] = []
        self.busy_until_s = -math.inf

    def add(self, written: tuple[int, ...], landed: bool = False) -> None:
        """A record whose cells ``written`` changed; ``landed``: their write times are known."""
        self.pending.append((written, landed))

    def pay(self, t_s: float) -> float:
        """The loop's record store at ``t_s`` for the pending records: when the loop goes on."""
        eeprom = self.eeprom
        for written, landed in self.pending:
            starts: list[float] | None = None if landed or eeprom is None else []
            t_s, self.busy_until_s = record_write_times(written, t_s, self.busy_until_s,
                                                        self.s_per_byte, starts)
            if starts is not None and eeprom is not None:
                eeprom.land(starts)
        self.pending.clear()
        return t_s
