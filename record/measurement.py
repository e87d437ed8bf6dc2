"""What a run measured: a :class:`Measurement` (one judged figure), a :class:`Trial` (one
repetition with its raw samples) and a :class:`SuiteRecord` (one suite's trials and summary)."""

from __future__ import annotations

import bisect
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypedDict, get_args

from armbench.drivers.model.settings import SettingsError
from armbench.record.fields import (
    Better,
    Outcome,
    RecordError,
    SuiteStatus,
    TrialStatus,
    _choice,
    _get,
    _int,
    _list,
    _located,
    _num,
    _obj,
    _opt_num,
    _opt_str,
    _str,
)
from armbench.record.journal import StoredSamples
from armbench.record.limits import Limit, LimitsConfig
from armbench.record.shapes import MeasurementJson, SuiteJson, TrialJson

__all__ = ["Measurement", "SuiteRecord", "Trial", "default_better", "judge"]

#: Units whose metrics are errors or durations: smaller is better unless a suite says otherwise.
_LOWER_IS_BETTER_UNITS = frozenset({"mm", "um", "m", "rad", "mrad", "deg", "s", "ms", "us"})


def default_better(unit: str) -> Better | None:
    """The regression direction of a unit: ``"lower"`` for lengths, angles and durations
    (errors, times), None (no direction: changes are shown, never regressions) otherwise."""
    return "lower" if unit in _LOWER_IS_BETTER_UNITS else None


@dataclass(frozen=True, slots=True)
class Measurement:
    """One named figure: ``value`` in ``unit``, the ``limit`` it was judged against and the
    ``outcome``; ``better`` is the regression direction (None: changes are never regressions).

    ``value`` must be finite: a figure that cannot be computed makes the trial an error instead.
    """

    name: str
    value: float
    unit: str
    limit: Limit | None
    outcome: Outcome
    better: Better | None
    description: str = ""

    def __post_init__(self) -> None:
        where = f"measurement {self.name!r}"
        if not self.name or "*" in self.name:
            raise RecordError(where, "a measurement needs a name without wildcards")
        object.__setattr__(self, "value", _num(self.value, f"{where}.value"))
        _choice(self.outcome, f"{where}.outcome", get_args(Outcome))
        _choice(self.better, f"{where}.better", (*get_args(Better), None))

    def to_json(self) -> MeasurementJson:
        """The JSON object of this measurement."""
        return {
            "name": self.name,
            "value": self.value,
            "unit": self.unit,
            "outcome": self.outcome,
            "limit": None if self.limit is None else self.limit.to_json(),
            "better": self.better,
            "description": self.description,
        }

    @classmethod
    def from_json(cls, data: object, where: str) -> Measurement:
        """Parse a measurement object; ``where`` is its dotted path, for errors."""
        d = _obj(data, where)
        limit_data = _get(d, "limit", where)
        limit = None
        if limit_data is not None:
            lw = f"{where}.limit"
            ld = _obj(limit_data, lw)
            limit = Limit(
                metric=_str(_get(ld, "metric", lw), f"{lw}.metric"),
                unit=_str(_get(ld, "unit", lw), f"{lw}.unit"),
                low=_opt_num(_get(ld, "low", lw), f"{lw}.low"),
                high=_opt_num(_get(ld, "high", lw), f"{lw}.high"),
            )
        name = _str(_get(d, "name", where), f"{where}.name")
        value = _num(_get(d, "value", where), f"{where}.value")
        unit = _str(_get(d, "unit", where), f"{where}.unit")
        outcome = _choice(_get(d, "outcome", where), f"{where}.outcome", get_args(Outcome))
        better = _choice(_get(d, "better", where), f"{where}.better", (*get_args(Better), None))
        description = _str(d.get("description", ""), f"{where}.description")
        with _located(where):
            return cls(name, value, unit, limit, outcome, better, description)


def judge(
    name: str,
    value: float,
    unit: str,
    limits: LimitsConfig | None,
    *,
    better: Better | None = None,
    description: str = "",
) -> Measurement:
    """Measure ``name`` = ``value`` ``unit`` and judge it against its limit in ``limits``.

    Outcome ``"pass"``/``"fail"`` when a limit matches (most specific wildcard wins),
    ``"unjudged"`` when none does or ``limits`` is None. ``better`` defaults to
    :func:`default_better` of the unit. A limit in another unit than the measurement raises
    ``SettingsError`` naming the limit (the file is wrong, not the robot).
    """
    limit = None if limits is None else limits.limit_for(name)
    if limit is not None and limit.unit != unit:
        raise SettingsError(f'limits."{limit.metric}".unit', limit.unit,
                            f"does not match the unit {unit!r} of measurement {name!r}")
    if limit is None:
        outcome: Outcome = "unjudged"
    else:
        outcome = "pass" if limit.check(value) else "fail"
    return Measurement(name, value, unit, limit, outcome,
                       default_better(unit) if better is None else better, description)


