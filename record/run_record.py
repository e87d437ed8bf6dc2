"""The whole run (:class:`RunRecord`, the content of ``results.json``), its verdict, and
reading it back: :func:`validate_record` checks parsed JSON, :func:`load_record` a file (with
the journal of the trials finished since it was written)."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import get_args

from armbench.drivers.model.user_files import FileRefused, read_regular_file
from armbench.record.comparison import Comparison
from armbench.record.environment import Environment, new_run_id, utc_timestamp
from armbench.record.fields import (
    RecordError,
    Verdict,
    _choice,
    _get,
    _list,
    _num,
    _obj,
    _str,
)
from armbench.record.journal import journal_path, read_journal
from armbench.record.limits import best_match
from armbench.record.measurement import Measurement, SuiteRecord, Trial
from armbench.record.shapes import RecordJson

__all__ = ["PAPER_REFERENCE", "SCHEMA", "TOO_DEEP", "RunRecord", "load_record", "replay_journal",
           "validate_record"]

#: The schema identifier of the records this module writes and reads.
SCHEMA = "armbench-run/1"
#: What a file nested beyond the JSON parser's depth is called (it is no run record).
TOO_DEEP = "is nested too deeply to be a run record"
#: The paper's figures the report shows next to ours (mean Euclidean path error of §7, mm).
PAPER_REFERENCE: Mapping[str, float] = {"paper_mean_error_mm": 12.4}


#: The key of a campaign suite's parameters (``armbench.bench.campaign.CAMPAIGN_KEY``).
_CAMPAIGN_KEY = "campaign"


@dataclass(slots=True, kw_only=True)
class RunRecord:
    """The whole run. Mutable: :class:`RecordWriter` fills it in.

    ``planned_suites`` are the suites the run means to execute, in order; ``required`` what the
    run must measure to pass (suite names, metric names or ``*`` patterns; an untested one makes
    the verdict ``untested``); ``suites`` those started so far, by name; ``resumed`` the
    wall-clock labels of each resume; ``baseline`` the comparison
    with a baseline run, if one was given; ``reference`` the paper's figures for the report.
    """

    run_id: str
    created: str
    environment: Environment
    planned_suites: list[str] = field(default_factory=list)
    required: list[str] = field(default_factory=list)
    suites: dict[str, SuiteRecord] = field(default_factory=dict)
    resumed: list[str] = field(default_factory=list)
    baseline: Comparison | None = None
    reference: dict[str, float] = field(default_factory=lambda: dict(PAPER_REFERENCE))
    schema: str = SCHEMA

    @classmethod
    def new(cls, environment: Environment, planned_suites: Iterable[str] = (), *,
            run_id: str | None = None) -> RunRecord:
        """A fresh record created now, with a new run id unless one is given."""
        return cls(run_id=run_id or new_run_id(), created=utc_timestamp(),
                   environment=environment, planned_suites=list(planned_suites))

    def iter_measurements(self) -> Iterator[tuple[SuiteRecord, Trial | None, Measurement]]:
        """Every current measurement as (suite, trial or None for suite-level, measurement);
        superseded trials are left out."""
        for suite in self.suites.values():
            for trial in suite.trials:
                for m in trial.measurements:
                    yield suite, trial, m
            for m in suite.measurements:
                yield suite, None, m

    @property
    def end_s(self) -> float:
        """The latest run time (s) the record mentions: where a resumed run's clock continues."""
        times = [0.0]
        for s in self.suites.values():
            times.append(s.started_s)
            if s.ended_s is not None:
                times.append(s.ended_s)
            times.extend(t.ended_s for t in (*s.trials, *s.superseded_trials))
        return max(times)

    def suite_measurements(self) -> dict[str, Measurement]:
        """The suite-level measurements of all suites, by name (names are unique in a record)."""
        return {m.name: m for s in self.suites.values() for m in s.measurements}

    def disturbed_trials(self) -> list[tuple[str, int]]:
        """The current trials the link to the arm was lost during, as (suite, index)."""
        return [(s.name, t.index) for s in self.suites.values() for t in s.trials if t.disturbed]

    def disturbance_note(self) -> str | None:
        """The run-level line on disturbed trials (``"2 trials disturbed by link outages:
        accuracy 3, 4"``), None when no trial was."""
        disturbed = self.disturbed_trials()
        if not disturbed:
            return None
        by_suite: dict[str, list[str]] = {}
        for name, index in disturbed:
            by_suite.setdefault(name, []).append(str(index))
        shown = "; ".join(f"{name} {', '.join(ix[:10])}" + (" ..." if len(ix) > 10 else "")
                          for name, ix in by_suite.items())
        n = len(disturbed)
        return (f"{n} trial{'s' if n != 1 else ''} disturbed by link outages ({shown}): their "
                "measurements are kept but flagged")

    def untested(self) -> list[tuple[str, str, bool]]:
        """What the run measured nothing of, as ``(name, reason, required)``: every finished
        suite that is untested (:meth:`SuiteRecord.untested_reason`), then every required metric
        pattern that no current measurement matches. Only a required one changes the verdict."""
        out: list[tuple[str, str, bool]] = []
        for suite in self.suites.values():
            reason = suite.untested_reason()
            if reason is not None:
                out.append((suite.name, reason, suite.name in self.required))
        names = [m.name for _, _, m in self.iter_measurements()]
        for pattern in self.required:
            if pattern in self.planned_suites or pattern in self.suites:
                continue
            if not any(best_match((pattern,), n) for n in names):
                out.append((pattern, "not measured by any suite of the run", True))
        return out

    def suite_verdict(self, name: str) -> Verdict:
        """One suite's verdict, with the run's precedence: ``error``, ``incomplete`` (also a
        planned suite that never started), ``fail``, ``untested`` (it measured nothing),
        ``regression`` (one of its metrics regressed), ``pass``."""
        suite = self.suites.get(name)
        if suite is None:
            return "incomplete"
        if suite.status == "error" or any(t.status == "error" for t in suite.trials):
            return "error"
        if suite.status == "running":
            return "incomplete"
        if any(m.outcome == "fail" for m in _judged(suite)):
            return "fail"
        if suite.untested_reason() is not None:
            return "untested"
        if self.baseline is not None:
            names = {m.name for m in suite.measurements}
            if any(r.regressed and r.name in names for r in self.baseline.rows):
                return "regression"
        return "pass"

    @property
    def verdict(self) -> Verdict:
        """The run's verdict, first that applies: ``"error"`` (a suite or current trial errored),
        ``"incomplete"`` (a planned suite did not start or did not end), ``"fail"`` (a measurement
        outside its limit), ``"untested"`` (a required suite or metric measured nothing),
        ``"regression"`` (worse than the baseline), else ``"pass"``.

        A campaign suite (its parameters hold ``campaign``) is judged by its suite-level figures
        (the pass probabilities against their limits): a sample outside a limit is one of the
        campaign's findings, counted in those figures, not the campaign's failure."""
        suites = self.suites.values()
        if any(s.status == "error" or any(t.status == "error" for t in s.trials) for s in suites):
            return "error"
        if (any(s.status == "running" for s in suites)
                or any(name not in self.suites for name in self.planned_suites)):
            return "incomplete"
        if any(m.outcome == "fail" for s in suites for m in _judged(s)):
            return "fail"
        if any(required for _, _, required in self.untested()):
            return "untested"
        if self.baseline is not None and self.baseline.regressed:
            return "regression"
        return "pass"

    def to_json(self, trial_json: Callable[[Trial], object] = Trial.to_json) -> RecordJson:
        """The JSON object of the record (the content of ``results.json``); ``trial_json`` as in
        :meth:`SuiteRecord.to_json`."""
        return {
            "schema": self.schema,
            "run_id": self.run_id,
            "created": self.created,
            "resumed": list(self.resumed),
            "verdict": self.verdict,
            "reference": dict(self.reference),
            "environment": self.environment.to_json(),
            "planned_suites": list(self.planned_suites),
            "required": list(self.required),
            "baseline": None if self.baseline is None else self.baseline.to_json(),
            "suites": {name: s.to_json(trial_json) for name, s in self.suites.items()},
        }


