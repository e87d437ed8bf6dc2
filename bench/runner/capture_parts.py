"""The run's traffic capture: every connection writes a part file, added to ``capture.mcap``
once the trial it holds is in the record (:class:`CaptureParts`, through
:class:`~armbench.bench.runner.capture_run.RunCapture`); on ``--resume`` the parts a killed run left
behind are merged or dropped so ``capture.mcap`` stays one stream on the run clock
(:meth:`CaptureParts.recover`)."""

from __future__ import annotations

import contextlib
import logging
import re
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from armbench.drivers.capture.part import part_span
from armbench.drivers.model.settings import RobotSettings
from armbench.record import RunRecord, Trial

if TYPE_CHECKING:
    from armbench.bench.runner.capture_run import RunCapture

__all__ = ["CaptureParts", "job_part_tag"]

log = logging.getLogger("armbench.runner")

_JOB_PART = re.compile(
    r"\.capture\.part\d+-job-(?P<suite>.+)-(?P<index>\d+)-(?P<attempt>\d+)\.part")
"""A worker's capture part (:func:`job_part_tag`)."""

#: Seconds a part's frames may lie outside the span of the trial they belong to (the close of
#: its connection after the trial's end is taken).
_SLACK_S = 1e-6


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
        self.failed = False
        """Whether the capture could not be written (a full disk): it stopped, and the parts
        not yet in it stay on disk for a ``--resume`` to merge."""
        self._say = say
        self.run: RunCapture | None = None
        """The run's MCAP writer; None in a worker (:meth:`open_run`)."""

    def open_run(self, settings: RobotSettings, record: RunRecord) -> None:
        """Write parts into the run's ``capture.mcap`` (only the process holding the record
        does: a worker's parts stay files, sent back to it). The MCAP writer is imported here,
        so a worker never imports it."""
        from armbench.bench.runner.capture_run import RunCapture

        self.run = RunCapture(self.capture, settings, record, self.max_bytes)

    def merge(self, part: Path, offset_s: float = 0.0) -> None:
        """Add a connection's capture part to ``capture.mcap``: written with ``t_s`` on the run
        clock, or ``offset_s`` before it (a worker's trial). A part that might cross the size
        bound is dropped, and every one after it: the capture ends with a ``capture_stopped``
        event (said once)."""
        if not part.exists() or self.run is None:
            return
        try:
            if not self.stopped and not self.run.fits(part):
                self.stopped = True
                reason = f"the size bound of {self.max_bytes} bytes was reached"
                self.run.stop(reason)
                if self._say is not None:
                    self._say(f"capture stopped: {self.capture.name}: {reason}")
            if self.stopped:
                if not self.failed:  # kept after a write error: a resume merges it
                    with contextlib.suppress(OSError):
                        part.unlink()
                return
            self.run.add_part(part, offset_s)
        except OSError as exc:
            self._failed(exc)

    def _failed(self, exc: OSError) -> None:
        """The capture cannot be written (a full disk): it stops there, said once; the run and
        its record go on, and an error of the record is what the user sees, not this one. The
        parts not in it yet are kept: ``--resume`` (once there is room) merges those of
        recorded trials, as after a kill."""
        if not self.stopped:
            if self._say is not None:
                self._say(f"capture stopped: {self.capture.name} cannot be written: "
                          f"{exc.strerror or exc}; its parts stay for --resume")
            else:
                log.warning("capture %s cannot be written: %s", self.capture,
                            exc.strerror or exc)
        self.stopped = self.failed = True

    def trial(self, suite: str, trial: Trial) -> None:
        """A recorded trial's start and end as events in the capture."""
        if self.run is not None and not self.stopped:
            try:
                self.run.trial(suite, trial)
            except OSError as exc:
                self._failed(exc)

    def flush(self) -> None:
        """Write what is buffered as complete chunks (and delete the parts it came from)."""
        if self.run is not None and not self.stopped:
            try:
                self.run.flush()
            except OSError as exc:
                self._failed(exc)

    def finish(self, attachments: Mapping[str, Path]) -> None:
        """Attach the run's files and close ``capture.mcap`` (when one was written, in this
        session or an earlier one: a run killed after its last trial was in the capture, before
        the record was attached, is finished by a ``--resume`` that has nothing left to run)."""
        if self.run is not None and (self.run.sink is not None or self.capture.exists()):
            try:
                self.run.finish(attachments)
            except OSError as exc:
                self._failed(exc)

    def recover(self, record: RunRecord, out_dir: Path) -> None:
        """On ``--resume``: the capture parts a killed run left behind. A part holding a
        recorded trial (a worker's part named by its trial and attempt; a part of this process
        whose first frame falls within a recorded trial) is merged: the kill came between the
        record and the capture's next complete chunk. They are merged in the order of their
        trials on the run clock (not the order the files were written: workers end out of
        turn), each after its trials' start and end events unless the capture carried over
        holds them, as the uninterrupted run writes them; an error trial without a part (it
        failed before any traffic) gets its start and end alone. Any other part holds a trial the
        record lacks, which is measured again, and is dropped, so ``capture.mcap`` stays one
        stream on the run clock, in time order."""
        attempts = sorted(((name, t) for name, s in record.suites.items()
                           for t in (*s.trials, *s.superseded_trials)),
                          key=lambda a: a[1].started_s)
        tries: dict[tuple[str, int], list[Trial]] = {}
        for name, t in attempts:
            tries.setdefault((name, t.index), []).append(t)
        units: list[tuple[float, int, Path | None, float, list[tuple[str, Trial]]]] = []
        jobs: dict[tuple[str, int], list[tuple[int, Path]]] = {}
        for part in sorted(out_dir.glob(".capture.part*.part")):
            job = _JOB_PART.fullmatch(part.name)
            if job is not None:  # a worker's part: times from its own 0 (bench/runner/parallel)
                jobs.setdefault((job["suite"], int(job["index"])), []).append(
                    (int(job["attempt"]), part))
                continue
            span = part_span(part)
            held = [] if span is None else [
                (name, t) for name, t in attempts
                if t.started_s - _SLACK_S <= span[1] and span[0] <= t.ended_s + _SLACK_S]
            if span is not None and any(t.started_s - _SLACK_S <= span[0] <= t.ended_s + _SLACK_S
                                        for _, t in held):
                units.append((held[0][1].started_s, 0, part, 0.0, held))
            else:
                _drop(part)
        for (name, index), found in jobs.items():
            recorded = tries.get((name, index), [])
            # the newest parts are of the newest attempts: a kill loses only the tail
            found.sort()
            for k, (attempt, part) in enumerate(reversed(found)):
                if k < len(recorded):
                    trial = recorded[len(recorded) - 1 - k]
                    units.append((trial.started_s, attempt, part, trial.started_s,
                                  [(name, trial)]))
                else:
                    _drop(part)
        held_ids = {id(t) for unit in units for _, t in unit[4]}
        units.extend((t.started_s, -1, None, 0.0, [(name, t)]) for name, t in attempts
                     if t.status == "error" and id(t) not in held_ids)  # failed before traffic
        units.sort(key=lambda u: (u[0], u[1], "" if u[2] is None else u[2].name))
        written: set[int] = set()
        for _, _, unit_part, offset_s, held in units:
            for name, trial in held:
                if id(trial) not in written and (self.run is None
                                                 or not self.run.has_trial_events(name, trial)):
                    self.trial(name, trial)
                written.add(id(trial))
            if unit_part is not None:
                self.merge(unit_part, offset_s)


def _drop(part: Path) -> None:
    log.info("dropping %s: its trial is not in the record", part.name)
    with contextlib.suppress(OSError):
        part.unlink()
