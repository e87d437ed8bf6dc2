"""The accuracy square through ROS 2 (``armbench run ros2-square``; needs ``armbench[ros2]``).

A lab tests its ROS path and compares it with the driver's own: each lap is driven in two styles,
one trial each, alternating as the accuracy suite's styles do:

* ``coordinated`` — the driver itself, exactly the accuracy suite's coordinated style
  (``follow_path`` along the closed square at ``speed_m_s``, waypoints ``spacing_m`` apart);
* ``trajectory`` — the same waypoints and segment times, planned as ``follow_path`` plans them
  (:func:`armbench.frontends.ros2_node.client.square_trajectory`), sent as one
  ``control_msgs/action/FollowJointTrajectory`` goal by a separate rclpy process with a plain
  ``ActionClient`` (``python -m armbench.frontends.ros2_node.action_client``) to an armbench ROS 2
  node (:class:`~armbench.frontends.ros2_node.node.ArmNode`) serving the trial's arm, which
  streams it (the default tolerances: a lap the arm does not follow is refused by the action).

Both laps start the same way (the driver moves to the first corner, waits ``settle_s``) and are
measured the same way: the reply stream sampled every ``sample_period_s`` with the accuracy
suite's recorder (reported TCP, true TCP with truth), kept from the lap's first path command to
its arrival (times from that command), errors against the closed square with the accuracy suite's
figures. Names: ``ros2.<style>.<figure>`` with the accuracy suite's figure names, and
``ros2.path_error_ratio`` = trajectory mean / coordinated mean. Each ROS lap has a node of its own
in a namespace of its own, so trials measured at once do not hear each other; on virtual time the
node publishes ``/clock``. See ``docs/suites.md`` and ``docs/ros.md``.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import os
import sys
import tempfile
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Final

from armbench.bench.suites._common import (
    Measurements,
    StateRecorder,
    TrialAborted,
    guarded_trial,
    loop_time,
)
from armbench.bench.suites.accuracy import (  # the accuracy suite's figures, by design
    add_square_figures,
    approach_square,
    check_square,
    path_figures,
    plan_laps,
    summarize_styles,
)
from armbench.bench.suites.base import Suite, SuiteContext
from armbench.bench.suites.ros2_square_contract import ROS2_SQUARE
from armbench.bench.suites.workspace import DEFAULT_SQUARE_CENTRE_M, DEFAULT_SQUARE_SIDE_M
from armbench.drivers.host.paths import PathRun
from armbench.drivers.model.bounds import Bound, check, check_whole
from armbench.drivers.model.protocol import MAX_DUTY
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.clock.vclock import VirtualTimeLoop
from armbench.frontends.ros2_node import require_rclpy
from armbench.metrics import square_yz
from armbench.record import Measurement, Trial

__all__ = ["STYLES", "Ros2SquareSuite"]

#: The two ways a lap is driven, in the order they alternate.
STYLES: Final = ROS2_SQUARE.styles
N = ROS2_SQUARE
#: Virtual seconds a trial may see pass per real second of its client process (the emulator
#: alone runs a few hundred times real time): the trial's overall guard on virtual time.
VIRTUAL_PER_REAL: Final = 1000.0


def _lap_window(samples: list[dict[str, Any]], t0: float, run: PathRun) -> None:
    """Keep (in place) the samples from the run's first path command to its arrival, their times
    from that command."""
    start, end = run.t_start_s - t0, run.t_end_s - t0
    kept = [{**s, "t_s": round(s["t_s"] - start, 6)} for s in samples
            if start - 1e-9 <= s["t_s"] <= end + 1e-9]
    samples[:] = kept


class Ros2SquareSuite(Suite):
    """The square through ROS 2 against the driver's own coordinated run (see module doc)."""

    name = N.suite
    version = "1"
    metric_units: ClassVar[Mapping[str, str]] = {
        "ros2.*_mm": "mm", "ros2.*.lap_time_s": "s", "ros2.*.laps": "", "ros2.*_ratio": ""}

    def default_params(self, settings: RobotSettings) -> dict[str, Any]:
        """The accuracy suite's square and streaming; 3 laps per style."""
        return {
            N.centre: list(DEFAULT_SQUARE_CENTRE_M),
            N.side: DEFAULT_SQUARE_SIDE_M,
            "speed_m_s": 0.05,
            "spacing_m": 0.005,
            "laps": 3,
            "sample_period_s": 0.01,
            "settle_s": 0.2,
            "approach_duty": MAX_DUTY,
            "branch": "front-up",
            "roll_rad": 0.0,
            "styles": list(STYLES),
            "domain_id": -1,
            "client_timeout_s": 120.0,
            # the goals' path tolerance (each joint): the lap's path errors are the suite's
            # figures, not a reason to end it; this only stops a lap the arm does not follow at
            # all (a stall). Looser than the action's default, so that a host starved for a
            # moment in real time still gives a lap to measure; a shared host may need more.
            "path_tolerance_rad": 0.3,
            # the goal's goal_time_tolerance: 0 leaves the node the driver's own slack for a
            # move of the lap's length; a host starved for seconds in real time needs more
            "goal_time_tolerance_s": 0.0,
        }

    def validate(self, settings: RobotSettings, params: Mapping[str, Any]) -> None:
        """The extra and the message support first (one line, or a first build, before anything
        moves), then the accuracy suite's checks, ``domain_id`` (-1: ``ROS_DOMAIN_ID`` of the
        environment) and the client's time guard."""
        require_rclpy()
        from armbench.frontends.ros2_node.msgs_build import ensure_messages

        ensure_messages()  # the action's messages: a first build before anything moves
        where = f"suites.{self.name}"
        check_whole(f"{where}.domain_id", params["domain_id"], Bound(-1, 232))
        check(f"{where}.client_timeout_s", params["client_timeout_s"], Bound(1.0, 3600.0, "s"))
        check(f"{where}.path_tolerance_rad", params["path_tolerance_rad"],
              Bound(0.0, 2 * math.pi, "rad", low_open=True))
        check(f"{where}.goal_time_tolerance_s", params["goal_time_tolerance_s"],
              Bound(0.0, 3600.0, "s"))
        check_square(where, settings, params, STYLES)

    def metric_names(self, params: Mapping[str, Any]) -> frozenset[str]:
        """The figures of each style driven, and the path error ratios when both are."""
        return N.metric_names(params["styles"])

    def plan(self, params: Mapping[str, Any]) -> list[dict[str, Any]]:
        """One trial per (lap, style): lap 0 coordinated, lap 0 trajectory, lap 1 ..."""
        return plan_laps(params)

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        """Drive one lap in ``trial_params["style"]`` and measure its path errors."""
        p = ctx.params
        style = str(trial_params[N.style])
        corners = square_yz(p[N.centre], float(p[N.side]))
        lap_s = 4.0 * float(p[N.side]) / float(p["speed_m_s"])
        # loop seconds: on virtual time they run on while the client process starts (real
        # seconds, bounded by client_timeout_s), many times faster than real time
        client_s = float(p["client_timeout_s"]) * (
            VIRTUAL_PER_REAL if isinstance(asyncio.get_running_loop(), VirtualTimeLoop) else 1.0)
        timeout_s = 120.0 + 4.0 * lap_s + (client_s if style == N.trajectory else 0.0)
        ctx.progress(f"{N.suite}: lap {trial_params[N.lap]} ({style})")

        async def body(samples: list[dict[str, Any]]) -> tuple[list[dict[str, Any]],
                                                               list[Measurement]]:
            arm = ctx.arm
            branch, roll = str(p["branch"]), float(p["roll_rad"])
            await approach_square(arm, corners, p)
            t0 = loop_time()
            async with StateRecorder(ctx, t0, float(p["sample_period_s"]), into=samples):
                if style == N.coordinated:
                    run = await arm.follow_path([*corners, corners[0]],
                                                speed_m_s=float(p["speed_m_s"]),
                                                spacing_m=float(p["spacing_m"]), branch=branch,
                                                roll_rad=roll)
                else:
                    run = await _ros_lap(ctx, p, index)
            _lap_window(samples, t0, run)
            ms = Measurements(ctx)
            add_square_figures(ms, N.metric, style, path_figures(samples, corners))
            ms.add(N.metric(style, N.lap_time), run.duration_s, "s", undirected=True,
                   description="time from the first path command to the arrival at the start")
            return samples, ms.items

        return await guarded_trial(ctx, index, trial_params, body, timeout_s=timeout_s)

    def summarize(self, ctx: SuiteContext, trials: Sequence[Trial]) -> list[Measurement]:
        """Per style, the figures over the samples of all its done laps pooled; the ratio
        trajectory mean / coordinated mean (reported and true)."""
        p = ctx.params
        corners = square_yz(p[N.centre], float(p[N.side]))
        ms = Measurements(ctx)
        figures = summarize_styles(ms, N, STYLES, trials, corners)
        ros, own = figures.get(N.trajectory, {}), figures.get(N.coordinated, {})
        for key, name in ((N.mean, N.ratio), (N.true_mean, N.true_ratio)):
            if key in ros and own.get(key, 0.0) > 0.0:
                ms.add(name, ros[key] / own[key], "", better="lower",
                       description=f"{key} through ROS 2 / {key} of the driver's own run")
        return ms.items


