"""Planning and validation: :func:`prepare` checks *everything* a run reads before the arm is
touched and before the run directory exists, and returns the :class:`BenchPlan` the runner
executes.

Checked, in order: the run directory (or the record to resume), the port's target
(:func:`~armbench.drivers.transports.target.target_of`), the robot settings, the limits file, the
seed, the fault file (each of these from one source: a flag over the port's query over the robot
settings file over the default, :func:`~armbench.drivers.transports.target.resolve`), the
``[bench]`` table, each suite's
parameters (``Suite.params``) and plan, every limit and tolerance pattern and ``[suites.NAME]``
table of the config (:mod:`~armbench.bench.runner.config_check`), the baseline (readable, same
record schema, same limits spec, same suite versions), the tracker plug-in and the power switch.
Any problem raises an :class:`~armbench.drivers.model.errors.ArmbenchError` naming the field: the
CLI prints one line and exits 2.
"""

from __future__ import annotations

import fnmatch
import itertools
import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, cast

from armbench.bench.runner.arms import ArmRun, lay_out
from armbench.bench.runner.config_check import check_config, closest
from armbench.bench.runner.options import (
    DEFAULT_CONFIG,
    DEFAULT_OUTAGE_TIMEOUT_S,
    RUNNER_FILE,
    BenchPlan,
    Isolation,
    PlannedSuite,
    RunOptions,
    default_workers,
)
from armbench.bench.runner.overwrite import check_overwrite
from armbench.bench.runner.power import DEFAULT_COMMAND_TIMEOUT_S, CommandPower, ManualPower
from armbench.bench.runner.required import required_of
from armbench.bench.runner.truth import load_tracker
from armbench.bench.suites import ENTRY_POINT_GROUP as SUITES_ENTRY_POINT_GROUP
from armbench.bench.suites import SuiteError, load_suite, registered_suites, suite_names
from armbench.bench.suites.base import PowerSwitch
from armbench.drivers.capture.jsonl import capture_options
from armbench.drivers.model.bounds import Bound, check, check_whole
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.drivers.model.user_files import MAX_JSON_BYTES, FileRefused, read_regular_file
from armbench.drivers.transports.target import Target, given_by, target_of
from armbench.record import (
    RESULTS_FILE,
    RecordError,
    RunRecord,
    json_default,
    new_run_id,
    path_inside,
)
from armbench.record.baseline import BaselineError, check_suite_versions, load_baseline, read_record
from armbench.record.dut import dut_flags
from armbench.record.files import check_directory_writable
from armbench.record.limits import LimitsConfig, load_limits

if TYPE_CHECKING:
    from armbench.fakes.firmware.faults import Fault

__all__ = ["prepare"]

#: The most trials a suite may plan: a bound on a run's length (and on the plan held in memory).
MAX_TRIALS = 10_000

#: The ``[bench]`` times (s) and counts (and ``--retries``, ``--workers``), checked before
#: anything moves: the run clock stays far inside the capture's int32 seconds stamps (2**31 s)
#: over :data:`MAX_TRIALS` trials of every suite, and no count asks the machine for the
#: impossible. Documented in ``docs/runner.md``.
BENCH_BOUNDS: Final[Mapping[str, Bound]] = {
    "retries": Bound(0, 100, whole=True), "workers": Bound(1, 1024, whole=True),
    "reply_timeout_s": Bound(0.0, 60.0, "s", low_open=True),
    "connect_timeout_s": Bound(0.0, 600.0, "s", low_open=True),
    "outage_timeout_s": Bound(0.0, 600.0, "s", low_open=True),
    "settle_s": Bound(0.0, 600.0, "s"),
    "power_timeout_s": Bound(0.0, 600.0, "s", low_open=True),
    "move_timeout_scale": Bound(0.0, 100.0, low_open=True),
}
#: ``--seed``: any whole number from 0.
_SEED = Bound(0, math.inf, whole=True)

