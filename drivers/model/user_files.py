"""Reading and appending to a file a user names (``--config``, ``--settings``, ``--faults``, a
``results.json``, a capture, ``--summary``): only a regular file, and at most a bounded number
of bytes of it.

``/dev/zero`` would be read until memory runs out and a FIFO nobody writes to (or reads from)
would block the bench for ever, so anything that is not a regular file is refused before a byte
is read or written. The file is opened without blocking (a FIFO opens at once, or fails at once
for writing) and checked on the open descriptor, so what is checked is what is used. Problems
raise :class:`FileRefused` with a reason for people; callers turn it into their own typed error
naming the option or file.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO

from armbench.drivers.model.errors import ArmbenchError

__all__ = ["MAX_JSON_BYTES", "MAX_TOML_BYTES", "FileRefused", "append_regular_file",
           "check_appendable_file", "file_kind", "open_regular_file", "read_regular_file"]

#: The most bytes a TOML file a user hands over (limits, settings, faults) may hold: 1 MiB,
#: a hundred times the packaged limits file.
MAX_TOML_BYTES = 1 << 20
#: The most bytes of a small JSON file of a run directory (``runner.json``, ``fleet.json``):
#: 16 MiB, thousands of times what a run writes there.
MAX_JSON_BYTES = 16 << 20

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"), (stat.S_ISREG, "a regular file"))
_NONBLOCK = getattr(os, "O_NONBLOCK", 0)
_BINARY = getattr(os, "O_BINARY", 0)


class FileRefused(ArmbenchError):
    """A file cannot be used; ``reason`` says why (``"does not exist"``, ``"is a FIFO, ..."``)."""

    def __init__(self, path: Path, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path = path
        self.reason = reason


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, for people: ``"a FIFO"``, ``"a directory"``..."""
    return next((name for test, name in _KINDS if test(mode)), "a file of another kind")


def _open_regular(p: Path, flags: int, what: str, verb: str) -> int:
    """A descriptor of the regular file at ``p`` opened with ``flags`` (and O_NONBLOCK, which
    is then cleared), or :class:`FileRefused`; ``verb`` says what failed (``"read"``)."""
    try:
        fd = os.open(p, flags | _NONBLOCK | _BINARY, 0o666)
    except FileNotFoundError:
        raise FileRefused(p, "does not exist" if verb == "read" else
                          f"cannot be {verb}: " + ("it is a broken symbolic link"
                                                   if p.parent.is_dir() else
                                                   f"its folder {p.parent} does not exist")
                          ) from None
    except IsADirectoryError:
        raise FileRefused(p, f"is a directory, not {what}") from None
    except OSError as exc:
        # ENXIO: a FIFO opened for writing that nobody reads (O_NONBLOCK fails at once)
        reason = f"is a FIFO, not {what}" if p.is_fifo() else f"cannot be {verb}: " \
                                                               f"{exc.strerror or exc}"
        raise FileRefused(p, reason) from None
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISREG(mode) and _NONBLOCK:
            os.set_blocking(fd, True)
    except OSError as exc:
        os.close(fd)
        raise FileRefused(p, f"cannot be {verb}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(mode):
        os.close(fd)
        why = "" if stat.S_ISDIR(mode) else f" (only a regular file is {verb})"
        raise FileRefused(p, f"is {file_kind(mode)}, not {what}{why}")
    return fd


def open_regular_file(path: str | Path, what: str) -> BinaryIO:
    """The regular file at ``path`` opened for reading (binary); ``what`` names what it should
    be (``"a capture"``) in the reasons. A missing file, a directory, a FIFO, a device or an
    unreadable file raises :class:`FileRefused`, without blocking."""
    return os.fdopen(_open_regular(Path(path), os.O_RDONLY, what, "read"), "rb")


def read_regular_file(path: str | Path, what: str, max_bytes: int | None = None) -> bytes:
    """The bytes of the regular file at ``path`` (see :func:`open_regular_file`); one of more
    than ``max_bytes`` bytes (None: no bound) raises :class:`FileRefused` too, read no further
    than the bound."""
    p = Path(path)
    with open_regular_file(p, what) as fh:
        try:
            data = fh.read() if max_bytes is None else fh.read(max_bytes + 1)
        except OSError as exc:
            raise FileRefused(p, f"cannot be read: {exc.strerror or exc}") from None
    if max_bytes is not None and len(data) > max_bytes:
        raise FileRefused(p, f"is larger than {max_bytes} bytes, the bound for {what}")
    return data


def check_appendable_file(path: str | Path, what: str) -> None:
    """Refuse, before any work, a file that :func:`append_regular_file` could not append to: an
    existing file that is not a regular file or cannot be written, or a missing file whose
    folder is missing or not writable (found by creating and removing a file there). Nothing
    is left behind."""
    p = Path(path)
    if os.path.lexists(p):
        os.close(_open_regular(p, os.O_WRONLY | os.O_APPEND, what, "written"))
        return
    folder = p.parent
    if not folder.is_dir():
        raise FileRefused(p, f"cannot be written: {folder} is not a folder" if folder.exists()
                          else f"cannot be written: its folder {folder} does not exist")
    probe = folder / f".{p.name}.{os.getpid()}.armbench-probe"
    try:
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL | _NONBLOCK, 0o600))
    except OSError as exc:
        raise FileRefused(p, f"cannot be written in {folder}: {exc.strerror or exc}") from None
    os.unlink(probe)


def append_regular_file(path: str | Path, data: bytes, what: str) -> None:
    """Append ``data`` to the regular file at ``path``, created if missing (a step summary may
    hold what earlier steps wrote, which is kept). A FIFO, a device, a directory, a missing
    folder or a failed write (a full disk) raises :class:`FileRefused`, without blocking."""
    p = Path(path)
    fd = _open_regular(p, os.O_WRONLY | os.O_APPEND | os.O_CREAT, what, "written")
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
    except OSError as exc:
        raise FileRefused(p, f"could not be written: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
