"""``armbench fk`` and ``armbench ik``: forward and inverse kinematics from the command line.

Angles are radians (``fk --deg``: degrees), lengths metres. ``fk`` takes protocol-convention joint
angles (DH angles with ``--dh``) and warns on stderr of an angle outside its joint's limits (90
taken as radians is 14 turns: ``--deg`` was probably meant); ``ik`` prints every solution branch
and whether it is inside the joint limits. Negative
numbers may be given as plain positionals (``armbench fk 0.1 -0.2 0 0``) or after ``--``.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from typing import Any

import numpy as np

from armbench.cli.commands.bounds import add_bounded
from armbench.drivers.model.bounds import Bound
from armbench.drivers.model.kinematics import (
    IKSolution,
    KinematicsError,
    dh_to_protocol,
    fk_dh,
    ik,
    protocol_to_dh,
)
from armbench.drivers.model.settings import RobotSettings, load_settings

__all__ = ["register"]

#: The longest gripper ``--d4`` accepts (m): the tool points out of the flange, and a gripper
#: half as long as the arm itself (about 0.9 m) is already far beyond the RoboLink's payload.
MAX_GRIPPER_OFFSET_M = 0.5

#: What argparse should take for a negative number rather than an option: also ``-1e-3``.
_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|nan)$", re.IGNORECASE)


def _accept_negative_numbers(p: argparse.ArgumentParser) -> None:
    # argparse (3.11) only recognises ``-1`` and ``-0.5`` as negative numbers; widen its matcher
    # so that ``-1e-3`` works as a positional too. No option of these parsers looks like a number.
    if hasattr(p, "_negative_number_matcher"):
        p._negative_number_matcher = _NEGATIVE_NUMBER


def _common(p: argparse.ArgumentParser) -> None:
    add_bounded(p, "--d4", Bound(0.0, MAX_GRIPPER_OFFSET_M, "m"), default=None, metavar="M",
                help="gripper offset d4 in metres (overrides the settings file)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--settings", default=None, metavar="FILE",
                   help="robot settings TOML file (default: built-in robot model)")


def register(sub: Any) -> None:
    """Add the ``fk`` and ``ik`` subcommands."""
    f: argparse.ArgumentParser = sub.add_parser(
        "fk",
        description="Pose of the TCP (frame 4) in the base frame for four joint angles in radians "
                    "(protocol convention, zero = all joints looking up, joint 1 to the front; "
                    "DH angles with --dh). Prints the 4×4 pose and the TCP position in mm and m; "
                    "warns of an angle outside its joint's limits.")
    for n in range(1, 5):
        f.add_argument(f"q{n}", type=float, metavar=f"Q{n}",
                       help=f"joint {n} angle, radians (degrees with --deg)")
    f.add_argument("--dh", action="store_true",
                   help="the angles are DH angles θ1..θ4, not protocol angles")
    f.add_argument("--deg", action="store_true", help="the angles are in degrees")
    _common(f)
    f.set_defaults(func=_run_fk)
    _accept_negative_numbers(f)

    i: argparse.ArgumentParser = sub.add_parser(
        "ik",
        description="Every closed-form solution (front/back × elbow up/down) putting the TCP at "
                    "X Y Z (metres, base frame), with whether it is inside the joint limits. "
                    "Only the roll about the tool axis is free (--roll).",
        epilog="Exit status: 0 if at least one solution is inside the joint limits, 1 if none "
               "is, 2 if the target is unreachable or an argument is invalid.")
    for axis in "xyz":
        i.add_argument(axis, type=float, metavar=axis.upper(),
                       help=f"target {axis} in metres, base frame")
    i.add_argument("--roll", type=float, default=0.0, metavar="R",
                   help="joint-4 angle (roll about the tool axis), radians, protocol convention "
                        "(also with --dh); default 0")
    i.add_argument("--dh", action="store_true",
                   help="print DH angles θ1..θ4 instead of protocol angles")
    _common(i)
    i.set_defaults(func=_run_ik)
    _accept_negative_numbers(i)


def _settings(args: argparse.Namespace) -> RobotSettings:
    settings = load_settings(args.settings)
    if args.d4 is not None:
        settings = settings.with_d4(args.d4)
    return settings


def _vec(values: Any, width: int = 10, digits: int = 6) -> str:
    return "[" + ", ".join(f"{float(v):+{width}.{digits}f}" for v in values) + "]"


def _run_fk(args: argparse.Namespace) -> int:
    settings = _settings(args)
    given = [float(args.q1), float(args.q2), float(args.q3), float(args.q4)]
    if not all(math.isfinite(v) for v in given):
        raise KinematicsError(f"joint angles must be finite, got {given}")
    if args.deg:
        given = [math.radians(v) for v in given]
    if args.dh:
        theta = np.asarray(given)
        q = dh_to_protocol(theta, settings)
    else:
        q = np.asarray(given)
        theta = protocol_to_dh(q, settings)
    pose = fk_dh(theta, settings.geometry)
    tcp_m = pose[:3, 3]
    outside = _outside_limits(q, settings, args.deg)
    for line in outside:
        print(f"armbench fk: warning: {line}", file=sys.stderr)
    if args.json:
        print(json.dumps({
            "convention": "dh" if args.dh else "protocol",
            "q_protocol_rad": q.tolist(),
            "theta_dh_rad": theta.tolist(),
            "d4_m": settings.geometry.d4_m,
            "pose": pose.tolist(),
            "tcp_m": tcp_m.tolist(),
            "tcp_mm": (tcp_m * 1000.0).tolist(),
            "within_limits": not outside,
        }))
        return 0
    print(f"joint angles, protocol (rad): {_vec(q)}")
    print(f"joint angles, DH θ     (rad): {_vec(theta)}")
    print(f"gripper offset d4: {settings.geometry.d4_m:g} m")
    print("pose T (base frame, translation in m):")
    for row in pose:
        print("  " + _vec(row, width=13, digits=9))
    x, y, z = (float(v) for v in tcp_m)
    print(f"TCP: x = {x * 1e3:.3f} mm, y = {y * 1e3:.3f} mm, z = {z * 1e3:.3f} mm   "
          f"({x:.9f}, {y:.9f}, {z:.9f}) m")
    return 0


def _outside_limits(q: Any, settings: RobotSettings, deg: bool) -> list[str]:
    """A line per protocol angle of ``q`` (rad) outside its joint's limits."""
    lines = []
    for n, (value, low, high) in enumerate(zip(q, settings.lower_rad, settings.upper_rad,
                                               strict=True), start=1):
        if low <= value <= high:
            continue
        hint = ("" if deg or abs(value) <= 2 * math.pi
                else "; angles are radians: was --deg meant?")
        lines.append(f"joint {n} at {float(value):.6g} rad ({math.degrees(value):.6g}°) is "
                     f"outside its limits {math.degrees(low):g}..{math.degrees(high):g}°{hint}")
    return lines


