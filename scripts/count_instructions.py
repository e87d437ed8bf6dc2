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
``fake://`` (``driver.fake_realtime_factor``). The two do not ask the emulator for the same work
(the driver's moves stop at each pose, the bare emulator's do not), so the host's own cost is
counted against a third: ``replay``, the emulator sent the very commands the driver sent, at the
same loop times, its replies handed to a receiver that drops them (``set_receiver``, as the
driver receives them): the same emulator work and hand-over without the host
(``instructions.host_per_reply``). ``capture`` is the driver's workload writing a trial's capture
part with the emulator's truth, as a trial does (``instructions.capture_per_reply``). Needs
``valgrind`` on ``PATH``; takes a few minutes (callgrind runs Python about 50 times slower).
``--startup A B`` adds the cost of one start-up recovery trial (a power cut and the watch of the
recovery, the suite's defaults): a campaign of ``B`` trials in one process less one of ``A``,
over ``B - A``; a few minutes more.
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
import asyncio
import json
import sys
import tempfile
from armbench.fakes.clock.vclock import run_virtual
mode, size = sys.argv[1], float(sys.argv[2])
writes_path = sys.argv[3] if len(sys.argv) > 3 else ""


async def moves(capture_dir):
    from armbench.bench.runner.part_events import emulator_truth
    from armbench.cli.perf.emulator_perf import POSES
    from armbench.drivers.capture.part import PartWriter
    from armbench.drivers.host.arm import Arm
    from armbench.drivers.model.settings import SerialSettings
    from armbench.fakes.links.fake_transport import FakeTransport
    loop = asyncio.get_running_loop()
    transport = FakeTransport("fake://", SerialSettings())
    part = None if capture_dir is None else PartWriter(
        capture_dir + "/x.part", loop.time(), truth=emulator_truth(transport))
    writes = []
    async with Arm.connect("fake://", transport=transport, capture=part) as arm:
        sent = transport.write
        async def write(data):
            writes.append((loop.time() - t0, data.decode("ascii")))
            await sent(data)
        transport.write = write
        t0, k = loop.time(), 0
        while loop.time() - t0 < size:
            await arm.move_joints(POSES[k % 2], 99)
            k += 1
        writes.append((loop.time() - t0, ""))
        print("replies", arm.frames_received)
    if part is not None:
        part.close()
    if writes_path:
        with open(writes_path, "w") as fh:
            json.dump(writes, fh)


async def replay():
    from armbench.drivers.model.settings import SerialSettings
    from armbench.fakes.links.fake_transport import FakeTransport
    with open(writes_path) as fh:
        writes = json.load(fh)
    loop = asyncio.get_running_loop()
    transport = FakeTransport("fake://", SerialSettings())
    await transport.open()
    transport.set_receiver(lambda data: None)
    t0 = loop.time()
    for t_s, text in writes:
        await asyncio.sleep(max(0.0, t0 + t_s - loop.time()))
        if text:
            await transport.write(text.encode("ascii"))
    await transport.close()


if mode == "startup":
    from armbench.bench.campaign import CampaignOptions, run_campaign
    with tempfile.TemporaryDirectory() as out:
        run_campaign(CampaignOptions("startup-recovery", int(size), seed=0, out=out + "/c",
                                     workers=1), progress=None)
elif mode == "bare":
    from armbench.cli.perf.emulator_perf import emulate
    run_virtual(emulate(size, moving=True))
elif mode == "replay":
    run_virtual(replay())
elif mode == "capture":
    with tempfile.TemporaryDirectory() as out:
        run_virtual(moves(out))
else:
    run_virtual(moves(None))
"""


def count(mode: str, size: float, writes: str = "") -> tuple[int, int]:
    """Instructions of one run of workload ``mode`` for ``size`` simulated seconds (trials for
    ``startup``), and the replies the driver received (0 without a driver). ``writes``: the file
    the driver's commands are written to (``driver``) or replayed from (``replay``)."""
    with tempfile.TemporaryDirectory(prefix="armbench-callgrind-") as tmp:
        out = os.path.join(tmp, "callgrind.out")
        done = subprocess.run(
            ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", sys.executable,
             "-c", WORKLOAD, mode, str(size), writes],
            capture_output=True, text=True, env={**os.environ, **FIXED_ENV}, check=False)
    found = re.search(r"Collected : (\d+)", done.stderr)
    if done.returncode != 0 or found is None:
        raise SystemExit(f"callgrind failed on {mode} {size}: {done.stderr[-2000:]}")
    replies = re.search(r"^replies (\d+)$", done.stdout, re.MULTILINE)
    return int(found.group(1)), int(replies.group(1)) if replies else 0


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
    replies = 0
    with tempfile.TemporaryDirectory(prefix="armbench-writes-") as tmp:
        for mode in ("bare", "driver", "replay", "capture"):
            runs = [count(mode, size, os.path.join(tmp, f"{size}.json"))
                    for size in (args.short, args.long)]
            per_s[mode] = (runs[1][0] - runs[0][0]) / span_s
            if mode == "driver":
                replies = runs[1][1] - runs[0][1]
            print(f"instructions.{mode}_per_sim_s  {per_s[mode] / 1e6:10.2f} M/sim s")
    print(f"instructions.driver_per_bare     {per_s['driver'] / per_s['bare']:10.3f} x   "
          f"(the host's share: {(per_s['driver'] - per_s['bare']) / 1e6:.2f} M/sim s)")
    host = (per_s["driver"] - per_s["replay"]) * span_s
    emulator = per_s["replay"] * span_s
    print(f"instructions.host_per_reply    {host / replies:10.0f}     (the emulator's "
          f"{emulator / replies:.0f}, doing the same work: the host {host / emulator:.3f} of it; "
          f"{replies} replies in {span_s:g} sim s)")
    capture = (per_s["capture"] - per_s["driver"]) * span_s
    print(f"instructions.capture_per_reply {capture / replies:10.0f}     (a trial's capture "
          f"part with the truth: {capture / emulator:.3f} of the emulator's)")
    if args.startup is not None:
        a, b = args.startup
        trial = (count("startup", b)[0] - count("startup", a)[0]) / (b - a)
        print(f"instructions.startup_per_trial {trial / 1e6:10.2f} M/trial")
    return 0


if __name__ == "__main__":
    sys.exit(main())
