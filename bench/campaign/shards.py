"""Joining shards: ``armbench run --shard I/N`` (or ``armbench campaign --shard I/N``) measures
every N-th trial from I − 1 and leaves the suite summaries out; :func:`merge_shards` joins the N
shard records into one record, as an unsharded run would have written it: the same trials (each
exactly once, by index) and the suite summaries computed over all of them by the same code.

The shards must be of one run: the same shard count, each shard once, the same port, settings,
seed, unit under test, faults, limits file, suites, suite versions and parameters. Run ids,
timestamps and ``started_s`` (each shard's own clock) differ from an unsharded run; a merged
suite's wall-clock time is its trials' (measured in the shards) plus its summary's; the traffic
capture is not merged (each shard keeps its own ``capture.mcap``).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from armbench.bench.campaign.campaign_run import BatchedWriter, CampaignOptions, prepare_campaign
from armbench.bench.runner import (
    RUNNER_FILE,
    BenchPlan,
    ProgressPrinter,
    RunOptions,
    RunOutcome,
    exit_status,
    prepare,
)
from armbench.bench.runner.plan import json_equal
from armbench.bench.runner.trials import TrialRunner, default_emulator
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.user_files import MAX_JSON_BYTES, FileRefused, read_regular_file
from armbench.record import RESULTS_FILE, RecordError, RunRecord, Trial, load_record
from armbench.record.files import check_directory_writable

__all__ = ["MergeError", "merge_shards"]


class MergeError(ArmbenchError):
    """Shards that do not make one run (a shard missing or twice, different inputs)."""


@dataclasses.dataclass(frozen=True, slots=True)
class _Shard:
    path: Path
    record: RunRecord
    info: dict[str, Any]
    index: int
    count: int


def _read_shard(directory: Path) -> _Shard:
    record = load_record(directory / RESULTS_FILE)
    try:
        info = json.loads(read_regular_file(directory / RUNNER_FILE, "a runner.json",
                                            MAX_JSON_BYTES))
    except (FileRefused, ValueError, RecursionError) as exc:
        raise MergeError(f"{directory}: no readable {RUNNER_FILE} ({exc}): not a run "
                         "directory") from None
    shard = info.get("shard") if isinstance(info, dict) else None
    if not (isinstance(shard, list) and len(shard) == 2 and all(isinstance(x, int)
                                                                 for x in shard)):
        raise MergeError(f"{directory}: not a shard (run with --shard I/N)")
    return _Shard(directory, record, info, shard[0], shard[1])


def _check_same_run(shards: Sequence[_Shard]) -> None:
    """Each shard of one count once, all of one run's inputs."""
    first = shards[0]
    seen: dict[int, Path] = {}
    for s in shards:
        if s.count != first.count:
            raise MergeError(f"{s.path}: shard {s.index}/{s.count}, but {first.path} is of "
                             f"{first.count}")
        if s.index in seen:
            raise MergeError(f"{s.path} and {seen[s.index]} are both shard {s.index}/{s.count}")
        seen[s.index] = s.path
        a, b = first.record, s.record
        for what, x, y in (
                ("port", a.environment.port, b.environment.port),
                ("settings", a.environment.settings, b.environment.settings),
                ("seed", a.environment.seed, b.environment.seed),
                ("unit under test", a.environment.dut.to_json(), b.environment.dut.to_json()),
                ("faults", a.environment.faults, b.environment.faults),
                ("limits", a.environment.config_path, b.environment.config_path),
                ("suites", a.planned_suites, b.planned_suites),
                ("required figures", a.required, b.required),
                ("campaign", first.info.get("campaign"), s.info.get("campaign")),
                ("suite parameters", {n: (x.version, x.params) for n, x in a.suites.items()},
                 {n: (x.version, x.params) for n, x in b.suites.items()})):
            if not json_equal(x, y):
                raise MergeError(f"{s.path}: its {what} differ from {first.path}'s: not shards "
                                 "of one run")
    missing = sorted(set(range(1, first.count + 1)) - seen.keys())
    if missing:
        raise MergeError(f"shard(s) {', '.join(f'{i}/{first.count}' for i in missing)} missing")


