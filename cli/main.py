"""The ``armbench`` command line: one module per subcommand under ``armbench.cli.commands``.

Only the module of the command asked for is imported (``armbench --help`` imports none), so a
command pays at start for what it uses, not for scipy, matplotlib and Jinja2 of the others.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence
from importlib.metadata import version
from typing import Any, NoReturn

from armbench.bench.workers.blas_threads import one_blas_thread
from armbench.bench.workers.collector_pace import pace_collector
from armbench.bench.workers.process_end import end_process
from armbench.cli.commands.bounds import check_bounds
from armbench.drivers.model.errors import ArmbenchError

__all__ = ["COMMANDS", "EXIT_BROKEN_PIPE", "build_parser", "main", "program"]

#: Exit status when stdout's reader closed the pipe: what a process killed by SIGPIPE reports.
EXIT_BROKEN_PIPE = 141

_COMMANDS = "armbench.cli.commands."
#: Each subcommand: the module whose ``register(subparsers)`` adds its parser and sets ``func``,
#: and the line ``armbench --help`` shows for it (the parser's ``help``; defined here only).
COMMANDS: dict[str, tuple[str, str]] = {
    "run": (_COMMANDS + "run", "run bench suites and judge them against limits and a baseline"),
    "fk": (_COMMANDS + "kinematics", "forward kinematics: joint angles → TCP pose"),
    "ik": (_COMMANDS + "kinematics", "inverse kinematics: TCP position → every joint solution"),
    "perf": ("armbench.cli.perf.command", "measure codec, emulator and driver throughput"),
    "emulate": (_COMMANDS + "emulate", "serve the emulated arm on a pty or TCP port"),
    "monitor": (_COMMANDS + "monitor",
                "live joint angles, TCP position, frame rate and error counts"),
    "move": (_COMMANDS + "move", "move to joint angles or a TCP position"),
    "i2c": (_COMMANDS + "i2c", "I²C bus tools (scan the joint boards)"),
    "report": (_COMMANDS + "report", "render run reports (DIR/report.html) and the run index"),
    "compare": (_COMMANDS + "compare", "compare run B with baseline run A, metric by metric"),
    "config": (_COMMANDS + "config",
               "print a run's effective config (limits, parameters) as TOML: config show"),
    "firmware": (_COMMANDS + "firmware",
                 "build the firmware in the loop (AVR images and simavr harness)"),
    "calibrate": (_COMMANDS + "calibrate",
                  "fit the robot model of an arm (settings with uncertainties)"),
    "twin-check": (_COMMANDS + "twin_check", "measure how well the twin predicts an arm's capture"),
    "campaign": (_COMMANDS + "campaign",
                 "many trials of one suite over drawn conditions (Monte Carlo on the emulator)"),
    "merge": (_COMMANDS + "merge", "join the shards of a run into one record"),
    "urdf": (_COMMANDS + "urdf", "write a URDF of the arm (RViz, Foxglove's 3D panel)"),
    "ros2": (_COMMANDS + "ros2", "serve the arm as a ROS 2 node (extra armbench[ros2])"),
}


def _verbosity_options(parser: argparse.ArgumentParser, default: Any) -> None:
    """``-v``/``-q``, accepted before the subcommand and after it (``default``: 0 on the top
    parser, ``SUPPRESS`` on a subcommand's, so that one does not reset the other)."""
    parser.add_argument("-v", "--verbose", action="count", default=default,
                        help="more logging (-v info, -vv debug: every frame in and out)")
    parser.add_argument("-q", "--quiet", action="count", default=default,
                        help="less logging: errors only")


class _Subcommands:
    """The subparsers as a command module sees them: each parser it adds gets its help line from
    :data:`COMMANDS` and the verbosity options."""

    def __init__(self, sub: Any, common: argparse.ArgumentParser) -> None:
        self._sub = sub
        self._common = common
        self.added: set[str] = set()

    def add_parser(self, name: str, **kwargs: Any) -> argparse.ArgumentParser:
        self.added.add(name)
        parser: argparse.ArgumentParser = self._sub.add_parser(
            name, help=COMMANDS[name][1], parents=[self._common], **kwargs)
        return parser


def _command_in(argv: Sequence[str]) -> str | None:
    """The subcommand named in ``argv``: its first word that is not an option (the top-level
    options take no value)."""
    for word in argv:
        if not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The argument parser: the module of the command named in ``argv`` registered in full, every
    other command by its help line only; ``argv=None``: every module registered."""
    parser = argparse.ArgumentParser(
        prog="armbench",
        description="Hardware-in-the-loop test bench for the Igus RoboLink 4-DoF arm.",
        epilog="Run 'armbench COMMAND --help' for a command's options and exit statuses.")
    parser.add_argument("--version", action="version", version=f"armbench {version('armbench')}")
    _verbosity_options(parser, 0)
    common = argparse.ArgumentParser(add_help=False)
    _verbosity_options(common, argparse.SUPPRESS)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    named = _command_in(argv) if argv is not None else None
    wanted = ({module for module, _ in COMMANDS.values()} if argv is None
              else {COMMANDS[named][0]} if named else set())
    subcommands = _Subcommands(sub, common)
    for name, (module, help_line) in COMMANDS.items():
        if name in subcommands.added:
            continue
        if module in wanted:
            importlib.import_module(module).register(subcommands)
        else:
            sub.add_parser(name, help=help_line)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one subcommand; user errors (a number option out of its bound among them,
    :mod:`armbench.cli.commands.bounds`) print one line on stderr and exit with status 2."""
    words = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(words)
    args = parser.parse_args(words)
    level = min(2, max(-1, args.verbose - args.quiet))
    logging.basicConfig(level={-1: logging.ERROR, 0: logging.WARNING, 1: logging.INFO,
                               2: logging.DEBUG}[level],
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        check_bounds(args)
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


def program() -> NoReturn:
    """The ``armbench`` program (its console script, ``python -m armbench``): :func:`main` on
    the command line, then the process ends with its status, without the interpreter's
    teardown (:func:`~armbench.bench.workers.process_end.end_process`). The process collects
    its garbage at armbench's pace (:mod:`~armbench.bench.workers.collector_pace`) and runs
    one BLAS thread (:mod:`~armbench.bench.workers.blas_threads`)."""
    pace_collector()
    one_blas_thread()
    end_process(main())
