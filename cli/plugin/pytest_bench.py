"""The armbench pytest plugin's record: bench tests in plain pytest, into a run record (the
``arm`` fixture is :mod:`armbench.cli.plugin.pytest_arm`'s).

Loaded by :mod:`armbench.cli.plugin.pytest_plugin` (the ``pytest11`` entry point) when
pytest-asyncio is installed; the options, the fixtures and the record are described there.
"""

from __future__ import annotations

import os
import re
import shutil
from collections.abc import Callable, Generator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, overload

import pytest

from armbench.cli.plugin.pytest_plugin import (
    CONFIG_OPTION,
    PORT_OPTION,
    RECORD_MODE_OPTION,
    RECORD_OPTION,
    SETTINGS_OPTION,
)
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.numbers import finite_float
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.transports.capabilities import ArmInputs
from armbench.drivers.transports.target import Target, given_by, target_of
from armbench.record import (
    RESULTS_FILE,
    Better,
    Measurement,
    Outcome,
    RecordError,
    RecordWriter,
    RunRecord,
    Trial,
    TrialStatus,
    capture_environment,
    default_better,
    judge,
)
from armbench.record.ci_run import ci_run
from armbench.record.journal import journal_path
from armbench.record.limits import Limit, LimitsConfig, load_limits

__all__ = [
    "SUITE_NAME",
    "BenchSession",
    "BenchTrial",
    "arm_port",
    "arm_settings",
    "bench_record",
    "bench_session",
    "record_measurement",
]

#: The record's suite holding the pytest trials.
SUITE_NAME = "pytest"
#: Version of the suite "pytest" in the record.
SUITE_VERSION = "1"
#: Trial-level measurement of every test: 1 when the test body passed, 0 when an assertion failed.
PASSED_METRIC = "pytest.passed"

_PASSED_LIMIT = Limit(PASSED_METRIC, "bool", low=1.0)
_TRIAL_KEY = pytest.StashKey["BenchTrial"]()
_SESSION_KEY = pytest.StashKey["BenchSession"]()
_CALL_KEY = pytest.StashKey[pytest.TestReport]()
_EXC_KEY = pytest.StashKey["BaseException | None"]()
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]+")


# --------------------------------------------------------------------------------------------
# The session record
# --------------------------------------------------------------------------------------------