_BENCH_KEYS = {"retries", "isolation", "reply_timeout_s", "connect_timeout_s", "outage_timeout_s",
               "settle_s",
               "power_timeout_s", "tracker", "workers", "capture", "capture_max_bytes",
               "scheduler", "move_timeout_scale"}


@dataclass(slots=True)
class _Inputs:
    """What the files of the run say: settings, limits, seed, faults and the suites asked for."""

    settings: RobotSettings
    settings_path: str | None
    config: LimitsConfig
    seed: int
    faults: list[Fault]
    suite_refs: list[str]


@dataclass(slots=True)
class _BenchKnobs:
    """The ``[bench]`` table with the command line's overrides, checked."""

    retries: int
    workers: int
    isolation: Isolation
    reply_timeout_s: float
    connect_timeout_s: float
    outage_timeout_s: float
    settle_s: float
    power_timeout_s: float
    tracker_params: Mapping[str, Any]
    capture: bool
    capture_max_bytes: int | None
    scheduler: str | None = None
    move_timeout_scale: float = 1.0


def check_storable(where: str, value: object) -> None:
    """Refuse, naming its dotted path, the first value under ``value`` the record cannot store:
    a float that is not finite (TOML has ``inf`` and ``nan``, JSON has not)."""
    stack: list[tuple[str, object]] = [(where, value)]
    while stack:
        path, node = stack.pop()
        if isinstance(node, float) and not math.isfinite(node):
            raise SettingsError(path, node, "is not finite; a run record cannot store it")
        if isinstance(node, Mapping):
            stack.extend((f"{path}.{k}" if path else str(k), v) for k, v in node.items())
        elif isinstance(node, (list, tuple)):
            stack.extend((f"{path}[{i}]", v) for i, v in enumerate(node))


def _bench_number(bench: Mapping[str, Any], key: str, default: float) -> float:
    """``[bench] key`` (else ``default``) within its :data:`BENCH_BOUNDS` bound."""
    return check(f"bench.{key}", bench.get(key, default), BENCH_BOUNDS[key])


def json_equal(a: object, b: object) -> bool:
    """Whether two values are the same once written as JSON (tuples and lists alike)."""
    def norm(x: object) -> object:
        return cast(object, json.loads(json.dumps(x, default=json_default, sort_keys=True)))

    try:
        return bool(norm(a) == norm(b))
    except (TypeError, ValueError):
        return False


def _load_runner_info(directory: Path) -> dict[str, Any]:
    path = directory / RUNNER_FILE
    if not os.path.lexists(path):
        return {}
    try:  # a FIFO or a device in a folder given to --resume is refused, not waited on
        data = json.loads(read_regular_file(path, "a runner.json", MAX_JSON_BYTES))
    except (FileRefused, ValueError, RecursionError) as exc:
        raise RecordError(str(path), f"cannot be read: {exc}") from None
    if not isinstance(data, dict):
        raise RecordError(str(path), "is not a JSON object")
    return data


def _check_port(port: str) -> Target:
    """The port's target: its scheme and transport, its address (``socket://HOST:PORT`` with
    both, nothing more), a serial device that exists and is a character device, the settings its
    query carries. Whether an arm answers there is asked later (:mod:`.probe`)."""
    target = target_of(port)  # unknown scheme or a transport that cannot be imported
    target.query()  # its query checked
    target.preflight()  # built, not opened: the address, the device looked at
    return target


