"""The files a command writes where the user says (``--out``): checked before any work starts, so a
long calibration or replay never ends in an unwritable path or over a file of the user's.

:func:`check_out_files` refuses, with one line naming the path: a directory, or a file, in the
way; a device or a FIFO; a path under a file or in a missing directory; a directory that cannot
be written (read-only file system, no permission; found by creating a file there, which also
holds for root); an existing file unless ``force`` is given; and, even with ``force``, a file
of a run's record (``results.json``, its journal, ``report.html``, the capture, ...) in a
directory that holds a run. :func:`check_out_dir` does the same for a directory a command
fills (its writer creates it if missing). Writers then replace each file atomically
(:func:`armbench.record.files.atomic_write`).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Final

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.user_files import file_kind
from armbench.record.files import (
    CAPTURE_FILE,
    JOURNAL_FILE,
    LEGACY_CAPTURE_FILE,
    REPORT_FILE,
    RESULTS_FILE,
)

__all__ = ["RUN_FILES", "OutputError", "check_out_dir", "check_out_files", "is_run_file"]

#: The files of a run directory (``armbench.record.files``; ``junit.xml`` and
#: ``runner.json`` of ``armbench.bench.runner.options``; the fleet's and the index's pages): never
#: replaced by another command's output.
RUN_FILES: Final = frozenset({RESULTS_FILE, JOURNAL_FILE, REPORT_FILE, CAPTURE_FILE,
                              LEGACY_CAPTURE_FILE, "junit.xml", "runner.json", "fleet.json",
                              "fleet.html", "index.html", "campaign.html"})


class OutputError(ArmbenchError):
    """An output path that cannot or must not be written; names the option and the path."""

    def __init__(self, option: str, path: Path, problem: str) -> None:
        super().__init__(f"{option} {path}: {problem}")
        self.option = option
        self.path = path
        self.problem = problem


def is_run_file(path: Path) -> bool:
    """Whether ``path`` is one of a run's record files: a name of :data:`RUN_FILES` in a
    directory holding a run record (or its journal)."""
    return path.name in RUN_FILES and any(
        (path.parent / name).exists() for name in (RESULTS_FILE, JOURNAL_FILE))


def _nearest(path: Path) -> Path:
    """``path`` or its closest ancestor that exists (or is a dangling link)."""
    probe = path
    while not os.path.lexists(probe) and probe.parent != probe:
        probe = probe.parent
    return probe


def _writable_dir(option: str, shown: Path, directory: Path, *, missing_ok: bool) -> None:
    """A file can be made in ``directory``; if it is missing (and ``missing_ok``: the writer
    creates it), in its closest existing ancestor, which must be a directory."""
    existing = _nearest(directory)
    if existing != directory and not missing_ok:
        raise OutputError(option, shown, f"{directory} does not exist")
    if not existing.is_dir():
        raise OutputError(option, shown, f"{existing} is not a directory")
    try:
        with tempfile.TemporaryFile(dir=existing, prefix=".armbench-probe-"):
            pass
    except OSError as exc:
        raise OutputError(option, shown, f"cannot write in {existing}: "
                                         f"{exc.strerror or exc}") from None


def check_out_files(option: str, paths: Sequence[Path], *, force: bool = False) -> None:
    """Refuse, before any work, output files that cannot or must not be written (see the module
    doc). ``paths`` are every file the command will write for ``option``, the first the one the
    user named."""
    shown = paths[0]
    if len({p.resolve() for p in paths}) < len(paths):
        raise OutputError(option, shown, "its outputs (" + ", ".join(p.name for p in paths)
                                         + ") would overwrite each other; choose another name")
    for path in paths:
        if path.is_dir():
            raise OutputError(option, shown, f"{path} is a directory")
        if os.path.lexists(path) and not (path.is_symlink() or path.is_file()):
            raise OutputError(option, shown, f"{path} is {file_kind(os.stat(path).st_mode)}, "
                                             "not a file; it is never replaced")
        if is_run_file(path):
            raise OutputError(option, shown, f"{path} belongs to the run record in "
                                             f"{path.parent}; it is never overwritten")
        if os.path.lexists(path) and not force:
            raise OutputError(option, shown, f"{path} exists (give --force to overwrite it)")
    for directory in dict.fromkeys(p.parent for p in paths):
        _writable_dir(option, shown, directory, missing_ok=False)


def check_out_dir(option: str, directory: Path, names: Sequence[str]) -> None:
    """Refuse, before any work, an output directory that cannot be written, or in which one of
    the files ``names`` the command writes already exists."""
    if os.path.lexists(directory) and not directory.is_dir():
        raise OutputError(option, directory, "is not a directory")
    for name in names:
        if os.path.lexists(directory / name):
            raise OutputError(option, directory, f"{directory / name} exists; choose another "
                                                 "directory")
    _writable_dir(option, directory, directory, missing_ok=True)