class BenchSession:
    """The session's target, settings, limits and, with ``--arm-record``, its record writer."""

    def __init__(self, port: str, settings: RobotSettings, settings_path: str | None,
                 limits: LimitsConfig | None, out_dir: Path | None,
                 mode: str = "new", *, target: Target | None = None,
                 inputs: ArmInputs | None = None) -> None:
        self.port = port
        self.target = target if target is not None else target_of(port)
        """What the port names and can do."""
        self.inputs = inputs if inputs is not None else ArmInputs(settings, None)
        """The seed and faults of a fresh arm (``--arm-settings`` over the port's query over the
        settings file)."""
        self.settings = settings
        self.settings_path = settings_path
        self.limits = limits
        self.out_dir = out_dir
        self.writer: RecordWriter | None = None
        self._next_index = 0
        self.arms_opened = 0
        """Connections the ``arm`` fixture opened (one per test, module or session)."""
        self.arm_tests = 0
        """Tests that used the ``arm`` fixture."""
        if out_dir is None:
            return
        results = out_dir / RESULTS_FILE
        if mode == "resume" and results.exists():
            self.writer = RecordWriter.resume(out_dir)
            suite = self.writer.record.suites.get(SUITE_NAME)
            if suite is None:
                raise RecordError(str(results), f"holds no {SUITE_NAME!r} suite: not a record "
                                                "of bench tests")
            # this session's tests are trials of the same suite, after the recorded ones; its
            # summary is computed again over all of them at the end
            self._next_index = 1 + max((t.index for t in (*suite.trials,
                                                          *suite.superseded_trials)),
                                       default=-1)
            suite.status, suite.ended_s, suite.measurements = "running", None, []
        else:
            if mode == "replace" and results.exists():
                for old in (results, journal_path(results)):
                    old.unlink(missing_ok=True)
                shutil.rmtree(out_dir / "captures", ignore_errors=True)
            env = capture_environment(port=port, settings=settings, limits=limits,
                                      ci=ci_run(os.environ))
            record = RunRecord.new(env, [SUITE_NAME])
            self.writer = RecordWriter(out_dir, record)
        self.writer.begin_suite(SUITE_NAME, SUITE_VERSION, {"port": port})

    def now_s(self) -> float:
        """Run time (s) of the record; 0 without one."""
        return self.writer.elapsed_s() if self.writer is not None else 0.0

    def new_trial(self, nodeid: str, name: str) -> BenchTrial:
        """The trial of a test starting now."""
        index = self._next_index
        self._next_index += 1
        return BenchTrial(index=index, nodeid=nodeid, test_name=name, limits=self.limits,
                          started_s=self.now_s())

    def add(self, trial: Trial) -> None:
        """Write a finished trial."""
        if self.writer is not None:
            self.writer.add_trial(SUITE_NAME, trial)

    def capture_path(self, name: str) -> Path | None:
        """Where an arm writes its traffic capture with a record: ``captures/<name>.jsonl``
        (a test's arm ``NNNN-<test>``, a shared one ``session`` or ``module-<module>``)."""
        if self.writer is None:
            return None
        name = _UNSAFE.sub("_", name).strip("_")[:80] or "test"
        path = self.writer.artifact_path(Path("captures") / f"{name}.jsonl")
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def finish(self) -> None:
        """End the suite with its summary and write junit.xml and report.html."""
        writer = self.writer
        if writer is None:
            return
        suite = writer.suite(SUITE_NAME)
        if suite.status == "running":
            writer.end_suite(SUITE_NAME, summarize(suite.trials, self.limits))
        from armbench.cli.commands.run_files import write_reports

        write_reports(writer.record, writer.out_dir)


def summarize(trials: Sequence[Trial], limits: LimitsConfig | None) -> list[Measurement]:
    """Suite-level measurements of the pytest trials: each trial-level metric (but
    ``pytest.passed``) once, at its worst over the tests that recorded it (the largest value when
    lower is better, the smallest when higher is better, the mean without a direction), judged
    against the limit its trials were judged with."""
    by_name: dict[str, list[Measurement]] = {}
    for t in trials:
        if t.status != "done":
            continue
        for m in t.measurements:
            if m.name != PASSED_METRIC:
                by_name.setdefault(m.name, []).append(m)
    out: list[Measurement] = []
    for name, ms in by_name.items():
        first = ms[0]
        values = [m.value for m in ms]
        if first.better == "lower":
            value = max(values)
        elif first.better == "higher":
            value = min(values)
        else:
            value = sum(values) / len(values)
        description = (f"worst of {len(ms)} tests" if len(ms) > 1 and first.better
                       else f"mean of {len(ms)} tests" if len(ms) > 1 else first.description)
        if first.limit is not None and first.limit.metric == name:
            outcome: Outcome = "pass" if first.limit.check(value) else "fail"
            out.append(Measurement(name, value, first.unit, first.limit, outcome, first.better,
                                   description))
        else:
            out.append(judge(name, value, first.unit, limits, better=first.better,
                             description=description))
    return out


@overload
def bench_session(config: pytest.Config) -> BenchSession: ...


@overload
def bench_session(config: pytest.Config, *, create: bool) -> BenchSession | None: ...


