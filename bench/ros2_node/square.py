"""The accuracy square through ROS 2 against the driver's own coordinated run, on one arm.

The node serves the arm; first the driver drives the square itself (to the first corner, a
settling pause, then :meth:`~armbench.drivers.arm.Arm.follow_path`, as the accuracy suite's
``coordinated`` style does), then a separate process (:mod:`armbench.bench.ros2_node.client`
``square``) sends the same square as a ``JointTrajectory``, which the node streams. Both laps
are measured the same way: the reply stream from the first path command to the arrival, one
sample per ``sample_period_s``, the reported TCP (forward kinematics) against the closed square by
:func:`armbench.bench.suites.accuracy.path_figures`.
"""

from __future__ import annotations

import asyncio
import json
import math
import os
import sys
from collections.abc import Mapping, Sequence
from typing import Any

from armbench.bench.ros2_node.node import ArmNode, NodeOptions, PublishingArm
from armbench.bench.suites._common import settled_state
from armbench.bench.suites.accuracy import path_figures
from armbench.bench.suites.workspace import DEFAULT_SQUARE_CENTRE_M, DEFAULT_SQUARE_SIDE_M
from armbench.drivers.arm import PathRun
from armbench.drivers.errors import ArmbenchError
from armbench.drivers.settings import RobotSettings
from armbench.metrics import square_yz

__all__ = ["SquareOptions", "compare_square", "run_samples"]


class SquareOptions:
    """The square and how it is driven (the accuracy suite's defaults)."""

    def __init__(self, centre_m: Sequence[float] = DEFAULT_SQUARE_CENTRE_M,
                 side_m: float = DEFAULT_SQUARE_SIDE_M,
                 speed_m_s: float = 0.05, spacing_m: float = 0.005, branch: str = "front-up",
                 sample_period_s: float = 0.01, settle_s: float = 0.2,
                 client_timeout_s: float = 120.0) -> None:
        self.centre_m = tuple(float(c) for c in centre_m)
        self.side_m = float(side_m)
        self.speed_m_s = float(speed_m_s)
        self.spacing_m = float(spacing_m)
        self.branch = branch
        self.sample_period_s = float(sample_period_s)
        self.settle_s = float(settle_s)
        self.client_timeout_s = float(client_timeout_s)


def run_samples(run: PathRun, settings: RobotSettings,
                period_s: float) -> list[dict[str, Any]]:
    """One sample (``reported_m``: FK of the reported joints) per ``period_s`` of ``run``."""
    out: list[dict[str, Any]] = []
    last = -math.inf
    for s in run.states:
        if s.t_s - last + 1e-9 >= period_s:
            out.append({"t_s": s.t_s, "reported_m": list(s.tcp_m(settings))})
            last = s.t_s
    return out


def _client_argv(sq: SquareOptions, settings_file: str | None) -> list[str]:
    argv = [sys.executable, "-m", "armbench.bench.ros2_node.client", "square",
            "--timeout", str(sq.client_timeout_s), "--centre", *map(str, sq.centre_m),
            "--side", str(sq.side_m), "--speed", str(sq.speed_m_s),
            "--spacing", str(sq.spacing_m), "--branch", sq.branch]
    return [*argv, "--settings", settings_file] if settings_file else argv


async def _ros_lap(node: ArmNode, sq: SquareOptions, settings_file: str | None,
                   env: Mapping[str, str] | None) -> dict[str, Any]:
    proc = await asyncio.create_subprocess_exec(
        *_client_argv(sq, settings_file), stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE, env=dict(env) if env is not None else None)
    out, err = await proc.communicate()
    try:
        result: dict[str, Any] = json.loads(out.decode().strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        raise ArmbenchError(f"the ROS client failed (status {proc.returncode}): "
                            f"{err.decode().strip()[-500:]}") from None
    if proc.returncode != 0 or result.get("lap", {}).get("state") != "done":
        raise ArmbenchError(f"the ROS client's square did not complete: {json.dumps(result)}")
    return result


async def compare_square(port: str, settings: RobotSettings, options: NodeOptions,
                         sq: SquareOptions, *, settings_file: str | None = None,
                         reply_timeout_s: float = 0.5, connect_timeout_s: float = 3.0,
                         env: Mapping[str, str] | None = None) -> dict[str, Any]:
    """Drive the square twice on ``port`` (driver, then ROS client) and return both figures
    (mm), ``ratio`` (ROS mean / driver mean) and the client's report."""
    corners = square_yz(sq.centre_m, sq.side_m)
    async with PublishingArm(port, settings, reply_timeout_s=reply_timeout_s,
                             connect_timeout_s=connect_timeout_s) as arm:
        node = ArmNode(arm, options)
        serving = asyncio.ensure_future(node.run())
        try:
            await arm.move_to(corners[0], branch=sq.branch, coordinated=True)
            await settled_state(arm, sq.settle_s)
            node.event("lap_start", by="driver")
            driver = await arm.follow_path([*corners, corners[0]], speed_m_s=sq.speed_m_s,
                                           spacing_m=sq.spacing_m, branch=sq.branch)
            node.event("lap_end", by="driver", duration_s=driver.duration_s)
            node.event("lap_start", by="ros2")
            client = await _ros_lap(node, sq, settings_file, env)
            ros = node.last_run
            assert ros is not None
            node.event("lap_end", by="ros2", duration_s=ros.duration_s)
        finally:
            serving.cancel()
            await asyncio.wait({serving})
    d = path_figures(run_samples(driver, settings, sq.sample_period_s), corners)
    r = path_figures(run_samples(ros, settings, sq.sample_period_s), corners)
    return {"driver": {"mean_mm": d["mean_mm"], "rms_mm": d["rms_mm"], "max_mm": d["max_mm"],
                       "lap_s": driver.duration_s, "waypoints": len(driver.waypoints)},
            "ros": {"mean_mm": r["mean_mm"], "rms_mm": r["rms_mm"], "max_mm": r["max_mm"],
                    "lap_s": ros.duration_s, "waypoints": len(ros.waypoints)},
            "ratio": r["mean_mm"] / d["mean_mm"] if d["mean_mm"] > 0 else math.nan,
            "client": client, "domain_id": os.environ.get("ROS_DOMAIN_ID")}
