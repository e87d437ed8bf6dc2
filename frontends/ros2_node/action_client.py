"""A plain rclpy ``ActionClient`` of the node's ``FollowJointTrajectory`` server, run as a process
of its own: ``python -m armbench.frontends.ros2_node.action_client --goal JSON ...``; prints one
JSON object on stdout.

A goal is JSON: ``{"names": [...], "points": [[q...]...], "times_s": [...]}`` and optionally
``"path_tolerance"`` / ``"goal_tolerance"`` (``{joint: rad}``), ``"goal_time_tolerance_s"`` and
``"stamp_s"`` (``header.stamp``). Given once, the goal is sent and its result reported; given
again, each next goal is sent once the previous one has sent feedback (it is under way), and the
result of each is reported (preemption). ``--cancel-after N`` cancels the (last) goal after its
N-th feedback and reports the cancel's answer. Each result: ``status`` (``SUCCEEDED``,
``ABORTED``, ``CANCELED``), ``error_code``, ``error_string``, the feedback received (count, first
and last) and the real seconds from sending to the result. ``--controller`` and ``--namespace``
name the server (``/<namespace>/<controller>/follow_joint_trajectory``). Every wait is bounded by
``--timeout`` (real seconds), a guard against a hung graph only. The message support comes from
the cache (:mod:`.msgs_build`), built first if absent.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

from armbench.frontends.ros2_node.follow_action import ACTION, DEFAULT_CONTROLLER
from armbench.frontends.ros2_node.msgs_build import ensure_messages

__all__ = ["goal_message", "main"]

_STATUS = {4: "SUCCEEDED", 5: "CANCELED", 6: "ABORTED"}


class Timeout(Exception):
    """A bounded wait of the client ran out."""


def _duration(msg: Any, t_s: float) -> None:
    ns = max(0, round(float(t_s) * 1e9))
    msg.sec, msg.nanosec = divmod(ns, 1_000_000_000)


def goal_message(goal: dict[str, Any]) -> Any:
    """A ``FollowJointTrajectory.Goal`` of the JSON goal (see the module doc)."""
    from control_msgs.action import FollowJointTrajectory
    from control_msgs.msg import JointTolerance
    from trajectory_msgs.msg import JointTrajectoryPoint

    msg = FollowJointTrajectory.Goal()
    msg.trajectory.joint_names = list(goal["names"])
    _duration(msg.trajectory.header.stamp, goal.get("stamp_s", 0.0))
    for q, t in zip(goal["points"], goal["times_s"], strict=True):
        p = JointTrajectoryPoint()
        p.positions = [float(v) for v in q]
        _duration(p.time_from_start, t)
        msg.trajectory.points.append(p)
    for field in ("path_tolerance", "goal_tolerance"):
        setattr(msg, field, [JointTolerance(name=name, position=float(v))
                             for name, v in goal.get(field, {}).items()])
    _duration(msg.goal_time_tolerance, goal.get("goal_time_tolerance_s", 0.0))
    return msg


def _spin_until(executor: Any, done: Callable[[], bool], deadline: float, what: str) -> None:
    while not done():
        if time.monotonic() > deadline:
            raise Timeout(f"timed out waiting for {what}")
        executor.spin_once(timeout_sec=0.05)


def _point(p: Any) -> dict[str, list[float]]:
    return {"positions": list(p.positions), "velocities": list(p.velocities)}


class Goal:
    """One goal sent: its feedback and its result as they come."""

    def __init__(self, client: Any, message: Any) -> None:
        self.feedback: list[dict[str, Any]] = []
        self.t0 = time.monotonic()
        self.sent = client.send_goal_async(message, feedback_callback=self._on_feedback)
        self.result: Any = None
        self.result_s: float | None = None

    def _on_feedback(self, msg: Any) -> None:
        f = msg.feedback
        self.feedback.append({"index": int(f.index), "joint_names": list(f.joint_names),
                              "desired": _point(f.desired), "actual": _point(f.actual),
                              "error": _point(f.error)})

    def under_way(self) -> bool:
        """Whether the goal has sent feedback (or ended: refused, or at once)."""
        return bool(self.feedback) or self.ended()

    def ended(self) -> bool:
        """Whether its result has come (or the server did not accept it)."""
        return self.result is not None or (self.sent.done() and not self.handle().accepted)

    def handle(self) -> Any:
        """The goal's handle (once the server answered)."""
        return self.sent.result()

    def ask_result(self) -> None:
        """Ask for the result (once accepted)."""
        future = self.handle().get_result_async()
        future.add_done_callback(self._on_result)

    def _on_result(self, future: Any) -> None:
        self.result = future.result()
        self.result_s = time.monotonic() - self.t0

    def report(self) -> dict[str, Any]:
        """The goal's result and feedback (see the module doc)."""
        r = self.result
        return {"accepted": bool(self.handle().accepted),
                "status": _STATUS.get(int(r.status), str(r.status)),
                "error_code": int(r.result.error_code), "error_string": r.result.error_string,
                "feedback": len(self.feedback),
                "first_feedback": self.feedback[0] if self.feedback else None,
                "last_feedback": self.feedback[-1] if self.feedback else None,
                "result_s": self.result_s}


