"""The bench runner behind ``armbench run``: validate everything, run the suites trial by trial
against the arm, keep ``results.json`` current, compare with a baseline, write the reports.

::

    outcome = run_sync(RunOptions(suites=["accuracy"], port="fake://", out="runs/x"))
    outcome.exit_status            # 0 pass, 1 limit or regression failed, 2 could not run, 130

Order of work:

1. :func:`prepare` checks *everything* before the arm is touched: the limits file, suite names and
   parameters (``Suite.params``), each suite's plan, the robot settings, the fault file, the
   baseline (readable, same record schema, same limits spec), the port's scheme, the tracker
   plug-in, the power switch, the run directory (or the record to resume). Any problem raises an
   :class:`~armbench.drivers.errors.ArmbenchError` naming the field: the CLI prints one line and
   exits 2.
2. :func:`execute` runs each planned suite: ``begin_suite``, then every trial the record does not
   have yet (``completed_trials``), each written to disk the moment it ends (``add_trial``), then
   ``summarize`` and ``end_suite``; then the baseline comparison, ``junit.xml`` and
   ``report.html``.

On ``fake://`` (default ``isolation = "trial"``) every trial runs against a freshly powered
emulator seeded from (seed, suite, trial index), so each trial is reproducible on its own and a
resumed run measures exactly what an uninterrupted one would. On hardware one connection serves
the whole run (reconnecting with back-off after a lost port).

The run clock of the record (``started_s``, ``duration_s``, ...) is the event loop's: monotonic
seconds on hardware, simulated seconds on ``fake://`` (where minutes of robot time take seconds).
Semantics of errors, retries, cancellation and resume: ``docs/runner.md``.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import dataclasses
import hashlib
import html
import json
import logging
import math
import multiprocessing
import os
import pickle
import random
import re
import shutil
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Literal
from urllib.parse import parse_qs, urlsplit

from armbench.bench.baseline import BaselineError, compare, load_baseline
from armbench.bench.limits import LimitsConfig, load_limits
from armbench.bench.power import DEFAULT_COMMAND_TIMEOUT_S, CommandPower, EmulatorPower, ManualPower
from armbench.bench.record import (
    CAPTURE_FILE,
    REPORT_FILE,
    RESULTS_FILE,
    RecordError,
    RecordWriter,
    RunRecord,
    Trial,
    Verdict,
    atomic_write_bytes,
    capture_environment,
    continued_clock_s,
    load_record,
    new_run_id,
    path_inside,
)
from armbench.bench.suites import Suite, SuiteContext, load_suite, suite_names
from armbench.bench.suites.base import PoseSource, PowerSwitch
from armbench.bench.truth import EmulatorTruth, aclose_source, aopen_source, load_tracker
from armbench.drivers.capture import capture_options, merge_capture, shift_capture
from armbench.drivers.errors import ArmbenchError, TransportError
from armbench.drivers.settings import RobotSettings, SettingsError, load_settings
from armbench.drivers.transports import scheme_of, transport_class

if TYPE_CHECKING:  # the emulator is imported only for fake:// runs
    from armbench.bench.workers import JobResult, TrialJob
    from armbench.fakes.arm import ArmEmulator
    from armbench.fakes.faults import Fault
    from armbench.fakes.settings import EmulatorSettings

__all__ = [
    "CAPTURE_FILE",
    "DEFAULT_CONFIG",
    "EXIT_ERROR",
    "EXIT_FAIL",
    "EXIT_INTERRUPTED",
    "EXIT_PASS",
    "JUNIT_FILE",
    "REPORT_FILE",
    "RUNNER_FILE",
    "BenchPlan",
    "EmulatorFactory",
    "PlannedSuite",
    "ProgressPrinter",
    "RunAborted",
    "RunOptions",
    "RunOutcome",
    "derive_seed",
    "execute",
    "exit_status",
    "prepare",
    "run_bench",
    "run_sync",
    "write_reports",
]

log = logging.getLogger("armbench.runner")

#: The limits file used when ``--config`` is not given (shipped with the package).
DEFAULT_CONFIG = Path(__file__).with_name("default_bench.toml")
#: Files of a run directory besides ``results.json``.
JUNIT_FILE = "junit.xml"
#: How the run was invoked (suite references, files), read back by ``--resume``.
RUNNER_FILE = "runner.json"
#: Bytes per read when a connection's capture part is appended to ``capture.jsonl``.
_COPY_CHUNK = 1 << 20

EXIT_PASS = 0
EXIT_FAIL = 1
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130

_EXIT_BY_VERDICT: dict[Verdict, int] = {
    "pass": EXIT_PASS, "fail": EXIT_FAIL, "regression": EXIT_FAIL,
    "error": EXIT_ERROR, "incomplete": EXIT_ERROR,
}

Isolation = Literal["trial", "run"]
_BENCH_KEYS = {"retries", "isolation", "reply_timeout_s", "connect_timeout_s", "settle_s",
               "power_timeout_s", "tracker", "workers", "capture", "capture_max_bytes"}

EmulatorFactory = Callable[["RobotSettings", "EmulatorSettings", "Sequence[Fault]"],
                           "ArmEmulator"]
"""Builds the ``fake://`` emulator of a connection (tests pass one to watch the emulators)."""


def exit_status(verdict: Verdict) -> int:
    """The exit status of a run with this verdict: 0 pass, 1 fail or regression, 2 error or
    incomplete."""
    return _EXIT_BY_VERDICT[verdict]


def derive_seed(seed: int, *labels: object) -> int:
    """A seed for one part of the run (a trial, an emulator), stable across processes and Python
    versions: the top 26 bits of SHA-256 of the base seed and the labels (< 2**26: small enough
    for any seed field, e.g. the emulator's boards derive ``31 * seed + board`` from it)."""
    text = json.dumps([seed, *[str(x) for x in labels]])
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "big") >> (64 - 26)


class RunAborted(ArmbenchError):
    """The bench stopped before the end (the arm cannot be reached); the record on disk keeps
    every finished trial and a ``--resume`` continues."""


# --------------------------------------------------------------------------------------------
# Options and the validated plan
# --------------------------------------------------------------------------------------------