def _resumed_inputs(resume: RunRecord, info: Mapping[str, Any], target: Target) -> _Inputs:
    """The settings, limits, seed, faults and suites of the run being resumed, unchanged."""
    env = resume.environment
    resolved = target.inputs(given_by(RUNNER_FILE, settings=info.get("settings")))
    settings_path = resolved.given.settings
    settings = resolved.robot
    if not json_equal(settings.to_mapping(), env.settings):
        raise SettingsError("settings", settings_path or "defaults",
                            "differ from the settings the run began with; start a new run")
    config_path = info.get("config") or env.config_path
    config = load_limits(config_path) if config_path else LimitsConfig()
    if env.limits_spec_version is not None and config.spec_version != env.limits_spec_version:
        raise SettingsError("spec_version", config.spec_version,
                            f"differs from the run's {env.limits_spec_version!r}")
    seed = env.seed if env.seed is not None else 0
    from armbench.fakes.firmware.faults import parse_faults

    faults = parse_faults(env.faults, "environment.faults") if env.faults else []
    refs = info.get("suites") or {}
    suite_refs = [refs.get(name, name) if isinstance(refs, dict) else name
                  for name in resume.planned_suites]
    check_registered_suites(suite_refs)
    return _Inputs(settings, settings_path, config, seed, faults, suite_refs)


def check_registered_suites(suite_refs: Sequence[object]) -> None:
    """A resumed run loads only registered suites (:func:`registered_suites`): the record and
    ``runner.json`` are files anyone may hand over, and a module they name would run its code
    on import. Anything else is refused naming it, before anything is imported."""
    registered = registered_suites()
    targets = set(registered.values())
    for ref in suite_refs:
        if isinstance(ref, str) and (ref in registered or ref in targets):
            continue
        raise SuiteError(f"--resume: the run names suite {ref!r}, which is not registered "
                         f"(known: {', '.join(registered)}; a suite of your own is registered "
                         f"as an entry point of the group {SUITES_ENTRY_POINT_GROUP!r}); a run "
                         "folder cannot make armbench import a module it names")


def _new_inputs(options: RunOptions, target: Target) -> _Inputs:
    """The settings, limits, seed, faults and suites a new run is given: each of the settings,
    the seed and the faults from one source, a flag over the port's query over the robot
    settings file over the default (:func:`~armbench.drivers.transports.target.resolve`)."""
    flags = given_by({"settings": "--settings", "seed": "--seed", "faults": "--faults"},
                     settings=None if options.settings is None else os.fspath(options.settings),
                     seed=None if options.seed is None else check_whole("--seed", options.seed,
                                                                       _SEED),
                     faults=None if options.faults is None else os.fspath(options.faults))
    resolved = target.inputs(flags)
    settings_path = resolved.given.settings
    settings = resolved.robot
    config_file = Path(options.config) if options.config is not None else DEFAULT_CONFIG
    config = load_limits(config_file)
    seed = resolved.seed if resolved.seed is not None else 0
    faults: list[Fault] = list(resolved.faults)
    suite_refs = list(options.suites) or suite_names()
    if len(set(suite_refs)) != len(suite_refs):
        raise ArmbenchError(f"SUITE: a suite is named twice in {suite_refs}")
    return _Inputs(settings, settings_path, config, seed, faults, suite_refs)


