"""Instructions per simulated second, counted by valgrind's callgrind: the bare emulator against
the emulator with the driver in the loop, on the installed build.

CPU seconds on a shared machine vary by a third from one minute to the next; instruction counts
do not (the same count for the same build and inputs, whatever else runs). Each workload runs
twice, for ``--short`` and ``--long`` simulated seconds, and the difference of the two counts is
the cost of ``long - short`` simulated seconds, without the interpreter's start-up and imports.
``PYTHONHASHSEED`` is fixed, so dictionaries are laid out alike in every run, and numpy's
OpenBLAS runs no threads of its own: its idle threads spin for as long as the scheduler lets
them, which made counts of the same run differ by up to 2 %. So fixed, three runs of the same
work differ by a few thousand instructions in 800 million.

    python scripts/count_instructions.py [--short 5] [--long 15] [--startup 10 30]

Workloads (those of ``armbench perf``): ``bare``, the emulator alone at full duty with its
replies dropped (``emulator.realtime_factor``); ``driver``, full-duty ``move_joints`` over
``fake://`` (``driver.fake_realtime_factor``). Needs ``valgrind`` on ``PATH``; takes a minute or
two (callgrind runs Python about 50 times slower). ``--startup A B`` adds the cost of one
start-up recovery trial (a power cut and the watch of the recovery, the suite's defaults): a
campaign of ``B`` trials in one process less one of ``A``, over ``B - A``; a few minutes more.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile

#: What makes two runs of the same work count the same instructions (see above).
FIXED_ENV = {"PYTHONHASHSEED": "0", "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}

WORKLOAD = """
import sys
import tempfile
from armbench.fakes.clock.vclock import run_virtual
mode, size = sys.argv[1], float(sys.argv[2])
if mode == "startup":
    from armbench.bench.campaign import CampaignOptions, run_campaign
    with tempfile.TemporaryDirectory() as out:
        run_campaign(CampaignOptions("startup-recovery", int(size), seed=0, out=out + "/c",
                                     workers=1), progress=None)
elif mode == "bare":
    from armbench.cli.perf.emulator_perf import emulate
    run_virtual(emulate(size, moving=True))
else:
    from armbench.cli.perf.driver_perf import _moves
    run_virtual(_moves(size))
"""


def count(mode: str, size: float) -> int:
    """Instructions of one run of workload ``mode`` for ``size`` simulated seconds (trials for
    ``startup``)."""
    with tempfile.TemporaryDirectory(prefix="armbench-callgrind-") as tmp:
        out = os.path.join(tmp, "callgrind.out")
        done = subprocess.run(
            ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", sys.executable,
             "-c", WORKLOAD, mode, str(size)],
            capture_output=True, text=True, env={**os.environ, **FIXED_ENV}, check=False)
    found = re.search(r"Collected : (\d+)", done.stderr)
    if done.returncode != 0 or found is None:
        raise SystemExit(f"callgrind failed on {mode} {size}: {done.stderr[-2000:]}")
    return int(found.group(1))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--short", type=float, default=5.0, help="simulated s of the short run")
    parser.add_argument("--long", type=float, default=15.0, help="simulated s of the long run")
    parser.add_argument("--startup", type=int, nargs=2, metavar=("A", "B"),
                        help="also count a start-up recovery trial: campaigns of A and B trials")
    args = parser.parse_args(argv)
    if shutil.which("valgrind") is None:
        raise SystemExit("valgrind is not on PATH (Debian: apt-get install valgrind)")
    if not args.long > args.short >= 0:
        raise SystemExit(f"--long {args.long} must be more than --short {args.short} >= 0")
    if args.startup is not None and not args.startup[1] > args.startup[0] >= 1:
        raise SystemExit(f"--startup {args.startup[0]} {args.startup[1]}: B must be more than "
                         "A >= 1")
    span_s = args.long - args.short
    per_s: dict[str, float] = {}
    for mode in ("bare", "driver"):
        per_s[mode] = (count(mode, args.long) - count(mode, args.short)) / span_s
        print(f"instructions.{mode}_per_sim_s  {per_s[mode] / 1e6:10.2f} M/sim s")
    print(f"instructions.driver_per_bare     {per_s['driver'] / per_s['bare']:10.3f} x   "
          f"(the host's share: {(per_s['driver'] - per_s['bare']) / 1e6:.2f} M/sim s)")
    if args.startup is not None:
        a, b = args.startup
        trial = (count("startup", b) - count("startup", a)) / (b - a)
        print(f"instructions.startup_per_trial {trial / 1e6:10.2f} M/trial")
    return 0


if __name__ == "__main__":
    sys.exit(main())
