"""The messages of a combined I²C transaction: the Linux kernel's ``struct i2c_msg`` in ctypes, with
the constructors of smbus2's ``i2c_msg``.

The emulated master builds its transactions exactly as it would for ``smbus2.SMBus.i2c_rdwr`` on a
real bus, but smbus2 imports ``fcntl`` (for the ioctl) and so cannot be imported on Windows; the
emulator needs the message layout only. A real bus (``armbench i2c scan --bus N``) takes smbus2's
own class, which has this layout.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from ctypes import POINTER, Structure, c_char, c_uint16, create_string_buffer, string_at

__all__ = ["I2C_M_RD", "I2CMessage"]

#: ``flags`` of a read message (``I2C_M_RD`` of ``linux/i2c.h``).
I2C_M_RD = 0x0001


class I2CMessage(Structure):
    """One message: ``addr`` (7-bit), ``flags`` (:data:`I2C_M_RD` or 0), ``len`` bytes at
    ``buf``."""

    _fields_ = (("addr", c_uint16), ("flags", c_uint16), ("len", c_uint16),
                ("buf", POINTER(c_char)))

    def __iter__(self) -> Iterator[int]:
        """The message's bytes as ints (what a read filled in)."""
        return iter(string_at(self.buf, self.len))

    def __len__(self) -> int:
        return int(self.len)

    def __bytes__(self) -> bytes:
        return string_at(self.buf, self.len)

    @staticmethod
    def read(address: int, length: int) -> I2CMessage:
        """A read of ``length`` bytes from ``address``."""
        return I2CMessage(addr=address, flags=I2C_M_RD, len=length,
                          buf=create_string_buffer(length))

    @staticmethod
    def write(address: int, data: bytes | Iterable[int]) -> I2CMessage:
        """A write of ``data`` to ``address``."""
        payload = bytes(data)
        return I2CMessage(addr=address, flags=0, len=len(payload),
                          buf=create_string_buffer(payload, len(payload)))