def _plan(shard: _Shard, out: Path) -> BenchPlan:
    """The plan the shards ran (their suites, parameters, settings, limits, seed), writing to
    ``out``."""
    env = shard.record.environment
    info = shard.info
    campaign = info.get("campaign")
    if isinstance(campaign, dict):
        return prepare_campaign(CampaignOptions(
            suite=str(campaign["suite"]), samples=int(campaign["samples"]),
            settings=info.get("settings"), config=info.get("config"), out=out, seed=env.seed))
    refs = info.get("suites") or {}
    plan = prepare(RunOptions(
        suites=[refs.get(n, n) for n in shard.record.planned_suites],
        ports=[env.port] if env.port else [],
        config=info.get("config"), settings=info.get("settings"), faults=info.get("faults"),
        out=out, seed=env.seed))
    return dataclasses.replace(plan, shard=None)


def _final_trials(shards: Sequence[_Shard], name: str, n: int) -> list[tuple[Trial, ...]]:
    """Per index of suite ``name``: its superseded attempts and its trial, from the one shard
    that measured it."""
    out: list[tuple[Trial, ...] | None] = [None] * n
    for s in shards:
        rec = s.record.suites.get(name)
        if rec is None:
            continue
        for t in rec.trials:
            if not 0 <= t.index < n:
                raise MergeError(f"{s.path}: {name} trial {t.index} is not in the plan")
            if out[t.index] is not None:
                raise MergeError(f"{name} trial {t.index} is in two shards")
            earlier = tuple(x for x in rec.superseded_trials if x.index == t.index)
            out[t.index] = (*earlier, t)
    missing = [i for i, x in enumerate(out) if x is None]
    if missing:
        raise MergeError(f"{name}: trial(s) {missing[:10]} measured by no shard (was a shard "
                         "interrupted? resume it first)")
    return [x for x in out if x is not None]


async def _merge(shards: Sequence[_Shard], plan: BenchPlan) -> RunRecord:
    first = shards[0].record
    plan.out_dir.mkdir(parents=True, exist_ok=True)
    record = RunRecord.new(first.environment, first.planned_suites)
    record.required = list(first.required)  # every shard was asked the same
    writer = BatchedWriter(plan.out_dir, record)
    runner = TrialRunner(plan, writer, ProgressPrinter(None, 0), default_emulator)
    for ps in plan.suites:
        recorded = first.suites.get(ps.name)
        if recorded is None:
            continue
        if not json_equal(recorded.params, ps.params) or recorded.version != ps.suite.version:
            raise MergeError(f"{ps.name}: the shards' parameters or version differ from this "
                             "armbench's plan of the same inputs")
        writer.begin_suite(ps.name, ps.suite.version, ps.params, started_s=0.0)
        stopped: Trial | None = None
        for attempts in _final_trials(shards, ps.name, len(ps.trials)):
            for t in attempts:
                writer.add_trial(ps.name, t)
            if attempts[-1].status == "error" and stopped is None:
                stopped = attempts[-1]
        runner.begin_wall(ps.name)  # the shards' trials' wall time, then the summary's
        if stopped is not None:
            runner.end_suite(ps.name, error=f"trial {stopped.index}: {stopped.error}")
            continue
        await runner.summarize(ps)
    writer.write()
    return writer.record


def merge_shards(directories: Sequence[str | Path], out: str | Path) -> RunOutcome:
    """Join the shard records in ``directories`` into one record in ``out`` (see the module
    doc); ``out`` must not hold a record yet."""
    from armbench.fakes.clock.vclock import run_virtual

    if not directories:
        raise MergeError("no shard directories given")
    out_dir = Path(out)
    check_directory_writable(out_dir, "--out")  # before a shard is read
    if (out_dir / RESULTS_FILE).exists():
        raise RecordError(str(out_dir / RESULTS_FILE), "already holds a run record; choose "
                                                       "another --out")
    shards = sorted((_read_shard(Path(d)) for d in directories), key=lambda s: s.index)
    _check_same_run(shards)
    plan = _plan(shards[0], out_dir)
    record = run_virtual(_merge(shards, plan))
    return RunOutcome(out_dir, record, exit_status(record.verdict))