def bench_session(config: pytest.Config, *, create: bool = True) -> BenchSession | None:
    """The session's bench: made on first use from the options (a bad one is a usage error);
    None before that when not ``create``."""
    session = config.stash.get(_SESSION_KEY, None)
    if session is None and not create:
        return None
    if session is None:
        port = str(config.getoption(PORT_OPTION))
        settings_path = config.getoption(SETTINGS_OPTION)
        limits_path = config.getoption(CONFIG_OPTION)
        record_dir = config.getoption(RECORD_OPTION)
        mode = str(config.getoption(RECORD_MODE_OPTION, "new"))
        try:
            target = target_of(port)
            target.preflight()  # the address, the device looked at: not opened
            inputs = target.inputs(given_by({"settings": SETTINGS_OPTION},
                                            settings=settings_path))
            limits = load_limits(limits_path) if limits_path else None
            session = BenchSession(port, inputs.robot, inputs.given.settings, limits,
                                   Path(record_dir) if record_dir else None, mode, target=target,
                                   inputs=inputs)
        except ArmbenchError as exc:
            raise pytest.UsageError(f"armbench: {exc}") from None
        config.stash[_SESSION_KEY] = session
    return session


# --------------------------------------------------------------------------------------------
# One test's trial
# --------------------------------------------------------------------------------------------


LimitSpec = Limit | tuple[float | None, float | None] | Mapping[str, float | None] | None


@dataclass
class BenchTrial:
    """The trial of one test: its measurements and samples, written to the record at teardown."""

    index: int
    nodeid: str
    test_name: str
    limits: LimitsConfig | None
    started_s: float
    params: dict[str, Any] = field(default_factory=dict)
    samples: list[dict[str, Any]] = field(default_factory=list)
    measurements: list[Measurement] = field(default_factory=list)

    def measure(self, name: str, value: float, unit: str, *, limit: LimitSpec = None,
                better: Better | None = None, description: str = "") -> Measurement:
        """Record ``name`` = ``value`` ``unit`` and judge it: against ``limit`` when given —
        ``(low, high)`` (either may be None), ``{"low": ..., "high": ...}`` or a
        :class:`~armbench.record.limits.Limit` — else against ``--arm-config``'s limits (unjudged
        without).
        Returns the measurement; one outside its limit fails the test when the body has ended.
        """
        if any(m.name == name for m in self.measurements):
            raise RecordError(f"measurement {name!r}", f"recorded twice in {self.nodeid}")
        if finite_float(value) is None:
            raise RecordError(f"measurement {name!r}.value",
                              f"{value!r} is not a finite number")
        bound = _limit(name, unit, limit)
        if bound is None:
            m = judge(name, float(value), unit, self.limits, better=better,
                      description=description)
        else:
            m = Measurement(name, float(value), unit, bound,
                            "pass" if bound.check(float(value)) else "fail",
                            default_better(unit) if better is None else better, description)
        self.measurements.append(m)
        return m

    def sample(self, **fields: Any) -> None:
        """Add one raw sample (any JSON values; by convention ``t_s`` and positions in metres)."""
        self.samples.append(dict(fields))

    @property
    def failed(self) -> list[Measurement]:
        """The measurements outside their limits."""
        return [m for m in self.measurements if m.outcome == "fail"]


def _limit(name: str, unit: str, spec: LimitSpec) -> Limit | None:
    if spec is None:
        return None
    if isinstance(spec, Limit):
        if spec.unit != unit:
            raise RecordError(f"measurement {name!r}.limit",
                              f"unit {spec.unit!r} differs from the measurement's {unit!r}")
        return spec
    if isinstance(spec, Mapping):
        unknown = set(spec) - {"low", "high"}
        if unknown:
            raise RecordError(f"measurement {name!r}.limit",
                              f"unknown keys {sorted(unknown)} (use low and high)")
        low, high = spec.get("low"), spec.get("high")
    elif isinstance(spec, tuple) and len(spec) == 2:
        low, high = spec
    else:
        raise RecordError(f"measurement {name!r}.limit",
                          f"{spec!r} is not (low, high), {{'low': .., 'high': ..}} or a Limit")
    for bound in (low, high):
        if bound is not None and finite_float(bound) is None:
            raise RecordError(f"measurement {name!r}.limit", f"bound {bound!r} is not finite")
    if low is None and high is None:
        raise RecordError(f"measurement {name!r}.limit", "sets neither low nor high")
    if low is not None and high is not None and low > high:
        raise RecordError(f"measurement {name!r}.limit", f"low {low} is above high {high}")
    return Limit(name, unit, None if low is None else float(low),
                 None if high is None else float(high))


