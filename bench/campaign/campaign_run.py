"""Running a campaign: :func:`prepare_campaign` turns the options into a bench plan whose one
suite is a :class:`~armbench.bench.campaign.suite.CampaignSuite`, and :func:`run_campaign` runs
it with the bench runner (same record, progress, worker processes or Dask cluster, shards).

Two things differ from ``armbench run``: no traffic capture (thousands of trials would write
gigabytes), and ``results.json`` is written at most about once a second while trials come in
(:class:`BatchedWriter`; rewriting a record of thousands of trials after each one costs time
growing with the square of their number) and always at the end of the suite.
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from armbench.bench.campaign.draws import read_uncertainties
from armbench.bench.campaign.suite import CampaignSuite, campaign_params
from armbench.bench.runner import (
    EXIT_INTERRUPTED,
    RUNNER_FILE,
    BenchPlan,
    PlannedSuite,
    RunOptions,
    RunOutcome,
    prepare,
)
from armbench.bench.runner.execute import execute
from armbench.bench.runner.plan import MAX_TRIALS, check_registered_suites, json_equal
from armbench.bench.runner.trials import LoopClockWriter
from armbench.drivers.model.bounds import Bound, check_whole
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.user_files import MAX_JSON_BYTES, FileRefused, read_regular_file
from armbench.record import RESULTS_FILE, RecordError, Trial, load_record, path_inside
from armbench.record.baseline import read_record

__all__ = ["BatchedWriter", "CampaignOptions", "prepare_campaign", "run_campaign"]


@dataclass(slots=True)
class CampaignOptions:
    """What ``armbench campaign`` was asked (see ``docs/campaigns.md``)."""

    suite: str
    samples: int
    settings: str | Path | None = None
    """A calibration's settings file: its fitted values with sigmas are drawn."""
    config: str | Path | None = None
    out: str | Path | None = None
    runs_root: str | Path = "runs"
    seed: int | None = None
    workers: int | None = None
    scheduler: str | None = None
    shard: tuple[int, int] | None = None
    resume: str | Path | None = None
    """A campaign's run directory to continue: its suite, samples, settings, limits, seed and
    shard come from there."""


class BatchedWriter(LoopClockWriter):
    """A record writer that writes after a trial only when ``min_interval_s`` (wall) has passed
    since the last write (at least 20 times the last write's duration); every other write (a
    suite's begin and end, the baseline) happens at once."""

    min_interval_s = 1.0

    def __init__(self, *args: object, **kwargs: object) -> None:
        self._last_write = -float("inf")
        self._write_s = 0.0
        self._batching = False
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]

    def add_trial(self, name: str, trial: Trial) -> None:
        self._batching = True
        try:
            super().add_trial(name, trial)
        finally:
            self._batching = False

    def write(self) -> Path:
        now = time.perf_counter()
        if self._batching and now - self._last_write < max(self.min_interval_s,
                                                           20.0 * self._write_s):
            return self.path
        path = super().write()
        self._last_write = time.perf_counter()
        self._write_s = self._last_write - now
        return path


def _resumed(options: CampaignOptions) -> BenchPlan:
    """The plan of the campaign in ``options.resume``, to continue: the same inputs drawn again
    (the draws depend on the seed and the sample only), checked against the record."""
    assert options.resume is not None
    directory = Path(options.resume)
    record = read_record(path_inside(directory, RESULTS_FILE))
    try:
        info = json.loads(read_regular_file(directory / RUNNER_FILE, "a runner.json",
                                            MAX_JSON_BYTES))
        campaign = info["campaign"]
        suite, samples = str(campaign["suite"]), int(campaign["samples"])
    except FileRefused as exc:
        raise RecordError(str(exc.path), exc.reason) from None
    except (ValueError, KeyError, TypeError, RecursionError):
        raise RecordError(str(directory / RUNNER_FILE), "does not describe a campaign; "
                                                        "armbench run --resume continues a "
                                                        "run") from None
    check_registered_suites([suite])  # a folder cannot make armbench import its code
    if options.suite not in ("", suite) or options.samples not in (0, samples):
        raise ArmbenchError(f"--resume: the campaign in {directory} is {suite} with {samples} "
                            "samples; give neither SUITE nor --samples")
    shard = info.get("shard")
    plan = prepare_campaign(CampaignOptions(
        suite, samples, settings=info.get("settings"), config=info.get("config"),
        seed=record.environment.seed, workers=options.workers, scheduler=options.scheduler,
        shard=(shard[0], shard[1]) if isinstance(shard, list) and len(shard) == 2 else None,
        runs_root=directory.parent))
    for ps in plan.suites:
        rec = record.suites.get(ps.name)
        if rec is not None and (rec.version != ps.suite.version
                                or not json_equal(rec.params, ps.params)):
            raise RecordError(f"suites.{ps.name}.params", "differ from what the campaign's "
                                                          "inputs give now; start a new one")
    return dataclasses.replace(plan, out_dir=directory, resume=record, run_id=record.run_id,
                               runner_info={**info, **plan.runner_info})


def prepare_campaign(options: CampaignOptions) -> BenchPlan:
    """Validate the options and plan the campaign (draws included), before anything runs."""
    if options.resume is not None:
        return _resumed(options)
    check_whole("--samples", options.samples, Bound(1, MAX_TRIALS))
    plan = prepare(RunOptions(
        suites=[options.suite], config=options.config, out=options.out,
        runs_root=options.runs_root, seed=options.seed, settings=options.settings,
        workers=options.workers, scheduler=options.scheduler, shard=options.shard))
    caps = plan.target.capabilities
    if not (caps.virtual and caps.fresh_per_trial):
        raise ArmbenchError(f"campaign: campaigns run on a simulated arm on virtual time, started "
                            f"fresh per trial (fake://); {plan.port!r} is not one")
    uncertain = read_uncertainties(options.settings) if options.settings is not None else []
    (ps,) = plan.suites
    suite = CampaignSuite(ps.suite, plan.settings)
    params = campaign_params(ps.params, options.samples, plan.seed, uncertain)
    trials: list[Mapping[str, Any]] = list(suite.plan(params))
    planned = PlannedSuite(ps.ref, suite, params, trials)
    info = {**plan.runner_info, "campaign": {"suite": ps.ref, "samples": options.samples}}
    return dataclasses.replace(plan, suites=[planned], capture=False, runner_info=info)


def run_campaign(options: CampaignOptions, *,
                 progress: IO[str] | None = sys.stderr) -> RunOutcome:
    """Plan and run a campaign on a virtual-time loop; Ctrl-C returns the record on disk with
    exit status 130."""
    from armbench.fakes.clock.vclock import run_virtual

    plan = prepare_campaign(options)
    try:
        return run_virtual(execute(plan, progress=progress, writer_class=BatchedWriter))
    except (KeyboardInterrupt, asyncio.CancelledError):
        if not (plan.out_dir / RESULTS_FILE).exists():
            raise KeyboardInterrupt from None
        record = load_record(plan.out_dir / RESULTS_FILE)
        return RunOutcome(plan.out_dir, record, EXIT_INTERRUPTED, interrupted=True,
                          error="interrupted", warnings=tuple(plan.warnings))
