"""``armbench compare A B``: the suite-level metrics of run B against baseline run A.

Prints the metric-by-metric table of :func:`armbench.record.baseline.format_comparison` (or JSON
with ``--json``). Exit status: 3 when a metric regressed beyond its tolerance, 0 otherwise, 2 when a
record cannot be used (missing, invalid, another schema, limits spec or suite version, a changed
unit, or a run B that measured none of the baseline's metrics) or the config names a metric no
suite records (:mod:`armbench.bench.runner.config_check`).
Tolerances come from ``--config bench.toml`` (``[regression]``), else from the packaged
``default_bench.toml``: the same file, and the same function
(:func:`armbench.record.baseline.compare`), ``armbench run --baseline`` judges with.
``--html OUT`` also writes the comparison as a page in the run report's style.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from armbench.bench.runner.config_check import check_config
from armbench.bench.runner.outputs import check_out_files
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings
from armbench.record import RESULTS_FILE
from armbench.record.baseline import compare, format_comparison, load_baseline, read_record
from armbench.record.verdict import DEFAULT_CONFIG, EXIT_PASS, EXIT_REGRESSION, load_config

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add the ``compare`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "compare",
        description="Compare the suite-level measurements of run B with those of baseline run "
                    "A, with the [regression] tolerances armbench run --baseline uses.",
        epilog=f"Exit status: 0 nothing regressed, 2 bad input, {EXIT_REGRESSION} a metric "
               "regressed beyond its tolerance (the status armbench run gives a regression). "
               "See docs/ci.md.")
    p.add_argument("baseline", metavar="A", help="baseline results.json (or its run directory)")
    p.add_argument("current", metavar="B", help="results.json of the run to judge (or its "
                                                "run directory)")
    p.add_argument("--config", "--limits", dest="config", metavar="TOML", default=None,
                   help="config whose [regression] tolerances apply, as for armbench run "
                        "--config (default: the packaged default_bench.toml; armbench config "
                        "show prints it)")
    p.add_argument("--json", action="store_true", help="print the comparison as JSON")
    p.add_argument("--html", metavar="OUT", default=None,
                   help="also write the comparison as a self-contained HTML page to OUT")
    p.set_defaults(func=_run)


def _results(name: str) -> Path:
    path = Path(name)
    return path / RESULTS_FILE if path.is_dir() else path


def _note_other_config(recorded: str | None, given: str | None) -> None:
    """Say on stderr when run B was judged with another config than this comparison uses: the
    tolerances (and so the rows) may differ from those ``armbench run --baseline`` stored."""
    if recorded is None:
        return
    used = Path(given) if given is not None else DEFAULT_CONFIG
    try:
        same = Path(recorded).resolve() == used.resolve()
    except OSError:
        same = False
    if not same:
        print(f"armbench compare: note: run B was judged with the config {recorded}; these "
              f"tolerances come from {used} (give --config to judge as that run did)",
              file=sys.stderr)


def _run(args: argparse.Namespace) -> int:
    if args.html is not None:  # an existing page is replaced; a device, a folder never
        check_out_files("--html", [Path(args.html)], force=True)
    config = load_config(args.config)
    check_config(config, RobotSettings())  # a misspelt tolerance would apply to nothing
    baseline = load_baseline(_results(args.baseline))
    current = read_record(_results(args.current))
    comparison = compare(current, baseline, config)
    compared = sum(r.status == "compared" for r in comparison.rows)
    missing = sum(r.status == "missing" for r in comparison.rows)
    if not compared and missing:
        raise ArmbenchError(f"run {current.run_id} measured none of the baseline's suite-level "
                            f"metrics (0 compared, {missing} missing): nothing to judge")
    _note_other_config(current.environment.config_path, args.config)  # judged: no error left
    if args.json:
        print(json.dumps({"run_id": current.run_id, **comparison.to_json()}, indent=1))
    else:
        print(format_comparison(comparison, run_id=current.run_id))
    if args.html is not None:
        from armbench.reports.pages.compare_page import render_compare

        render_compare(baseline, current, comparison, args.html)
    return EXIT_REGRESSION if comparison.regressed else EXIT_PASS