async def _ros_lap(ctx: SuiteContext, p: Mapping[str, Any], index: int) -> PathRun:
    """The lap through ROS 2: a node over ``ctx.arm`` (a namespace of its own), the square sent
    as a ``FollowJointTrajectory`` goal by a client process; the node's run of it."""
    from armbench.frontends.ros2_node.client import square_trajectory
    from armbench.frontends.ros2_node.node import ArmNode, NodeOptions

    arm = ctx.arm
    domain = int(p["domain_id"])
    namespace = f"/armbench_ros2_square_{os.getpid()}_{index}"
    virtual = isinstance(asyncio.get_running_loop(), VirtualTimeLoop)
    qs, times = square_trajectory(ctx.settings, arm.state.q_rad, p[N.centre], float(p[N.side]),
                                  float(p["speed_m_s"]), float(p["spacing_m"]), str(p["branch"]),
                                  roll_rad=float(p["roll_rad"]))
    names = [j.name for j in ctx.settings.joints]
    path_rad = float(p["path_tolerance_rad"])
    trajectory = {"names": names, "points": qs[1:], "times_s": times[1:],  # qs[0]: the first
                  "path_tolerance": dict.fromkeys(names, path_rad),  # corner, the arm
                  "goal_time_tolerance_s": float(p["goal_time_tolerance_s"])}
    env = dict(os.environ)
    if domain >= 0:
        env["ROS_DOMAIN_ID"] = str(domain)
    # drop: the clock never waits for ROS here (the client reads /joint_states for the arm's
    # position only), so a client that leaves before the graph notices costs the lap nothing
    node = ArmNode(arm, NodeOptions(namespace=namespace, clock=virtual, slow_subscriber="drop",
                                    domain_id=domain if domain >= 0 else None))
    serving = asyncio.ensure_future(node.run())
    with tempfile.TemporaryDirectory(prefix="armbench-ros2-") as tmp:
        path = os.path.join(tmp, "square.json")
        with open(path, "w", encoding="utf-8") as f:
            json.dump(trajectory, f)
        try:
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "armbench.frontends.ros2_node.action_client",
                "--goal-file", path, "--namespace", namespace,
                "--timeout", str(float(p["client_timeout_s"])), stdout=asyncio.subprocess.PIPE,
                stderr=asyncio.subprocess.PIPE, env=env)
            try:
                out, err = await proc.communicate()
            finally:
                if proc.returncode is None:
                    with contextlib.suppress(ProcessLookupError):
                        proc.kill()
                    await proc.wait()
        finally:
            serving.cancel()
            await asyncio.wait({serving})
    try:
        result: dict[str, Any] = json.loads(out.decode().strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        raise TrialAborted(f"the ROS client failed (status {proc.returncode}): "
                           f"{err.decode(errors='replace').strip()[-300:]}") from None
    if result.get("status") != "SUCCEEDED" or node.last_run is None:
        raise TrialAborted(f"the square through ROS 2 did not complete: "
                           f"{json.dumps(result)[:300]}")
    return node.last_run