def _solution_json(s: IKSolution) -> dict[str, Any]:
    return {
        "branch": s.branch,
        "aliases": list(s.aliases),
        "q_protocol_rad": list(s.q_protocol),
        "theta_dh_rad": list(s.theta_dh),
        "within_limits": s.within_limits,
        "violations": [{"joint": v.joint, "value_rad": v.value_rad, "limit_rad": v.limit_rad,
                        "bound": v.bound} for v in s.limit_violations],
    }


def _run_ik(args: argparse.Namespace) -> int:
    settings = _settings(args)
    target = [float(args.x), float(args.y), float(args.z)]
    solutions = ik(target, settings, roll=args.roll)
    any_ok = any(s.within_limits for s in solutions)
    if args.json:
        print(json.dumps({
            "target_m": target,
            "roll_rad": args.roll,
            "d4_m": settings.geometry.d4_m,
            "convention": "dh" if args.dh else "protocol",
            "solutions": [_solution_json(s) for s in solutions],
        }))
        return 0 if any_ok else 1
    x, y, z = target
    conv = "DH θ1..θ4" if args.dh else "protocol q1..q4"
    print(f"target ({x:.6f}, {y:.6f}, {z:.6f}) m, roll {args.roll:g} rad, "
          f"d4 {settings.geometry.d4_m:g} m: {len(solutions)} solution(s), {conv} in rad")
    for s in solutions:
        angles = s.theta_dh if args.dh else s.q_protocol
        status = ("within limits" if s.within_limits
                  else "OUT OF LIMITS: " + "; ".join(str(v) for v in s.limit_violations))
        print(f"  {s.branch:<10s} {_vec(angles)}  {status}")
        if s.aliases:
            print(f"  {'':<10s} (coincides with {', '.join(s.aliases)})")
    if not any_ok:
        print("no solution is inside the joint limits")
    return 0 if any_ok else 1
