"""The run folder's lock: one writer at a time (a run, or a resume of it).

While ``armbench run`` (or ``--resume``) writes a run folder it holds an OS lock on
``OUT/.armbench.lock`` (``fcntl.flock`` on POSIX, ``msvcrt.locking`` on Windows), so a second
writer — a ``--resume`` of a run still going, two runs given the same ``--out`` — is refused
before it reads or writes anything, with the holder's pid, host, command and start time, which
the holder writes into the file. The OS drops the lock when its process ends, however it ends
(``kill -9`` included): a folder left by a killed run is never locked. The file is removed when
the lock is released.

The lock is re-entrant within a process (the command holds it around the run and its reports,
the runner around the record): a folder held by this process is held again, and released when
the outermost holder lets it go.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import socket
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from armbench.drivers.model.errors import ArmbenchError

__all__ = ["LOCK_FILE", "RunFolderBusy", "RunFolderLock", "hold_run_folder"]

#: The lock file inside a run folder.
LOCK_FILE = ".armbench.lock"

#: Byte locked on Windows: past anything written into the file, so the holder's details stay
#: readable (a byte range locked with ``msvcrt.locking`` cannot be read by other processes).
_WINDOWS_LOCK_OFFSET = 1 << 20


class RunFolderBusy(ArmbenchError):
    """Another process holds the run folder's lock."""


def _try_lock(fd: int) -> bool:
    """Take the lock of the open file ``fd`` without waiting; False if another process has it."""
    if sys.platform == "win32":
        import msvcrt

        os.lseek(fd, _WINDOWS_LOCK_OFFSET, os.SEEK_SET)
        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True
    import fcntl

    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def _unlock(fd: int) -> None:
    if sys.platform == "win32":
        import msvcrt

        os.lseek(fd, _WINDOWS_LOCK_OFFSET, os.SEEK_SET)
        msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)
        return
    import fcntl

    fcntl.flock(fd, fcntl.LOCK_UN)


def _holder(path: Path) -> str:
    """What the lock file says of its holder, as a phrase."""
    try:
        info: Any = json.loads(path.read_bytes()[:_WINDOWS_LOCK_OFFSET].decode("utf-8"))
    except (OSError, ValueError):
        info = None
    if not isinstance(info, dict):
        return "another process (it has not written its details yet)"
    command = " ".join(str(a) for a in info.get("command", [])) or "?"
    return (f"pid {info.get('pid', '?')} on {info.get('host', '?')} ({command}, started "
            f"{info.get('started', '?')})")


class RunFolderLock:
    """The lock of one run folder, held by this process (:func:`hold_run_folder`)."""

    def __init__(self, directory: Path, fd: int) -> None:
        self.directory = directory
        self.path = directory / LOCK_FILE
        self._fd: int | None = fd

    @classmethod
    def acquire(cls, directory: str | Path) -> RunFolderLock:
        """Lock ``directory`` (which must exist) or raise :class:`RunFolderBusy` naming the
        holder; an :class:`ArmbenchError` when the lock file cannot be made."""
        folder = Path(directory)
        path = folder / LOCK_FILE
        while True:
            try:
                fd = os.open(path, os.O_RDWR | os.O_CREAT | getattr(os, "O_BINARY", 0), 0o666)
            except OSError as exc:
                raise ArmbenchError(f"run folder {folder}: cannot write its lock file "
                                    f"{LOCK_FILE}: {exc.strerror or exc}") from exc
            if not _try_lock(fd):
                os.close(fd)
                raise RunFolderBusy(f"run folder {folder} is being written by "
                                    f"{_holder(path)}; wait for it to end")
            # the holder before us may have removed the file between our open and our lock:
            # then the lock is on a file nobody else sees, and we try again
            try:
                same = os.path.samestat(os.fstat(fd), os.stat(path))
            except OSError:
                same = False
            if same:
                break
            os.close(fd)
        lock = cls(folder, fd)
        lock._write_details()
        return lock

    def _write_details(self) -> None:
        fd = self._fd
        assert fd is not None
        details = {"pid": os.getpid(), "host": socket.gethostname(), "command": sys.argv,
                   "started": datetime.datetime.now(datetime.UTC).strftime(
                       "%Y-%m-%dT%H:%M:%SZ")}
        data = (json.dumps(details) + "\n").encode("utf-8")
        with contextlib.suppress(OSError):  # the details help; the lock is what counts
            os.ftruncate(fd, 0)
            os.lseek(fd, 0, os.SEEK_SET)
            os.write(fd, data)

    def release(self) -> None:
        """Remove the lock file and let the lock go (idempotent)."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        with contextlib.suppress(OSError):  # removed while held: nobody can lock it meanwhile
            self.path.unlink()
        try:
            with contextlib.suppress(OSError):
                _unlock(fd)
        finally:
            os.close(fd)


_HELD: dict[Path, tuple[RunFolderLock, int]] = {}
"""Folders this process holds (resolved path → lock, depth)."""


@contextlib.contextmanager
def hold_run_folder(directory: str | Path) -> Iterator[RunFolderLock]:
    """Hold ``directory``'s lock for the ``with`` block (re-entrant within the process)."""
    key = Path(directory).resolve()
    held = _HELD.get(key)
    if held is not None:
        _HELD[key] = (held[0], held[1] + 1)
        lock = held[0]
    else:
        lock = RunFolderLock.acquire(directory)
        _HELD[key] = (lock, 1)
    try:
        yield lock
    finally:
        lock_now, depth = _HELD[key]
        if depth > 1:
            _HELD[key] = (lock_now, depth - 1)
        else:
            del _HELD[key]
            lock_now.release()
