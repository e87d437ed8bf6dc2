"""What ``armbench run`` is asked (:class:`RunOptions`), what ``prepare`` makes of it
(:class:`BenchPlan`), what a run leaves (:class:`RunOutcome`), and the runner's constants: file
names of a run directory, exit statuses, seeds."""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol

from armbench.bench.suites import Suite
from armbench.bench.suites.base import PoseSource, PowerSwitch
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.transports.target import Target
from armbench.record import CAPTURE_FILE, REPORT_FILE, RESULTS_FILE, RunRecord, Verdict
from armbench.record.dut import Dut
from armbench.record.limits import LimitsConfig
from armbench.record.verdict import (
    DEFAULT_CONFIG,
    EXIT_ERROR,
    EXIT_FAIL,
    EXIT_INCOMPLETE,
    EXIT_INTERRUPTED,
    EXIT_PASS,
    EXIT_REGRESSION,
    exit_status,
)

if TYPE_CHECKING:  # the emulator is imported only for fake:// runs
    from armbench.fakes.firmware.arm_emulator import ArmEmulator
    from armbench.fakes.firmware.emulator_settings import EmulatorSettings
    from armbench.fakes.firmware.faults import Fault

__all__ = [
    "CAPTURE_FILE", "DEFAULT_CONFIG", "DEFAULT_OUTAGE_TIMEOUT_S", "EXIT_ERROR", "EXIT_FAIL",
    "EXIT_INCOMPLETE", "EXIT_INTERRUPTED", "EXIT_PASS", "EXIT_REGRESSION", "JUNIT_FILE",
    "REPORT_FILE", "RUNNER_FILE", "BenchPlan",
    "EmulatorFactory", "Isolation", "PlannedSuite", "RunAborted", "RunAhead", "RunOptions",
    "RunOutcome",
    "default_workers", "derive_seed", "exit_status", "shard_assignment",
]

#: Files of a run directory besides ``results.json`` (``REPORT_FILE`` and ``CAPTURE_FILE``: the
#: record's ``files``).
JUNIT_FILE = "junit.xml"
#: How the run was invoked (suite references, files), read back by ``--resume``.
RUNNER_FILE = "runner.json"

#: How long a lost port may stay silent before the trial ends in ``LinkLostError`` (s): a USB
#: re-enumeration or a ser2net restarted by systemd takes a few seconds.
DEFAULT_OUTAGE_TIMEOUT_S = 10.0


Isolation = Literal["trial", "run"]

EmulatorFactory = Callable[["RobotSettings", "EmulatorSettings", "Sequence[Fault]"],
                           "ArmEmulator"]
"""Builds the ``fake://`` emulator of a connection (tests pass one to watch the emulators)."""


def _condition(params: Mapping[str, Any]) -> tuple[tuple[str, str], ...]:
    """The condition of a trial: its text and flag parameters (a lap style, a cut kind, a named
    condition), without counters (lap, cycle) and drawn numbers."""
    return tuple(sorted((k, repr(v)) for k, v in params.items() if isinstance(v, (str, bool))))


def shard_assignment(suites: Sequence[Sequence[Mapping[str, Any]]], n: int) -> list[list[int]]:
    """The 0-based shard (of ``n``) of every trial of every suite, from their parameters.

    Trials are dealt to the shards in turn, condition by condition (the trials of one style,
    kind or named condition together), the dealer carrying on from one condition and one suite
    to the next: every shard gets its share, within one trial, of every condition of every suite
    and of every suite (a plan alternating two lap styles does not put one style in each of two
    shards, and suites of one trial each do not all land in shard 1).
    """
    dealer = 0
    out: list[list[int]] = []
    for trials in suites:
        groups: dict[tuple[tuple[str, str], ...], list[int]] = {}
        for index, params in enumerate(trials):
            groups.setdefault(_condition(params), []).append(index)
        shards = [0] * len(trials)
        for indices in groups.values():
            for index in indices:
                shards[index] = dealer % n
                dealer += 1
        out.append(shards)
    return out


