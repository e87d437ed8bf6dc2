"""``armbench perf``: print the benchmark figures (or one JSON object with ``--json``)."""

from __future__ import annotations

import argparse
import json
from typing import Any

from armbench.bench.perf import PerfOptions, run_benchmarks
from armbench.hot_modules import build_name

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add the ``perf`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "perf",
        description="Measure armbench's throughput figures; targets are set on their ratios.")
    p.add_argument("--json", action="store_true",
                   help='print {"build": ..., "figures": [...]} on one line')
    p.add_argument("--only", action="append", default=[], metavar="PREFIX",
                   help="only figures whose name starts with PREFIX (repeatable), e.g. codec")
    p.add_argument("--port", default=None, help="also measure against this port (your hardware)")
    p.add_argument("--quick", action="store_true", help="smaller workloads, rougher figures")
    p.add_argument("--repeats", type=int, default=5, help="best of N runs per figure (default 5)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    opts = PerfOptions(port=args.port, repeats=max(1, args.repeats), quick=args.quick)
    figures = run_benchmarks(opts, args.only)
    if args.json:
        print(json.dumps({"build": build_name(), "figures": [f.to_json() for f in figures]}))
        return 0
    print(f"build of the hot modules: {build_name()}")
    for f in figures:
        extra = ""
        if f.bound is not None and f.ratio is not None:
            extra = f"   bound {f.bound:,.1f} {f.unit}, ratio {f.ratio:.3f}"
        note = f"   ({f.note})" if f.note else ""
        print(f"{f.name:32s} {f.value:>14,.1f} {f.unit}{extra}{note}")
    return 0
