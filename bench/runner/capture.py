"""The run's traffic capture: every connection writes a part file, appended to
``capture.jsonl`` once the trial it holds is in the record (:class:`CaptureParts`); on
``--resume`` the parts a killed run left behind are merged or dropped so ``capture.jsonl`` stays
one stream on the run clock (:meth:`CaptureParts.recover`)."""

from __future__ import annotations

import contextlib
import json
import logging
import re
import shutil
from collections.abc import Callable
from pathlib import Path

from armbench.bench.record import RunRecord
from armbench.drivers.capture import merge_capture, shift_capture

__all__ = ["CaptureParts", "job_part_tag"]

log = logging.getLogger("armbench.runner")

#: Bytes per read when a connection's capture part is appended to ``capture.jsonl``.
_COPY_CHUNK = 1 << 20

_JOB_PART = re.compile(
    r"\.capture\.part\d+-job-(?P<suite>.+)-(?P<index>\d+)-(?P<attempt>\d+)\.jsonl")
"""A worker's capture part (:func:`job_part_tag`)."""


def job_part_tag(suite: str, index: int, attempt: int) -> str:
    """The name tag of a worker's capture parts: ``.capture.part-job-<suite>-<index>-<attempt>``."""
    return f"-job-{suite}-{index}-{attempt}"


def _first_capture_time(part: Path) -> float | None:
    """``t_s`` of the first record of a capture part, or None if it has none readable."""
    try:
        with part.open(encoding="ascii") as fh:
            return float(json.loads(fh.readline())["t_s"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


class CaptureParts:
    """Appends capture parts to the run's ``capture.jsonl`` (``capture``)."""

    def __init__(self, capture: Path, max_bytes: int | None = None,
                 say: Callable[[str], None] | None = None) -> None:
        self.capture = capture
        self.max_bytes = max_bytes
        """The capture's size bound (``[bench] capture_max_bytes``); None: unbounded."""
        self.stopped = False
        """Whether the capture reached its bound (said once through ``say``)."""
        self._say = say

    def merge(self, part: Path, offset_s: float = 0.0) -> None:
        """Append a connection's capture to ``capture.jsonl``: written with ``t_s`` on the run
        clock, or ``offset_s`` before it (a worker's trial)."""
        if not part.exists():
            return
        try:
            if self.max_bytes is not None:
                stopped = merge_capture(part, self.capture, offset_s, self.max_bytes)
                if stopped and not self.stopped:
                    self.stopped = True
                    if self._say is not None:
                        self._say(f"capture stopped: {self.capture.name} reached its size bound "
                                  f"of {self.max_bytes} bytes")
            else:
                with part.open("rb") as src, self.capture.open("ab") as dst:
                    if offset_s:
                        shift_capture(src, dst, offset_s)
                    else:
                        shutil.copyfileobj(src, dst, _COPY_CHUNK)
        except OSError as exc:
            log.warning("capture %s could not be merged into %s: %s", part, self.capture, exc)
            return
        with contextlib.suppress(OSError):
            part.unlink()

    def recover(self, record: RunRecord, out_dir: Path) -> None:
        """On ``--resume``: the capture parts a killed run left behind. A part whose first frame
        falls within a recorded trial is merged (the kill came between the record and the merge);
        any other holds a trial the record lacks, which is measured again, and is dropped, so
        ``capture.jsonl`` stays one stream on the run clock."""
        spans = [(t.started_s, t.ended_s) for s in record.suites.values()
                 for t in (*s.trials, *s.superseded_trials)]
        parts = sorted(out_dir.glob(".capture.part*.jsonl"), key=lambda p: p.stat().st_mtime)
        recorded = {(name, t.index): t for name, s in record.suites.items() for t in s.trials}
        for part in parts:
            job = _JOB_PART.fullmatch(part.name)
            if job is not None:  # a worker's part: times from its own 0 (bench/runner/parallel)
                trial = recorded.get((job["suite"], int(job["index"])))
                if trial is not None:
                    self.merge(part, trial.started_s)
                    continue
            else:
                first = _first_capture_time(part)
                if first is not None and any(a - 1e-6 <= first <= b + 1e-6 for a, b in spans):
                    self.merge(part)
                    continue
            log.info("dropping %s: its trial is not in the record", part.name)
            with contextlib.suppress(OSError):
                part.unlink()