def default_workers() -> int:
    """Worker processes of a run whose ``[bench] workers`` and ``--workers`` say nothing: one
    per CPU, at most two."""
    return min(2, os.cpu_count() or 1)


def derive_seed(seed: int, *labels: object) -> int:
    """A seed for one part of the run (a trial, an emulator), stable across processes and Python
    versions: the top 26 bits of SHA-256 of the base seed and the labels (< 2**26: small enough
    for any seed field, e.g. the emulator's boards derive ``31 * seed + board`` from it)."""
    text = json.dumps([seed, *[str(x) for x in labels]])
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "big") >> (64 - 26)


class RunAhead(Protocol):
    """Work the caller of a run does before the run ends, in threads of its own, so that it is
    not waiting once the trials end (the ``run`` command: the report's imports, then each
    suite's plots). Both calls come from the run's loop and return at once."""

    def started(self) -> None:
        """A first trial is in a record: the run is under way (called for each arm)."""

    def summarized(self, record: RunRecord, suite: str) -> None:
        """Suite ``suite``'s summary is in ``record`` (which the run goes on writing)."""


class RunAborted(ArmbenchError):
    """The bench stopped before the end (the arm cannot be reached); the record on disk keeps
    every finished trial and a ``--resume`` continues."""


@dataclass(slots=True)
class RunOptions:
    """What ``armbench run`` was asked to do (all optional; see ``docs/runner.md``)."""

    suites: Sequence[str] = ()
    """Suite names or ``module:Class`` references; empty: every registered suite."""
    ports: Sequence[str] = ()
    """The arms, each ``PORT`` or ``NAME=PORT`` (``--port``): one is a run of one arm, several a
    fleet (:mod:`~armbench.bench.runner.arms`); none: one arm on ``fake://``, or when resuming
    the arms of the run resumed (one arm's port may be given again)."""
    config: str | Path | None = None
    """Limits file (``bench.toml``); None: the packaged ``record/default_bench.toml``."""
    out: str | Path | None = None
    """Run directory; None: ``<runs_root>/<run id>``."""
    overwrite: bool = False
    """Replace the run ``out`` holds (:mod:`~armbench.bench.runner.overwrite`); else a folder
    that holds one is refused."""
    runs_root: str | Path = "runs"
    baseline: str | Path | None = None
    resume: str | Path | None = None
    seed: int | None = None
    settings: str | Path | None = None
    faults: str | Path | None = None
    tracker: str | None = None
    power_command: tuple[str, str] | None = None
    power_manual: bool = False
    retries: int | None = None
    """Extra attempts for a trial that ends in error; None: ``[bench] retries`` or 0."""
    capture: bool | None = None
    """Capture the traffic (``capture.mcap``); None: ``[bench] capture`` or true."""
    capture_max_mb: float | None = None
    """The capture's size bound (MB); None: ``[bench] capture_max_bytes`` or unbounded."""
    workers: int | None = None
    """Processes measuring ``fake://`` trials at once; None: ``[bench] workers`` or one per CPU
    (at most 2)."""
    scheduler: str | None = None
    """A Dask scheduler (``tcp://HOST:PORT``) measuring the ``fake://`` trials; None:
    ``[bench] scheduler`` or the local process pool."""
    shard: tuple[int, int] | None = None
    """``(I, N)``: measure only shard I of N (1-based) of every suite's trials (CI)."""
    require: Sequence[str] = ()
    """Suites or metric patterns the run must measure besides the planned suites
    (``--require``)."""
    optional: Sequence[str] = ()
    """Planned suites the run may leave untested (``--optional``)."""
    dut: str | None = None
    """The unit under test's name (``--dut``), over the config's ``[dut] name``."""
    meta: Sequence[str] = ()
    """``KEY=VALUE`` pairs of the unit under test (``--meta``), over the config's ``[dut]``."""


@dataclass(slots=True)
class PlannedSuite:
    """One suite of the plan: its reference (CLI name or ``module:Class``), instance, validated
    parameters and trial plan."""

    ref: str
    suite: Suite
    params: dict[str, Any]
    trials: list[Mapping[str, Any]]

    @property
    def name(self) -> str:
        """The suite's name in the record."""
        return self.suite.name