def _wall_s(value: float | None, where: str) -> float | None:
    """A wall-clock time (s): None, or a finite number >= 0."""
    if value is None:
        return None
    seconds = _num(value, where)
    if seconds < 0:
        raise RecordError(where, "must be >= 0")
    return seconds


class _WallJson(TypedDict, total=False):
    wall_s: float


def _wall_json(wall_s: float | None) -> _WallJson:
    """``{"wall_s": ...}`` when the time was measured, else nothing (records before it)."""
    return {} if wall_s is None else {"wall_s": wall_s}


def _unique_names(measurements: Sequence[Measurement], where: str) -> None:
    seen: set[str] = set()
    for m in measurements:
        if m.name in seen:
            raise RecordError(where, f"measurement {m.name!r} appears twice")
        seen.add(m.name)


@dataclass(frozen=True, slots=True)
class Trial:
    """One repetition of a suite's experiment.

    ``index`` counts from 0 within the suite; ``started_s`` (s, run time) and ``duration_s`` (s)
    place it on the run's clock; ``params`` are its inputs; ``samples`` the raw data (any JSON
    objects, e.g. ``{"t_s": ..., "reported_m": [x, y, z], "true_m": [x, y, z]}``);
    ``measurements`` the per-trial figures. ``status`` is ``"error"`` when the trial could not be
    carried out (lost port, timeout, bench bug), with ``error`` saying why; a robot that performs
    badly is a ``"done"`` trial with failed measurements.
    """

    index: int
    started_s: float
    duration_s: float
    params: Mapping[str, Any] = field(default_factory=dict)
    samples: Sequence[Mapping[str, Any]] = ()
    measurements: Sequence[Measurement] = ()
    status: TrialStatus = "done"
    error: str | None = None
    events: Sequence[Mapping[str, Any]] = ()
    """What happened to the bench during the trial (JSON objects with an ``"event"`` name, times
    ``*_t_s`` in seconds from the trial's start), e.g. each ``"link outage"`` of the connection
    to the arm."""
    disturbed: bool = False
    """The link to the arm was lost during the trial: its measurements are kept but flagged."""
    skipped: str | None = None
    """Why the trial measured nothing though it ran (no power switch, no reference instrument):
    an untested trial, never a passed one."""
    wall_s: float | None = None
    """Wall-clock seconds the trial took (robot time is ``duration_s``); None when not
    measured."""

    def __post_init__(self) -> None:
        where = f"trial {self.index}"
        object.__setattr__(self, "events", tuple(self.events))
        for i, ev in enumerate(self.events):
            if not isinstance(ev, Mapping) or not isinstance(ev.get("event"), str):
                raise RecordError(f"{where}.events[{i}]", "must be an object with an 'event' name")
        if not isinstance(self.disturbed, bool):
            raise RecordError(f"{where}.disturbed", "must be true or false")
        if isinstance(self.index, bool) or not isinstance(self.index, int) or self.index < 0:
            raise RecordError(f"{where}.index", "must be an integer >= 0")
        object.__setattr__(self, "started_s", _num(self.started_s, f"{where}.started_s"))
        object.__setattr__(self, "duration_s", _num(self.duration_s, f"{where}.duration_s"))
        if self.duration_s < 0:
            raise RecordError(f"{where}.duration_s", "must be >= 0")
        object.__setattr__(self, "wall_s", _wall_s(self.wall_s, f"{where}.wall_s"))
        _choice(self.status, f"{where}.status", get_args(TrialStatus))
        if (self.status == "error") != (self.error is not None):
            raise RecordError(f"{where}.error", "is given exactly when status is 'error'")
        if self.skipped is not None and (self.status != "done" or not self.skipped):
            raise RecordError(f"{where}.skipped", "is a non-empty reason of a done trial")
        if not isinstance(self.samples, StoredSamples):  # kept on disk, read when used
            object.__setattr__(self, "samples", tuple(self.samples))
        object.__setattr__(self, "measurements", tuple(self.measurements))
        _unique_names(self.measurements, f"{where}.measurements")

    @property
    def ended_s(self) -> float:
        """Run time (s) at which the trial ended."""
        return self.started_s + self.duration_s

    def to_json(self) -> TrialJson:
        """The JSON object of this trial (samples last, as they are the bulk)."""
        return {
            "index": self.index,
            "status": self.status,
            "error": self.error,
            "started_s": self.started_s,
            "duration_s": self.duration_s,
            "params": dict(self.params),
            "measurements": [m.to_json() for m in self.measurements],
            "disturbed": self.disturbed,
            "skipped": self.skipped,
            "events": [dict(ev) for ev in self.events],
            **_wall_json(self.wall_s),
            "samples": list(self.samples),
        }

    @classmethod
    def from_json(cls, data: object, where: str) -> Trial:
        """Parse a trial object; ``where`` is its dotted path, for errors."""
        d = _obj(data, where)
        samples = [_obj(s, f"{where}.samples[{i}]")
                   for i, s in enumerate(_list(_get(d, "samples", where), f"{where}.samples"))]
        ms = _list(_get(d, "measurements", where), f"{where}.measurements")
        index = _int(_get(d, "index", where), f"{where}.index")
        started_s = _num(_get(d, "started_s", where), f"{where}.started_s")
        duration_s = _num(_get(d, "duration_s", where), f"{where}.duration_s")
        params = _obj(_get(d, "params", where), f"{where}.params")
        measurements = [Measurement.from_json(m, f"{where}.measurements[{i}]")
                        for i, m in enumerate(ms)]
        status = _choice(_get(d, "status", where), f"{where}.status", get_args(TrialStatus))
        error = _opt_str(_get(d, "error", where), f"{where}.error")
        events = [_obj(ev, f"{where}.events[{i}]")  # absent from records before issue 20
                  for i, ev in enumerate(_list(d.get("events", []), f"{where}.events"))]
        disturbed = d.get("disturbed", False)
        if not isinstance(disturbed, bool):
            raise RecordError(f"{where}.disturbed", "must be true or false")
        skipped = _opt_str(d.get("skipped"), f"{where}.skipped")  # absent before issue 37
        wall_s = _opt_num(d.get("wall_s"), f"{where}.wall_s")  # absent before issue 37
        with _located(where):
            return cls(index, started_s, duration_s, params, samples, measurements, status,
                       error, events, disturbed, skipped, wall_s)


