"""``armbench firmware build``: compile the reference firmware and the simavr harness."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from armbench.bench.runner.outputs import OutputError, check_out_dir
from armbench.fakes.avr.harness import FIRMWARE_SOURCE, build

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add the ``firmware`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "firmware",
        description="Build the paper's firmware for the ATmega328P (joint1..4.elf/.hex) and the "
                    "simavr harness that runs four of them, with the system toolchain (Debian: "
                    "gcc-avr avr-libc simavr libsimavr-dev).")
    actions = p.add_subparsers(dest="action", required=True, metavar="ACTION")
    b = actions.add_parser("build", help="compile into a cache folder (printed)")
    b.add_argument("--source", type=Path, default=FIRMWARE_SOURCE, metavar="DIR",
                   help="firmware sources (default: the checkout's firmware/)")
    b.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="output folder, relative to the working directory (default: "
                        "~/.cache/armbench/firmware/<digest>); never inside the sources")
    b.add_argument("--force", action="store_true", help="rebuild even if up to date")
    b.set_defaults(func=_build)


def _build(args: argparse.Namespace) -> int:
    source = Path(args.source).absolute()
    out = None if args.out is None else Path(args.out).absolute()
    if out is not None:  # checked before anything is compiled
        if out.resolve() == source.resolve() or source.resolve() in out.resolve().parents:
            raise OutputError("--out", Path(args.out), f"is inside the firmware sources "
                                                       f"{source}; build elsewhere")
        check_out_dir("--out", out, ())
    print(build(source, out, force=args.force))
    return 0
