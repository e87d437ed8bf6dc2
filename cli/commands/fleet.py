"""``armbench run --port P1 --port P2 ...``: the fleet half of the run command (no subcommand of
its own): runs every arm at once (``bench/runner/fleet_run.py``), writes each arm's reports and the
fleet page, prints one line per arm and returns the fleet's exit status (``docs/fleet.md``)."""

from __future__ import annotations

import logging
import sys
from collections.abc import Sequence

from armbench.bench.runner import RunOptions
from armbench.bench.runner.fleet_run import FleetOutcome, run_fleet_sync
from armbench.cli.commands.run_files import step_summary, write_reports

__all__ = ["print_summary", "run_fleet"]

log = logging.getLogger("armbench.runner")

#: The page of the fleet inside its run directory.
FLEET_PAGE = "fleet.html"


def run_fleet(options: RunOptions, ports: Sequence[str], *, summary: str | None = None) -> int:
    """Run the fleet, write its reports, print its summary (and append each arm's Markdown
    summary to ``summary``); the fleet's exit status."""
    outcome = run_fleet_sync(options, ports, progress=sys.stderr)
    for arm_outcome in outcome.outcomes:
        if arm_outcome is not None:
            write_reports(arm_outcome.record, arm_outcome.out_dir,
                          capture_max_bytes=arm_outcome.capture_max_bytes)
    page = outcome.out_dir / FLEET_PAGE
    try:
        from armbench.reports.pages.fleet_page import render_fleet

        render_fleet(outcome.out_dir, page)
    except Exception as exc:  # the records and reports are on disk: say so, keep the status
        log.warning("the fleet page failed (%s: %s)", type(exc).__name__, exc)
    print_summary(outcome)
    if summary is not None:
        for arm_outcome in outcome.outcomes:
            if arm_outcome is not None:
                step_summary(summary, arm_outcome)
    if page.exists():
        print(f"  fleet page  {page}", file=sys.stdout)
    return outcome.exit_status


def print_summary(outcome: FleetOutcome) -> None:
    """One line per arm: name, verdict, exit status, what went wrong, its folder."""
    out = sys.stdout
    width = max(len(a.name) for a in outcome.arms)
    failed = outcome.failed
    print(f"fleet of {len(outcome.arms)} arm(s): exit {outcome.exit_status}" +
          (f", not passed: {', '.join(failed)}" if failed else ", every arm passed"), file=out)
    for arm, result, error, status in zip(outcome.arms, outcome.outcomes, outcome.errors,
                                          outcome.statuses, strict=True):
        verdict = "error" if result is None else result.verdict
        notes = []
        if error:
            notes.append(error)
        if result is not None:
            record = result.record
            fails = list(dict.fromkeys(m.name for _, _, m in record.iter_measurements()
                                       if m.outcome == "fail"))
            if fails:
                notes.append(f"outside limits: {', '.join(fails[:4])}"
                             + (f" and {len(fails) - 4} more" if len(fails) > 4 else ""))
            if record.baseline is not None and record.baseline.regressions:
                notes.append("regressed: " + ", ".join(r.name for r in
                                                       record.baseline.regressions[:4]))
        where = outcome.out_dir / arm.name
        print(f"  {arm.name:<{width}}  {verdict.upper():<10} exit {status}  {where}"
              + (f"  ({'; '.join(notes)})" if notes else ""), file=out)
    out.flush()
