"""Local serial port (``/dev/ttyUSB0``, ``/dev/ttyACM0``, ``COM3``, a pty's ``/dev/pts/N``) via
pyserial-asyncio-fast.

pyserial-asyncio-fast was chosen over pyserial-asyncio 0.6 on measured figures (see
``docs/transports.md`` and ``cli/perf/transports_perf.py``). The port is opened with the baud rate,
data bits, parity and stop bits of :class:`~armbench.drivers.model.settings.SerialSettings`;
modem-control ioctls that a pty does not support are ignored by pyserial. A Linux pty keeps baud
rate and stop
bits but forces 8 data bits without parity, and glibc then reports the second ``tcsetattr``
pyserial makes as EINVAL: on a pty use 8N1/8N2 (any baud rate); real UARTs take every setting.

The port is held exclusively (pyserial's ``exclusive``: an advisory ``flock`` on POSIX): a second
armbench, or any program that locks the same way, is refused with :data:`IN_USE` instead of
sharing the line. Two readers of one port each get part of the replies, and pyserial then
reports the other's reads as a lost device ("readiness to read but returned no data").

A pty ends with its far end, and the kernel gives its number to the next pty anyone opens. A
reconnection (:meth:`SerialTransport.follow`) therefore does not open a new pty under the lost
one's ``/dev/pts/N``, nor through a symbolic link older than the pty it now leads to (a link a
killed emulator left behind): that pty belongs to another program, and opening it would hold
that program's port and read its bytes. A link made for the new pty (an emulator restarted with
``--link``) is followed.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import stat
from dataclasses import dataclass
from typing import Any

from armbench.drivers.model.errors import TransportError
from armbench.drivers.model.settings import SerialSettings
from armbench.drivers.model.user_files import file_kind
from armbench.drivers.transports.base import Transport
from armbench.drivers.transports.streams import StreamTransport

__all__ = ["IN_USE", "NO_DEVICE", "OPEN_TIMEOUT_S", "PTY_TAKEN", "PtyIdentity", "SerialTransport",
           "check_device", "pyserial_settings"]

OPEN_TIMEOUT_S = 5.0
"""Seconds :meth:`SerialTransport.open` waits for the device to open (USB adapters can be slow)."""

#: Why a device name that names nothing is refused, with where to look.
NO_DEVICE = ("no such serial device (is the arm plugged in? 'python3 -m serial.tools.list_ports' "
             "lists the ports)")

#: Why a port another process holds is refused.
IN_USE = ("is in use by another program (it holds the port's lock; two programs reading one "
          "port would each get part of the replies)")

#: Why a reconnection does not open the pty now under the lost one's name.
PTY_TAKEN = ("now leads to a new pty that took the lost one's number (a pty ends with its far "
             "end and the kernel gives the number to the next pty opened): it belongs to "
             "another program and is not opened")

#: The controlling terminal of whoever runs armbench: a terminal, never an arm.
CONTROLLING_TERMINAL = "/dev/tty"

PTY_SLAVE_MAJORS = range(136, 144)
"""Device major numbers of Unix 98 pty slaves (``/dev/pts/N``; the kernel's
``Documentation/admin-guide/devices.txt``)."""


@dataclass(frozen=True)
class PtyIdentity:
    """Which pty a port name leads to: the pty node's device and inode numbers and its change
    time in ns, which a new pty of the same number does not share, and the change time of the
    symbolic link the name is (None when it is no link). Change times come from the kernel's
    coarse clock (a few ms): a link made for a pty is never older than it, a link left behind
    by a killed emulator is older than the pty that took its number later."""

    node: tuple[int, int]
    ctime_ns: int
    link_ctime_ns: int | None

    @classmethod
    def of(cls, port: str) -> PtyIdentity | None:
        """The identity of the pty ``port`` leads to; None for anything but a pty slave (or a
        name that leads nowhere)."""
        if os.name != "posix":
            return None
        try:
            node = os.stat(port)
            name = os.lstat(port)
        except (OSError, ValueError):
            return None
        if not stat.S_ISCHR(node.st_mode) or os.major(node.st_rdev) not in PTY_SLAVE_MAJORS:
            return None
        return cls((node.st_rdev, node.st_ino), node.st_ctime_ns,
                   name.st_ctime_ns if stat.S_ISLNK(name.st_mode) else None)

    def taken_by(self, now: PtyIdentity | None) -> bool:
        """Whether ``now``, what the name leads to after this pty was lost, is another program's
        pty: a different pty node reached directly, or through a link older than it."""
        return (now is not None and (now.node, now.ctime_ns) != (self.node, self.ctime_ns)
                and (now.link_ctime_ns is None or now.link_ctime_ns < now.ctime_ns))


def check_device(port: str) -> None:
    """Refuse, naming it, a device name that cannot be a serial port, found by looking at it
    without opening it: a name that names nothing (or is too long to name anything), anything
    but a character device (a regular file, a FIFO, a directory) and the controlling terminal.
    POSIX only: ``COM3`` names no file."""
    if os.name != "posix":
        return
    try:
        mode = os.stat(port).st_mode
    except FileNotFoundError:
        raise TransportError(port, NO_DEVICE) from None
    except ValueError:  # a NUL byte
        raise TransportError(port, "is not a device name (it holds a NUL character)") from None
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            raise TransportError(port, f"no such serial device: a name of {len(port)} "
                                       "characters is longer than a file name may be") from None
        raise TransportError(port, f"cannot be looked at: {exc.strerror or exc}") from None
    if not stat.S_ISCHR(mode):
        raise TransportError(port, f"is {file_kind(mode)}, not a serial device (a character "
                                   "device such as /dev/ttyUSB0)")
    if os.path.realpath(port) == CONTROLLING_TERMINAL:
        raise TransportError(port, "is the controlling terminal of this process, not a serial "
                                   "device")


def _is_terminal(port: str) -> bool:
    """Whether the device ``port`` is a terminal (True when it cannot be told): asked only once
    opening it failed, so the failure can say that /dev/null or /dev/zero is no serial port."""
    if os.name != "posix":
        return True
    try:
        fd = os.open(port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except OSError:
        return True
    try:
        return os.isatty(fd)
    finally:
        os.close(fd)



def _open_errors() -> tuple[type[Exception], ...]:
    """What opening a port may raise: pyserial lets ``termios.error`` out of ``open()`` on POSIX
    (imported here, not at start: the module loads on every system)."""
    errors: tuple[type[Exception], ...] = (OSError, ValueError)
    with contextlib.suppress(ImportError):
        import termios

        errors += (termios.error,)
    return errors


def pyserial_settings(settings: SerialSettings) -> dict[str, Any]:
    """The ``serial.Serial`` keyword arguments of ``settings`` (baudrate in bit/s). pyserial's
    stop-bit constants are the numbers 1, 1.5 and 2 themselves."""
    return {
        "baudrate": settings.baudrate,
        "bytesize": settings.bytesize,
        "parity": settings.parity,
        "stopbits": settings.stopbits,
    }


class SerialTransport(StreamTransport):
    """A local serial device. EOF, EIO (a pty whose other end closed) or a vanished USB device
    while open is a :class:`PortLostError`."""

    scheme = ""
    eof_reason = "device closed (end of file)"

    def __init__(self, port: str, serial: SerialSettings, *,
                 open_timeout_s: float = OPEN_TIMEOUT_S) -> None:
        super().__init__(port, serial)
        self.open_timeout_s = open_timeout_s
        """Seconds :meth:`open` waits for the device."""
        self.pty: PtyIdentity | None = None
        """The pty the port led to when it opened (None for anything but a pty)."""
        self._lost_pty: PtyIdentity | None = None

    def follow(self, previous: Transport) -> None:
        """Remember the pty the previous transport of this port had: a new pty under its
        name, reached the same way, is refused with :data:`PTY_TAKEN`."""
        if isinstance(previous, SerialTransport) and previous.port == self.port:
            self._lost_pty = previous.pty or previous._lost_pty

    async def _connect(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        # pyserial picks its platform's backend when imported: on POSIX that imports fcntl and
        # termios, so it is imported when a port opens, not when the module loads
        import serial_asyncio_fast

        check_device(self.port)
        pty = PtyIdentity.of(self.port)
        if self._lost_pty is not None and self._lost_pty.taken_by(pty):
            raise self._error(PTY_TAKEN)
        try:
            async with asyncio.timeout(self.open_timeout_s):
                pair = await serial_asyncio_fast.open_serial_connection(
                    loop=asyncio.get_running_loop(), url=self.port, exclusive=True,
                    **pyserial_settings(self.serial))
            self.pty = pty
            return pair
        except TimeoutError:
            raise self._error(f"device did not open within {self.open_timeout_s:g} s") from None
        except _open_errors() as exc:  # serial.SerialException is an OSError
            if "exclusively lock" in str(exc):  # pyserial's words when the lock is held
                raise self._error(IN_USE) from exc
            if not _is_terminal(self.port):
                raise self._error("is not a serial device (a character device that is not a "
                                  "terminal)") from exc
            raise self._error(f"cannot open: {exc}") from exc

    def preflight(self) -> None:
        """The device name looked at, not opened (:func:`check_device`)."""
        check_device(self.port)

    def _loss(self, exc: OSError) -> str:
        return f"device lost: {exc}"

    def _gone(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> str | None:
        exc = reader.exception()
        if exc is not None:
            return f"device lost: {exc}"
        if writer.is_closing():  # the transport closes itself on a read/write error
            return "device lost"
        return None

    def _after_write(self, writer: asyncio.StreamWriter) -> str | None:
        # pyserial-asyncio drops writes to a failed port silently
        return "device lost while writing" if writer.is_closing() else None