def _judged(suite: SuiteRecord) -> Iterator[Measurement]:
    """The measurements that judge ``suite``: a campaign's suite-level figures only, else
    every current one."""
    if _CAMPAIGN_KEY not in suite.params:
        for t in suite.trials:
            yield from t.measurements
    yield from suite.measurements


def validate_record(data: object) -> RunRecord:
    """Check a parsed ``results.json`` and build its :class:`RunRecord`.

    Raises :class:`RecordError` naming the field for a record of another schema, a missing field
    or a value of the wrong type. The stored ``verdict`` is checked for form only; the record's
    verdict is recomputed from its content. Unknown keys are ignored.
    """
    d = _obj(data, "record")
    if "schema" not in d:
        raise RecordError("schema", f"missing: not an armbench run record (expected {SCHEMA!r})")
    if d["schema"] != SCHEMA:
        raise RecordError("schema", f"{d['schema']!r} is not supported (this armbench reads "
                                    f"{SCHEMA!r})")
    _choice(_get(d, "verdict", ""), "verdict", get_args(Verdict))
    suites_data = _obj(_get(d, "suites", ""), "suites")
    suites: dict[str, SuiteRecord] = {}
    for name, s in suites_data.items():
        suite = SuiteRecord.from_json(s, f"suites.{name}")
        if suite.name != name:
            raise RecordError(f"suites.{name}.name", f"{suite.name!r} differs from its key")
        suites[name] = suite
    seen: dict[str, str] = {}
    for suite in suites.values():
        for m in suite.measurements:
            if m.name in seen:
                raise RecordError(f"suites.{suite.name}.measurements",
                                  f"{m.name!r} is also a measurement of suite {seen[m.name]!r}")
            seen[m.name] = suite.name
    baseline = _get(d, "baseline", "")
    reference = _obj(_get(d, "reference", ""), "reference")
    resumed = _list(_get(d, "resumed", ""), "resumed")
    planned = _list(_get(d, "planned_suites", ""), "planned_suites")
    required = _list(d.get("required", []), "required")  # absent before issue 37
    return RunRecord(
        run_id=_str(_get(d, "run_id", ""), "run_id"),
        created=_str(_get(d, "created", ""), "created"),
        environment=Environment.from_json(_get(d, "environment", ""), "environment"),
        planned_suites=[_str(p, f"planned_suites[{i}]") for i, p in enumerate(planned)],
        required=[_str(r, f"required[{i}]") for i, r in enumerate(required)],
        suites=suites,
        resumed=[_str(r, f"resumed[{i}]") for i, r in enumerate(resumed)],
        baseline=None if baseline is None else Comparison.from_json(baseline, "baseline"),
        reference={k: _num(v, f"reference.{k}") for k, v in reference.items()},
    )


