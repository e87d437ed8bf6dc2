"""The JSON shapes of ``results.json``, as the record's ``to_json`` methods make them: what
crosses from the record to the file and to other programs (``compare --json``). Fields as in
``docs/record.md``; ``params`` and ``samples`` are JSON objects of a suite's own making."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NotRequired, TypedDict

from armbench.record.fields import Better, Outcome, RowStatus, SuiteStatus, TrialStatus
from armbench.record.limits import LimitJson

__all__ = [
    "ComparisonJson",
    "ComparisonRowJson",
    "EnvironmentJson",
    "MeasurementJson",
    "RecordJson",
    "SuiteJson",
    "TargetJson",
    "TrialJson",
]


class MeasurementJson(TypedDict):
    """One judged figure."""

    name: str
    value: float
    unit: str
    outcome: Outcome
    limit: LimitJson | None
    better: Better | None
    description: str


class TrialJson(TypedDict):
    """One repetition of a suite's experiment (samples last: they are the bulk)."""

    index: int
    status: TrialStatus
    error: str | None
    started_s: float
    duration_s: float
    params: dict[str, Any]
    measurements: list[MeasurementJson]
    disturbed: bool
    skipped: str | None
    events: list[dict[str, Any]]
    samples: list[Mapping[str, Any]]
    wall_s: NotRequired[float]


class SuiteJson(TypedDict):
    """One suite's part; its trials as the caller of ``to_json`` makes them (a writer streaming
    them from disk leaves placeholders)."""

    name: str
    version: str
    status: SuiteStatus
    error: str | None
    started_s: float
    ended_s: float | None
    params: dict[str, Any]
    measurements: list[MeasurementJson]
    trials: list[object]
    superseded_trials: list[object]
    wall_s: NotRequired[float]


class ComparisonRowJson(TypedDict):
    """One metric compared with the baseline."""

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


class ComparisonJson(TypedDict):
    """The baseline comparison (``record.baseline``)."""

    baseline_run_id: str
    baseline_created: str
    baseline_git_revision: str
    regressed: bool
    rows: list[ComparisonRowJson]


class TargetJson(TypedDict):
    """The kind of target a run measured (its truth source is ``truth_source``)."""

    kind: str


class EnvironmentJson(TypedDict):
    """What the run ran on and with."""

    armbench_version: str
    git_revision: str
    python: str
    platform: str
    port: str | None
    seed: int | None
    limits_spec_version: str | None
    config_path: str | None
    truth_source: str | None
    faults: list[dict[str, Any]]
    settings: dict[str, Any]
    dut: NotRequired[dict[str, Any]]
    ci: NotRequired[dict[str, str | None]]
    target: NotRequired[TargetJson]


class RecordJson(TypedDict):
    """The whole ``results.json``."""

    schema: str
    run_id: str
    created: str
    resumed: list[str]
    verdict: str
    reference: dict[str, float]
    environment: EnvironmentJson
    planned_suites: list[str]
    required: list[str]
    baseline: ComparisonJson | None
    suites: dict[str, SuiteJson]
