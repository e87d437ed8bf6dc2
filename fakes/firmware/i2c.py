"""A simulated I²C bus with smbus2's call shape, and the register layout the boards share.

The master calls ``bus.i2c_rdwr(*msgs)`` with messages of ``smbus2.i2c_msg``'s layout
(:mod:`armbench.fakes.firmware.i2c_messages`) exactly as it would on a real ``smbus2.SMBus``: the
call is synchronous, fills read buffers, and raises ``OSError`` with ``EREMOTEIO`` when a slave does
not
acknowledge its address (what Linux i2c-dev reports) or ``EIO`` on a bus error. Time is the bus's
``clock``: each transaction advances it by what the bus speed implies (start, 9 bits per byte with
the acknowledge, stop, repeated starts), so the master's loop takes as long as it would on the
wire without an ``await`` per transaction.

Register layout (``docs/i2c.md``; the paper gives none). Little-endian, one pointer per slave:

=========  ====  ======  ===================================================================
register   addr  access  content
=========  ====  ======  ===================================================================
REFERENCE  0x01  write   target position (uint16 wire ticks, as on the UART) + duty (uint8)
POSITION   0x02  read    current position (uint16 wire ticks, from the encoder counter)
STATUS     0x03  read    bit0 moving, bit1 moving CW, bit2 recovering, bit3 recovery stalled
                         at a limit, bit4 initialised
WHO_AM_I   0x04  read    0xA0 | joint number
=========  ====  ======  ===================================================================

A write's first byte sets the pointer; a read returns from the pointer and leaves it on POSITION,
so the master's per-loop traffic is one 4-byte write and one 2-byte read per slave.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final, Protocol

from armbench.fakes.firmware.i2c_messages import I2C_M_RD, I2CMessage

__all__ = [
    "I2C_M_RD",
    "REG_POSITION",
    "REG_REFERENCE",
    "REG_STATUS",
    "REG_WHO_AM_I",
    "BusClock",
    "I2CBus",
    "I2CDevice",
    "I2CStats",
    "transaction_bits",
]

# Final: compiled code reads them as constants, not through the module's dictionary
REG_REFERENCE: Final = 0x01
REG_POSITION: Final = 0x02
REG_STATUS: Final = 0x03
REG_WHO_AM_I: Final = 0x04


class I2CDevice(Protocol):
    """A slave as the bus sees it: the handlers Arduino's Wire library calls in its ISR."""

    def on_receive(self, data: bytes, t_s: float) -> None:
        """The master wrote ``data`` (first byte: register); ``t_s`` is the end of the write."""

    def on_request(self, length: int, t_s: float) -> bytes:
        """The master reads ``length`` bytes at ``t_s``; the bus pads a short answer with 0xFF."""
        ...


class BusClock:
    """The master's notion of now, in seconds, advanced by its own work (I²C, EEPROM, CPU)."""

    __slots__ = ("now",)

    def __init__(self, now: float = 0.0) -> None:
        self.now = now


@dataclass(slots=True)
class I2CStats:
    """What crossed the bus."""

    transactions: int = 0
    bytes: int = 0
    naks: int = 0
    bus_errors: int = 0


def transaction_bits(msgs: tuple[I2CMessage, ...]) -> int:
    """Bit times of one combined transaction: START, then per message the address byte and data
    bytes (9 bits each with ACK), a repeated START between messages, and a STOP."""
    bits = 1
    for m in msgs:
        bits += 9 * (1 + m.len) + 1
    return bits


class I2CBus:
    """The shared bus between the master (joint 1) and the slaves (joints 2–4)."""

    def __init__(self, clock: BusClock, bit_s: float) -> None:
        self.clock = clock
        self.bit_s = bit_s
        self.stats = I2CStats()
        self._devices: dict[int, I2CDevice] = {}
        self.fault: Callable[[int, float], int] | None = None
        """Fault hook: ``(address, t_s) -> errno`` (0 for none); set by fault injection."""

    def attach(self, address: int, device: I2CDevice) -> None:
        """Connect a slave at a 7-bit address (Wire.begin(address))."""
        if not 0x08 <= address <= 0x77:
            raise ValueError(f"address: 0x{address:02x} is not a 7-bit slave address")
        self._devices[address] = device

    def detach(self, address: int) -> None:
        """Disconnect a slave (powered off or reset); it NAKs from now on."""
        self._devices.pop(address, None)

    def scan(self) -> list[int]:
        """Addresses that acknowledge, as ``i2cdetect`` would find them (costs bus time)."""
        found = []
        for address in range(0x08, 0x78):
            try:
                self.i2c_rdwr(I2CMessage.write(address, b""))
            except OSError:
                continue
            found.append(address)
        return found

    def i2c_rdwr(self, *msgs: I2CMessage) -> None:
        """Run a combined transaction, as ``smbus2.SMBus.i2c_rdwr`` does."""
        bit_s = self.bit_s
        clock = self.clock
        now = clock.now + bit_s  # START
        stats = self.stats
        stats.transactions += 1
        fault = self.fault
        devices = self._devices
        for m in msgs:
            address = m.addr
            device = devices.get(address)
            code = 0 if fault is None else fault(address, now)
            if code or device is None:
                clock.now = now + 10 * bit_s  # address byte, NAK, STOP
                if code == errno.EIO:
                    stats.bus_errors += 1
                else:
                    stats.naks += 1
                    code = errno.EREMOTEIO
                raise OSError(code, f"{os.strerror(code)} (I²C address 0x{address:02x})")
            length = m.len
            now += (9 * length + 10) * bit_s  # address + data bytes with ACKs, repeated START
            stats.bytes += length
            if m.flags & I2C_M_RD:
                data = device.on_request(length, now)
                buf = m.buf
                if length == 2 and len(data) == 2:  # the master's position read: hot
                    buf[0] = data[0]
                    buf[1] = data[1]
                    continue
                if len(data) != length:  # a short answer reads as 0xFF (the idle bus level)
                    data = data[:length].ljust(length, b"\xff")
                for i in range(length):
                    buf[i] = data[i]
            else:
                device.on_receive(m.buf[:length], now)
        clock.now = now  # the last bit time above is the STOP
