"""Reading a file a user names (``--config``, ``--settings``, ``--faults``, a ``results.json``):
only a regular file, and at most a bounded number of bytes of it.

``/dev/zero`` would be read until memory runs out and a FIFO nobody writes to would block the
bench for ever, so anything that is not a regular file is refused before a byte is read. The
file is opened without blocking (a FIFO opens at once) and checked on the open descriptor, so
what is checked is what is read. Problems raise :class:`FileRefused` with a reason for people;
callers turn it into their own typed error naming the option or file.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from armbench.drivers.errors import ArmbenchError

__all__ = ["MAX_TOML_BYTES", "FileRefused", "file_kind", "read_regular_file"]

#: The most bytes a TOML file a user hands over (limits, settings, faults) may hold: 1 MiB,
#: a hundred times the packaged limits file.
MAX_TOML_BYTES = 1 << 20

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISREG, "a regular file"))


class FileRefused(ArmbenchError):
    """A file cannot be used; ``reason`` says why (``"does not exist"``, ``"is a FIFO, ..."``)."""

    def __init__(self, path: Path, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path = path
        self.reason = reason


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, for people: ``"a FIFO"``, ``"a directory"``..."""
    return next((name for test, name in _KINDS if test(mode)), "a file of another kind")


def read_regular_file(path: str | Path, what: str, max_bytes: int | None = None) -> bytes:
    """The bytes of the regular file at ``path``; ``what`` names what it should be (``"a TOML
    file"``) in the reasons. A missing file, a directory, a FIFO, a device, an unreadable file or
    one of more than ``max_bytes`` bytes (None: no bound) raises :class:`FileRefused`."""
    p = Path(path)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(p, flags)
    except FileNotFoundError:
        raise FileRefused(p, "does not exist") from None
    except IsADirectoryError:
        raise FileRefused(p, f"is a directory, not {what}") from None
    except OSError as exc:
        raise FileRefused(p, f"cannot be read: {exc.strerror or exc}") from None
    try:
        mode = os.fstat(fd).st_mode
    except OSError as exc:
        os.close(fd)
        raise FileRefused(p, f"cannot be read: {exc.strerror or exc}") from None
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise FileRefused(p, f"is {file_kind(mode)}, not {what} (only a regular file is read)")
    with os.fdopen(fd, "rb") as fh:
        try:
            data = fh.read() if max_bytes is None else fh.read(max_bytes + 1)
        except OSError as exc:
            raise FileRefused(p, f"cannot be read: {exc.strerror or exc}") from None
    if max_bytes is not None and len(data) > max_bytes:
        raise FileRefused(p, f"is larger than {max_bytes} bytes, the bound for {what}")
    return data
