"""``armbench merge``: join the shards of a run (``armbench run --shard I/N``, ``armbench
campaign --shard I/N``) into one record, as the unsharded run would have written it.

``armbench merge DIR... --out DIR``

Exit status: as ``armbench run`` (and ``armbench campaign``) for the merged record: 0 pass, 1 a
limit failed, 3 regressed, 4 incomplete; 2 for shards that do not make one run.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from armbench.bench.campaign import CAMPAIGN_KEY, merge_shards
from armbench.cli.commands.run_files import write_reports
from armbench.record.verdict import exit_status

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add the ``merge`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "merge",
        description="Join shard run directories (--shard I/N) into one record: every trial once, "
                    "the suite summaries computed over all of them.",
        epilog="Exit status (the merged record's verdict, as armbench run): 0 pass, 1 a limit "
               "failed, 2 bad input or shards that do not make one run, 3 regressed, 4 "
               "incomplete. See docs/ci.md.")
    p.add_argument("shards", nargs="+", metavar="DIR", help="the shards' run directories")
    p.add_argument("--out", required=True, metavar="DIR", help="the merged run directory")
    p.set_defaults(func=_merge)


def _merge(args: argparse.Namespace) -> int:
    outcome = merge_shards(args.shards, args.out)
    record = outcome.record
    if any(CAMPAIGN_KEY in s.params for s in record.suites.values()):
        from armbench.cli.commands.campaign import write_campaign_page

        write_campaign_page(record, outcome)
        status = exit_status(record.verdict)  # the campaign's verdict, as armbench campaign
    else:
        write_reports(record, outcome.out_dir)
        status = outcome.exit_status
    trials = sum(len(s.trials) for s in record.suites.values())
    print(f"merged {len(args.shards)} shard(s) into run {record.run_id}: {trials} trial(s), "
          f"verdict {record.verdict}", file=sys.stdout)
    print(f"  results.json  {outcome.results_path}", file=sys.stdout)
    return status