def _bench_knobs(config: LimitsConfig, options: RunOptions, target: Target) -> _BenchKnobs:
    """The ``[bench]`` table (unknown keys refused) with ``--retries`` and ``--workers``."""
    bench = config.bench_params()
    for key, value in bench.items():
        if key not in _BENCH_KEYS:
            near = closest(key, _BENCH_KEYS)
            raise SettingsError(f"bench.{key}", value, "is not a bench parameter ("
                                + (f"closest: {', '.join(near)}; " if near else "")
                                + f"known: {', '.join(sorted(_BENCH_KEYS))})")
    retries = check_whole("bench.retries", bench.get("retries", 0), BENCH_BOUNDS["retries"])
    if options.retries is not None:
        retries = check_whole("--retries", options.retries, BENCH_BOUNDS["retries"])
    workers = check_whole("bench.workers", bench.get("workers", default_workers()),
                          BENCH_BOUNDS["workers"])
    if options.workers is not None:
        workers = check_whole("--workers", options.workers, BENCH_BOUNDS["workers"])
    fresh = target.capabilities.fresh_per_trial
    isolation = bench.get("isolation", "trial" if fresh else "run")
    if isolation not in ("trial", "run"):
        raise SettingsError("bench.isolation", isolation, "must be 'trial' or 'run'")
    if isolation == "trial" and not fresh:
        raise SettingsError("bench.isolation", isolation,
                            f"'trial' (a fresh arm per trial) needs a target that starts one "
                            f"(fake://); {target.port!r} does not")
    tracker_params = bench.get("tracker", {})
    if not isinstance(tracker_params, Mapping):
        raise SettingsError("bench.tracker", tracker_params, "is not a table")
    capture, capture_max_bytes = capture_options(bench, options.capture, options.capture_max_mb)
    scheduler = options.scheduler if options.scheduler is not None else bench.get("scheduler")
    if scheduler is not None:
        from armbench.bench.runner.cluster import check_scheduler

        check_scheduler("--scheduler" if options.scheduler is not None else "bench.scheduler",
                        scheduler, target.capabilities.parallel)
    return _BenchKnobs(
        retries=retries, workers=workers, isolation=isolation, capture=capture,
        capture_max_bytes=capture_max_bytes,
        reply_timeout_s=_bench_number(bench, "reply_timeout_s", 0.5),
        connect_timeout_s=_bench_number(bench, "connect_timeout_s", 3.0),
        outage_timeout_s=_bench_number(bench, "outage_timeout_s", DEFAULT_OUTAGE_TIMEOUT_S),
        settle_s=_bench_number(bench, "settle_s", 0.0),
        power_timeout_s=_bench_number(bench, "power_timeout_s", DEFAULT_COMMAND_TIMEOUT_S),
        tracker_params=tracker_params, scheduler=scheduler,
        move_timeout_scale=_bench_number(bench, "move_timeout_scale", 1.0))


def _plan_suites(suite_refs: Sequence[str], inputs: _Inputs,
                 resume: RunRecord | None) -> list[PlannedSuite]:
    """Each suite loaded, its parameters validated and its trials planned; a resumed suite must
    be of the recorded version with the recorded parameters."""
    config = inputs.config
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
            params = suite.params(inputs.settings, configured)
            trials: list[Mapping[str, Any]] = [
                dict(t) for t in itertools.islice(suite.plan(params), MAX_TRIALS + 1)]
        except ArmbenchError:
            raise
        except Exception as exc:  # a wrongly typed value the suite did not check itself
            raise SettingsError(f"suites.{suite.name}", configured,
                                f"cannot be used: {type(exc).__name__}: {exc}") from exc
        if len(trials) > MAX_TRIALS:
            raise SettingsError(f"suites.{suite.name}", configured,
                                f"plans more than {MAX_TRIALS} trials; at most {MAX_TRIALS} "
                                "trials per suite")
        if resume is not None:
            rec = resume.suites.get(suite.name)
            measured = 0 if rec is None else len({t.index for t in rec.completed_trials()})
            if rec is not None and rec.status == "done" and measured < len(trials):
                raise RecordError(f"suites.{suite.name}.status",
                                  f"'done' with {measured} of {len(trials)} trials measured "
                                  "(was the record edited?); start a new run")
            if rec is not None and rec.status != "done":
                if rec.version != suite.version:
                    raise RecordError(f"suites.{suite.name}.version",
                                      f"recorded {rec.version!r}, this armbench has "
                                      f"{suite.version!r}; start a new run")
                if not json_equal(rec.params, params):
                    raise RecordError(f"suites.{suite.name}.params",
                                      "differ from the recorded ones (was the limits file "
                                      "changed?); start a new run")
        planned.append(PlannedSuite(ref, suite, params, trials))
    return planned