def follow(node: Any, goals: Sequence[dict[str, Any]], cancel_after: int, deadline: float,
           name: str) -> dict[str, Any]:
    """Send the goals (see the module doc); the report of each, and of the cancel."""
    from control_msgs.action import FollowJointTrajectory
    from rclpy.action import ActionClient
    from rclpy.executors import SingleThreadedExecutor

    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    client = ActionClient(node, FollowJointTrajectory, name)
    _spin_until(executor, client.server_is_ready, deadline, f"the action server {name}")
    sent: list[Goal] = []
    for k, goal in enumerate(goals):
        g = Goal(client, goal_message(goal))
        sent.append(g)
        _spin_until(executor, g.sent.done, deadline, f"the answer to goal {k + 1}")
        if g.handle().accepted:
            g.ask_result()
        if k < len(goals) - 1:  # the next once this one is under way
            _spin_until(executor, g.under_way, deadline, f"feedback of goal {k + 1}")
    out: dict[str, Any] = {}
    last = sent[-1]
    if cancel_after:
        _spin_until(executor, lambda: len(last.feedback) >= cancel_after
                    or last.result is not None, deadline, f"{cancel_after} feedback messages")
        t = time.monotonic()
        answer = last.handle().cancel_goal_async()
        _spin_until(executor, answer.done, deadline, "the answer to the cancel")
        out["cancel"] = {"goals_canceling": len(answer.result().goals_canceling),
                         "answer_s": time.monotonic() - t, "feedback_before": len(last.feedback)}
    for k, g in enumerate(sent):
        _spin_until(executor, g.ended, deadline, f"the result of goal {k + 1}")
    reports = [g.report() for g in sent]
    if cancel_after:
        out["cancel"]["feedback_after"] = last.report()["feedback"] - out["cancel"][
            "feedback_before"]
    client.destroy()
    executor.shutdown()
    return {**out, **reports[-1], "results": reports}


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m armbench.frontends.ros2_node.action_client")
    p.add_argument("--goal", action="append", default=[], help="a goal as JSON (module doc)")
    p.add_argument("--goal-file", action="append", default=[], metavar="FILE",
                   help="a goal as a JSON file (after those of --goal)")
    p.add_argument("--cancel-after", type=int, default=0, metavar="N",
                   help="cancel the last goal after its N-th feedback")
    p.add_argument("--controller", default=DEFAULT_CONTROLLER)
    p.add_argument("--namespace", default="", help="the node's namespace")
    p.add_argument("--timeout", type=float, default=60.0, help="real seconds, a hang guard")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Send the goals; 0 and the JSON report, or 1 and ``{"error": ...}``."""
    args = _parser().parse_args(argv)
    goals = [json.loads(g) for g in args.goal]
    for name in args.goal_file:
        with open(name, encoding="utf-8") as f:
            goals.append(json.load(f))
    if not goals:
        raise SystemExit("give --goal JSON or --goal-file FILE")
    deadline = time.monotonic() + args.timeout
    ensure_messages()
    import os

    import rclpy

    rclpy.init()
    node = rclpy.create_node(f"armbench_action_client_{os.getpid()}",
                             namespace=args.namespace or None)
    try:
        out = follow(node, goals, args.cancel_after, deadline, f"{args.controller}/{ACTION}")
    except Timeout as exc:
        print(json.dumps({"error": str(exc)}))
        return 1
    finally:
        node.destroy_node()
        rclpy.shutdown()
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
