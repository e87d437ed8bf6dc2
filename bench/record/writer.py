"""The writer that keeps ``results.json`` of a run current while the run goes on."""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Iterable, Mapping
from pathlib import Path, PurePath
from typing import Any

from armbench.bench.record.comparison import Comparison
from armbench.bench.record.environment import utc_timestamp
from armbench.bench.record.fields import RecordError
from armbench.bench.record.files import RESULTS_FILE, atomic_write_bytes, path_inside
from armbench.bench.record.jsonformat import _JsonText, _to_json_text
from armbench.bench.record.model import Measurement, SuiteRecord, Trial, _unique_names
from armbench.bench.record.run import RunRecord, load_record

__all__ = ["RecordWriter"]


class RecordWriter:
    """Keeps ``results.json`` of one run up to date in ``out_dir``.

    The record is written when the writer is created, after every trial, at the end of every
    suite and on :meth:`write`; each write is atomic, so the file on disk is always a complete,
    valid record of everything measured so far. Typical use by a suite::

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
        self._trial_text: dict[int, tuple[Trial, _JsonText]] = {}
        self._base_s = record.end_s
        self._t0 = time.monotonic()
        self.write()

    @classmethod
    def resume(cls, out_dir: str | Path, *, filename: str = RESULTS_FILE) -> RecordWriter:
        """Continue the interrupted run in ``out_dir``: load and validate its record, remove
        temporary files a crash may have left, note the resume time (``record.resumed``) and
        continue the run clock where the record stopped."""
        directory = Path(out_dir)
        path = path_inside(directory, filename)
        record = load_record(path)
        for stale in directory.glob(f".{path.name}.*.tmp"):
            with contextlib.suppress(OSError):
                stale.unlink()
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
        """Write the record now (atomically); returns its path."""
        doc = self.record.to_json()
        for name, suite in self.record.suites.items():
            for key, trials in (("trials", suite.trials),
                                ("superseded_trials", suite.superseded_trials)):
                doc["suites"][name][key] = [self._encoded(name, t) for t in trials]
        text = _to_json_text(doc, str(self.path))
        atomic_write_bytes(self.path, (text + "\n").encode("utf-8"))
        return self.path

    def _encoded(self, suite: str, trial: Trial) -> _JsonText:
        """The JSON text of a trial, encoded once (trials are final once added)."""
        cached = self._trial_text.get(id(trial))
        if cached is not None and cached[0] is trial:
            return cached[1]
        # A trial sits at depth 4: record > suites > <suite> > trials > [trial].
        text = _JsonText(_to_json_text(trial.to_json(),
                                       f"suites.{suite}.trials[index {trial.index}]", level=4))
        self._trial_text[id(trial)] = (trial, text)
        return text

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
        """Add a finished trial (done or errored) to suite ``name`` and write the record.

        A trial re-measuring an errored one (same index) moves the old one to
        ``superseded_trials``; re-measuring a done trial is an error.
        """
        suite = self.suite(name)
        if suite.status != "running":
            raise RecordError(f"suites.{name}", f"is {suite.status}; begin it before adding trials")
        self._encoded(name, trial)
        for i, old in enumerate(suite.trials):
            if old.index == trial.index:
                if old.status == "done":
                    raise RecordError(f"suites.{name}.trials[index {trial.index}]",
                                      "is already measured")
                suite.superseded_trials.append(suite.trials.pop(i))
                break
        suite.trials.append(trial)
        suite.trials.sort(key=lambda t: t.index)
        self.write()

    def end_suite(self, name: str, measurements: Iterable[Measurement] = (), *,
                  error: str | None = None, ended_s: float | None = None) -> None:
        """End suite ``name`` with its suite-level ``measurements`` and write the record.

        With ``error`` the suite ends as ``"error"`` (a resumed run continues it). Suite-level
        names must be unique across the record. ``ended_s`` (s, run time) defaults to now.
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
        self.write()

    def set_baseline(self, comparison: Comparison | None) -> None:
        """Store the baseline comparison in the record and write it."""
        self.record.baseline = comparison
        self.write()
