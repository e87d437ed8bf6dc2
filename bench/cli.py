"""The ``armbench`` command line: one module per subcommand under ``armbench.bench.commands``."""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence

from armbench.drivers.errors import ArmbenchError

__all__ = ["COMMAND_MODULES", "EXIT_BROKEN_PIPE", "main"]

#: Exit status when stdout's reader closed the pipe: what a process killed by SIGPIPE reports.
EXIT_BROKEN_PIPE = 141

#: Each module exposes ``register(subparsers)``, which adds its parser and sets ``func``.
COMMAND_MODULES: tuple[str, ...] = (
    "armbench.bench.commands.run",
    "armbench.bench.commands.kinematics",
    "armbench.bench.commands.perf",
    "armbench.bench.commands.emulate",
    "armbench.bench.commands.monitor",
    "armbench.bench.commands.move",
    "armbench.bench.commands.i2c",
    "armbench.bench.commands.report",
    "armbench.bench.commands.compare",
    "armbench.bench.commands.firmware",
    "armbench.bench.commands.calibrate",
    "armbench.bench.commands.twin_check",
    "armbench.bench.commands.campaign",
    "armbench.bench.commands.merge",
    "armbench.bench.commands.urdf",
)


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser with every subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="armbench",
        description="Hardware-in-the-loop test bench for the Igus RoboLink 4-DoF arm.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more logging (-v info, -vv debug: every frame in and out)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one subcommand; user errors print one line on stderr and exit with status 2."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=(logging.WARNING, logging.INFO, logging.DEBUG)[min(args.verbose, 2)],
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        status: int = args.func(args)
    except ArmbenchError as exc:
        print(f"armbench {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"armbench {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader went away (``armbench compare ... | head``)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no error at exit
        return EXIT_BROKEN_PIPE
    return status
