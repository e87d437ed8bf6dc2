"""``armbench move``: move the arm to joint angles or to a TCP position and print the final state.

``armbench move Q1 Q2 Q3 Q4`` (radians, protocol convention) or ``armbench move --xyz X Y Z``
(metres, base frame, optional ``--roll``). Targets outside the limits, unreachable positions and
timeouts are errors (exit status 2) and nothing is sent for a refused target. Against ``fake://``
the emulator runs in-process on virtual time, starting from its power-up pose.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import re
import sys
from typing import Any

from armbench.cli.commands.bounds import REPLY_TIMEOUT_S, TIMEOUT_S, add_bounded
from armbench.cli.commands.monitor import run_on_port
from armbench.drivers.host.arm import Arm, InvalidTargetError, JointState
from armbench.drivers.host.link import CONNECT_TIMEOUT_S
from armbench.drivers.model.bounds import Bound
from armbench.drivers.model.kinematics import BRANCHES
from armbench.drivers.model.protocol import MAX_DUTY
from armbench.drivers.model.settings import load_settings

__all__ = ["register"]

#: ``--tolerance``: more than a radian off would count a pose far from the target as arrived.
TOLERANCE_RAD = Bound(0.0, 1.0, "rad", low_open=True)
_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|nan)$", re.IGNORECASE)


def register(sub: Any) -> None:
    """Add the ``move`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "move",
        description="Move the arm to four joint angles (radians, protocol convention) or, with "
                    "--xyz, to a TCP position (metres, base frame); print the final state.",
        epilog="Exit status: 0 when arrived, 2 for a refused target, an unreachable position, a "
               "timeout or a lost port.")
    p.add_argument("q", nargs="*", type=float, metavar="Q",
                   help="four joint angles Q1 Q2 Q3 Q4 in radians")
    p.add_argument("--xyz", nargs=3, type=float, metavar=("X", "Y", "Z"),
                   help="TCP target in metres instead of joint angles")
    p.add_argument("--roll", type=float, default=0.0, metavar="R",
                   help="with --xyz: joint-4 roll about the tool axis, radians (default 0)")
    p.add_argument("--branch", choices=BRANCHES, default=None,
                   help="with --xyz: IK branch (default: the one closest to the current state)")
    p.add_argument("--port", default="fake://",
                   help="serial device, socket://HOST:PORT, rfc2217://HOST:PORT or fake:// "
                        "(default fake://, the emulator on virtual time)")
    p.add_argument("--duty", type=int, default=MAX_DUTY, metavar="V",
                   help="PWM duty 1..99 of speed law (12) (default 99, the fastest)")
    p.add_argument("--coordinated", action="store_true",
                   help="slow the joints with shorter ways so that all arrive together")
    add_bounded(p, "--tolerance", TOLERANCE_RAD, default=None, metavar="RAD",
                help="arrival tolerance per joint in radians (default: a few ticks)")
    add_bounded(p, "--timeout", TIMEOUT_S, default=None, metavar="S",
                help="give up after S seconds (default: from the distance and law (12))")
    add_bounded(p, "--reply-timeout", REPLY_TIMEOUT_S, default=0.5, metavar="S",
                help="hold the arm and give up after S s without a reply (default 0.5)")
    add_bounded(p, "--connect-timeout", TIMEOUT_S, default=CONNECT_TIMEOUT_S, metavar="S",
                help=f"wait S s for the arm's first reply (default {CONNECT_TIMEOUT_S:g})")
    p.add_argument("--settings", default=None, metavar="FILE", help="robot settings TOML")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=_run)
    if hasattr(p, "_negative_number_matcher"):  # let "-1e-3" be a positional, as in fk/ik
        p._negative_number_matcher = _NEGATIVE_NUMBER


def _run(args: argparse.Namespace) -> int:
    if args.xyz is None and len(args.q) != 4:
        raise InvalidTargetError(None, "target", args.q,
                                 "needs four joint angles Q1 Q2 Q3 Q4 or --xyz X Y Z")
    if args.xyz is not None and args.q:
        raise InvalidTargetError(None, "target", args.q, "give joint angles or --xyz, not both")
    if args.xyz is None and (args.branch is not None or args.roll != 0.0):
        raise InvalidTargetError(None, "--roll/--branch", args.roll, "only apply with --xyz")
    settings = load_settings(args.settings)
    return run_on_port(args.port, _move(args, settings))


def _describe(arm: Arm, state: JointState) -> dict[str, Any]:
    return {"t_s": state.t_s, "q_rad": list(state.q_rad),
            "q_deg": [math.degrees(q) for q in state.q_rad], "ticks": list(state.ticks),
            "tcp_m": list(state.tcp_m(arm.settings))}


async def _move(args: argparse.Namespace, settings: Any) -> int:
    async with Arm.connect(args.port, settings, reply_timeout_s=args.reply_timeout,
                           connect_timeout_s=args.connect_timeout) as arm:
        loop = asyncio.get_running_loop()
        start = arm.state
        t0 = loop.time()
        if args.xyz is not None:
            final = await arm.move_to(args.xyz, args.roll, branch=args.branch, duty=args.duty,
                                      coordinated=args.coordinated, tolerance_rad=args.tolerance,
                                      timeout_s=args.timeout)
        else:
            final = await arm.move_joints(args.q, args.duty, coordinated=args.coordinated,
                                          tolerance_rad=args.tolerance, timeout_s=args.timeout)
        assert final is not None
        elapsed = loop.time() - t0
        record = {"port": args.port, "elapsed_s": elapsed, "start": _describe(arm, start),
                  "final": _describe(arm, final), "commands_sent": arm.commands_sent,
                  "resends": arm.resends, "frames_dropped": arm.frames_dropped}
        truth = arm.ground_truth()
        if truth is not None:
            record["ground_truth_rad"] = list(truth.true_rad)
    if args.json:
        print(json.dumps(record))
        return 0
    print(f"arrived after {elapsed:.3f} s ({arm.commands_sent} command(s), {arm.resends} resent)")
    for name in ("start", "final"):
        d = record[name]
        q = " ".join(f"{v:+.5f}" for v in d["q_rad"])
        deg = " ".join(f"{v:+8.3f}" for v in d["q_deg"])
        x, y, z = d["tcp_m"]
        print(f"{name:>5s}: q = [{q}] rad = [{deg}]°  TCP = ({x:+.4f}, {y:+.4f}, {z:+.4f}) m")
    if truth is not None:
        print("truth: q = [" + " ".join(f"{v:+.5f}" for v in truth.true_rad) + "] rad "
              "(emulator ground truth)")
    sys.stdout.flush()
    return 0
