"""The run's traffic capture ``capture.mcap``: what the runner writes into it besides frames.

The driver of each connection writes a binary part (:class:`~armbench.drivers.capture.part.
PartWriter`: frames, the emulator's ground truth, power switches and faults, on that process's
loop clock); the runner adds each part to the run's :class:`~armbench.drivers.capture.mcap_writer.
McapCapture` once its trial is in the record, moved onto the run clock, with the trial's start
and end as events. At the end ``results.json`` is attached. A resumed run copies what the killed
run's file holds (up to its last complete chunk) into a new one, after the frames of an older
run's ``capture.jsonl`` (kept as it is), so the new file holds every session. A size bound is
kept by
adding a part only while the file, the part's bytes (more than it adds, compressed) and
:data:`CLOSING_BYTES` fit in it.
"""

from __future__ import annotations

import contextlib
import datetime
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from armbench.drivers.capture.append import ZSTD_MEDIA_TYPE, zstd_attachment
from armbench.drivers.capture.jsonl import CaptureError, read_capture
from armbench.drivers.capture.mcap_writer import McapCapture
from armbench.drivers.capture.part import PartWriter
from armbench.drivers.capture.read import capture_start_ns, iter_events, iter_messages
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings
from armbench.record import LEGACY_CAPTURE_FILE, RunRecord, Trial

__all__ = ["CLOSING_BYTES", "RunCapture"]

#: Bytes kept for what closing a bounded capture writes (stop event, tally, summary).
CLOSING_BYTES = 65_536


def _clock_of(port: str | None) -> str:
    """``"virtual"`` or ``"real"``: the clock of the port's target (real when no port is
    recorded or its target cannot be loaded here)."""
    from armbench.drivers.transports.target import target_of

    if port is None:
        return "real"
    try:
        return target_of(port).capabilities.clock
    except ArmbenchError:
        return "real"


