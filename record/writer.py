"""The writer that keeps the record of a run on disk while the run goes on: ``results.json`` at
checkpoints, the trials in between appended to its journal (``armbench.record.journal``)."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
import time
from collections.abc import Iterable, Mapping
from dataclasses import replace
from pathlib import Path, PurePath
from typing import IO, Any, BinaryIO, cast

from armbench.drivers.capture.jsonl import capture_end_s
from armbench.record.comparison import Comparison
from armbench.record.environment import utc_timestamp
from armbench.record.fields import RecordError
from armbench.record.files import CAPTURE_FILE, RESULTS_FILE, atomic_write, path_inside
from armbench.record.journal import StoredSamples, append_line, journal_path
from armbench.record.jsonformat import Placeholder, _to_json_text, iter_encode, json_line
from armbench.record.measurement import Measurement, SuiteRecord, Trial, _unique_names
from armbench.record.run_record import RunRecord, load_record

__all__ = ["RecordWriter", "continued_clock_s"]

#: The depth a trial has in ``results.json`` (``suites.NAME.trials[i]``), until a write says.
_TRIAL_LEVEL = 4


def continued_clock_s(out_dir: Path, record: RunRecord) -> float:
    """The run time (s) a run continues from in ``out_dir``: the latest time its record or its
    capture (``capture.jsonl`` and the parts of connections a kill left unmerged) mentions, so
    that neither jumps back after a resume. A worker's parts (``-job-``) are on their own clock
    and inside their recorded trials."""
    captures = [out_dir / CAPTURE_FILE,
                *(p for p in out_dir.glob(".capture.part*.part") if "-job-" not in p.name)]
    ends = [t for p in captures if (t := capture_end_s(p)) is not None]
    return max([record.end_s, *ends])


class RecordWriter:
    """Keeps ``results.json`` of one run up to date in ``out_dir``.

    ``results.json`` is written when the writer is created, when a suite begins or ends, when the
    baseline is set and on :meth:`write`, each time atomically and streamed trial by trial; a
    trial that ends in between is appended to the journal beside it (one fsynced line), so
    keeping a trial costs that trial's size, however many came before, and the files on disk
    always hold everything measured so far (:func:`load_record` reads both). A kept trial's
    samples stay on disk (:class:`StoredSamples`), so memory holds one trial's samples at a
    time. Typical use by a suite::

        suite = writer.begin_suite("accuracy", version="1", params=params)
        done = {t.index for t in writer.completed_trials("accuracy")}
        for i in range(n):
            if i in done:
                continue        # measured before an interruption
            t0 = writer.elapsed_s()
            ...
            writer.add_trial("accuracy", Trial(i, t0, writer.elapsed_s() - t0, ...))
        writer.end_suite("accuracy", measurements)

    A new writer refuses a directory that already holds a record unless ``overwrite``; use
    :meth:`resume` to continue one.
    """

    def __init__(self, out_dir: str | Path, record: RunRecord, *,
                 filename: str = RESULTS_FILE, overwrite: bool = False) -> None:
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        if len(PurePath(filename).parts) != 1:
            raise RecordError("file name", f"{filename!r} must be a plain file name")
        self.path = path_inside(self.out_dir, filename)
        if self.path.exists() and not overwrite:
            raise RecordError(str(self.path), "already holds a run record; resume it or choose "
                                              "another run directory")
        self.record = record
        self.journal = journal_path(self.path)
        self._base_s = continued_clock_s(self.out_dir, record)
        self._t0 = time.monotonic()
        self._written: dict[int, tuple[Trial, int]] = {}
        """The trials :meth:`write` put in ``results.json``, by their samples' identity, with
        the level they were encoded at."""
        self._ahead: IO[bytes] | None = None
        """Where :meth:`add_trial` leaves each trial's text as :meth:`write` will put it in
        ``results.json``: a nameless temporary file beside the record (gone with the writer,
        or its process), emptied by each write."""
        self._encoded: dict[int, tuple[Trial, int, int, int]] = {}
        """The trials in :attr:`_ahead`, by identity: the trial, its level, offset and
        length."""
        self._trial_level = _TRIAL_LEVEL
        # temporary files of a writer killed mid-write (the run folder's lock keeps any other
        # writer out): a fresh run into the folder of one that died before its first record
        # removes them as a resume does
        for stale in self.out_dir.glob(f".{self.path.name}.*.tmp"):
            with contextlib.suppress(OSError):
                stale.unlink()
        self.write()

    @classmethod
    def resume(cls, out_dir: str | Path, *, filename: str = RESULTS_FILE) -> RecordWriter:
        """Continue the interrupted run in ``out_dir``: load and validate its record, note the
        resume time (``record.resumed``) and continue the run clock where the record stopped
        (temporary files a crash may have left are removed as for a new writer)."""
        directory = Path(out_dir)
        path = path_inside(directory, filename)
        record = load_record(path)  # with the journal's trials
        record.resumed.append(utc_timestamp())
        return cls(directory, record, filename=filename, overwrite=True)

    def elapsed_s(self) -> float:
        """Run time (s): monotonic seconds since the run started, continuing after a resume
        from the latest time in the record (the interruption itself does not count)."""
        return self._base_s + time.monotonic() - self._t0

    def artifact_path(self, name: str | PurePath) -> Path:
        """A path for another file of this run (``junit.xml``, plots), refused if it would leave
        the run directory."""
        return path_inside(self.out_dir, name)

    def write(self) -> Path:
        """Write ``results.json`` now (atomically, streamed trial by trial) and empty the
        journal, whose trials it now holds; returns its path.

        A trial this writer put in ``results.json`` before, unchanged since (the same trial
        object, its samples still there), is copied from the file being replaced instead of
        encoded again: its text is the same, and a run writes the record at every suite's begin
        and end."""
        placed: list[tuple[Trial, int, int, int]] = []
        suite_of = {id(t): name for name, suite in self.record.suites.items()
                    for t in (*suite.trials, *suite.superseded_trials)}
        written = self._written

        def trial_json(trial: Trial) -> Placeholder:
            return Placeholder(trial)

        def text_of(trial: Trial, level: int, old: BinaryIO | None,
                    ahead: IO[bytes] | None) -> bytes:
            self._trial_level = level
            samples = trial.samples
            seen = written.get(id(samples))
            if (old is not None and seen is not None and seen[0] is trial and seen[1] == level
                    and isinstance(samples, StoredSamples) and samples.path == self.path
                    and not samples.entry):
                old.seek(samples.offset)
                data = old.read(samples.length)
                if len(data) == samples.length:
                    return data
            cached = encoded.get(id(trial))
            if ahead is not None and cached is not None and cached[0] is trial \
                    and cached[1] == level:
                ahead.seek(cached[2])
                data = ahead.read(cached[3])
                if len(data) == cached[3]:
                    return data
            text = _to_json_text(trial.to_json(), f"suites.{suite_of[id(trial)]}"
                                 f".trials[index {trial.index}]", level=level)
            return text.encode("utf-8")

        def stream(fh: BinaryIO) -> None:
            offset = 0
            old = ahead = None
            if written:
                with contextlib.suppress(OSError):
                    old = self.path.open("rb")
            if encoded:
                ahead = self._ahead
            try:
                for piece in iter_encode(self.record.to_json(trial_json)):
                    if isinstance(piece, Placeholder):
                        trial = cast(Trial, piece.item)
                        data = text_of(trial, piece.level, old, ahead)
                        placed.append((trial, offset, len(data), piece.level))
                    else:
                        data = piece.encode("utf-8")
                    fh.write(data)
                    offset += len(data)
                fh.write(b"\n")
            finally:
                if old is not None:
                    old.close()

        encoded, self._encoded = self._encoded, {}
        self._written = {}
        try:
            atomic_write(self.path, stream)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, RecordError):
                raise
            raise RecordError(str(self.path), f"cannot be stored as JSON: {exc}") from None
        stored = {id(t): StoredSamples(self.path, offset, length, len(t.samples), entry=False)
                  for t, offset, length, _level in placed if t.samples}
        for t, offset, length, _level in placed:
            if isinstance(t.samples, StoredSamples):
                t.samples.move(self.path, offset, length, entry=False)
        final: dict[int, Trial] = {}
        for suite in self.record.suites.values():
            for trials in (suite.trials, suite.superseded_trials):
                for k, t in enumerate(trials):
                    if not isinstance(t.samples, StoredSamples) and id(t) in stored:
                        trials[k] = replace(t, samples=stored[id(t)])
                    final[id(t)] = trials[k]
        for t, _offset, _length, level in placed:
            kept = final.get(id(t))
            if kept is not None and isinstance(kept.samples, StoredSamples):
                self._written[id(kept.samples)] = (kept, level)
        with contextlib.suppress(FileNotFoundError):
            self.journal.unlink()
        if self._ahead is not None:
            with contextlib.suppress(OSError):
                self._ahead.seek(0)
                self._ahead.truncate()
        return self.path

    @property
    def ahead_trials(self) -> int:
        """Trials encoded as they were added and not yet in ``results.json``."""
        return len(self._encoded)

    # -- suites --------------------------------------------------------------------------

    def suite(self, name: str) -> SuiteRecord:
        """The record of suite ``name``; RecordError if it has not begun."""
        try:
            return self.record.suites[name]
        except KeyError:
            raise RecordError(f"suites.{name}", "has not begun") from None

    def suite_done(self, name: str) -> bool:
        """True when suite ``name`` ended without error (a resumed run skips it)."""
        s = self.record.suites.get(name)
        return s is not None and s.status == "done"

    def completed_trials(self, name: str) -> list[Trial]:
        """The finished (status ``"done"``) trials of suite ``name``, by index; empty if the suite
        has not begun. A resumed suite measures every other index again."""
        s = self.record.suites.get(name)
        return [] if s is None else s.completed_trials()

    def begin_suite(self, name: str, version: str, params: Mapping[str, Any] | None = None, *,
                    started_s: float | None = None) -> SuiteRecord:
        """Start suite ``name`` (or continue it after a resume) and write the record.

        Continuing needs the same ``version`` and ``params`` as recorded, so trials measured
        under different conditions never mix. A suite already ``"done"`` is returned unchanged.
        ``started_s`` (s, run time) defaults to now.
        """
        params_json = json.loads(_to_json_text(dict(params or {}), f"suites.{name}.params"))
        existing = self.record.suites.get(name)
        if existing is not None:
            if existing.version != version:
                raise RecordError(f"suites.{name}.version", f"recorded {existing.version!r}, "
                                  f"resumed with {version!r}; start a new run")
            if existing.params != params_json:
                raise RecordError(f"suites.{name}.params", "differ from the recorded ones; "
                                  "start a new run")
            if existing.status == "done":
                return existing
            existing.status, existing.error, existing.ended_s = "running", None, None
        else:
            existing = SuiteRecord(name=name, version=version, params=params_json,
                                   started_s=self.elapsed_s() if started_s is None else started_s)
            self.record.suites[name] = existing
            if name not in self.record.planned_suites:
                self.record.planned_suites.append(name)
        self.write()
        return existing

    def add_trial(self, name: str, trial: Trial) -> None:
        """Add a finished trial (done or errored) to suite ``name`` and keep it on disk.

        A trial re-measuring an errored one (same index) moves the old one to
        ``superseded_trials``; re-measuring a done trial is an error. The trial is appended to
        the journal (``results.json`` is rewritten at the suite's end); its samples are kept
        there, not in memory.
        """
        suite = self.suite(name)
        if suite.status != "running":
            raise RecordError(f"suites.{name}", f"is {suite.status}; begin it before adding trials")
        where = f"suites.{name}.trials[index {trial.index}]"
        line = json_line({"suite": name, "trial": trial.to_json()}, where)
        old = suite.current(trial.index)
        if old is not None and old.status == "done":
            raise RecordError(where, "is already measured")
        offset, length = append_line(self.journal, line)
        text = self._encode_ahead(trial, where)
        if trial.samples and not isinstance(trial.samples, StoredSamples):
            trial = replace(trial, samples=StoredSamples(self.journal, offset, length,
                                                         len(trial.samples), entry=True))
        suite.place(trial)
        if text is not None:
            self._keep_ahead(trial, text)

    def _encode_ahead(self, trial: Trial, where: str) -> bytes | None:
        """The text :meth:`write` will put in ``results.json`` for ``trial``, encoded now,
        while its samples are in memory and the run goes on, instead of at the suite's end
        (where a suite of 150 trials made the run wait for all of them); None if it cannot be
        (:meth:`write` says why)."""
        try:
            return _to_json_text(trial.to_json(), where, level=self._trial_level).encode("utf-8")
        except RecordError:
            return None

    def _keep_ahead(self, trial: Trial, text: bytes) -> None:
        """Keep ``text`` (``trial``'s) in :attr:`_ahead`; a write that fails leaves it out
        (it is encoded again when needed)."""
        try:
            if self._ahead is None:
                # kept open while the writer is: a nameless file no crash leaves behind
                self._ahead = tempfile.TemporaryFile(dir=self.out_dir)  # noqa: SIM115
            offset = self._ahead.seek(0, os.SEEK_END)
            self._ahead.write(text)
        except OSError:
            return
        self._encoded[id(trial)] = (trial, self._trial_level, offset, len(text))

    def end_suite(self, name: str, measurements: Iterable[Measurement] = (), *,
                  error: str | None = None, ended_s: float | None = None,
                  wall_s: float | None = None) -> None:
        """End suite ``name`` with its suite-level ``measurements`` and write the record.

        With ``error`` the suite ends as ``"error"`` (a resumed run continues it). Suite-level
        names must be unique across the record. ``ended_s`` (s, run time) defaults to now;
        ``wall_s`` is the wall-clock seconds the suite took, if measured.
        """
        suite = self.suite(name)
        ms = list(measurements)
        _unique_names(ms, f"suites.{name}.measurements")
        for other in self.record.suites.values():
            if other is suite:
                continue
            clash = {m.name for m in other.measurements} & {m.name for m in ms}
            if clash:
                raise RecordError(f"suites.{name}.measurements",
                                  f"{sorted(clash)[0]!r} is also a measurement of suite "
                                  f"{other.name!r}")
        suite.measurements = ms
        suite.status = "done" if error is None else "error"
        suite.error = error
        suite.ended_s = self.elapsed_s() if ended_s is None else ended_s
        suite.wall_s = wall_s
        self.write()

    def set_baseline(self, comparison: Comparison | None) -> None:
        """Store the baseline comparison in the record and write it."""
        self.record.baseline = comparison
        self.write()
