"""``armbench run --port P1 --port P2 ...``: the fleet's half of the run command's output (no
subcommand of its own): once every arm has run (``bench/runner/fleet_run.py``) and its reports
are written, the fleet page and one line per arm (``docs/fleet.md``)."""

from __future__ import annotations

import logging
import sys

from armbench.bench.runner import RunResult

__all__ = ["FLEET_PAGE", "fleet_summary", "print_summary"]

log = logging.getLogger("armbench.runner")

#: The page of the fleet inside its run directory.
FLEET_PAGE = "fleet.html"


def fleet_summary(result: RunResult) -> None:
    """Write the fleet page and print the fleet's lines (the page's path last)."""
    page = result.out_dir / FLEET_PAGE
    try:
        from armbench.reports.pages.fleet_page import render_fleet

        render_fleet(result.out_dir, page)
    except Exception as exc:  # the records and reports are on disk: say so, keep the status
        log.warning("the fleet page failed (%s: %s)", type(exc).__name__, exc)
    print_summary(result)
    if page.exists():
        print(f"  fleet page  {page}", file=sys.stdout)


def print_summary(result: RunResult) -> None:
    """One line per arm: name, verdict, exit status, what went wrong, its folder."""
    out = sys.stdout
    names = result.names
    width = max(len(n) for n in names)
    failed = result.failed
    print(f"fleet of {len(names)} arm(s): exit {result.exit_status}" +
          (f", not passed: {', '.join(failed)}" if failed else ", every arm passed"), file=out)
    for name, arm, outcome, error, status in zip(names, result.arms, result.outcomes,
                                                 result.errors, result.statuses, strict=True):
        verdict = "error" if outcome is None else outcome.verdict
        notes = []
        if error:
            notes.append(error)
        if outcome is not None:
            record = outcome.record
            fails = list(dict.fromkeys(m.name for _, _, m in record.iter_measurements()
                                       if m.outcome == "fail"))
            if fails:
                notes.append(f"outside limits: {', '.join(fails[:4])}"
                             + (f" and {len(fails) - 4} more" if len(fails) > 4 else ""))
            if record.baseline is not None and record.baseline.regressions:
                notes.append("regressed: " + ", ".join(r.name for r in
                                                       record.baseline.regressions[:4]))
        print(f"  {name:<{width}}  {verdict.upper():<10} exit {status}  {arm.out}"
              + (f"  ({'; '.join(notes)})" if notes else ""), file=out)
    out.flush()