@dataclass(slots=True)
class BenchPlan:
    """Everything :func:`~armbench.bench.runner.plan.prepare` validated; the runner only runs
    it."""

    port: str
    target: Target
    """What the port names and what it can do (its clock, fresh arms, workers, truth, power)."""
    settings: RobotSettings
    settings_path: str | None
    config: LimitsConfig
    seed: int
    faults: list[Fault]
    suites: list[PlannedSuite]
    out_dir: Path
    resume: RunRecord | None
    baseline: RunRecord | None
    retries: int
    isolation: Isolation
    reply_timeout_s: float
    connect_timeout_s: float
    settle_s: float
    power: PowerSwitch | None
    tracker: PoseSource | None
    run_id: str
    runner_info: dict[str, Any] = field(default_factory=dict)
    outage_timeout_s: float = DEFAULT_OUTAGE_TIMEOUT_S
    move_timeout_scale: float = 1.0
    """How long a lost port may stay lost before its trial ends in ``LinkLostError`` (``[bench]
    outage_timeout_s``): the reconnection's time bound, counted from the last reply."""
    workers: int = 1
    """Processes measuring trials at once (``[bench] workers``) on a target that allows it."""
    capture: bool = True
    """Whether connections write the traffic capture (``[bench] capture``, ``--no-capture``; a
    campaign of thousands of trials does not)."""
    capture_max_bytes: int | None = None
    """The capture's size bound in bytes; None: unbounded."""
    warnings: list[str] = field(default_factory=list)
    """What the verdict carries beside pass or fail (a limits file that judges nothing)."""
    scheduler: str | None = None
    """The Dask scheduler measuring the trials (``[bench] scheduler``), or None."""
    shard: tuple[int, int] | None = None
    """``(I, N)``: only the trials of shard I of N (:func:`in_shard`); suites are not summarised
    (``armbench merge`` does it over every shard)."""
    required: list[str] = field(default_factory=list)
    """What the run must measure to pass (:func:`~armbench.bench.runner.required.required_of`)."""
    dut: Dut = field(default_factory=Dut)
    """The unit under test: the config's ``[dut]`` with ``--dut`` and ``--meta`` over it (a
    resumed run's as recorded)."""

    def total_trials(self) -> int:
        """Trials still to measure (done trials of a resumed record excluded)."""
        total = 0
        for s in self.suites:
            total += len(self.remaining_trials(s))
        return total

    def remaining_trials(self, s: PlannedSuite) -> list[int]:
        """Indices of suite ``s`` still to measure."""
        rec = None if self.resume is None else self.resume.suites.get(s.name)
        if rec is not None and rec.status == "done":
            return []
        done = set() if rec is None else {t.index for t in rec.completed_trials()}
        return [i for i in self.shard_trials(s) if i not in done]

    def shard_trials(self, s: PlannedSuite) -> list[int]:
        """Indices of suite ``s`` this run measures: all, or those of its shard
        (:func:`shard_assignment` over every suite of the plan)."""
        if self.shard is None:
            return list(range(len(s.trials)))
        i, n = self.shard
        shards = shard_assignment([p.trials for p in self.suites], n)[
            next(k for k, p in enumerate(self.suites) if p is s)]
        return [k for k, owner in enumerate(shards) if owner == i - 1]


@dataclass(slots=True)
class RunOutcome:
    """What a run left: the directory, the record, its verdict and the exit status."""

    out_dir: Path
    record: RunRecord
    exit_status: int
    interrupted: bool = False
    error: str | None = None
    """Why the bench stopped early (connection lost for good, a baseline that cannot be used)."""
    warnings: tuple[str, ...] = ()
    """What the verdict carries beside pass or fail (a limits file that judges nothing)."""
    capture_max_bytes: int | None = None
    """The capture's size bound (None: unbounded), which the report attached to it keeps."""

    @property
    def verdict(self) -> Verdict:
        """The record's verdict."""
        return self.record.verdict

    @property
    def results_path(self) -> Path:
        """``results.json`` of the run."""
        return self.out_dir / RESULTS_FILE
