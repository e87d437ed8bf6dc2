"""A ROS 2 client of the node, run as a process of its own: ``python -m
armbench.frontends.ros2_node.client MODE ...``; prints one JSON object on stdout.

Modes:

* ``listen --count N``: subscribe ``/joint_states``, ``/clock``, ``/robot_description`` and
  ``/armbench/events`` until N joint states arrived; report the count, the first and last stamps,
  the rate per stamp second, the latency of each message (receive wall time − stamp; in real
  time only the node stamps with wall-clock time) as p50/p99, and the client node's clock at the
  end (``--sim-time``: ``use_sim_time``, so the time of ``/clock``).
* ``send --trajectory JSON`` (or ``--trajectory-file FILE``): publish one ``JointTrajectory``
  (``{"names": [...], "points": [[q...]...], "times_s": [...]}``) and report the node's final
  status for it; given several times, each next one as soon as the previous one is under way,
  and the final status of each; ``seen``: the goals seen on ``/armbench/commanded``
  (``--no-commanded``: not waited for; ``--no-states``: ``/joint_states`` not subscribed) and
  the kinds of the events (``--wait-event KIND`` waits
  for one too: topics are not ordered with each other).
* ``idle``: subscribe ``/joint_states`` (reliable, ``KEEP_ALL``) and never take a message: a
  subscriber that stopped reading. Prints ``{"subscribed": true}`` once the node's publisher is
  matched, then stays until ``--timeout``.
* ``square``: the accuracy square as the driver plans it
(:func:`armbench.drivers.host.paths.plan_path`,
  segment times of :func:`armbench.drivers.host.motion.segment_duties` at ``--speed``), sent as two
  trajectories: to the first corner, then the lap; report both statuses.
* ``flood --count N``: with ``--twice`` a trajectory to a pose, waited for, and the same again
  (the arm is there already; the two statuses on a line of their own); then N trajectories back
  to back (``--window W``: at most W of them without a status yet) with ``header.stamp`` zero,
  every ``--same-every``-th to where the arm is (its newest ``/joint_states``), the others small
  moves; then wait for each one's final status, matched by its source (this client's publisher
  GID and sequence number), and for ``--settle`` more ``/joint_states``. Reports the final
  states counted, the trajectories with none (``missing``) or several (``duplicates``), and the
  two first statuses.

A sender matches a status to its trajectory by ``source`` (its publisher's GID and the
trajectory's publication sequence number, a range for a lost one), or by ``header.stamp`` where the
middleware gives no source (``send`` and ``square`` stamp each trajectory with the process id and
its number).

``--namespace NS``: the node's namespace. Every wait is bounded by ``--timeout`` (real
seconds), a guard against a hung graph only.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from armbench.bench.suites.workspace import DEFAULT_SQUARE_CENTRE_M, DEFAULT_SQUARE_SIDE_M
from armbench.drivers.host.motion import joint_times_s, segment_duties
from armbench.drivers.host.paths import plan_path
from armbench.drivers.model.protocol import MAX_DUTY
from armbench.drivers.model.settings import RobotSettings, load_settings
from armbench.frontends.ros2_node.node import FINAL, STATUS_DEPTH, TOPICS
from armbench.metrics import square_yz

if TYPE_CHECKING:  # rclpy and the messages are imported where used: the module imports without
    from rclpy.executors import Executor  # the extra
    from rclpy.node import Node

__all__ = ["main", "square_trajectory"]

#: Time given to the approach to the first corner, on top of what duty 99 needs.
APPROACH_MARGIN = 1.5


class Timeout(Exception):
    """A bounded wait of the client ran out."""


def _executor(node: Node) -> Executor:
    """rclpy's events executor (C++: takes a message with no wait set built per message, so a
    Python subscriber keeps up with far more messages per second), else the single-threaded."""
    from rclpy.executors import SingleThreadedExecutor

    try:
        from rclpy.experimental.events_executor import EventsExecutor

        ex = EventsExecutor(context=node.context)
    except ImportError:
        ex = SingleThreadedExecutor(context=node.context)
    ex.add_node(node)
    return ex


_EXECUTORS: dict[int, Executor] = {}


def _executor_of(node: Node) -> Executor:
    return _EXECUTORS.get(id(node)) or _EXECUTORS.setdefault(id(node), _executor(node))


def _spin_until(node: Node, done: Callable[[], bool], deadline: float, what: str) -> None:
    ex = _executor_of(node)
    while not done():
        if time.monotonic() > deadline:
            raise Timeout(f"timed out waiting for {what}")
        ex.spin_once(timeout_sec=0.05)


def _stamp_s(stamp: Any) -> float:
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def listen(node: Node, count: int, deadline: float) -> dict[str, Any]:
    """``listen`` mode (see the module doc)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState as JointStateMsg
    from std_msgs.msg import String

    stamps: list[float] = []
    received: list[float] = []
    clocks: list[float] = []
    urdf: list[str] = []
    events: list[dict[str, Any]] = []

    def on_js(msg: Any) -> None:
        received.append(time.time())
        stamps.append(_stamp_s(msg.header.stamp))

    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    # every message kept until taken: a subscriber slower than the stream for a while (virtual
    # time, a loaded host) catches up instead of losing the oldest
    every = QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL)
    node.create_subscription(JointStateMsg, TOPICS["joint_states"], on_js, every)
    node.create_subscription(Clock, TOPICS["clock"],
                             lambda m: clocks.append(_stamp_s(m.clock)), 1000)
    node.create_subscription(String, TOPICS["robot_description"],
                             lambda m: urdf.append(str(m.data)), latched)
    node.create_subscription(String, TOPICS["events"],
                             lambda m: events.append(json.loads(m.data)), 50)
    _spin_until(node, lambda: len(stamps) >= count and bool(urdf), deadline,
                f"{count} joint states and the robot description")
    node_now_s = node.get_clock().now().nanoseconds * 1e-9  # /clock's time with use_sim_time
    span = stamps[-1] - stamps[0]
    lat = np.array(received) - np.array(stamps)
    return {"count": len(stamps), "first_stamp_s": stamps[0], "last_stamp_s": stamps[-1],
            "rate_hz": (len(stamps) - 1) / span if span > 0 else 0.0,
            "stamps_in_order": bool(np.all(np.diff(stamps) >= 0)),
            "latency_p50_s": float(np.percentile(lat, 50)),
            "latency_p99_s": float(np.percentile(lat, 99)),
            "clocks": len(clocks), "clock_last_s": clocks[-1] if clocks else None,
            "node_now_s": node_now_s,
            "robot_description": urdf[0], "events": events}