def _check_limit_units(planned: Sequence[PlannedSuite], config: LimitsConfig) -> None:
    """Every limit that judges a metric a suite declares (``Suite.metric_units``) is in that
    metric's unit: a wrong unit is the file's mistake, found before trial 0 runs."""
    for ps in planned:
        for pattern, unit in ps.suite.metric_units.items():
            applying = [config.limit_for(pattern)] + [
                limit for limit in config.limits.values()
                if fnmatch.fnmatchcase(limit.metric, pattern)]
            for limit in applying:
                if limit is not None and limit.unit != unit:
                    raise SettingsError(f'limits."{limit.metric}".unit', limit.unit,
                                        f"does not match the unit {unit!r} of the {ps.name} "
                                        f"metrics {pattern}")


def _warnings(config: LimitsConfig) -> list[str]:
    """What the verdict must say beside pass or fail: a limits file that judges nothing."""
    if config.limits:
        return []
    where = f"the limits file {config.path}" if config.path else "the run's limits"
    return [f"{where} sets no limits: every measurement is unjudged"]


def _load_checked_baseline(path: str | Path, config: LimitsConfig,
                           planned: Sequence[PlannedSuite]) -> RunRecord:
    """The baseline record, refused if its limits spec or a suite's version differs."""
    baseline = load_baseline(path)
    theirs = baseline.environment.limits_spec_version
    if theirs is not None and theirs != config.spec_version:
        raise BaselineError(f"baseline {path}: limits spec version {theirs!r} "
                            f"differs from this run's {config.spec_version!r}")
    # figures of another suite version measure something else
    check_suite_versions(baseline, {ps.name: ps.suite.version for ps in planned}, path)
    return baseline


def _power_switch(options: RunOptions, target: Target,
                  timeout_s: float) -> PowerSwitch | None:
    """The power switch asked for on hardware (checked), None for the target's own. A target on
    virtual time takes none: a relay command or an operator works in wall-clock time."""
    if options.power_command is not None and options.power_manual:
        raise ArmbenchError("--power-command and --power-manual: choose one")
    if target.virtual and (options.power_command is not None or options.power_manual):
        raise ArmbenchError(f"--power-command/--power-manual: {target.port} runs on virtual "
                            "time; the bench switches its power itself")
    if options.power_command is not None:
        off, on = options.power_command
        command_power = CommandPower(off, on, timeout_s=timeout_s)
        command_power.check()
        return command_power
    if options.power_manual:
        return ManualPower()
    return None


def _resume_flags(options: RunOptions) -> None:
    """Refuse the options a resumed run takes from its record."""
    for flag, given in (("SUITE", bool(options.suites)), ("--config", options.config),
                        ("--seed", options.seed is not None),
                        ("--settings", options.settings), ("--faults", options.faults),
                        ("--shard", options.shard is not None),
                        ("--dut", options.dut is not None), ("--meta", bool(options.meta))):
        if given:
            raise ArmbenchError(f"--resume: {flag} comes from the run being resumed and "
                                "cannot be given again")


