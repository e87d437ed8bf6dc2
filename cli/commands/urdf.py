"""``armbench urdf [--settings FILE] [--out FILE]``: the arm as a URDF for RViz and Foxglove.

Built from the DH table, the robot settings (joint limits, link lengths) and the settings' twin
(efforts from its pull-out torques, link masses) by
:func:`armbench.frontends.ros2_node.state_topics.node_urdf`, the URDF ``armbench ros2`` serves on
``/robot_description``; the joint positions are the protocol angles the driver reports on
``/joint_states``. Written to ``--out`` (replaced atomically; an unwritable path is refused before
anything is built, :mod:`armbench.bench.runner.outputs`) or printed.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from armbench.bench.runner.outputs import check_out_files
from armbench.drivers.model.settings import load_settings
from armbench.frontends.ros2_node.state_topics import node_urdf
from armbench.record.files import atomic_write_bytes

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add the ``urdf`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "urdf",
        description="A URDF of the arm from the DH table and the robot settings: revolute "
                    "joints j1..j4 with the settings' limits (protocol angles), the speed of "
                    "the fastest duty by law (12), the efforts of the twin's drives, simple "
                    "link geometry with collision and inertial elements and a <ros2_control> "
                    "block; the origin of link4 is the TCP. The URDF armbench ros2 serves.")
    p.add_argument("--settings", default=None, metavar="FILE",
                   help="robot settings TOML file (default: built-in robot model)")
    p.add_argument("--out", default=None, metavar="FILE", help="write here (default: stdout)")
    p.set_defaults(func=_main)


def _main(args: argparse.Namespace) -> int:
    if args.out is not None:  # an existing URDF is replaced; a run's record file never
        check_out_files("--out", [Path(args.out)], force=True)
    settings = load_settings(args.settings)
    text = node_urdf(settings)
    if args.out is None:
        sys.stdout.write(text)
        return 0
    atomic_write_bytes(args.out, text.encode("utf-8"))
    return 0
