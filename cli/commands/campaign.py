"""``armbench campaign``: many trials of one suite over drawn conditions on the emulator, their
distributions and pass probabilities (see ``docs/campaigns.md``).

``armbench campaign SUITE --samples N [--settings fitted.toml] [--config bench.toml]
[--seed N] [--workers N | --scheduler tcp://HOST:PORT] [--shard I/N] [--out DIR]``;
``armbench campaign --resume DIR [--workers N | --scheduler ...]``

Writes ``results.json`` (the record: one trial per sample, the distributions as ``campaign.*``
suite figures) and ``campaign.html`` (histograms, pass probabilities with Wilson intervals).
Exit status (``docs/ci.md``): the campaign's verdict — 0 every ``campaign.*`` figure with a limit
in the config (``[limits."campaign.all_limits.pass_ci_low_pct"] low = 95``) passed it, 1 one did
not, 2 it could not run, 4 a sample is in error or the campaign is unfinished, 130 interrupted.
Samples failing their own limits are the campaign's findings (counted in the pass probabilities
over every sample), not its failure.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from armbench.bench.campaign import CampaignOptions, run_campaign
from armbench.bench.runner import EXIT_ERROR, EXIT_INTERRUPTED, RunOutcome
from armbench.bench.runner.plan import MAX_TRIALS
from armbench.cli.commands.run import shard_arg
from armbench.drivers.model.errors import ArmbenchError
from armbench.record import RunRecord
from armbench.record.verdict import EXIT_PASS, exit_status

__all__ = ["register", "write_campaign_page"]


def register(sub: Any) -> None:
    """Add the ``campaign`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "campaign",
        description="Run SUITE --samples times on the emulator, each sample over drawn "
                    "conditions: the arm's fitted settings drawn from their uncertainties "
                    "(--settings, a calibration's output), and for startup-recovery the state "
                    "and moment of each power cut. Writes results.json and campaign.html.",
        epilog="Exit status: 0 every campaign.* figure with a limit in --config passed it (e.g. "
               "[limits.\"campaign.all_limits.pass_ci_low_pct\"] low = 95), 1 one did not, 2 "
               "bad input, 4 a sample in error or the campaign unfinished, 130 interrupted. "
               "See docs/campaigns.md and docs/ci.md.")
    p.add_argument("suite", metavar="SUITE", nargs="?", default="",
                   help="the suite (accuracy, startup-recovery, ...)")
    p.add_argument("--samples", type=int, default=None, metavar="N",
                   help=f"samples to draw, 1 to {MAX_TRIALS} (required unless --resume)")
    p.add_argument("--resume", metavar="DIR",
                   help="continue the interrupted campaign in DIR (its inputs are kept)")
    p.add_argument("--settings", metavar="FILE",
                   help="robot settings TOML; values with a 'fitted: ± sigma' comment "
                        "(armbench calibrate) are drawn per sample")
    p.add_argument("--config", metavar="FILE", help="limits and suite parameters")
    p.add_argument("--seed", type=int, default=None, metavar="N", help="campaign seed")
    p.add_argument("--out", metavar="DIR", help="run directory (default runs/<run id>/)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="local worker processes (default: [bench] workers, else one per CPU, "
                        "at most 2)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="measure the samples on this Dask scheduler's workers")
    p.add_argument("--shard", type=shard_arg, metavar="I/N",
                   help="measure only shard I of N of the samples; join with armbench merge")
    p.set_defaults(func=_campaign)


def write_campaign_page(record: RunRecord, outcome: RunOutcome) -> None:
    """``campaign.html`` beside the record."""
    from armbench.reports.pages.campaign_page import CAMPAIGN_PAGE, render_campaign

    path = render_campaign(record, outcome.out_dir / CAMPAIGN_PAGE)
    print(f"  {CAMPAIGN_PAGE:<13} {path}", file=sys.stdout)


def _campaign(args: argparse.Namespace) -> int:
    if args.resume is None and not args.suite:
        raise ArmbenchError("SUITE: name the suite of the campaign (or --resume DIR)")
    if args.resume is None and args.samples is None:
        raise ArmbenchError(f"--samples: required; give the number of samples to draw "
                            f"(1 to {MAX_TRIALS})")
    if args.resume is not None:
        given = [flag for flag, value in (("--settings", args.settings), ("--config", args.config),
                                          ("--seed", args.seed), ("--out", args.out),
                                          ("--shard", args.shard)) if value is not None]
        if given:
            raise ArmbenchError(f"--resume: {given[0]} comes from the campaign being resumed")
    outcome = run_campaign(CampaignOptions(
        suite=args.suite, samples=args.samples or 0, settings=args.settings, config=args.config,
        out=args.out, seed=args.seed, workers=args.workers, scheduler=args.scheduler,
        shard=args.shard, resume=args.resume), progress=sys.stderr)
    record = outcome.record
    suite = next(iter(record.suites.values()), None)
    errors = 0 if suite is None else sum(t.status == "error" for t in suite.trials)
    print(f"campaign {record.run_id}: {args.suite}, "
          f"{0 if suite is None else len(suite.trials) - errors} sample(s) measured"
          + (f", {errors} in error" if errors else ""), file=sys.stdout)
    if suite is not None:
        by_name = {m.name: m for m in suite.measurements}
        for m in suite.measurements:
            if m.name.endswith((".pass_pct", ".rate_pct")):
                stem = m.name.removesuffix("_pct").rsplit(".", 1)[0]
                kind = m.name.removesuffix("_pct").rsplit(".", 1)[1]
                low = by_name.get(f"{stem}.{kind}_ci_low_pct")
                high = by_name.get(f"{stem}.{kind}_ci_high_pct")
                ci = (f" [95 % CI {low.value:.4g} .. {high.value:.4g}]"
                      if low is not None and high is not None else "")
                print(f"  {m.name} = {m.value:.4g} %{ci}  ({m.description})", file=sys.stdout)
        for m in suite.measurements:
            if m.outcome != "unjudged":
                print(f"  {'FAIL' if m.outcome == 'fail' else 'pass':<6} {m.name} = "
                      f"{m.value:.4g} {m.unit} (limit {m.limit.describe() if m.limit else '-'})",
                      file=sys.stdout)
    verdict = record.verdict
    if not any(m.outcome != "unjudged" for m in (suite.measurements if suite else [])):
        verdict_note = " (no campaign.* limit in the config: the figures are not judged)"
    else:
        verdict_note = ""
    print(f"campaign verdict: {verdict}{verdict_note}", file=sys.stdout)
    print(f"  results.json  {outcome.results_path}", file=sys.stdout)
    if args.shard is None and suite is not None:
        write_campaign_page(record, outcome)
    complete = (suite is not None and suite.status == "done" and not errors
                and outcome.error is None)
    if not complete:
        print(f"  continue with: armbench campaign --resume {outcome.out_dir}", file=sys.stdout)
    if outcome.interrupted:
        return EXIT_INTERRUPTED
    status = exit_status(verdict)
    return EXIT_ERROR if outcome.error is not None and status == EXIT_PASS else status