@dataclass(slots=True)
class RunOptions:
    """What ``armbench run`` was asked to do (all optional; see ``docs/runner.md``)."""

    suites: Sequence[str] = ()
    """Suite names or ``module:Class`` references; empty: every registered suite."""
    port: str | None = None
    """The arm's port; None: ``fake://`` (or the recorded port when resuming)."""
    config: str | Path | None = None
    """Limits file (``bench.toml``); None: the packaged ``bench/default_bench.toml``."""
    out: str | Path | None = None
    """Run directory; None: ``<runs_root>/<run id>``."""
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
    workers: int | None = None
    """Processes measuring ``fake://`` trials at once; None: ``[bench] workers`` or one per CPU
    (at most 2)."""
    capture: bool | None = None
    """Capture the traffic (``capture.jsonl``); None: ``[bench] capture`` or true."""
    capture_max_mb: float | None = None
    """The capture's size bound (MB); None: ``[bench] capture_max_bytes`` or unbounded."""


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
    """Everything :func:`prepare` validated; :func:`execute` only runs it."""

    port: str
    fake: bool
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
    workers: int = 1
    """Processes measuring ``fake://`` trials at once (``[bench] workers``)."""
    capture: bool = True
    capture_max_bytes: int | None = None

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
        return [i for i in range(len(s.trials)) if i not in done]


@dataclass(slots=True)
class RunOutcome:
    """What a run left: the directory, the record, its verdict and the exit status."""

    out_dir: Path
    record: RunRecord
    exit_status: int
    interrupted: bool = False
    error: str | None = None
    """Why the bench stopped early (connection lost for good, a baseline that cannot be used)."""

    @property
    def verdict(self) -> Verdict:
        """The record's verdict."""
        return self.record.verdict

    @property
    def results_path(self) -> Path:
        """``results.json`` of the run."""
        return self.out_dir / RESULTS_FILE


def _bench_params(config: LimitsConfig) -> dict[str, Any]:
    params = config.bench_params()
    for key, value in params.items():
        if key not in _BENCH_KEYS:
            raise SettingsError(f"bench.{key}", value, "is not a bench parameter (known: "
                                f"{', '.join(sorted(_BENCH_KEYS))})")
    return params


def _number(where: str, value: object, *, low: float, strict: bool) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SettingsError(where, value, "is not a finite number")
    if value < low or (strict and value == low):
        raise SettingsError(where, value, f"must be {'>' if strict else '>='} {low:g}")
    return float(value)


