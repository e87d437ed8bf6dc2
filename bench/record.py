"""The run record (``results.json``): what a bench run measured, judged and compared.

One :class:`RunRecord` per run holds the environment, one :class:`SuiteRecord` per suite with its
:class:`Trial` list (raw samples plus per-trial :class:`Measurement` s) and suite-level
measurements, the baseline comparison and the verdict. :class:`RecordWriter` rewrites the file
atomically after every finished trial, so an interrupted run loses nothing measured and can be
resumed. The JSON schema (``armbench-run/1``) is documented field by field in ``docs/record.md``;
readers ignore keys they do not know, so fields may be added without a new schema version.

Times: ``created``/``resumed`` are wall-clock ISO 8601 labels; every ``*_s`` field is seconds of
run time on the monotonic clock (see :meth:`RecordWriter.elapsed_s`).
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import json
import math
import numbers
import os
import platform
import secrets
import subprocess
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, date, datetime
from datetime import time as time_of_day
from pathlib import Path, PurePath
from typing import Any, Literal, get_args

from armbench.bench.limits import Limit, LimitsConfig
from armbench.drivers.errors import ArmbenchError
from armbench.drivers.settings import RobotSettings, SettingsError

__all__ = [
    "PAPER_REFERENCE",
    "RESULTS_FILE",
    "SCHEMA",
    "Better",
    "Comparison",
    "ComparisonRow",
    "Environment",
    "Measurement",
    "Outcome",
    "RecordError",
    "RecordWriter",
    "RowStatus",
    "RunRecord",
    "SuiteRecord",
    "SuiteStatus",
    "Trial",
    "TrialStatus",
    "Verdict",
    "atomic_write_bytes",
    "capture_environment",
    "default_better",
    "git_revision",
    "judge",
    "load_record",
    "new_run_id",
    "path_inside",
    "run_directory",
    "utc_timestamp",
    "validate_record",
]

#: The schema identifier of the records this module writes and reads.
SCHEMA = "armbench-run/1"
#: The record's file name inside a run directory.
RESULTS_FILE = "results.json"
#: The paper's figures the report shows next to ours (mean Euclidean path error of §7, mm).
PAPER_REFERENCE: Mapping[str, float] = {"paper_mean_error_mm": 12.4}

Outcome = Literal["pass", "fail", "unjudged"]
Better = Literal["lower", "higher"]
TrialStatus = Literal["done", "error"]
SuiteStatus = Literal["running", "done", "error"]
Verdict = Literal["pass", "fail", "regression", "error", "incomplete"]
RowStatus = Literal["compared", "new", "missing"]

#: Units whose metrics are errors or durations: smaller is better unless a suite says otherwise.
_LOWER_IS_BETTER_UNITS = frozenset({"mm", "um", "m", "rad", "mrad", "deg", "s", "ms", "us"})


class RecordError(ArmbenchError, ValueError):
    """A record is invalid, of another schema, or cannot be written; ``where`` names the field
    (dotted path into ``results.json``) or file."""

    def __init__(self, where: str, reason: str) -> None:
        super().__init__(f"{where}: {reason}")
        self.where = where
        self.reason = reason


def default_better(unit: str) -> Better | None:
    """The regression direction of a unit: ``"lower"`` for lengths, angles and durations
    (errors, times), None (no direction: changes are shown, never regressions) otherwise."""
    return "lower" if unit in _LOWER_IS_BETTER_UNITS else None


def utc_timestamp() -> str:
    """Now, as an ISO 8601 UTC label to the second (wall clock: a label, not a measurement)."""
    return datetime.now(UTC).isoformat(timespec="seconds")


def new_run_id() -> str:
    """A fresh run id: UTC time plus random hex, e.g. ``"20240501T120301Z-3f9a2c"``."""
    return f"{datetime.now(UTC):%Y%m%dT%H%M%SZ}-{secrets.token_hex(3)}"


# --------------------------------------------------------------------------------------------
# JSON reading helpers: every error names the dotted field
# --------------------------------------------------------------------------------------------


def _obj(value: object, where: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise RecordError(where, f"expected an object, got {type(value).__name__}")
    return value


def _get(data: Mapping[str, Any], key: str, where: str) -> Any:
    if key not in data:
        raise RecordError(f"{where}.{key}" if where else key, "missing")
    return data[key]


def _str(value: object, where: str) -> str:
    if not isinstance(value, str):
        raise RecordError(where, f"expected a string, got {value!r}")
    return value


def _opt_str(value: object, where: str) -> str | None:
    return None if value is None else _str(value, where)


def _num(value: object, where: str) -> float:
    """A finite real number as a float (numpy scalars included, booleans not)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise RecordError(where, f"expected a number, got {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise RecordError(where, f"{value!r} is not finite")
    return number


def _opt_num(value: object, where: str) -> float | None:
    return None if value is None else _num(value, where)


def _int(value: object, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise RecordError(where, f"expected an integer, got {value!r}")
    return value


def _bool(value: object, where: str) -> bool:
    if not isinstance(value, bool):
        raise RecordError(where, f"expected true or false, got {value!r}")
    return value


def _list(value: object, where: str) -> list[Any]:
    if not isinstance(value, list):
        raise RecordError(where, f"expected a list, got {type(value).__name__}")
    return value


def _choice(value: object, where: str, choices: Iterable[str | None]) -> Any:
    allowed = tuple(choices)
    if value not in allowed:
        raise RecordError(where, f"{value!r} is not one of {', '.join(map(repr, allowed))}")
    return value


@contextlib.contextmanager
def _located(where: str) -> Iterator[None]:
    """Prefix ``where`` to a RecordError raised by a constructor's own checks."""
    try:
        yield
    except RecordError as exc:
        if exc.where.startswith(where):
            raise
        raise RecordError(where, str(exc)) from None


# --------------------------------------------------------------------------------------------
# Measurements, trials, suites
# --------------------------------------------------------------------------------------------


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

    def to_json(self) -> dict[str, Any]:
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

    def __post_init__(self) -> None:
        where = f"trial {self.index}"
        if isinstance(self.index, bool) or not isinstance(self.index, int) or self.index < 0:
            raise RecordError(f"{where}.index", "must be an integer >= 0")
        object.__setattr__(self, "started_s", _num(self.started_s, f"{where}.started_s"))
        object.__setattr__(self, "duration_s", _num(self.duration_s, f"{where}.duration_s"))
        if self.duration_s < 0:
            raise RecordError(f"{where}.duration_s", "must be >= 0")
        _choice(self.status, f"{where}.status", get_args(TrialStatus))
        if (self.status == "error") != (self.error is not None):
            raise RecordError(f"{where}.error", "is given exactly when status is 'error'")
        object.__setattr__(self, "samples", tuple(self.samples))
        object.__setattr__(self, "measurements", tuple(self.measurements))
        _unique_names(self.measurements, f"{where}.measurements")

    @property
    def ended_s(self) -> float:
        """Run time (s) at which the trial ended."""
        return self.started_s + self.duration_s

    def to_json(self) -> dict[str, Any]:
        """The JSON object of this trial (samples last, as they are the bulk)."""
        return {
            "index": self.index,
            "status": self.status,
            "error": self.error,
            "started_s": self.started_s,
            "duration_s": self.duration_s,
            "params": dict(self.params),
            "measurements": [m.to_json() for m in self.measurements],
            "samples": list(self.samples),
        }

    @classmethod
    def from_json(cls, data: object, where: str) -> Trial:
        """Parse a trial object; ``where`` is its dotted path, for errors."""
        d = _obj(data, where)
        samples = _list(_get(d, "samples", where), f"{where}.samples")
        for i, s in enumerate(samples):
            _obj(s, f"{where}.samples[{i}]")
        ms = _list(_get(d, "measurements", where), f"{where}.measurements")
        index = _int(_get(d, "index", where), f"{where}.index")
        started_s = _num(_get(d, "started_s", where), f"{where}.started_s")
        duration_s = _num(_get(d, "duration_s", where), f"{where}.duration_s")
        params = _obj(_get(d, "params", where), f"{where}.params")
        measurements = [Measurement.from_json(m, f"{where}.measurements[{i}]")
                        for i, m in enumerate(ms)]
        status = _choice(_get(d, "status", where), f"{where}.status", get_args(TrialStatus))
        error = _opt_str(_get(d, "error", where), f"{where}.error")
        with _located(where):
            return cls(index, started_s, duration_s, params, samples, measurements, status,
                       error)


@dataclass(slots=True, kw_only=True)
class SuiteRecord:
    """One suite's part of the run. Mutable: :class:`RecordWriter` fills it in as trials finish.

    ``version`` is the suite code's version (trials of different versions never mix);
    ``params`` the suite's parameters; ``trials`` the current trials by index;
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

    def completed_trials(self) -> list[Trial]:
        """The trials with status ``"done"``, by index (a resumed suite skips these)."""
        return [t for t in self.trials if t.status == "done"]

    def to_json(self) -> dict[str, Any]:
        """The JSON object of this suite."""
        return {
            "name": self.name,
            "version": self.version,
            "status": self.status,
            "error": self.error,
            "started_s": self.started_s,
            "ended_s": self.ended_s,
            "params": self.params,
            "measurements": [m.to_json() for m in self.measurements],
            "trials": [t.to_json() for t in self.trials],
            "superseded_trials": [t.to_json() for t in self.superseded_trials],
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
            trials=trials("trials"),
            superseded_trials=trials("superseded_trials"),
            measurements=[Measurement.from_json(m, f"{where}.measurements[{i}]")
                          for i, m in enumerate(ms)],
        )
        indices = [t.index for t in suite.trials]
        if len(set(indices)) != len(indices):
            raise RecordError(f"{where}.trials", "two trials share an index")
        _unique_names(suite.measurements, f"{where}.measurements")
        return suite


# --------------------------------------------------------------------------------------------
# Baseline comparison (the data; armbench.bench.baseline computes it)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ComparisonRow:
    """One metric compared with the baseline (values in ``unit``).

    ``status``: ``"compared"``, ``"new"`` (no baseline value) or ``"missing"`` (no value in this
    run). ``change_abs`` = value - baseline (unit), ``change_pct`` its percentage of ``|baseline|``
    (None for a zero baseline); ``tolerance`` the allowed worsening (unit) =
    ``|baseline| * tolerance_pct / 100 + tolerance_abs``; ``regressed`` when the metric got worse
    in its ``better`` direction by more than that.
    """

    name: str
    unit: str
    status: RowStatus
    baseline: float | None
    value: float | None
    change_abs: float | None
    change_pct: float | None
    tolerance: float | None
    tolerance_pct: float
    tolerance_abs: float
    better: Better | None
    regressed: bool

    @property
    def result(self) -> str:
        """The row's word, as ``armbench compare`` and the report show it: ``REGRESSED``,
        ``improved`` (better by more than the tolerance), ``ok``, ``new`` or ``missing``."""
        if self.status != "compared":
            return self.status
        if self.regressed:
            return "REGRESSED"
        if self.better is None or self.change_abs is None or self.tolerance is None:
            return "ok"
        gain = -self.change_abs if self.better == "lower" else self.change_abs
        return "improved" if gain > self.tolerance else "ok"

    def to_json(self) -> dict[str, Any]:
        """The JSON object of this row."""
        return {
            "name": self.name, "unit": self.unit, "status": self.status,
            "baseline": self.baseline, "value": self.value,
            "change_abs": self.change_abs, "change_pct": self.change_pct,
            "tolerance": self.tolerance, "tolerance_pct": self.tolerance_pct,
            "tolerance_abs": self.tolerance_abs, "better": self.better,
            "regressed": self.regressed,
        }

    @classmethod
    def from_json(cls, data: object, where: str) -> ComparisonRow:
        """Parse a comparison row; ``where`` is its dotted path, for errors."""
        d = _obj(data, where)

        def num(key: str) -> float | None:
            return _opt_num(_get(d, key, where), f"{where}.{key}")

        return cls(
            name=_str(_get(d, "name", where), f"{where}.name"),
            unit=_str(_get(d, "unit", where), f"{where}.unit"),
            status=_choice(_get(d, "status", where), f"{where}.status", get_args(RowStatus)),
            baseline=num("baseline"), value=num("value"),
            change_abs=num("change_abs"), change_pct=num("change_pct"),
            tolerance=num("tolerance"),
            tolerance_pct=_num(_get(d, "tolerance_pct", where), f"{where}.tolerance_pct"),
            tolerance_abs=_num(_get(d, "tolerance_abs", where), f"{where}.tolerance_abs"),
            better=_choice(_get(d, "better", where), f"{where}.better", (*get_args(Better), None)),
            regressed=_bool(_get(d, "regressed", where), f"{where}.regressed"),
        )


@dataclass(frozen=True, slots=True)
class Comparison:
    """A run's suite-level measurements against those of a baseline run.

    ``baseline_*`` identify the baseline record; ``rows`` go in the run's measurement order, then
    the baseline's missing metrics; ``regressed`` is true when any row regressed.
    """

    baseline_run_id: str
    baseline_created: str
    baseline_git_revision: str
    rows: tuple[ComparisonRow, ...]

    @property
    def regressed(self) -> bool:
        """True when at least one metric regressed."""
        return any(r.regressed for r in self.rows)

    @property
    def regressions(self) -> list[ComparisonRow]:
        """The rows that regressed."""
        return [r for r in self.rows if r.regressed]

    def to_json(self) -> dict[str, Any]:
        """The JSON object of this comparison (``record.baseline``)."""
        return {
            "baseline_run_id": self.baseline_run_id,
            "baseline_created": self.baseline_created,
            "baseline_git_revision": self.baseline_git_revision,
            "regressed": self.regressed,
            "rows": [r.to_json() for r in self.rows],
        }

    @classmethod
    def from_json(cls, data: object, where: str) -> Comparison:
        """Parse a comparison object; ``where`` is its dotted path, for errors."""
        d = _obj(data, where)
        rows = _list(_get(d, "rows", where), f"{where}.rows")
        return cls(
            baseline_run_id=_str(_get(d, "baseline_run_id", where), f"{where}.baseline_run_id"),
            baseline_created=_str(_get(d, "baseline_created", where),
                                  f"{where}.baseline_created"),
            baseline_git_revision=_str(_get(d, "baseline_git_revision", where),
                                       f"{where}.baseline_git_revision"),
            rows=tuple(ComparisonRow.from_json(r, f"{where}.rows[{i}]")
                       for i, r in enumerate(rows)),
        )


# --------------------------------------------------------------------------------------------
# Environment and the run record
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Environment:
    """What the run ran on and with: versions, port, robot settings, seed, injected faults and the
    limits file. ``settings`` is :meth:`RobotSettings.to_mapping` (units in the keys)."""

    armbench_version: str
    git_revision: str
    python: str
    platform: str
    port: str | None
    settings: Mapping[str, Any]
    seed: int | None
    faults: tuple[Mapping[str, Any], ...]
    limits_spec_version: str | None
    config_path: str | None

    def to_json(self) -> dict[str, Any]:
        """The JSON object of this environment."""
        return {
            "armbench_version": self.armbench_version,
            "git_revision": self.git_revision,
            "python": self.python,
            "platform": self.platform,
            "port": self.port,
            "seed": self.seed,
            "limits_spec_version": self.limits_spec_version,
            "config_path": self.config_path,
            "faults": [dict(f) for f in self.faults],
            "settings": dict(self.settings),
        }

    @classmethod
    def from_json(cls, data: object, where: str) -> Environment:
        """Parse an environment object; ``where`` is its dotted path, for errors."""
        d = _obj(data, where)

        def text(key: str) -> str:
            return _str(_get(d, key, where), f"{where}.{key}")

        def opt_text(key: str) -> str | None:
            return _opt_str(_get(d, key, where), f"{where}.{key}")

        seed = _get(d, "seed", where)
        faults = _list(_get(d, "faults", where), f"{where}.faults")
        return cls(
            armbench_version=text("armbench_version"),
            git_revision=text("git_revision"),
            python=text("python"),
            platform=text("platform"),
            port=opt_text("port"),
            settings=_obj(_get(d, "settings", where), f"{where}.settings"),
            seed=None if seed is None else _int(seed, f"{where}.seed"),
            faults=tuple(_obj(f, f"{where}.faults[{i}]") for i, f in enumerate(faults)),
            limits_spec_version=opt_text("limits_spec_version"),
            config_path=opt_text("config_path"),
        )


def git_revision() -> str:
    """``git rev-parse HEAD`` of the armbench checkout, or ``"unknown"`` (not a checkout, no git,
    git failing or hanging)."""
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=Path(__file__).resolve().parent,
            capture_output=True, text=True, timeout=5.0, check=True,
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    rev = out.stdout.strip()
    return rev or "unknown"


def _armbench_version() -> str:
    try:
        return importlib.metadata.version("armbench")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def capture_environment(
    *,
    port: str | None = None,
    settings: RobotSettings | None = None,
    seed: int | None = None,
    faults: Iterable[Mapping[str, Any]] = (),
    limits: LimitsConfig | None = None,
) -> Environment:
    """The environment of this process: armbench version (package metadata), git revision,
    Python and platform, plus what the run was given. ``settings`` None records the defaults;
    ``faults`` are plain mappings (``dataclasses.asdict`` of each fault)."""
    return Environment(
        armbench_version=_armbench_version(),
        git_revision=git_revision(),
        python=platform.python_version(),
        platform=platform.platform(),
        port=port,
        settings=(settings or RobotSettings()).to_mapping(),
        seed=seed,
        faults=tuple(dict(f) for f in faults),
        limits_spec_version=None if limits is None else limits.spec_version,
        config_path=None if limits is None else limits.path,
    )


@dataclass(slots=True, kw_only=True)
class RunRecord:
    """The whole run. Mutable: :class:`RecordWriter` fills it in.

    ``planned_suites`` are the suites the run means to execute, in order; ``suites`` those started
    so far, by name; ``resumed`` the wall-clock labels of each resume; ``baseline`` the comparison
    with a baseline run, if one was given; ``reference`` the paper's figures for the report.
    """

    run_id: str
    created: str
    environment: Environment
    planned_suites: list[str] = field(default_factory=list)
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

    @property
    def verdict(self) -> Verdict:
        """The run's verdict, first that applies: ``"error"`` (a suite or current trial errored),
        ``"incomplete"`` (a planned suite did not start or did not end), ``"fail"`` (a measurement
        outside its limit), ``"regression"`` (worse than the baseline), else ``"pass"``."""
        suites = self.suites.values()
        if any(s.status == "error" or any(t.status == "error" for t in s.trials) for s in suites):
            return "error"
        if (any(s.status == "running" for s in suites)
                or any(name not in self.suites for name in self.planned_suites)):
            return "incomplete"
        if any(m.outcome == "fail" for _, _, m in self.iter_measurements()):
            return "fail"
        if self.baseline is not None and self.baseline.regressed:
            return "regression"
        return "pass"

    def to_json(self) -> dict[str, Any]:
        """The JSON object of the record (the content of ``results.json``)."""
        return {
            "schema": self.schema,
            "run_id": self.run_id,
            "created": self.created,
            "resumed": list(self.resumed),
            "verdict": self.verdict,
            "reference": dict(self.reference),
            "environment": self.environment.to_json(),
            "planned_suites": list(self.planned_suites),
            "baseline": None if self.baseline is None else self.baseline.to_json(),
            "suites": {name: s.to_json() for name, s in self.suites.items()},
        }


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
    return RunRecord(
        run_id=_str(_get(d, "run_id", ""), "run_id"),
        created=_str(_get(d, "created", ""), "created"),
        environment=Environment.from_json(_get(d, "environment", ""), "environment"),
        planned_suites=[_str(p, f"planned_suites[{i}]") for i, p in enumerate(planned)],
        suites=suites,
        resumed=[_str(r, f"resumed[{i}]") for i, r in enumerate(resumed)],
        baseline=None if baseline is None else Comparison.from_json(baseline, "baseline"),
        reference={k: _num(v, f"reference.{k}") for k, v in reference.items()},
    )


def load_record(path: str | Path) -> RunRecord:
    """Read and validate a ``results.json``; errors name the file and the field."""
    p = Path(path)
    try:
        data = json.loads(p.read_bytes())
    except FileNotFoundError:
        raise RecordError(str(p), "does not exist") from None
    except IsADirectoryError:
        raise RecordError(str(p), "is a directory, not a results.json") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RecordError(str(p), f"is not valid JSON: {exc}") from None
    except OSError as exc:
        raise RecordError(str(p), f"cannot be read: {exc.strerror or exc}") from None
    try:
        return validate_record(data)
    except RecordError as exc:
        raise RecordError(f"{p}: {exc.where}", exc.reason) from None


# --------------------------------------------------------------------------------------------
# Files: paths kept inside the run directory, atomic writes
# --------------------------------------------------------------------------------------------


def path_inside(directory: str | Path, name: str | PurePath) -> Path:
    """``directory / name``, refusing a ``name`` that could lead out of ``directory``: absolute,
    containing ``..``, empty, or resolving (through symlinks) to a place outside it."""
    raw = os.fspath(name)
    base = Path(directory)
    pure = PurePath(raw)
    if not raw or "\0" in raw:
        raise RecordError("file name", f"{raw!r} is not a usable name")
    if pure.is_absolute() or pure.anchor:
        raise RecordError("file name", f"{raw!r} is absolute; names are relative to {base}")
    if ".." in pure.parts:
        raise RecordError("file name", f"{raw!r} contains '..' and could leave {base}")
    target = base / pure
    real_base = base.resolve()
    real = target.resolve()
    if real != real_base and real_base not in real.parents:
        raise RecordError("file name", f"{raw!r} leads to {real}, outside {real_base} "
                                       "(a symlink pointing out?)")
    return target


def run_directory(root: str | Path, run_name: str) -> Path:
    """The directory of run ``run_name`` inside ``root``, created if missing. The run name must be
    one plain path component that stays inside ``root`` (no ``/``, ``..`` or symlink out)."""
    if not run_name or run_name in (".", "..") or any(c in run_name for c in "/\\\0"):
        raise RecordError("run name", f"{run_name!r} must be one plain name (no '/', '\\', "
                                      "'.' or '..')")
    root_path = Path(root)
    root_path.mkdir(parents=True, exist_ok=True)
    target = path_inside(root_path, run_name)
    try:
        target.mkdir(exist_ok=True)
    except FileExistsError:
        raise RecordError("run name", f"{target} exists and is not a directory") from None
    return target


def _json_default(obj: object) -> Any:
    """JSON for the non-JSON values suites commonly hand over: numpy arrays and scalars
    (``tolist``), TOML dates and times (ISO 8601)."""
    if isinstance(obj, (datetime, date, time_of_day)):
        return obj.isoformat()
    tolist = getattr(obj, "tolist", None)
    if callable(tolist):
        return tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


_SCALARS = (str, int, float, bool, type(None))
#: A flat object is written on one line when it is at most this long (characters).
_INLINE_WIDTH = 120


class _JsonText(str):
    """JSON text encoded earlier (a cached trial), emitted verbatim by :func:`_encode`."""


def _compact(value: object) -> str:
    return json.dumps(value, ensure_ascii=False, allow_nan=False, separators=(", ", ": "),
                      default=_json_default)


def _is_scalar(value: object) -> bool:
    return isinstance(value, _SCALARS) and not isinstance(value, _JsonText)


def _is_flat(values: Iterable[object]) -> bool:
    """True when every value is a scalar or a list of scalars (a sample, a limit, a vector)."""
    return all(_is_scalar(v) or (isinstance(v, (list, tuple)) and all(map(_is_scalar, v)))
               for v in values)


def _encode(value: object, level: int = 0) -> str:
    """Strict JSON (no NaN) for people and diffs: nested containers indented one space per
    level; lists of scalars (``[x, y, z]``) and short flat objects (a sample) on one line.

    Unlike ``json.dumps(indent=...)``, which runs the pure-Python encoder over everything, the
    one-line parts go through the C encoder; and cached trials (:class:`_JsonText`) are pasted in.
    """
    if isinstance(value, _JsonText):
        return value
    if isinstance(value, _SCALARS):
        return _compact(value)
    if isinstance(value, Mapping):
        if not value:
            return "{}"
        if _is_flat(value.values()):
            text = _compact(value)
            if len(text) <= _INLINE_WIDTH:
                return text
        pad = " " * (level + 1)
        items = (f"{pad}{_compact(str(k))}: {_encode(v, level + 1)}" for k, v in value.items())
        return "{\n" + ",\n".join(items) + "\n" + " " * level + "}"
    if isinstance(value, (list, tuple)):
        if not value:
            return "[]"
        if all(map(_is_scalar, value)):
            return _compact(value)
        pad = " " * (level + 1)
        items = (f"{pad}{_encode(v, level + 1)}" for v in value)
        return "[\n" + ",\n".join(items) + "\n" + " " * level + "]"
    return _encode(_json_default(value), level)


def _to_json_text(value: object, where: str, level: int = 0) -> str:
    """:func:`_encode` with errors (NaN, unknown types) as a RecordError naming ``where``."""
    try:
        return _encode(value, level)
    except (TypeError, ValueError) as exc:
        raise RecordError(where, f"cannot be stored as JSON: {exc} (NaN and infinity are not "
                                 "JSON; use null or leave the value out)") from None


def _fsync_directory(directory: Path) -> None:
    """Make a rename in ``directory`` durable (POSIX; a no-op where a directory cannot be
    opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    except OSError:
        return
    try:
        with contextlib.suppress(OSError):
            os.fsync(fd)
    finally:
        os.close(fd)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Replace ``path`` with ``data`` atomically: a temporary file in the same directory is
    written, fsync'ed and renamed over ``path`` (``os.replace``), then the directory is fsync'ed.
    Readers see the old or the new content, never a mix; no temporary file is left behind."""
    target = Path(path)
    tmp = target.with_name(f".{target.name}.{secrets.token_hex(6)}.tmp")
    try:
        # 0o666 and the umask, like any new file (mkstemp would make it private, 0o600).
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0),
                     0o666)
    except OSError as exc:
        raise RecordError(str(target), f"could not be written: {exc.strerror or exc}") from exc
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise RecordError(str(target), f"could not be written: {exc.strerror or exc}") from exc
        raise
    _fsync_directory(target.parent)


# --------------------------------------------------------------------------------------------
# The writer
# --------------------------------------------------------------------------------------------


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