# --------------------------------------------------------------------------------------------
# Fixtures
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="session")
def arm_port(pytestconfig: pytest.Config) -> str:
    """The ``--arm-port`` of the session (default ``fake://``)."""
    return bench_session(pytestconfig).port


@pytest.fixture(scope="session")
def arm_settings(pytestconfig: pytest.Config) -> RobotSettings:
    """The robot settings of the session (``--arm-settings``, else the defaults)."""
    return bench_session(pytestconfig).settings


@pytest.fixture
def bench_record(request: pytest.FixtureRequest) -> BenchTrial:
    """This test's trial in the bench record (see :class:`BenchTrial`)."""
    node = request.node
    existing: BenchTrial | None = node.stash.get(_TRIAL_KEY, None)
    if existing is not None:
        return existing
    trial = bench_session(request.config).new_trial(node.nodeid, node.name)
    trial.params["test"] = node.nodeid
    node.stash[_TRIAL_KEY] = trial
    return trial


@pytest.fixture
def record_measurement(bench_record: BenchTrial) -> Callable[..., Measurement]:
    """``record_measurement(name, value, unit, *, limit=None, better=None, description="")``:
    :meth:`BenchTrial.measure` of this test."""
    return bench_record.measure


# --------------------------------------------------------------------------------------------
# Hooks
# --------------------------------------------------------------------------------------------


def configure(config: pytest.Config) -> None:
    """Set up for a session; called by the entry point once this module is registered."""
    if config.getoption(RECORD_OPTION, None):
        bench_session(config)  # fail now on a bad option or a directory that holds a record


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]
                              ) -> Generator[None, pytest.TestReport, pytest.TestReport]:
    report = yield
    trial = item.stash.get(_TRIAL_KEY, None)
    if trial is None:
        return report
    if report.when == "call":
        if report.passed and trial.failed:
            report.outcome = "failed"
            report.longrepr = "measurement(s) outside their limits:\n" + "\n".join(
                f"  {m.name} = {m.value:g} {m.unit} "
                f"(limit {m.limit.describe() if m.limit else '-'})" for m in trial.failed)
        item.stash[_CALL_KEY] = report
        item.stash[_EXC_KEY] = call.excinfo.value if call.excinfo is not None else None
    elif report.when == "setup" and report.failed:
        item.stash[_CALL_KEY] = report
        item.stash[_EXC_KEY] = call.excinfo.value if call.excinfo is not None else None
    elif report.when == "teardown":
        _finish_trial(item, trial, report)
    return report


def _finish_trial(item: pytest.Item, trial: BenchTrial, teardown: pytest.TestReport) -> None:
    session = bench_session(item.config)
    main = item.stash.get(_CALL_KEY, None)
    exc = item.stash.get(_EXC_KEY, None)
    if main is None or main.skipped or hasattr(main, "wasxfail"):
        return  # skipped (or xfail): not a measurement of the arm
    now = session.now_s()
    status: TrialStatus = "done"
    error = None
    measurements = list(trial.measurements)
    if main.when == "setup" or (main.failed and exc is not None
                                and not isinstance(exc, AssertionError)):
        status, error = "error", _describe(exc)
    elif teardown.failed:
        status, error = "error", f"teardown: {teardown.longreprtext.strip()[-300:]}"
    else:
        passed = 0.0 if (exc is not None and isinstance(exc, AssertionError)) else 1.0
        measurements.append(Measurement(PASSED_METRIC, passed, "bool", _PASSED_LIMIT,
                                        "pass" if passed else "fail", "higher",
                                        "the test body passed its assertions"))
    session.add(Trial(trial.index, trial.started_s, max(0.0, now - trial.started_s),
                      params=trial.params, samples=trial.samples, measurements=measurements,
                      status=status, error=error))


def _describe(exc: BaseException | None) -> str:
    if exc is None:
        return "failed"
    return f"{type(exc).__name__}: {exc}"[:500]


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    bench = session.config.stash.get(_SESSION_KEY, None)
    if bench is not None:
        bench.finish()
