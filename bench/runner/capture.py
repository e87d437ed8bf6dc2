"""The run's traffic capture: every connection writes a part file, added to ``capture.mcap``
once the trial it holds is in the record (:class:`CaptureParts`, through
:class:`~armbench.bench.capture_run.RunCapture`); on ``--resume`` the parts a killed run left
behind are merged or dropped so ``capture.mcap`` stays one stream on the run clock
(:meth:`CaptureParts.recover`)."""

from __future__ import annotations

import contextlib
import logging
import re
from collections.abc import Callable, Mapping
from pathlib import Path

from armbench.bench.capture_run import RunCapture
from armbench.bench.record import RunRecord, Trial
from armbench.drivers.capture_part import first_part_time
from armbench.drivers.settings import RobotSettings

__all__ = ["CaptureParts", "job_part_tag"]

log = logging.getLogger("armbench.runner")

_JOB_PART = re.compile(
    r"\.capture\.part\d+-job-(?P<suite>.+)-(?P<index>\d+)-(?P<attempt>\d+)\.part")
"""A worker's capture part (:func:`job_part_tag`)."""


def job_part_tag(suite: str, index: int, attempt: int) -> str:
    """The name tag of a worker's capture parts: ``.capture.part-job-<suite>-<index>-<attempt>``."""
    return f"-job-{suite}-{index}-{attempt}"


class CaptureParts:
    """Adds capture parts to the run's ``capture.mcap`` (``capture``)."""

    def __init__(self, capture: Path, max_bytes: int | None = None,
                 say: Callable[[str], None] | None = None) -> None:
        self.capture = capture
        self.max_bytes = max_bytes
        """The capture's size bound (``[bench] capture_max_bytes``); None: unbounded."""
        self.stopped = False
        """Whether the capture reached its bound (said once through ``say``)."""
        self._say = say
        self.run: RunCapture | None = None
        """The run's MCAP writer; None in a worker (:meth:`open_run`)."""

    def open_run(self, settings: RobotSettings, record: RunRecord) -> None:
        """Write parts into the run's ``capture.mcap`` (only the process holding the record
        does: a worker's parts stay files, sent back to it)."""
        self.run = RunCapture(self.capture, settings, record, self.max_bytes)

    def merge(self, part: Path, offset_s: float = 0.0) -> None:
        """Add a connection's capture part to ``capture.mcap``: written with ``t_s`` on the run
        clock, or ``offset_s`` before it (a worker's trial). A part that might cross the size
        bound is dropped, and every one after it: the capture ends with a ``capture_stopped``
        event (said once)."""
        if not part.exists() or self.run is None:
            return
        if not self.stopped and not self.run.fits(part):
            self.stopped = True
            reason = f"the size bound of {self.max_bytes} bytes was reached"
            self.run.stop(reason)
            if self._say is not None:
                self._say(f"capture stopped: {self.capture.name}: {reason}")
        if self.stopped:
            with contextlib.suppress(OSError):
                part.unlink()
            return
        try:
            self.run.add_part(part, offset_s)
        except OSError as exc:
            log.warning("capture %s could not be merged into %s: %s", part, self.capture, exc)

    def trial(self, suite: str, trial: Trial) -> None:
        """A recorded trial's start and end as events in the capture."""
        if self.run is not None and not self.stopped:
            self.run.trial(suite, trial)

    def flush(self) -> None:
        """Write what is buffered as complete chunks (and delete the parts it came from)."""
        if self.run is not None:
            self.run.flush()

    def finish(self, attachments: Mapping[str, Path]) -> None:
        """Attach the run's files and close ``capture.mcap`` (when one was written)."""
        if self.run is not None and self.run.sink is not None:
            self.run.finish(attachments)

    def recover(self, record: RunRecord, out_dir: Path) -> None:
        """On ``--resume``: the capture parts a killed run left behind. A part whose first frame
        falls within a recorded trial is merged (the kill came between the record and the merge);
        any other holds a trial the record lacks, which is measured again, and is dropped, so
        ``capture.mcap`` stays one stream on the run clock."""
        spans = [(t.started_s, t.ended_s) for s in record.suites.values()
                 for t in (*s.trials, *s.superseded_trials)]
        parts = sorted(out_dir.glob(".capture.part*.part"), key=lambda p: p.stat().st_mtime)
        recorded = {(name, t.index): t for name, s in record.suites.items() for t in s.trials}
        for part in parts:
            job = _JOB_PART.fullmatch(part.name)
            if job is not None:  # a worker's part: times from its own 0 (bench/runner/parallel)
                trial = recorded.get((job["suite"], int(job["index"])))
                if trial is not None:
                    self.merge(part, trial.started_s)
                    continue
            else:
                first = first_part_time(part)
                if first is not None and any(a - 1e-6 <= first <= b + 1e-6 for a, b in spans):
                    self.merge(part)
                    continue
            log.info("dropping %s: its trial is not in the record", part.name)
            with contextlib.suppress(OSError):
                part.unlink()