def _integer(where: str, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise SettingsError(where, value, "must be a whole number >= 0")
    return value


def _json_equal(a: object, b: object) -> bool:
    def norm(x: object) -> Any:
        return json.loads(json.dumps(x, default=_plain, sort_keys=True))

    try:
        return bool(norm(a) == norm(b))
    except (TypeError, ValueError):
        return False


def _plain(obj: object) -> Any:
    tolist = getattr(obj, "tolist", None)
    if callable(tolist):
        return tolist()
    isoformat = getattr(obj, "isoformat", None)
    if callable(isoformat):
        return isoformat()
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


def _load_runner_info(directory: Path) -> dict[str, Any]:
    path = directory / RUNNER_FILE
    if not path.exists():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise RecordError(str(path), f"cannot be read: {exc}") from None
    if not isinstance(data, dict):
        raise RecordError(str(path), "is not a JSON object")
    return data


def prepare(options: RunOptions) -> BenchPlan:
    """Validate ``options`` and everything they name, without touching the arm.

    Raises an :class:`~armbench.drivers.errors.ArmbenchError` (``SettingsError``, ``RecordError``,
    ``BaselineError``, ``TransportError``, ``SuiteError``, ``TrackerError``, ``PowerError``)
    whose message names the offending field or file.
    """
    resume: RunRecord | None = None
    info: dict[str, Any] = {}
    if options.resume is not None:
        resume_dir = Path(options.resume)
        for flag, given in (("SUITE", bool(options.suites)), ("--config", options.config),
                            ("--seed", options.seed is not None),
                            ("--settings", options.settings), ("--faults", options.faults)):
            if given:
                raise ArmbenchError(f"--resume: {flag} comes from the run being resumed and "
                                    "cannot be given again")
        if options.out is not None and Path(options.out).resolve() != resume_dir.resolve():
            raise ArmbenchError("--out: a resumed run continues in its own directory "
                                f"({resume_dir}); leave --out out")
        resume = load_record(path_inside(resume_dir, RESULTS_FILE))
        info = _load_runner_info(resume_dir)
        out_dir = resume_dir
    else:
        out_dir = Path(options.out) if options.out is not None else Path(options.runs_root)
        if options.out is not None and (out_dir / RESULTS_FILE).exists():
            raise RecordError(str(out_dir / RESULTS_FILE), "already holds a run record; resume "
                                                           "it (--resume) or choose another --out")

    # --- port -------------------------------------------------------------------------------
    env = None if resume is None else resume.environment
    port = options.port or (env.port if env is not None and env.port else None) or "fake://"
    transport_class(port)  # unknown scheme or a transport that cannot be imported
    if scheme_of(port) is None and "/" in port and not Path(port).exists():
        raise TransportError(port, "no such serial device (is the arm plugged in? "
                                   "'python3 -m serial.tools.list_ports' lists the ports)")
    fake = scheme_of(port) == "fake"
    url_settings: str | None = None
    url_seed: int | None = None
    url_faults: list[Fault] = []
    if fake:
        from armbench.drivers.transports.fake import parse_fake_url

        _, url_seed, url_faults = parse_fake_url(port)  # validates the query
        query = parse_qs(urlsplit(port).query)
        url_settings = query["settings"][-1] if "settings" in query else None

    # --- settings, limits, seed, faults ----------------------------------------------------
    if resume is not None:
        assert env is not None
        settings_path = info.get("settings") or url_settings
        settings = load_settings(settings_path) if settings_path else RobotSettings()
        if not _json_equal(settings.to_mapping(), env.settings):
            raise SettingsError("settings", settings_path or "defaults",
                                "differ from the settings the run began with; start a new run")
        config_path = info.get("config") or env.config_path
        config = load_limits(config_path) if config_path else LimitsConfig()
        if env.limits_spec_version is not None and config.spec_version != env.limits_spec_version:
            raise SettingsError("spec_version", config.spec_version,
                                f"differs from the run's {env.limits_spec_version!r}")
        seed = env.seed if env.seed is not None else 0
        from armbench.fakes.faults import parse_faults

        faults = parse_faults(env.faults, "environment.faults") if env.faults else []
        refs = info.get("suites") or {}
        suite_refs = [refs.get(name, name) if isinstance(refs, dict) else name
                      for name in resume.planned_suites]
    else:
        if options.settings is not None and url_settings is not None:
            raise ArmbenchError("--settings: the port already names a settings file; give one")
        settings_path = str(options.settings) if options.settings is not None else url_settings
        settings = load_settings(settings_path) if settings_path else RobotSettings()
        config_file = Path(options.config) if options.config is not None else DEFAULT_CONFIG
        config = load_limits(config_file)
        if options.seed is not None:
            seed = _integer("--seed", options.seed)
        else:
            seed = url_seed if url_seed is not None else 0
        faults = list(url_faults)
        if options.faults is not None:
            if not fake:
                raise ArmbenchError(f"--faults: faults are injected into the emulator; the port "
                                    f"{port!r} is not fake://")
            from armbench.fakes.faults import load_faults

            faults += load_faults(options.faults)
        suite_refs = list(options.suites) or suite_names()
        if len(set(suite_refs)) != len(suite_refs):
            raise ArmbenchError(f"SUITE: a suite is named twice in {suite_refs}")

    bench = _bench_params(config)
    retries = _integer("bench.retries", bench.get("retries", 0))
    if options.retries is not None:
        retries = _integer("--retries", options.retries)
    workers = _integer("bench.workers", bench.get("workers", min(2, os.cpu_count() or 1)))
    if options.workers is not None:
        workers = _integer("--workers", options.workers)
    if workers < 1:
        raise SettingsError("--workers" if options.workers is not None else "bench.workers",
                            workers, "must be at least 1")
    capture, capture_max_bytes = capture_options(bench, options.capture, options.capture_max_mb)
    isolation = bench.get("isolation", "trial" if fake else "run")
    if isolation not in ("trial", "run"):
        raise SettingsError("bench.isolation", isolation, "must be 'trial' or 'run'")
    if isolation == "trial" and not fake:
        raise SettingsError("bench.isolation", isolation,
                            "'trial' (a fresh emulator per trial) needs a fake:// port")
    reply_timeout_s = _number("bench.reply_timeout_s", bench.get("reply_timeout_s", 0.5),
                              low=0, strict=True)
    connect_timeout_s = _number("bench.connect_timeout_s", bench.get("connect_timeout_s", 3.0),
                                low=0, strict=True)
    settle_s = _number("bench.settle_s", bench.get("settle_s", 0.0), low=0, strict=False)
    power_timeout_s = _number("bench.power_timeout_s",
                              bench.get("power_timeout_s", DEFAULT_COMMAND_TIMEOUT_S),
                              low=0, strict=True)
    tracker_params = bench.get("tracker", {})
    if not isinstance(tracker_params, Mapping):
        raise SettingsError("bench.tracker", tracker_params, "is not a table")
    if fake:
        from armbench.fakes.settings import emulator_settings

        emulator_settings(settings, seed=0)  # the [emulator] table, checked now

    # --- suites -----------------------------------------------------------------------------
    planned: list[PlannedSuite] = []
    names: dict[str, str] = {}
    for ref in suite_refs:
        suite = load_suite(ref)
        if suite.name in names:
            raise ArmbenchError(f"SUITE: {ref!r} and {names[suite.name]!r} are both suite "
                                f"{suite.name!r}")
        names[suite.name] = ref
        configured = config.suite_params(suite.name)
        if ref != suite.name and ref in config.suites:
            if suite.name in config.suites:
                raise SettingsError(f"suites.{ref}", config.suite_params(ref),
                                    f"and [suites.{suite.name}] both configure suite "
                                    f"{suite.name!r}; keep one")
            configured = config.suite_params(ref)
        try:
            params = suite.params(settings, configured)
            trials: list[Mapping[str, Any]] = [dict(t) for t in suite.plan(params)]
        except ArmbenchError:
            raise
        except Exception as exc:  # a wrongly typed value the suite did not check itself
            raise SettingsError(f"suites.{suite.name}", configured,
                                f"cannot be used: {type(exc).__name__}: {exc}") from exc
        if resume is not None:
            rec = resume.suites.get(suite.name)
            if rec is not None and rec.status != "done":
                if rec.version != suite.version:
                    raise RecordError(f"suites.{suite.name}.version",
                                      f"recorded {rec.version!r}, this armbench has "
                                      f"{suite.version!r}; start a new run")
                if not _json_equal(rec.params, params):
                    raise RecordError(f"suites.{suite.name}.params",
                                      "differ from the recorded ones (was the limits file "
                                      "changed?); start a new run")
        planned.append(PlannedSuite(ref, suite, params, trials))

    # --- baseline ---------------------------------------------------------------------------
    baseline = None
    if options.baseline is not None:
        baseline = load_baseline(options.baseline)
        theirs = baseline.environment.limits_spec_version
        if theirs is not None and theirs != config.spec_version:
            raise BaselineError(f"baseline {options.baseline}: limits spec version {theirs!r} "
                                f"differs from this run's {config.spec_version!r}")
        for ps in planned:  # figures of another suite version measure something else
            theirs_suite = baseline.suites.get(ps.name)
            if theirs_suite is not None and theirs_suite.version != ps.suite.version:
                raise BaselineError(f"baseline {options.baseline}: suites.{ps.name}.version "
                                    f"{theirs_suite.version!r} differs from this run's "
                                    f"{ps.suite.version!r}; measure a new baseline")

    # --- measurement source and power -------------------------------------------------------
    tracker = load_tracker(options.tracker, settings, tracker_params) if options.tracker else None
    power: PowerSwitch | None = None
    if options.power_command is not None and options.power_manual:
        raise ArmbenchError("--power-command and --power-manual: choose one")
    if fake and (options.power_command is not None or options.power_manual):
        raise ArmbenchError("--power-command/--power-manual: on fake:// the bench switches the "
                            "emulator's power itself")
    if options.power_command is not None:
        off, on = options.power_command
        command_power = CommandPower(off, on, timeout_s=power_timeout_s)
        command_power.check()
        power = command_power
    elif options.power_manual:
        power = ManualPower()

    run_id = resume.run_id if resume is not None else new_run_id()
    if resume is None and options.out is None:
        out_dir = Path(options.runs_root) / run_id
    runner_info = {
        "suites": {s.name: s.ref for s in planned},
        "settings": str(Path(settings_path).resolve()) if settings_path else None,
        "config": str(Path(config.path).resolve()) if config.path else None,
        "faults": str(Path(options.faults).resolve()) if options.faults is not None else None,
    }
    if resume is not None:
        runner_info = {**info, **{k: v for k, v in runner_info.items() if k == "suites"}}
    return BenchPlan(
        port=port, fake=fake, settings=settings, settings_path=settings_path, config=config,
        seed=seed, faults=faults, suites=planned, out_dir=out_dir, resume=resume,
        baseline=baseline, retries=retries, isolation=isolation,
        reply_timeout_s=reply_timeout_s, connect_timeout_s=connect_timeout_s, settle_s=settle_s,
        power=power, tracker=tracker, run_id=run_id, runner_info=runner_info, workers=workers,
        capture=capture, capture_max_bytes=capture_max_bytes,
    )


# --------------------------------------------------------------------------------------------
# Progress
# --------------------------------------------------------------------------------------------


def _clock(seconds: float) -> str:
    s = max(0, round(seconds))
    h, rest = divmod(s, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class ProgressPrinter:
    """One line per trial on ``stream`` (stderr): suite, trial k of n, elapsed and an estimate of
    the remaining time; rewritten in place on a terminal.

    Elapsed and remaining are the operator's time (the wall clock, ``time.perf_counter``): on
    ``fake://`` the robot's simulated time runs much faster and is shown beside it as ``robot``.
    The estimate is each suite's mean trial time so far (the run's mean for a suite that has not
    measured a trial yet) times the trials left.
    """

    def __init__(self, stream: IO[str] | None, total_trials: int, *,
                 robot_clock: Callable[[], float] | None = None) -> None:
        self.stream = stream
        self.total = total_trials
        self.done = 0
        self.robot_clock = robot_clock
        self._tty = bool(stream is not None and getattr(stream, "isatty", lambda: False)())
        self._t0 = time.perf_counter()
        self._durations: dict[str, list[float]] = {}
        self._remaining: dict[str, int] = {}
        self._open_line = False
        self.lines: list[str] = []
        """Every line shown (for tests and logs)."""

    def plan(self, suite: str, remaining: int) -> None:
        """Declare how many trials of ``suite`` are left."""
        self._remaining[suite] = remaining

    def estimate_s(self) -> float | None:
        """Seconds (wall) the remaining trials should take, None before any trial ended."""
        everything = [d for ds in self._durations.values() for d in ds]
        if not everything:
            return None
        overall = sum(everything) / len(everything)
        total = 0.0
        for suite, left in self._remaining.items():
            ds = self._durations.get(suite)
            total += left * (sum(ds) / len(ds) if ds else overall)
        return total

    def trial(self, suite: str, k: int, n: int, status: str, wall_s: float) -> None:
        """Trial ``k`` (1-based) of ``n`` of ``suite`` ended with ``status``."""
        self.done += 1
        self._durations.setdefault(suite, []).append(wall_s)
        self._remaining[suite] = max(0, self._remaining.get(suite, 1) - 1)
        elapsed = time.perf_counter() - self._t0
        est = self.estimate_s()
        parts = [f"[{suite}] trial {k}/{n} {status}", f"run {self.done}/{self.total}",
                 f"elapsed {_clock(elapsed)}",
                 f"remaining ~{_clock(est)}" if est is not None else "remaining ?"]
        if self.robot_clock is not None:
            parts.append(f"robot time {_clock(self.robot_clock())}")
        self._show("  ".join(parts), in_place=True)

    def message(self, text: str) -> None:
        """A line that stays (suite start and end, warnings)."""
        self._show(text, in_place=False)

    def finish(self) -> None:
        """End an in-place line."""
        if self._open_line and self.stream is not None:
            self.stream.write("\n")
            self.stream.flush()
        self._open_line = False

    def _show(self, line: str, *, in_place: bool) -> None:
        self.lines.append(line)
        stream = self.stream
        if stream is None:
            return
        if self._tty and in_place:
            stream.write("\r\x1b[K" + line)
            self._open_line = True
        else:
            if self._open_line:
                stream.write("\n")
                self._open_line = False
            stream.write(line + "\n")
        stream.flush()


# --------------------------------------------------------------------------------------------
# Execution
# --------------------------------------------------------------------------------------------


class _LoopClockWriter(RecordWriter):
    """A :class:`RecordWriter` whose run clock is the event loop's (simulated seconds on
    ``fake://``, monotonic seconds on hardware), continued across resumes."""

    def __init__(self, out_dir: str | Path, record: RunRecord, *, filename: str = RESULTS_FILE,
                 overwrite: bool = False) -> None:
        self._loop = asyncio.get_running_loop()
        self._loop_t0 = self._loop.time()
        self._start_s = continued_clock_s(Path(out_dir), record)
        super().__init__(out_dir, record, filename=filename, overwrite=overwrite)

    def elapsed_s(self) -> float:
        return self._start_s + self._loop.time() - self._loop_t0

    def advance(self, dt_s: float) -> None:
        """Move the run clock by ``dt_s`` (s) of robot time spent elsewhere: a trial measured
        in a worker process on its own loop."""
        self._start_s += dt_s


_JOB_PART = re.compile(
    r"\.capture\.part\d+-job-(?P<suite>.+)-(?P<index>\d+)-(?P<attempt>\d+)\.jsonl")
"""A worker's capture part (``armbench.bench.workers.job_part_tag``)."""


def _first_capture_time(part: Path) -> float | None:
    """``t_s`` of the first record of a capture part, or None if it has none readable."""
    try:
        with part.open(encoding="ascii") as fh:
            return float(json.loads(fh.readline())["t_s"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _default_emulator(robot: RobotSettings, settings: EmulatorSettings,
                      faults: Sequence[Fault]) -> ArmEmulator:
    from armbench.fakes.arm import ArmEmulator

    return ArmEmulator(robot, settings, faults)


#: What makes a trial unmeasurable without being a bug: the driver's and transports' errors, and
#: plain timeouts and OS errors (the suites' own guard treats the same ones alike).
_MEASUREMENT_ERRORS = (ArmbenchError, TimeoutError, OSError)


def _describe(exc: BaseException) -> str:
    if isinstance(exc, _MEASUREMENT_ERRORS):
        return f"{type(exc).__name__}: {exc}"
    return f"bench bug: {type(exc).__name__}: {exc}"


class _Connection:
    """One open arm (and its emulator on ``fake://``) with its capture part file."""

    def __init__(self, arm: Any, emulator: Any, part: Path) -> None:
        self.arm = arm
        self.emulator = emulator
        self.part = part


class _Run:
    """The state of one execution of a plan."""

    def __init__(self, plan: BenchPlan, writer: RecordWriter, progress: ProgressPrinter,
                 emulator_factory: EmulatorFactory, *, part_tag: str = "") -> None:
        self.plan = plan
        self.writer = writer
        self.progress = progress
        self.emulator_factory = emulator_factory
        self.conn: _Connection | None = None
        self.capture = writer.artifact_path(CAPTURE_FILE)
        self.capture_stopped = False
        self._parts = 0
        self._part_tag = part_tag
        self.unmerged: list[Path] = []
        """Capture parts of trials not yet in the record (merged once they are)."""
        self.last_arm: Any = None
        self.pool: Any = None
        """The worker processes of parallel trials (``armbench.bench.workers``), once started."""

    # -- connections ---------------------------------------------------------------------

    async def connect(self, emulator_seed: int) -> _Connection:
        from armbench.drivers.arm import Arm
        from armbench.drivers.capture import CaptureWriter

        plan = self.plan
        self._parts += 1
        part = self.writer.artifact_path(f".capture.part{self._parts}{self._part_tag}.jsonl")
        emulator = None
        transport = None
        if plan.fake:
            from armbench.drivers.transports.fake import FakeTransport
            from armbench.fakes.settings import emulator_settings

            emulator = self.emulator_factory(
                plan.settings, emulator_settings(plan.settings, seed=emulator_seed), plan.faults)
            transport = FakeTransport(plan.port, plan.settings.serial, emulator)
        capture: CaptureWriter | None = None
        try:
            # t_s on the run clock straight away: the part is appended to capture.jsonl as is
            if plan.capture:
                capture = CaptureWriter(part, asyncio.get_running_loop().time()
                                        - self.writer.elapsed_s(),
                                        max_bytes=plan.capture_max_bytes)
            arm = Arm.connect(plan.port, plan.settings, reply_timeout_s=plan.reply_timeout_s,
                              capture=capture, reconnect=not plan.fake,
                              connect_timeout_s=plan.connect_timeout_s, transport=transport)
            await arm.open()
        except BaseException:
            if capture is not None:
                capture.close()
            if emulator is not None:
                with contextlib.suppress(Exception):
                    await emulator.close()
            self._merge_capture(part)
            raise
        self.last_arm = arm
        return _Connection(arm, emulator, part)

    async def disconnect(self, conn: _Connection, *, merge: bool = True) -> None:
        """Close the arm (and its emulator); its capture part is merged now, or, with
        ``merge=False``, by the caller once the trial it holds is in the record."""
        try:
            await conn.arm.close()
        finally:
            if conn.emulator is not None:
                with contextlib.suppress(Exception):
                    await conn.emulator.close()
            if merge:
                self._merge_capture(conn.part)

    def recover_parts(self) -> None:
        """On ``--resume``: the capture parts a killed run left behind. A part whose first frame
        falls within a recorded trial is merged (the kill came between the record and the merge);
        any other holds a trial the record lacks, which is measured again, and is dropped, so
        ``capture.jsonl`` stays one stream on the run clock."""
        spans = [(t.started_s, t.ended_s) for s in self.writer.record.suites.values()
                 for t in (*s.trials, *s.superseded_trials)]
        parts = sorted(self.writer.out_dir.glob(".capture.part*.jsonl"),
                       key=lambda p: p.stat().st_mtime)
        recorded = {(name, t.index): t for name, s in self.writer.record.suites.items()
                    for t in s.trials}
        for part in parts:
            job = _JOB_PART.fullmatch(part.name)
            if job is not None:  # a worker's part: times from its own 0 (armbench.bench.workers)
                trial = recorded.get((job["suite"], int(job["index"])))
                if trial is not None:
                    self._merge_capture(part, trial.started_s)
                    continue
                log.info("dropping %s: its trial is not in the record", part.name)
                with contextlib.suppress(OSError):
                    part.unlink()
                continue
            first = _first_capture_time(part)
            if first is not None and any(a - 1e-6 <= first <= b + 1e-6 for a, b in spans):
                self._merge_capture(part)
            else:
                log.info("dropping %s: its trial is not in the record", part.name)
                with contextlib.suppress(OSError):
                    part.unlink()

    def _merge_capture(self, part: Path, offset_s: float = 0.0) -> None:
        """Append a connection's capture to ``capture.jsonl``: written with ``t_s`` on the run
        clock, or ``offset_s`` before it (a worker's trial)."""
        if not part.exists():
            return
        try:
            if self.plan.capture_max_bytes is not None:
                stopped = merge_capture(part, self.capture, offset_s, self.plan.capture_max_bytes)
                if stopped and not self.capture_stopped:
                    self.capture_stopped = True
                    self.progress.message(f"capture stopped: {self.capture.name} reached its "
                                          f"size bound of {self.plan.capture_max_bytes} bytes")
            else:
                with part.open("rb") as src, self.capture.open("ab") as dst:
                    if offset_s:
                        shift_capture(src, dst, offset_s)
                    else:
                        shutil.copyfileobj(src, dst, _COPY_CHUNK)
        except OSError as exc:
            log.warning("capture %s could not be merged into %s: %s", part, self.capture, exc)
            return
        with contextlib.suppress(OSError):
            part.unlink()

    # -- contexts -----------------------------------------------------------------------

    def context(self, ps: PlannedSuite, arm: Any, emulator: Any, rng_seed: int) -> SuiteContext:
        plan = self.plan
        power = plan.power
        truth = plan.tracker
        if plan.fake:
            source = emulator if emulator is not None else arm
            if power is None:
                power = EmulatorPower(source)
            if truth is None:
                truth = EmulatorTruth(source, plan.settings)

        def artifacts(name: str) -> Path:
            path = self.writer.artifact_path(Path(ps.name) / name)
            path.parent.mkdir(parents=True, exist_ok=True)
            return path

        def progress(message: str) -> None:
            self.progress.message(f"[{ps.name}] {message}")

        return SuiteContext(arm=arm, settings=plan.settings, limits=plan.config,
                            params=ps.params, rng=random.Random(rng_seed), power=power,
                            truth=truth, progress=progress, artifacts=artifacts)

    # -- suites and trials ---------------------------------------------------------------

    async def run_suite(self, ps: PlannedSuite) -> None:
        writer = self.writer
        name = ps.name
        if writer.suite_done(name):
            self.progress.message(f"[{name}] done in the record, skipped")
            return
        writer.begin_suite(name, ps.suite.version, ps.params)
        n = len(ps.trials)
        done = {t.index for t in writer.completed_trials(name)}
        todo = [i for i in range(n) if i not in done]
        self.progress.message(f"[{name}] {n} trial(s)" + (
            f", {len(done)} already measured" if done else ""))
        if self.parallel(ps, todo):
            stopped = await self._run_parallel(ps, todo)
        else:
            stopped = None
            first = True
            for index in todo:
                if not first and self.plan.settle_s > 0:
                    await asyncio.sleep(self.plan.settle_s)
                first = False
                trial = await self.run_trial(ps, index)
                if trial.status == "error":
                    stopped = trial
                    break
        if stopped is not None:
            writer.end_suite(name, error=f"trial {stopped.index}: {stopped.error}")
            self.progress.message(f"[{name}] stopped: trial {stopped.index}: {stopped.error}")
            return
        await self.summarize(ps)

    # -- parallel trials (armbench.bench.workers) -------------------------------------------------

    def parallel(self, ps: PlannedSuite, todo: Sequence[int]) -> bool:
        """Whether the trials of ``ps`` go to worker processes: ``fake://`` with trial isolation
        and the built-in emulator, more than one worker and trial, on a virtual-time loop (the
        run clock is moved by each trial's duration), and a plan that can be sent."""
        plan = self.plan
        if not (plan.fake and plan.isolation == "trial" and plan.workers > 1 and len(todo) > 1
                and self.emulator_factory is _default_emulator and plan.tracker is None
                and plan.power is None and isinstance(self.writer, _LoopClockWriter)):
            return False
        from armbench.fakes.vclock import VirtualTimeLoop

        if not isinstance(asyncio.get_running_loop(), VirtualTimeLoop):
            return False
        try:
            pickle.dumps(self._job(ps, todo[0], 0))
        except Exception as exc:  # a user's suite that cannot be sent: measured in turn
            log.info("suite %s: trials measured in turn (%s cannot be sent to a worker: %s)",
                     ps.name, type(exc).__name__, exc)
            return False
        return True

    def _job(self, ps: PlannedSuite, index: int, attempt: int) -> TrialJob:
        from armbench.bench.workers import TrialJob

        plan = dataclasses.replace(self.plan, suites=[], resume=None, baseline=None,
                                   runner_info={})
        return TrialJob(plan, ps, index, attempt)

    async def _run_parallel(self, ps: PlannedSuite, todo: Sequence[int]) -> Trial | None:
        """Measure ``todo`` in worker processes, commit them in order (as :meth:`run_trial`
        would, each attempt on the run clock); the trial that stopped the suite, or None."""
        from armbench.bench.workers import JobResult, run_job, worker_init

        loop = asyncio.get_running_loop()
        attempts = self.plan.retries + 1
        in_flight = asyncio.Semaphore(self.plan.workers)  # the pool's queue stays short

        def new_pool(workers: int) -> concurrent.futures.ProcessPoolExecutor:
            return concurrent.futures.ProcessPoolExecutor(
                workers, mp_context=multiprocessing.get_context("spawn"),
                initializer=worker_init, initargs=(os.getpid(),))

        async def shared(job: TrialJob) -> JobResult:
            if self.pool is None:
                self.pool = new_pool(self.plan.workers)
            pool = self.pool
            try:
                result: JobResult = await loop.run_in_executor(pool, run_job, job)
            except concurrent.futures.BrokenExecutor:
                if self.pool is pool:
                    self._drop_pool()
                raise
            return result

        async def alone(job: TrialJob) -> JobResult:
            """In a process of its own: a dying worker breaks the whole pool, failing the
            trials beside it too; measured alone, only the trial that kills its process fails."""
            pool = new_pool(1)
            try:
                result: JobResult = await loop.run_in_executor(pool, run_job, job)
            finally:
                pool.shutdown(wait=False)
            return result

        async def measure(index: int) -> list[JobResult]:
            """Every attempt of trial ``index`` (until one is done)."""
            results = []
            for attempt in range(attempts):
                job = self._job(ps, index, attempt)
                async with in_flight:
                    try:
                        try:
                            result = await shared(job)
                        except concurrent.futures.BrokenExecutor:
                            result = await alone(job)
                    except Exception as exc:  # the worker itself failed (killed, result unsent)
                        log.error("suite %s trial %d: worker failed: %s", ps.name, index, exc)
                        result = JobResult(Trial(index, 0.0, 0.0, params=ps.trials[index],
                                                 status="error",
                                                 error=f"worker: {_describe(exc)}"), (), ())
                results.append(result)
                if result.trial.status == "done":
                    break
            return results

        tasks = [asyncio.ensure_future(measure(index)) for index in todo]
        last_commit = time.perf_counter()
        try:
            for k, (index, task) in enumerate(zip(todo, tasks, strict=True)):
                await asyncio.sleep(0)  # a cancellation asked for meanwhile stops here, as in turn
                results = await task
                if k and self.plan.settle_s > 0:
                    self.writer_clock.advance(self.plan.settle_s)
                for attempt, result in enumerate(results):
                    # wall time per commit: what the progress estimate needs (throughput)
                    now = time.perf_counter()
                    trial = self._commit(ps, index, attempt, result, now - last_commit)
                    last_commit = now
                if trial.status == "error":
                    return trial
            return None
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            for path in self.writer.out_dir.glob(f".capture.part*-job-{ps.name}-*.jsonl"):
                with contextlib.suppress(OSError):  # parts of trials never committed
                    path.unlink()

    @property
    def writer_clock(self) -> _LoopClockWriter:
        assert isinstance(self.writer, _LoopClockWriter)
        return self.writer

    def _commit(self, ps: PlannedSuite, index: int, attempt: int, result: JobResult,
                wall_s: float) -> Trial:
        """One attempt measured by a worker, into the record as :meth:`run_trial` does: it
        starts on the run clock now and moves it by its duration; its capture is merged with
        its times moved onto the run clock."""
        clock = self.writer_clock
        start = clock.elapsed_s()
        trial = dataclasses.replace(result.trial, started_s=start)
        clock.advance(trial.duration_s)
        self.writer.add_trial(ps.name, trial)
        for part in result.parts:
            self._merge_capture(part, start - result.trial.started_s)
        for line in result.messages:
            self.progress.message(line)
        self._show_attempt(ps, index, attempt, trial, wall_s)
        return trial

    def _show_attempt(self, ps: PlannedSuite, index: int, attempt: int, trial: Trial,
                      wall_s: float) -> None:
        """The progress line of a recorded attempt: done, or its error and whether it is
        retried."""
        status = trial.status if trial.status == "done" else f"error ({trial.error})"
        if trial.status == "error" and attempt < self.plan.retries:
            status += f", retrying ({attempt + 1}/{self.plan.retries})"
        self.progress.trial(ps.name, index + 1, len(ps.trials), status, wall_s)

    async def summarize(self, ps: PlannedSuite) -> None:
        writer = self.writer
        arm = self.last_arm
        if arm is None:
            from armbench.drivers.arm import Arm

            arm = Arm(self.plan.port, self.plan.settings)  # never opened: summaries don't move
        ctx = self.context(ps, arm, None, derive_seed(self.plan.seed, ps.name, "summary"))
        try:
            measurements = ps.suite.summarize(ctx, writer.completed_trials(ps.name))
            writer.end_suite(ps.name, measurements)
        except Exception as exc:
            log.debug("summary of %s failed", ps.name, exc_info=True)
            writer.end_suite(ps.name, error=f"summary: {_describe(exc)}")
            self.progress.message(f"[{ps.name}] summary failed: {_describe(exc)}")
            return
        failed = [m.name for m in writer.suite(ps.name).measurements if m.outcome == "fail"]
        self.progress.message(f"[{ps.name}] done: {len(measurements)} measurement(s)"
                              + (f", {len(failed)} outside limits" if failed else ""))

    async def run_trial(self, ps: PlannedSuite, index: int) -> Trial:
        plan = self.plan
        attempts = plan.retries + 1
        trial: Trial | None = None
        for attempt in range(attempts):
            wall0 = time.perf_counter()
            trial = await self._attempt(ps, index, attempt)
            self.writer.add_trial(ps.name, trial)
            for part in self.unmerged:  # after the record: see recover_parts
                self._merge_capture(part)
            self.unmerged.clear()
            self._show_attempt(ps, index, attempt, trial, time.perf_counter() - wall0)
            if trial.status == "done":
                break
        assert trial is not None
        return trial

    async def _attempt(self, ps: PlannedSuite, index: int, attempt: int) -> Trial:
        plan = self.plan
        writer = self.writer
        trial_params = ps.trials[index]
        t0 = writer.elapsed_s()
        own: _Connection | None = None
        try:
            if plan.isolation == "trial":
                own = await self.connect(derive_seed(plan.seed, "emulator", ps.name, index,
                                                     attempt))
                conn = own
            else:
                conn = await self._run_connection()
            ctx = self.context(ps, conn.arm, conn.emulator, derive_seed(plan.seed, ps.name,
                                                                        index))
            result = await ps.suite.run_trial(ctx, index, trial_params)
            if not isinstance(result, Trial):
                raise TypeError(f"run_trial returned {type(result).__name__}, not a Trial")
            if result.index != index:
                raise ValueError(f"run_trial({index}) returned trial index {result.index}")
            duration = max(0.0, writer.elapsed_s() - t0)
            return dataclasses.replace(result, started_s=t0, duration_s=duration)
        except RunAborted:
            raise
        except Exception as exc:
            if not isinstance(exc, _MEASUREMENT_ERRORS):
                log.error("suite %s trial %d: %s", ps.name, index, _describe(exc),
                          exc_info=True)
            return Trial(index, t0, max(0.0, writer.elapsed_s() - t0), params=trial_params,
                         status="error", error=_describe(exc))
        finally:
            if own is not None:
                self.unmerged.append(own.part)
                await self.disconnect(own, merge=False)

    async def _run_connection(self) -> _Connection:
        """The run's connection (``isolation = "run"``), opened again when it was lost."""
        conn = self.conn
        if conn is not None and conn.arm.connected:
            return conn
        if conn is not None:
            self.conn = None
            await self.disconnect(conn)
            self.progress.message("the arm connection was lost; connecting again")
        try:
            self.conn = await self.connect(derive_seed(self.plan.seed, "emulator", "run")
                                           if self.plan.fake else 0)
        except ArmbenchError as exc:
            raise RunAborted(f"cannot connect to {self.plan.port}: {exc}") from exc
        return self.conn

    def _drop_pool(self) -> None:
        """Let the worker processes go (a busy one finishes its trial alone); the next parallel
        suite starts new ones."""
        pool, self.pool = self.pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)

    async def close(self) -> None:
        conn, self.conn = self.conn, None
        self._drop_pool()
        if conn is not None:
            await self.disconnect(conn)


def _new_record(plan: BenchPlan) -> RunRecord:
    env = capture_environment(port=plan.port, settings=plan.settings, seed=plan.seed,
                              faults=[dataclasses.asdict(f) for f in plan.faults],
                              limits=plan.config)
    return RunRecord.new(env, [s.name for s in plan.suites], run_id=plan.run_id)


async def execute(plan: BenchPlan, *, progress: IO[str] | None = None,
                  emulator_factory: EmulatorFactory | None = None) -> RunOutcome:
    """Run a prepared plan (see the module docstring); returns the outcome.

    Cancellation (Ctrl-C) abandons the current trial (the driver tells the arm to hold), keeps
    the record as it is on disk (every finished trial), writes ``junit.xml`` and ``report.html``
    of the partial record, and propagates :class:`asyncio.CancelledError`.
    """
    if plan.resume is not None:
        writer: RecordWriter = _LoopClockWriter.resume(plan.out_dir)
        for ps in plan.suites:  # planned suites may be re-checked, never changed
            if ps.name not in writer.record.planned_suites:
                writer.record.planned_suites.append(ps.name)
    else:
        plan.out_dir.mkdir(parents=True, exist_ok=True)
        writer = _LoopClockWriter(plan.out_dir, _new_record(plan))
    atomic_write_bytes(writer.artifact_path(RUNNER_FILE),
                       (json.dumps(plan.runner_info, indent=1) + "\n").encode())
    t_run0 = writer.elapsed_s()
    printer = ProgressPrinter(progress, plan.total_trials(),
                              robot_clock=(lambda: writer.elapsed_s() - t_run0) if plan.fake
                              else None)
    for ps in plan.suites:
        printer.plan(ps.name, len(plan.remaining_trials(ps)))
    run = _Run(plan, writer, printer,
               emulator_factory if emulator_factory is not None else _default_emulator)
    if plan.resume is not None:
        run.recover_parts()
    printer.message(f"armbench run {plan.run_id}: {', '.join(s.name for s in plan.suites)} on "
                    f"{plan.port} -> {plan.out_dir}")
    error: str | None = None
    interrupted = False
    try:
        if plan.tracker is not None:
            await aopen_source(plan.tracker)
        try:
            for ps in plan.suites:
                await run.run_suite(ps)
        finally:
            try:
                await run.close()
            finally:
                if plan.tracker is not None:
                    await aclose_source(plan.tracker)
        if plan.baseline is not None:
            try:
                writer.set_baseline(compare(writer.record, plan.baseline, plan.config))
            except BaselineError as exc:
                error = f"baseline: {exc}"
    except RunAborted as exc:
        error = str(exc)
    except (asyncio.CancelledError, KeyboardInterrupt):
        interrupted = True
        raise
    finally:
        printer.finish()
        if interrupted:
            printer.message(f"interrupted: the record keeps every finished trial; continue with "
                            f"armbench run --resume {plan.out_dir}")
        write_reports(writer.record, plan.out_dir)
    record = writer.record
    status = EXIT_ERROR if error is not None else exit_status(record.verdict)
    printer.message(f"verdict: {record.verdict}" + (f" ({error})" if error else ""))
    return RunOutcome(plan.out_dir, record, status, error=error)


def write_reports(record: RunRecord, out_dir: Path) -> None:
    """``junit.xml`` and ``report.html`` of ``record`` in ``out_dir``. The HTML report comes from
    ``reports.render_report`` when that package is available; otherwise (or if it fails) a plain
    text summary wrapped in HTML is written, so the file always exists."""
    from armbench.bench.junit import write_junit

    try:
        write_junit(record, path_inside(out_dir, JUNIT_FILE))
    except ArmbenchError as exc:
        log.warning("junit.xml not written: %s", exc)
    report = path_inside(out_dir, REPORT_FILE)
    try:
        from armbench.reports import render_report  # type: ignore[attr-defined, unused-ignore]

        capture = out_dir / CAPTURE_FILE
        render_report(record, report, capture=capture if capture.exists() else None)
        return
    except ImportError:
        pass
    except Exception as exc:
        log.warning("the HTML report failed (%s: %s); writing a plain summary", type(exc).__name__,
                    exc)
    text = text_summary(record)
    page = ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>armbench run "
            f"{html.escape(record.run_id)}</title></head>\n<body><pre>{html.escape(text)}</pre>"
            "</body></html>\n")
    atomic_write_bytes(report, page.encode("utf-8"))


def text_summary(record: RunRecord) -> str:
    """A plain-text summary of a record: verdict, suites, failed measurements, regressions."""
    lines = [f"armbench run {record.run_id}  created {record.created}  verdict {record.verdict}",
             f"port {record.environment.port}  seed {record.environment.seed}  "
             f"git {record.environment.git_revision}", ""]
    for name in record.planned_suites:
        s = record.suites.get(name)
        if s is None:
            lines.append(f"{name}: not started")
            continue
        errors = sum(t.status == "error" for t in s.trials)
        lines.append(f"{name}: {s.status}, {len(s.trials)} trial(s)"
                     + (f", {errors} in error" if errors else "")
                     + (f" — {s.error}" if s.error else ""))
        for m in s.measurements:
            limit = "" if m.limit is None else f"  (limit {m.limit.describe()})"
            lines.append(f"  {m.outcome:>8}  {m.name} = {m.value:.6g} {m.unit}{limit}")
        for t in s.trials:
            for m in t.measurements:
                if m.outcome == "fail":
                    lines.append(f"      fail  trial {t.index}: {m.name} = {m.value:.6g} "
                                 f"{m.unit}  (limit {m.limit.describe() if m.limit else '-'})")
    if record.baseline is not None:
        from armbench.bench.baseline import format_comparison

        lines += ["", f"baseline {record.baseline.baseline_run_id}:",
                  format_comparison(record.baseline)]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------
# Entry points
# --------------------------------------------------------------------------------------------


async def run_bench(options: RunOptions, *, progress: IO[str] | None = None,
                    emulator_factory: EmulatorFactory | None = None) -> RunOutcome:
    """Validate ``options`` (raising before any motion) and run them on the running loop."""
    plan = prepare(options)
    return await execute(plan, progress=progress, emulator_factory=emulator_factory)


def run_sync(options: RunOptions, *, progress: IO[str] | None = sys.stderr,
             emulator_factory: EmulatorFactory | None = None) -> RunOutcome:
    """Validate and run on a loop of the right kind: a virtual-time loop
    (``armbench.fakes.vclock``) for
    ``fake://``, ``asyncio.run`` otherwise. Ctrl-C returns the outcome of the record on disk with
    exit status 130."""
    plan = prepare(options)
    main = execute(plan, progress=progress, emulator_factory=emulator_factory)
    try:
        if plan.fake:
            from armbench.fakes.vclock import run_virtual

            return run_virtual(main)
        return asyncio.run(main)
    except (KeyboardInterrupt, asyncio.CancelledError):
        if not (plan.out_dir / RESULTS_FILE).exists():
            raise KeyboardInterrupt from None
        record = load_record(plan.out_dir / RESULTS_FILE)
        return RunOutcome(plan.out_dir, record, EXIT_INTERRUPTED, interrupted=True,
                          error="interrupted")
