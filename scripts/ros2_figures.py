"""Measure the ROS 2 node (``docs/ros.md``): ``/joint_states`` received by a subscriber process as
a fraction of the replies the arm sent in the same span, over ``fake://`` on virtual time (with
``/clock``) and over ``armbench emulate --pty`` in real time, and the latency from a reply read by
the driver to the message in the subscriber (p50, p99; real time only, where stamps are wall-clock).

    python scripts/ros2_figures.py [--count 4000] [--domain 42]

The subscriber is :mod:`armbench.frontends.ros2_node.client` ``listen``; prints one JSON object.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
from typing import Any

from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.clock.vclock import run_virtual
from armbench.frontends.ros2_node.node import ArmNode, NodeOptions, PublishingArm


async def _listen(port: str, count: int, clock: bool) -> dict[str, Any]:
    async with PublishingArm(port, RobotSettings()) as arm:
        node = ArmNode(arm, NodeOptions(clock=clock))
        serving = asyncio.ensure_future(node.run())
        try:
            with arm.record_states() as states:
                proc = await asyncio.create_subprocess_exec(
                    sys.executable, "-m", "armbench.frontends.ros2_node.client", "listen",
                    "--count", str(count), "--timeout", "300", stdout=asyncio.subprocess.PIPE)
                out, _ = await proc.communicate()
        finally:
            serving.cancel()
            await asyncio.wait({serving})
    got: dict[str, Any] = json.loads(out.decode().splitlines()[-1])
    got.pop("robot_description", None)
    got.pop("events", None)
    lo, hi = got["first_stamp_s"], got["last_stamp_s"]
    if not clock:  # stamps are wall-clock: back to loop time
        lo -= node.stamp_s(0.0)
        hi -= node.stamp_s(0.0)
    window = [s for s in states if lo - 1e-6 <= s.t_s <= hi + 1e-6]
    got["replies_in_span"] = len(window)
    got["fraction"] = got["count"] / len(window)
    got["reply_rate_hz"] = (len(window) - 1) / (window[-1].t_s - window[0].t_s)
    if clock:
        got.pop("latency_p50_s")
        got.pop("latency_p99_s")
    return got


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--count", type=int, default=4000)
    p.add_argument("--domain", type=int, default=42)
    args = p.parse_args()
    os.environ["ROS_DOMAIN_ID"] = str(args.domain)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    out: dict[str, Any] = {"fake": run_virtual(_listen("fake://", args.count, True))}
    emulator = subprocess.Popen([sys.executable, "-m", "armbench", "emulate", "--pty"],
                                stdout=subprocess.PIPE, text=True)
    try:
        assert emulator.stdout is not None
        line = emulator.stdout.readline()
        device = line.split(" on ", 1)[1].split()[0]
        out["pty"] = asyncio.run(_listen(device, args.count, False))
    finally:
        emulator.terminate()
        emulator.wait()
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