def prepare(options: RunOptions, arm: ArmRun | None = None) -> BenchPlan:
    """Validate ``options`` for ``arm`` (one of :func:`~armbench.bench.runner.arms.lay_out`'s;
    None: the one arm ``options`` name) and everything they name, without touching the arm or
    creating its run folder.

    Raises an :class:`~armbench.drivers.model.errors.ArmbenchError` (``SettingsError``,
    ``RecordError``, ``BaselineError``, ``TransportError``, ``SuiteError``, ``TrackerError``,
    ``PowerError``) whose message names the offending field or file.
    """
    if arm is None:
        arm = lay_out(options).only()
    resume: RunRecord | None = None
    info: dict[str, Any] = {}
    if arm.resume is not None:
        _resume_flags(options)
        resume = read_record(path_inside(arm.resume, RESULTS_FILE))
        info = _load_runner_info(arm.resume)
    else:
        if options.overwrite:
            check_overwrite(arm.out)
        elif (arm.out / RESULTS_FILE).exists():
            raise RecordError(str(arm.out / RESULTS_FILE), "already holds a run record; resume "
                                                           "it (--resume), replace it "
                                                           "(--overwrite) or choose another --out")
        check_directory_writable(arm.out, "--out" if options.out is not None else "run folder")
    env = None if resume is None else resume.environment
    target = _check_port(arm.port or (env.port if env is not None and env.port else None)
                         or "fake://")
    inputs = (_resumed_inputs(resume, info, target) if resume is not None
              else _new_inputs(options, target))
    knobs = _bench_knobs(inputs.config, options, target)
    dut = (resume.environment.dut if resume is not None
           else inputs.config.dut.with_flags(dut_flags(arm.dut, options.meta)))
    target.check_settings(inputs.settings)  # an emulator's [emulator] table, checked now
    check_storable("", inputs.settings.to_mapping())  # the record keeps the settings file
    planned = _plan_suites(inputs.suite_refs, inputs, resume)
    _check_limit_units(planned, inputs.config)
    check_config(inputs.config, inputs.settings, planned)
    required = (list(resume.required) if resume is not None else
                required_of([s.name for s in planned], inputs.config,
                            require=options.require, optional=options.optional))
    baseline = (None if arm.baseline is None
                else _load_checked_baseline(arm.baseline, inputs.config, planned))
    tracker = (load_tracker(options.tracker, inputs.settings, knobs.tracker_params)
               if options.tracker else None)
    power = _power_switch(options, target, knobs.power_timeout_s)

    run_id = resume.run_id if resume is not None else arm.run_id or new_run_id()
    settings_path = inputs.settings_path
    runner_info: dict[str, Any] = {
        "suites": {s.name: s.ref for s in planned},
        "settings": str(Path(settings_path).resolve()) if settings_path else None,
        "config": str(Path(inputs.config.path).resolve()) if inputs.config.path else None,
        "faults": str(Path(options.faults).resolve()) if options.faults is not None else None,
        "shard": None if options.shard is None else list(check_shard(options.shard)),
        "tracker": options.tracker,
    }
    if resume is not None:
        runner_info = {**info, "suites": runner_info["suites"]}
    return BenchPlan(
        port=target.port, target=target, settings=inputs.settings, settings_path=settings_path,
        config=inputs.config, seed=inputs.seed, faults=inputs.faults, suites=planned,
        out_dir=arm.out, resume=resume, baseline=baseline, retries=knobs.retries,
        isolation=knobs.isolation, reply_timeout_s=knobs.reply_timeout_s,
        move_timeout_scale=knobs.move_timeout_scale,
        connect_timeout_s=knobs.connect_timeout_s, outage_timeout_s=knobs.outage_timeout_s,
        settle_s=knobs.settle_s, power=power,
        tracker=tracker, run_id=run_id, runner_info=runner_info, workers=knobs.workers,
        capture=knobs.capture, capture_max_bytes=knobs.capture_max_bytes,
        warnings=_warnings(inputs.config), scheduler=knobs.scheduler,
        shard=_shard_of(runner_info), required=required, dut=dut,
    )


def check_shard(shard: tuple[int, int]) -> tuple[int, int]:
    """``(I, N)`` with 1 <= I <= N, else a SettingsError naming ``--shard``."""
    i, n = shard
    count = check_whole("--shard", n, Bound(1, math.inf, whole=True, why="N of I/N"))
    return check_whole("--shard", i, Bound(1, count, why="I of I/N, 1 <= I <= N")), count


def _shard_of(info: Mapping[str, Any]) -> tuple[int, int] | None:
    shard = info.get("shard")
    if shard is None:
        return None
    if not (isinstance(shard, list) and len(shard) == 2):
        raise RecordError(f"{RUNNER_FILE}.shard", f"{shard!r} is not [I, N]")
    return check_shard((shard[0], shard[1]))