def load_record(path: str | Path) -> RunRecord:
    """Read and validate a ``results.json`` and replay its journal; errors name the file and the
    field. Whatever keeps the file from being a record (not a regular file, not JSON, an integer
    beyond Python's digit limit, nesting beyond the parser's depth) is a :class:`RecordError`
    naming the file, never another exception."""
    p = Path(path)
    try:
        data = json.loads(read_regular_file(p, "a results.json"))
        record = validate_record(data)
    except FileRefused as exc:
        raise RecordError(str(p), exc.reason) from None
    except RecordError as exc:
        raise RecordError(f"{p}: {exc.where}", exc.reason) from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RecordError(str(p), f"is not valid JSON: {exc}") from None
    except ValueError as exc:  # an integer of more digits than int() converts
        raise RecordError(str(p), f"is not a run record: {_plain_reason(exc)}") from None
    except RecursionError:
        raise RecordError(str(p), TOO_DEEP) from None
    journal = journal_path(p)
    try:
        replay_journal(record, journal)
    except RecordError:
        raise
    except ValueError as exc:
        raise RecordError(str(journal), f"is not a journal of trials: {_plain_reason(exc)}") \
            from None
    except RecursionError:
        raise RecordError(str(journal), TOO_DEEP) from None
    return record


def _plain_reason(exc: ValueError) -> str:
    """The reason of a parser's ValueError without Python's advice to the programmer (``; use
    sys.set_int_max_str_digits() ...``)."""
    return str(exc).split("; use sys.", 1)[0]


def replay_journal(record: RunRecord, path: Path) -> int:
    """Add the trials of journal ``path`` (the trials a run finished after its ``results.json``
    was last written) to ``record``, skipping those it already holds; returns how many were
    added. Errors name the journal line."""
    added = 0
    for number, entry in read_journal(path):
        where = f"{path}:{number}"
        suite = record.suites.get(entry["suite"])
        if suite is None:
            raise RecordError(where, f"suite {entry['suite']!r} is not in the record")
        trial = Trial.from_json(entry["trial"], f"{where}: trial")
        if suite.holds(trial):
            continue
        try:
            suite.place(trial)
        except RecordError as exc:
            raise RecordError(where, f"{exc.where}: {exc.reason}") from None
        added += 1
    return added

