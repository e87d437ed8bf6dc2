"""Replay saved inputs through a harness without libFuzzer and say which still crash.

    python fuzz/replay.py config runs/fuzz/crashes/config/        # every file in a folder
    python fuzz/replay.py framer crash-1234abcd... other-file      # or single files

Prints ``ok`` or the crash signature (``Type@file:line``) per input, then the traceback of each
distinct signature; exit status 1 if any input still crashes. Handy after a fix, and to check that
the committed seed corpus passes (``python fuzz/replay.py framer fuzz/corpus/framer``).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback
from pathlib import Path

from _harness import signature

TARGETS = ("framer", "telnet", "config", "emulator_uart")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("target", choices=TARGETS)
    parser.add_argument("paths", nargs="+", type=Path)
    args = parser.parse_args(argv)
    sys.argv = sys.argv[:1]  # the harness module must not see our arguments
    harness = importlib.import_module(f"fuzz_{args.target}")
    files = sorted(f for p in args.paths for f in ([p] if p.is_file() else p.iterdir())
                   if f.is_file() and f.suffix != ".txt" and not f.name.startswith("."))
    first: dict[str, str] = {}
    for f in files:
        try:
            harness.test_one_input(f.read_bytes())
        except Exception as exc:  # every exception is a finding here
            sig = signature(exc)
            first.setdefault(sig, "".join(traceback.format_exception(exc)))
            print(f"CRASH {sig}  {f}")
        else:
            print(f"ok    {f}")
    for sig, tb in first.items():
        print(f"\n=== {sig}\n{tb}")
    print(f"{len(files)} inputs, {len(first)} distinct crash signatures")
    return 1 if first else 0


if __name__ == "__main__":
    sys.exit(main())