@dataclass(slots=True, kw_only=True)
class SuiteRecord:
    """One suite's part of the run. Mutable: :class:`RecordWriter` fills it in as trials finish.

    ``version`` is the suite code's version (trials of different versions never mix);
    ``params`` the suite's parameters; ``trials`` the current trials, in index order;
    ``superseded_trials`` errored trials that a resumed run measured again; ``measurements`` the
    suite-level figures (the ones compared with a baseline). ``status``: ``"running"`` until the
    suite ends (an interrupted suite stays so), then ``"done"`` or ``"error"`` (with ``error``).
    ``started_s``/``ended_s`` (s) are run time.
    """

    name: str
    version: str
    params: dict[str, Any] = field(default_factory=dict)
    status: SuiteStatus = "running"
    error: str | None = None
    started_s: float = 0.0
    ended_s: float | None = None
    trials: list[Trial] = field(default_factory=list)
    superseded_trials: list[Trial] = field(default_factory=list)
    measurements: list[Measurement] = field(default_factory=list)
    wall_s: float | None = None
    """Wall-clock seconds the suite took from its start to its end (robot time is
    ``ended_s - started_s``); None while it runs and in records before it was kept."""

    def untested_reason(self) -> str | None:
        """Why this finished suite measured nothing, or None: no trial ran, every trial was
        skipped (their reasons), or no trial left a figure. A running or errored suite is not
        untested: it is incomplete or in error."""
        if self.status != "done":
            return None
        done = [t for t in self.trials if t.status == "done"]
        if not done:
            return "no trial was measured (zero trials)"
        if all(t.skipped is not None for t in done):
            return "every trial skipped: " + "; ".join(dict.fromkeys(str(t.skipped)
                                                                     for t in done))
        if not self.measurements and not any(t.measurements for t in done):
            return "no figure was measured"
        return None

    def unjudged_figures(self) -> int:
        """How many figures this suite recorded when no limit judged any of them (0 when one
        was judged): measured but no claim, which the verdict says beside pass."""
        figures = [*(m for t in self.trials for m in t.measurements), *self.measurements]
        return 0 if any(m.outcome != "unjudged" for m in figures) else len(figures)

    def skipped_trials(self) -> list[Trial]:
        """The done trials that measured nothing (each with its reason)."""
        return [t for t in self.trials if t.status == "done" and t.skipped is not None]

    def completed_trials(self) -> list[Trial]:
        """The trials with status ``"done"``, by index (a resumed suite skips these)."""
        return [t for t in self.trials if t.status == "done"]

    def current(self, index: int) -> Trial | None:
        """The current trial of ``index``, if there is one: found by bisection, ``trials`` being
        in index order (:meth:`place` keeps them so; a campaign places 10 000)."""
        trials = self.trials
        i = bisect.bisect_left(trials, index, key=_trial_index)
        return trials[i] if i < len(trials) and trials[i].index == index else None

    def holds(self, trial: Trial) -> bool:
        """Whether this suite already holds ``trial`` (the same index, status, times and
        error, current or superseded): a journal replayed over a record that has it."""
        key = (trial.index, trial.status, trial.started_s, trial.duration_s, trial.error)
        current = self.current(trial.index)
        held = self.superseded_trials if current is None else [current, *self.superseded_trials]
        return any((t.index, t.status, t.started_s, t.duration_s, t.error) == key for t in held)

    def place(self, trial: Trial) -> None:
        """Add a finished trial in index order: one re-measuring an errored trial (same index)
        takes its place and moves it to ``superseded_trials``; re-measuring a done trial is a
        RecordError."""
        trials = self.trials
        i = bisect.bisect_left(trials, trial.index, key=_trial_index)
        if i < len(trials) and trials[i].index == trial.index:
            if trials[i].status == "done":
                raise RecordError(f"suites.{self.name}.trials[index {trial.index}]",
                                  "is already measured")
            self.superseded_trials.append(trials[i])
            trials[i] = trial
        else:
            trials.insert(i, trial)

    def to_json(self, trial_json: Callable[[Trial], object] = Trial.to_json) -> SuiteJson:
        """The JSON object of this suite; ``trial_json`` makes each trial's (the writer leaves
        a placeholder to stream the trial from disk)."""
        return {
            "name": self.name,
            "version": self.version,
            "status": self.status,
            "error": self.error,
            "started_s": self.started_s,
            "ended_s": self.ended_s,
            "params": self.params,
            "measurements": [m.to_json() for m in self.measurements],
            "trials": [trial_json(t) for t in self.trials],
            "superseded_trials": [trial_json(t) for t in self.superseded_trials],
            **_wall_json(self.wall_s),
        }

    @classmethod
    def from_json(cls, data: object, where: str) -> SuiteRecord:
        """Parse a suite object; ``where`` is its dotted path, for errors."""
        d = _obj(data, where)

        def trials(key: str) -> list[Trial]:
            items = _list(_get(d, key, where), f"{where}.{key}")
            return [Trial.from_json(t, f"{where}.{key}[{i}]") for i, t in enumerate(items)]

        ms = _list(_get(d, "measurements", where), f"{where}.measurements")
        suite = cls(
            name=_str(_get(d, "name", where), f"{where}.name"),
            version=_str(_get(d, "version", where), f"{where}.version"),
            params=dict(_obj(_get(d, "params", where), f"{where}.params")),
            status=_choice(_get(d, "status", where), f"{where}.status", get_args(SuiteStatus)),
            error=_opt_str(_get(d, "error", where), f"{where}.error"),
            started_s=_num(_get(d, "started_s", where), f"{where}.started_s"),
            ended_s=_opt_num(_get(d, "ended_s", where), f"{where}.ended_s"),
            trials=sorted(trials("trials"), key=_trial_index),  # in index order, as placed
            superseded_trials=trials("superseded_trials"),
            measurements=[Measurement.from_json(m, f"{where}.measurements[{i}]")
                          for i, m in enumerate(ms)],
            wall_s=_wall_s(_opt_num(d.get("wall_s"), f"{where}.wall_s"), f"{where}.wall_s"),
        )
        indices = [t.index for t in suite.trials]
        if len(set(indices)) != len(indices):
            raise RecordError(f"{where}.trials", "two trials share an index")
        _unique_names(suite.measurements, f"{where}.measurements")
        return suite


def _trial_index(trial: Trial) -> int:
    return trial.index
