"""``armbench report``: (re-)render run reports and the run index from the records alone.

``armbench report DIR...`` writes ``DIR/report.html`` from ``DIR/results.json`` (and
``DIR/capture.mcap``, or an older run's ``DIR/capture.jsonl``, when present); ``armbench report
--index RUNS_DIR`` writes ``RUNS_DIR/index.html`` over every run directory in ``RUNS_DIR``. Both
can be given at once.
Exit status 0 when everything rendered, 2 when a record could not be read (the other directories
are still rendered).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from armbench.bench.runner.outputs import check_out_files
from armbench.drivers.model.errors import ArmbenchError
from armbench.record import REPORT_FILE, RESULTS_FILE, TOO_DEEP

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add the ``report`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "report",
        description="Render the self-contained HTML report of each run directory from its "
                    "results.json, and/or the index of a directory of runs.")
    p.add_argument("dirs", nargs="*", metavar="DIR",
                   help="run directory holding results.json (or the results.json itself); "
                        "writes report.html beside it")
    p.add_argument("--index", metavar="RUNS_DIR", default=None,
                   help="also write RUNS_DIR/index.html over the runs in RUNS_DIR")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from armbench.reports import INDEX_FILE, render_index, render_report

    if not args.dirs and args.index is None:
        print("armbench report: error: give run directories, --index RUNS_DIR, or both",
              file=sys.stderr)
        return 2
    if args.index is not None:  # checked before any report is rendered
        check_out_files("--index", [Path(args.index) / INDEX_FILE], force=True)
    status = 0
    for d in args.dirs:
        path = Path(d)
        results = path / RESULTS_FILE if path.is_dir() else path
        try:
            out = render_report(results, results.parent / REPORT_FILE)
        except ArmbenchError as exc:
            print(f"armbench report: error: {exc}", file=sys.stderr)
            status = 2
            continue
        except RecursionError:
            print(f"armbench report: error: {results}: {TOO_DEEP}", file=sys.stderr)
            status = 2
            continue
        print(out)
    if args.index is not None:
        print(render_index(args.index, warn=lambda reason: print(
            f"armbench report: warning: {reason}", file=sys.stderr)))
    return status
