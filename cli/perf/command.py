"""``armbench perf``: print the benchmark figures (or one JSON object with ``--json``).

Each figure is printed as soon as it is measured (a full run takes minutes); stderr says which
benchmark is running, with ``--json`` too (stdout then holds the one JSON object only).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from typing import Any

from armbench.cli.perf import Figure, PerfOptions, run_benchmarks
from armbench.cli.perf.hot_modules import build_name

__all__ = ["check_port", "format_figure", "register"]


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


def format_figure(f: Figure) -> str:
    """One figure as a line of the text output."""
    extra = ""
    if f.bound is not None and f.ratio is not None:
        extra = f"   bound {f.bound:,.1f} {f.unit}, ratio {f.ratio:.3f}"
    note = f"   ({f.note})" if f.note else ""
    return f"{f.name:32s} {f.value:>14,.1f} {f.unit}{extra}{note}"


def check_port(port: str) -> None:
    """``--port`` checked before minutes of measuring: its form, the device, and an arm
    answering there (as the figure against it will connect: default settings and timeouts)."""
    from armbench.bench.runner.probe import find_arm, needs_probe
    from armbench.drivers.host.arm import CONNECT_TIMEOUT_S
    from armbench.drivers.model.settings import RobotSettings
    from armbench.drivers.transports.target import target_of

    target = target_of(port)
    target.preflight()
    if needs_probe(target):
        asyncio.run(find_arm(port, RobotSettings(), connect_timeout_s=CONNECT_TIMEOUT_S,
                             reply_timeout_s=0.5, not_done="nothing was measured"))


def _run(args: argparse.Namespace) -> int:
    if args.port is not None:
        check_port(args.port)
    opts = PerfOptions(port=args.port, repeats=max(1, args.repeats), quick=args.quick)
    t0 = time.monotonic()

    def starting(module: str) -> None:
        print(f"[{time.monotonic() - t0:6.1f} s] measuring {module} ...", file=sys.stderr,
              flush=True)

    def measured(f: Figure) -> None:
        if not args.json:
            print(format_figure(f), flush=True)

    if not args.json:
        print(f"build of the hot modules: {build_name()}", flush=True)
    figures = run_benchmarks(opts, args.only, starting=starting, measured=measured)
    if args.json:
        print(json.dumps({"build": build_name(), "figures": [f.to_json() for f in figures]}))
    return 0