class RunCapture:
    """The run's ``capture.mcap``, opened at the first part (a resumed run's earlier capture is
    carried over)."""

    def __init__(self, path: Path, settings: RobotSettings, record: RunRecord,
                 max_bytes: int | None = None) -> None:
        self.path = path
        self.settings = settings
        self.record = record
        self.max_bytes = max_bytes
        self.sink: McapCapture | None = None
        self._held: list[Path] = []
        """Parts added whose frames are not all on disk yet (deleted when they are)."""
        self.carried_events: set[tuple[str, str, int, int]] = set()
        """The bench events an earlier capture of the run holds, as (kind, suite, trial,
        ns): the trial events a resume must not write twice."""
        self.legacy_frames = 0
        """Frames carried over from an older run's ``capture.jsonl``."""

    def _metadata(self) -> dict[str, str]:
        env = self.record.environment
        return {"run_id": self.record.run_id, "created": self.record.created,
                "seed": str(env.seed), "port": str(env.port),
                "clock": _clock_of(env.port),
                "settings": json.dumps(self.settings.to_mapping(), sort_keys=True),
                "suites": json.dumps(self.record.planned_suites)}

    def open(self) -> McapCapture:
        """The writer (created on first use), holding what the run captured before a resume:
        an older run's ``capture.jsonl``, then the file a killed or interrupted session left."""
        if self.sink is None:
            earlier = self.path.with_name(f".{self.path.name}.earlier")
            if self.path.exists():
                os.replace(self.path, earlier)
            start_ns = run_start_ns(self.record.created)
            if earlier.exists():  # the file keeps the start its earlier part counted from
                with contextlib.suppress(Exception):
                    start_ns = capture_start_ns(earlier) or start_ns
            self.sink = McapCapture(self.path, self.settings, start_ns=start_ns,
                                    metadata=self._metadata())
            legacy = self.path.with_name(LEGACY_CAPTURE_FILE)
            if legacy.exists() and not _holds_frames(earlier):
                self._carry_legacy(legacy)
            if earlier.exists():
                with contextlib.suppress(Exception):
                    earlier_ns = capture_start_ns(earlier)
                    for event in iter_events(earlier):
                        self.carried_events.add(_event_key(event, earlier_ns))
                with contextlib.suppress(Exception):
                    self.sink.copy_messages(iter_messages(earlier))
                earlier.unlink()
        return self.sink

    def _carry_legacy(self, legacy: Path) -> None:
        """The frames of an older run's ``capture.jsonl`` (times on the run clock), through a
        part file, as a part a connection writes; the JSON Lines file stays as it is."""
        assert self.sink is not None
        part = self.path.with_name(f".{legacy.name}.part")
        writer = PartWriter(part, 0.0)
        try:
            for record in read_capture(legacy):
                writer.write(record.t_s, record.dir, record.frame, record.error)
                self.legacy_frames += 1
        except CaptureError as exc:  # what was read before the bad line is kept
            self.sink.traffic.events.append(f"{legacy.name} carried up to: {exc}")
        finally:
            writer.close()
        self.sink.add_part(part, 0.0)
        self.sink.flush()
        _unlink(part)

    def has_trial_events(self, suite: str, trial: Trial) -> bool:
        """Whether the capture carried over holds ``trial``'s start and end events."""
        start = ("trial_start", suite, trial.index, round(trial.started_s * 1e9))
        end = ("trial_end", suite, trial.index, round(trial.ended_s * 1e9))
        return start in self.carried_events and end in self.carried_events

    def _room(self) -> int | None:
        """Bytes the bound leaves (chunk in progress written first), None: unbounded."""
        if self.max_bytes is None:
            return None
        self.flush()
        size = self.path.stat().st_size if self.path.exists() else 0
        return self.max_bytes - CLOSING_BYTES - size

    def fits(self, part: Path) -> bool:
        """Whether ``part`` can be added within the size bound."""
        self.open()
        room = self._room()
        return room is None or part.stat().st_size <= room

    def stop(self, reason: str) -> None:
        """The capture stops at its bound (a ``capture_stopped`` event at the run's clock)."""
        self.open().stop(self.record.end_s, reason)

    def add_part(self, part: Path, offset_s: float) -> None:
        """Add a part; it is deleted once all its frames are on disk in complete chunks (so a
        run killed before that merges it again on resume, and never twice): when a chunk ended
        while it was added, the rest of it is written as a chunk of its own at once."""
        sink = self.open()
        chunks = sink.chunks
        sink.add_part(part, offset_s)
        if sink.chunks != chunks:
            self._release()  # the parts before this one are on disk
            sink.flush()
            _unlink(part)
        else:
            self._held.append(part)

    def _release(self) -> None:
        held, self._held = self._held, []
        for part in held:
            _unlink(part)

    def trial(self, suite: str, trial: Trial) -> None:
        """A trial's start and end as events (run clock)."""
        sink = self.open()
        sink.event(trial.started_s, "trial_start", suite, trial.index)
        sink.event(trial.ended_s, "trial_end", suite, trial.index,
                   {"status": trial.status, "error": trial.error})

    def flush(self) -> None:
        """Write what is buffered as complete chunks (and delete the parts it came from)."""
        if self.sink is not None:
            self.sink.flush()
            self._release()

    def finish(self, attachments: Mapping[str, Path]) -> None:
        """Attach the run's files, zstd-compressed (``results.json`` as ``results.json.zst``: a
        default run's record is 5 MB of JSON, half the capture's budget), and close the file."""
        sink = self.open()
        try:
            for name, path in attachments.items():
                with contextlib.suppress(OSError):
                    zst_name, data = zstd_attachment(name, path)
                    room = self._room()
                    if room is None or len(data) <= room:
                        sink.attach(zst_name, data, ZSTD_MEDIA_TYPE)
        finally:
            sink.close()
            self._release()


def _event_key(event: Any, start_ns: int) -> tuple[str, str, int, int]:
    """(kind, suite, trial, run-clock ns) of a carried event (its stamp less the start)."""
    stamp = event.stamp
    return (str(event.kind), str(event.suite), int(event.trial),
            int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec) - start_ns)


def run_start_ns(created: str) -> int:
    """Nanoseconds since the epoch of a record's ``created`` label (the run clock's zero in the
    capture); 0 when the label is not an ISO 8601 time (the capture then counts from 0)."""
    try:
        when = datetime.datetime.fromisoformat(created)
    except ValueError:
        return 0
    if when.tzinfo is None:
        when = when.replace(tzinfo=datetime.UTC)
    return max(0, round(when.timestamp() * 1e6) * 1000)


def _holds_frames(capture: Path) -> bool:
    """Whether an MCAP capture holds a frame (up to its last complete chunk)."""
    if not capture.exists():
        return False
    try:
        return next(iter_messages(capture, ("/uart/rx", "/uart/tx")), None) is not None
    except CaptureError:
        return False


def _unlink(path: Path) -> None:
    with contextlib.suppress(OSError):
        path.unlink()
