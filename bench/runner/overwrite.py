"""``armbench run --out DIR --overwrite``: the run that DIR holds (a run of one arm, or a fleet's)
gives way to a new one.

:func:`check_overwrite` runs with the other checks, before the arm is connected: DIR must hold
a record that reads as one (a ``results.json`` of the user's own is never taken for a run's).
:func:`remove_earlier_run` runs once the arms answered and DIR is locked: it removes the files a
run writes — its record and journal, ``junit.xml``, ``report.html``, the capture and its parts,
``runner.json``, the folders its suites wrote (``<suite>/``), a fleet's index and page and its
arms' folders — and nothing else: a file of the user's in DIR stays where it is.
"""

from __future__ import annotations

import contextlib
import shutil
from pathlib import Path

from armbench.bench.runner.options import JUNIT_FILE, RUNNER_FILE
from armbench.drivers.model.errors import ArmbenchError
from armbench.record import RESULTS_FILE, RecordError, load_record
from armbench.record.files import CAPTURE_FILE, JOURNAL_FILE, LEGACY_CAPTURE_FILE, REPORT_FILE
from armbench.record.fleet_index import FLEET_FILE, is_fleet, read_fleet_index

__all__ = ["OVERWRITE_FLAG", "check_overwrite", "remove_earlier_run"]

#: The flag that lets a new run replace the run in ``--out``.
OVERWRITE_FLAG = "--overwrite"
#: The files a run (or a fleet) writes in its folder; ``fleet.html`` is the fleet's page.
_RUN_FILES = (RESULTS_FILE, JOURNAL_FILE, REPORT_FILE, CAPTURE_FILE, LEGACY_CAPTURE_FILE,
              JUNIT_FILE, RUNNER_FILE, FLEET_FILE, "fleet.html")
#: Temporary and partial files a run leaves while it writes (``record.writer``, the capture).
_PARTIAL_GLOBS = (f".{RESULTS_FILE}.*.tmp", ".capture.part*.part")


def check_overwrite(out_dir: Path) -> None:
    """Refuse (``RecordError`` naming the file) a ``results.json`` or a fleet's index in
    ``out_dir`` that is not a run's: only a run is replaced."""
    try:
        if is_fleet(out_dir):
            index = read_fleet_index(out_dir)
            for arm in index.arms:
                if (out_dir / arm.name / RESULTS_FILE).exists():
                    load_record(out_dir / arm.name / RESULTS_FILE)
        elif (out_dir / RESULTS_FILE).exists():
            load_record(out_dir / RESULTS_FILE)
    except ArmbenchError as exc:
        raise RecordError(f"{OVERWRITE_FLAG} {out_dir}",
                          f"holds something that is not a run record, left as it is: "
                          f"{exc}") from None


def _suite_folders(out_dir: Path) -> list[Path]:
    """The folders the suites of the run in ``out_dir`` wrote their files to."""
    try:
        record = load_record(out_dir / RESULTS_FILE)
    except ArmbenchError:
        return []
    return [out_dir / name for name in record.planned_suites if (out_dir / name).is_dir()]


def remove_earlier_run(out_dir: Path) -> list[Path]:
    """Remove the run (or the fleet's runs) in ``out_dir``: the files and folders a run writes,
    nothing else. Returns what was removed. Call it with ``out_dir`` locked."""
    removed: list[Path] = []
    if is_fleet(out_dir):
        for arm in read_fleet_index(out_dir).arms:
            folder = out_dir / arm.name
            if folder.is_dir():
                removed += remove_earlier_run(folder)
                with contextlib.suppress(OSError):  # empty unless a file of the user's is in it
                    folder.rmdir()
    for folder in _suite_folders(out_dir):
        shutil.rmtree(folder)
        removed.append(folder)
    paths = [out_dir / name for name in _RUN_FILES]
    paths += [p for pattern in _PARTIAL_GLOBS for p in sorted(out_dir.glob(pattern))]
    for path in paths:
        if path.is_file() or path.is_symlink():
            path.unlink()
            removed.append(path)
    return removed