def idle(node: Node, deadline: float) -> dict[str, Any]:
    """``idle`` mode (see the module doc): no executor ever spins, so no message is taken."""
    from rclpy.qos import HistoryPolicy, QoSProfile
    from sensor_msgs.msg import JointState as JointStateMsg

    sub = node.create_subscription(JointStateMsg, TOPICS["joint_states"], lambda m: None,
                                   QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL))
    while sub.get_publisher_count() == 0:
        if time.monotonic() > deadline:
            raise Timeout("timed out waiting for the node's /joint_states")
        time.sleep(0.05)
    print(json.dumps({"subscribed": True}), flush=True)
    time.sleep(max(0.0, deadline - time.monotonic()))
    return {"subscribed": True, "taken": 0}


class Sender:
    """Publishes trajectories and waits for the node's final status of each. With ``states``
    it follows ``/joint_states`` (the arm's position, :attr:`q_rad`) and is ready once it has one;
    without, it never subscribes the stream (on virtual time the node publishes it as fast as the
    emulator runs, which a client on a loaded host need not take in) and is ready once matched."""

    def __init__(self, node: Node, deadline: float, *, states: bool = True) -> None:
        from rclpy.qos import DurabilityPolicy, QoSProfile
        from sensor_msgs.msg import JointState as JointStateMsg
        from std_msgs.msg import String
        from trajectory_msgs.msg import JointTrajectory

        self.node = node
        self.deadline = deadline
        self.statuses: list[dict[str, Any]] = []
        self.q_rad: list[float] | None = None
        self.states = 0
        """``/joint_states`` messages taken."""
        self.tag = os.getpid() % 2**31
        """Our trajectories' ``header.stamp.sec`` (the node echoes it in their statuses)."""
        self.pub = node.create_publisher(JointTrajectory, TOPICS["trajectory"], 10)
        # transient local, as the node's: a status published before the node's writer has
        # matched this reader (discovery is not symmetric in time) is still received
        self.sub = node.create_subscription(String, TOPICS["status"], self._on_status, QoSProfile(
            depth=STATUS_DEPTH, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        if states:  # the newest only: on virtual time the stream comes far faster than needed
            node.create_subscription(JointStateMsg, TOPICS["joint_states"], self._on_state, 1)
        self.commanded: list[list[float]] = []
        """Goals seen on ``/armbench/commanded``."""
        self.events: list[str] = []
        """Kinds of the events seen on ``/armbench/events``."""
        node.create_subscription(JointStateMsg, TOPICS["commanded"],
                                 lambda m: self.commanded.append(list(m.position)), 100)
        node.create_subscription(String, TOPICS["events"],
                                 lambda m: self.events.append(json.loads(m.data)["kind"]), 50)
        _spin_until(node, lambda: (self.pub.get_subscription_count() > 0
                                   and self.sub.get_publisher_count() > 0
                                   and (self.q_rad is not None or not states)), deadline,
                    "the armbench node")
        self._n = 0
        self.gid = next((bytes(i.endpoint_gid).hex()
                         for i in node.get_publishers_info_by_topic(self.pub.topic_name)
                         if (i.node_name, i.node_namespace)
                         == (node.get_name(), node.get_namespace())), None)
        """This client's publisher's GID (hex), as the node's statuses give it in ``source``."""

    def _on_status(self, msg: Any) -> None:
        self.statuses.append(json.loads(msg.data))

    def _on_state(self, msg: Any) -> None:
        self.q_rad = [float(v) for v in msg.position]
        self.states += 1

    def send(self, names: Sequence[str], points: Sequence[Sequence[float]],
             times_s: Sequence[float], *, until: Sequence[str] = FINAL) -> dict[str, Any]:
        """Publish one trajectory; its first status in ``until`` (default: its final status,
        ``state`` one of :data:`FINAL`)."""
        return self.status(self.publish(names, points, times_s), until)

    def publish(self, names: Sequence[str], points: Sequence[Sequence[float]],
                times_s: Sequence[float], *, stamped: bool = True) -> int:
        """Publish one trajectory (``header.stamp``: the process id and its number, or zero
        without ``stamped``); its number (1 for the first, as its sequence number)."""
        from builtin_interfaces.msg import Duration
        from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

        self._n += 1
        msg = JointTrajectory()
        if stamped:  # echoed back
            msg.header.stamp.sec, msg.header.stamp.nanosec = self.tag, self._n
        msg.joint_names = list(names)
        for q, t in zip(points, times_s, strict=True):
            p = JointTrajectoryPoint()
            p.positions = [float(v) for v in q]
            ns = round(float(t) * 1e9)
            p.time_from_start = Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
            msg.points.append(p)
        self.pub.publish(msg)
        return self._n

    def mine(self, status: dict[str, Any], n: int) -> bool:
        """Whether ``status`` is one of the ``n``-th trajectory sent."""
        source = status.get("source")
        if source is not None and self.gid is not None:
            return bool(source["gid"] == self.gid
                        and source["seq"] <= n <= source.get("seq_last", source["seq"]))
        return bool(status["stamp"] == [self.tag, n])

    def status(self, n: int, until: Sequence[str] = FINAL) -> dict[str, Any]:
        """The first status in ``until`` of the ``n``-th trajectory sent (waited for)."""

        def final() -> dict[str, Any] | None:
            return next((s for s in self.statuses if s["state"] in until and self.mine(s, n)),
                        None)

        _spin_until(self.node, lambda: final() is not None, self.deadline,
                    f"the status of trajectory {n} of {self.gid or self.tag}")
        out = final()
        assert out is not None
        return out


def send_all(sender: Sender, trajectories: Sequence[dict[str, Any]],
             wait_events: Sequence[str] = (), *, wait_commanded: bool = True) -> dict[str, Any]:
    """``send`` mode: each trajectory once the previous one is accepted (or refused), then the
    final status of the last (and the events of ``wait_events``: topics are not ordered with
    each other; and, with ``wait_commanded``, the goals of the last on ``/armbench/commanded``);
    with several, ``{"statuses": [final status of each]}``."""
    if not trajectories:
        raise SystemExit("send: give --trajectory JSON")
    for k, t in enumerate(trajectories):
        last = k == len(trajectories) - 1
        out = sender.send(t["names"], t["points"], t["times_s"],
                          until=FINAL if last else ("accepted", *FINAL))
    # of a trajectory done: its goals, on a topic of their own
    written = out.get("waypoints", 0) if wait_commanded else 0
    _spin_until(sender.node, lambda: (all(k in sender.events for k in wait_events)
                                      and len(sender.commanded) >= written),
                sender.deadline, f"the events {list(wait_events)} and {written} goals")
    seen = {"commanded": sender.commanded, "events": sender.events}
    if len(trajectories) == 1:
        return {**out, "seen": seen}
    return {"statuses": [sender.status(n) for n in range(1, len(trajectories) + 1)],
            "seen": seen}


#: ``flood``: the pose of the trajectory sent twice, and the times of every trajectory (s).
FLOOD_POSE_RAD = (0.1, -0.1, 0.1, 0.1)
FLOOD_TIME_S = 1.0


class _Tally:
    """The statuses of a sender's trajectories by number (its sequence numbers), as they come."""

    def __init__(self, sender: Sender, first: int) -> None:
        self.sender = sender
        self.first = first
        self.any: set[int] = set()
        """Trajectories with a status of any state."""
        self.finals: dict[int, list[str]] = {}
        """The final states of each trajectory (one each, if all is well)."""
        self._read = 0

    def update(self) -> None:
        """Count the statuses received since the last call."""
        statuses = self.sender.statuses
        for s in statuses[self._read:]:
            source = s.get("source")
            if not source or source["gid"] != self.sender.gid:
                continue
            for n in range(source["seq"], source.get("seq_last", source["seq"]) + 1):
                self.any.add(n)
                if s["state"] in FINAL:
                    self.finals.setdefault(n, []).append(s["state"])
        self._read = len(statuses)

    def answered(self, n: int) -> bool:
        """Whether trajectory ``n`` has a status yet (not one of the flood's: True)."""
        self.update()
        return n < self.first or n in self.any

    def all_final(self, ns: range) -> bool:
        """Whether each of ``ns`` has a final status yet."""
        self.update()
        return all(n in self.finals for n in ns)


def flood(sender: Sender, names: Sequence[str], count: int, same_every: int, window: int,
          settle: int, *, twice: bool) -> dict[str, Any]:
    """``flood`` mode (see the module doc)."""
    pose = list(FLOOD_POSE_RAD)
    out: dict[str, Any] = {}
    if twice:
        out["first"] = sender.send(names, [pose], [FLOOD_TIME_S])
        out["again"] = sender.send(names, [pose], [FLOOD_TIME_S])  # where the arm is already
        print(json.dumps(out), flush=True)  # a line before the result: under way
    sent = range(sender._n + 1, sender._n + 1 + count)
    tally = _Tally(sender, sent[0])
    for k, n in enumerate(sent):
        if window:  # no more than ``window`` without a status yet
            before = n - window
            _spin_until(sender.node, functools.partial(tally.answered, before), sender.deadline,
                        f"a status of trajectory {before}")
        assert sender.q_rad is not None
        step = 0.02 * (k % 5 - 2)
        q = sender.q_rad if k % same_every == 0 else [pose[0] + step, *pose[1:]]
        sender.publish(names, [q], [FLOOD_TIME_S], stamped=False)
        _executor_of(sender.node).spin_once(timeout_sec=0.0)  # statuses in, the newest state
    try:
        _spin_until(sender.node, lambda: tally.all_final(sent), sender.deadline,
                    f"a final status of each of {count} trajectories")
    except Timeout as exc:
        missing = [n for n in sent if n not in tally.finals]
        raise Timeout(f"{exc}: none for {len(missing)} (the first: {missing[:10]}, "
                      f"without any status: {[n for n in missing if n not in tally.any][:10]})"
                      ) from None
    seen = sender.states
    _spin_until(sender.node, lambda: sender.states >= seen + settle, sender.deadline,
                f"{settle} more /joint_states after the flood")
    tally.update()  # a second final status, had one come meanwhile
    states: dict[str, int] = {}
    for n in sent:
        for state in tally.finals.get(n, []):
            states[state] = states.get(state, 0) + 1
    return {**out, "finals": states,
            "missing": [n for n in sent if n not in tally.finals],
            "duplicates": [n for n in sent if len(tally.finals[n]) > 1],
            "states_after": sender.states - seen, "gid": sender.gid}


def square_trajectory(settings: RobotSettings, near_rad: Sequence[float],
                      centre_m: Sequence[float], side_m: float, speed_m_s: float,
                      spacing_m: float, branch: str, *,
                      roll_rad: float = 0.0) -> tuple[list[list[float]], list[float]]:
    """The square's waypoints (joint angles, rad) and their ``time_from_start`` (s, from the
    first corner) as :meth:`armbench.drivers.host.arm.Arm.follow_path` plans them."""
    corners = square_yz(centre_m, side_m)
    pts, qs = plan_path([*corners, corners[0]], settings,
                        (near_rad[0], near_rad[1], near_rad[2], near_rad[3]),
                        roll_rad=roll_rad, spacing_m=spacing_m, branch=branch)
    times = [0.0]
    for k in range(1, len(qs)):
        seg_s = float(np.linalg.norm(pts[k] - pts[k - 1])) / speed_m_s
        _, dur = segment_duties(qs[k - 1], qs[k], seg_s, settings, MAX_DUTY)
        times.append(times[-1] + dur)
    return [list(q) for q in qs], times


def square(sender: Sender, settings: RobotSettings, args: argparse.Namespace) -> dict[str, Any]:
    """``square`` mode (see the module doc)."""
    names = [j.name for j in settings.joints]
    assert sender.q_rad is not None
    qs, times = square_trajectory(settings, sender.q_rad, args.centre, args.side, args.speed,
                                  args.spacing, args.branch)
    reach_s = max(joint_times_s(sender.q_rad, qs[0], (MAX_DUTY,) * 4, settings))
    approach = sender.send(names, [qs[0]], [APPROACH_MARGIN * reach_s + 0.1])
    lap = sender.send(names, qs[1:], times[1:])
    return {"approach": approach, "lap": lap, "points": len(qs) - 1, "planned_s": times[-1]}


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m armbench.frontends.ros2_node.client")
    p.add_argument("mode", choices=("listen", "send", "square", "idle", "flood"))
    p.add_argument("--timeout", type=float, default=60.0, help="real seconds, a hang guard")
    p.add_argument("--count", type=int, default=200,
                   help="listen: joint states to take; flood: trajectories to send")
    p.add_argument("--same-every", type=int, default=3,
                   help="flood: every K-th trajectory to where the arm is")
    p.add_argument("--twice", action="store_true",
                   help="flood: first a pose and, once done, the same pose again (printed on a "
                        "line of its own)")
    p.add_argument("--window", type=int, default=0,
                   help="flood: at most W trajectories sent without a status yet (default 0: "
                        "back to back)")
    p.add_argument("--settle", type=int, default=100,
                   help="flood: /joint_states to take after the last final status")
    p.add_argument("--sim-time", action="store_true",
                   help="run the client's node with use_sim_time (its clock follows /clock)")
    p.add_argument("--trajectory", action="append", default=[],
                   help="send: a trajectory as JSON; given again, each next one is sent as soon "
                        "as the previous one is under way (it replaces it)")
    p.add_argument("--trajectory-file", action="append", default=[], metavar="FILE",
                   help="send: a trajectory as a JSON file (after those of --trajectory)")
    p.add_argument("--no-commanded", action="store_true",
                   help="send: do not wait for the goals on /armbench/commanded (a node over "
                        "an arm that does not publish them)")
    p.add_argument("--no-states", action="store_true",
                   help="send: do not subscribe /joint_states (ready once matched)")
    p.add_argument("--namespace", default="",
                   help="the node's namespace (the armbench node's --namespace)")
    p.add_argument("--wait-event", action="append", default=[], metavar="KIND",
                   help="send: also wait for an event of this kind on /armbench/events")
    p.add_argument("--settings", default=None)
    p.add_argument("--centre", type=float, nargs=3, default=DEFAULT_SQUARE_CENTRE_M)
    p.add_argument("--side", type=float, default=DEFAULT_SQUARE_SIDE_M)
    p.add_argument("--speed", type=float, default=0.05)
    p.add_argument("--spacing", type=float, default=0.005)
    p.add_argument("--branch", default="front-up")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run one mode; 0 and the JSON result, or 1 and ``{"error": ...}``."""
    args = _parser().parse_args(argv)
    import rclpy

    deadline = time.monotonic() + args.timeout
    rclpy.init()
    from rclpy.parameter import Parameter

    node = rclpy.create_node(f"armbench_client_{args.mode}_{os.getpid()}",
                             namespace=args.namespace or None,
                             parameter_overrides=[Parameter("use_sim_time",
                                                            value=args.sim_time)])
    try:
        if args.mode == "listen":
            out = listen(node, args.count, deadline)
        elif args.mode == "idle":
            out = idle(node, deadline)
        else:
            sender = Sender(node, deadline, states=not (args.mode == "send" and args.no_states))
            if args.mode == "send":
                trajectories = [json.loads(t) for t in args.trajectory]
                for name in args.trajectory_file:
                    with open(name, encoding="utf-8") as f:
                        trajectories.append(json.load(f))
                out = send_all(sender, trajectories, args.wait_event,
                               wait_commanded=not args.no_commanded)
            elif args.mode == "flood":
                out = flood(sender, [j.name for j in load_settings(args.settings).joints],
                            args.count, args.same_every, args.window, args.settle,
                            twice=args.twice)
            else:
                out = square(sender, load_settings(args.settings), args)
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
