"""The files of a run directory: their names (one home for each), paths kept inside the
directory, and atomic writes."""

from __future__ import annotations

import contextlib
import os
import secrets
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path, PurePath
from typing import BinaryIO

from armbench.drivers.model.user_files import file_kind
from armbench.record.fields import RecordError

__all__ = [
    "CAPTURE_FILE",
    "JOURNAL_FILE",
    "LEGACY_CAPTURE_FILE",
    "REPORT_FILE",
    "RESULTS_FILE",
    "atomic_write",
    "atomic_write_bytes",
    "check_directory_writable",
    "fsync_directory",
    "make_directory",
    "path_inside",
    "run_directory",
]

#: The record's file name inside a run directory.
RESULTS_FILE = "results.json"
#: The journal of the trials finished since ``results.json`` was last written, beside it
#: (``armbench.record.journal``).
JOURNAL_FILE = "results.journal.jsonl"
#: The HTML report beside it.
REPORT_FILE = "report.html"
#: The traffic capture (MCAP, ``armbench.drivers.capture.mcap_writer``) beside it.
CAPTURE_FILE = "capture.mcap"
#: The older JSON Lines capture (runs before MCAP), still read by every reader.
LEGACY_CAPTURE_FILE = "capture.jsonl"


def path_inside(directory: str | Path, name: str | PurePath) -> Path:
    """``directory / name``, refusing a ``name`` that could lead out of ``directory``: absolute,
    containing ``..``, empty, or resolving (through symlinks) to a place outside it."""
    raw = os.fspath(name)
    base = Path(directory)
    pure = PurePath(raw)
    if not raw or "\0" in raw:
        raise RecordError("file name", f"{raw!r} is not a usable name")
    if pure.is_absolute() or pure.anchor:
        raise RecordError("file name", f"{raw!r} is absolute; names are relative to {base}")
    if ".." in pure.parts:
        raise RecordError("file name", f"{raw!r} contains '..' and could leave {base}")
    target = base / pure
    real_base = base.resolve()
    real = target.resolve()
    if real != real_base and real_base not in real.parents:
        raise RecordError("file name", f"{raw!r} leads to {real}, outside {real_base} "
                                       "(a symlink pointing out?)")
    return target


def run_directory(root: str | Path, run_name: str) -> Path:
    """The directory of run ``run_name`` inside ``root``, created if missing. The run name must be
    one plain path component that stays inside ``root`` (no ``/``, ``..`` or symlink out)."""
    if not run_name or run_name in (".", "..") or any(c in run_name for c in "/\\\0"):
        raise RecordError("run name", f"{run_name!r} must be one plain name (no '/', '\\', "
                                      "'.' or '..')")
    root_path = Path(root)
    root_path.mkdir(parents=True, exist_ok=True)
    target = path_inside(root_path, run_name)
    try:
        target.mkdir(exist_ok=True)
    except FileExistsError:
        raise RecordError("run name", f"{target} exists and is not a directory") from None
    return target


def _display(path: Path) -> str:
    """``path`` as text that can be printed (bytes that are not UTF-8 as ``\\xNN``)."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")


def check_directory_writable(directory: str | Path, what: str) -> None:
    """Raise a RecordError naming ``what`` (``--out DIR``) unless ``directory`` is, or can be
    made, a directory this process can write into: checked on the nearest part of the path that
    exists (a file in the way, a path under a file, a read-only file system or folder, a place
    such as ``/proc`` where nothing can be made), creating nothing but a probe file that is
    removed at once."""
    target = Path(directory)
    probe = target
    while not probe.exists() and probe != probe.parent:
        if probe.is_symlink():  # a dangling symlink: mkdir would fail on it
            raise RecordError(what, f"{_display(probe)} is a broken symbolic link")
        probe = probe.parent
    if not probe.is_dir():
        where = "is" if probe == target else f"is under {_display(probe)}, which is"
        raise RecordError(what, f"{_display(target)} {where} a file, not a directory")
    try:  # made and removed, not os.access: root passes that check where nothing can be made
        with tempfile.TemporaryFile(dir=probe, prefix=".armbench-probe-"):
            pass
    except OSError as exc:
        reason = ("a read-only file system" if _read_only(probe)
                  else "no write permission" if isinstance(exc, PermissionError)
                  else exc.strerror or str(exc))
        raise RecordError(what, f"{_display(target)} cannot be written: {reason} at "
                                f"{_display(probe)}") from None


def _read_only(path: Path) -> bool:
    try:
        return bool(os.statvfs(path).f_flag & getattr(os, "ST_RDONLY", 1))
    except (OSError, AttributeError):
        return False


def make_directory(directory: str | Path, what: str) -> Path:
    """Create ``directory`` (and its parents) if missing; a RecordError naming ``what`` and the
    OS's reason, one line, when it cannot be."""
    target = Path(directory)
    try:
        target.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise RecordError(what, f"{_display(target)} exists and is not a directory") from None
    except OSError as exc:
        raise RecordError(what, f"{_display(target)} cannot be created: "
                                f"{exc.strerror or exc}") from None
    return target


def fsync_directory(directory: Path) -> None:
    """Make a rename in ``directory`` durable (POSIX; a no-op where a directory cannot be
    opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        with contextlib.suppress(OSError):
            os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Replace ``path`` with ``data`` atomically (see :func:`atomic_write`)."""
    atomic_write(path, lambda fh: fh.write(data))


def atomic_write(path: str | Path, write: Callable[[BinaryIO], object]) -> None:
    """Replace ``path`` atomically with what ``write`` writes to the file it is given: a
    temporary file in the same directory is written, fsync'ed and renamed over ``path``
    (``os.replace``), then the directory is fsync'ed. Readers see the old or the new content,
    never a mix; no temporary file is left behind. A device, a FIFO or a directory at ``path``
    is refused (as root, renaming over ``/dev/null`` would replace the device with a file); a
    symbolic link is replaced, not what it points to."""
    target = Path(path)
    with contextlib.suppress(FileNotFoundError):
        mode = os.lstat(target).st_mode
        if not (stat.S_ISREG(mode) or stat.S_ISLNK(mode)):
            raise RecordError(str(target), f"is {file_kind(mode)}, not a file; it is never "
                                           "replaced")
    tmp = target.with_name(f".{target.name}.{secrets.token_hex(6)}.tmp")
    try:
        # 0o666 and the umask, like any new file (mkstemp would make it private, 0o600).
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0),
                     0o666)
    except OSError as exc:
        raise RecordError(str(target), f"could not be written: {exc.strerror or exc}") from exc
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise RecordError(str(target), f"could not be written: {exc.strerror or exc}") from exc
        raise
    fsync_directory(target.parent)

