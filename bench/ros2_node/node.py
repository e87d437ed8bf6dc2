"""The ROS 2 node of ``armbench ros2``: the driver's arm on a ROS 2 graph (real rclpy, Fast DDS).

Topics (under the node's namespace, ``/`` by default; ``docs/ros2.md``):

=================================  ==============================  ============================
``/joint_states``                  ``sensor_msgs/JointState``      every reply of the arm
``/robot_description``             ``std_msgs/String``             the URDF (transient local)
``/armbench/joint_trajectory``     ``trajectory_msgs/JointTrajectory``  in: executed
``/armbench/trajectory_status``    ``std_msgs/String``             JSON: accepted, rejected, ...
``/armbench/commanded``            ``sensor_msgs/JointState``      each goal sent to the arm
``/armbench/events``               ``std_msgs/String``             JSON: the node's events
``/clock``                         ``rosgraph_msgs/Clock``         emulated targets only
=================================  ==============================  ============================

Threads: the driver runs on the asyncio loop of the command (virtual time for ``fake://``), rclpy
on an executor thread of its own. Publishing is done from the loop (rcl's publish is thread-safe);
a subscription callback only copies the message into plain Python values, keeps the newest one in
a slot of one and wakes the loop with ``call_soon_threadsafe``, so a peer cannot queue work
without bound. On virtual time the loop waits for ROS only to pace ``/joint_states``
(``slow_subscriber="pace"``: every half history, until every reliable subscriber has acknowledged
all, so nothing is lost); otherwise the clock jumps to the next timer of the emulator as always and
a trajectory is taken up at whatever virtual time it arrives; a waker from another thread is
served at the next iteration. Every writer's history is bounded (``KEEP_LAST``), and a message a
writer refuses is counted and dropped, never raised: a peer cannot fill the node or stop it.

Stamps are loop time on virtual time (and ``/clock`` carries the same time, published before each
``/joint_states``), else wall-clock time of the reply's arrival (``time.time()`` offset to loop
time once at start).

Safety: a refused trajectory moves nothing; an empty one stops the arm; a new one replaces the one
running (as ros_control does). When the arm falls silent the trajectory is abandoned and a hold is
sent; when the port is lost, or the node is shut down, the arm is stopped where it can be and the
node logs and publishes what it did.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Final

from armbench.bench.ros2_node import require_rclpy
from armbench.bench.ros2_node.trajectory import TrajectoryError, TrajectoryPlan, plan_trajectory
from armbench.drivers.arm import Arm, JointState, PathRun, ReplyTimeoutError
from armbench.drivers.errors import DriverError, PortLostError
from armbench.drivers.paths import LOOKAHEAD_S, stream_path
from armbench.drivers.protocol import MAX_DUTY, Command
from armbench.drivers.urdf import robot_urdf

__all__ = ["JOINT_STATES_DEPTH", "MAX_POINTS", "PACE_TIMEOUT_S", "SLOW_SUBSCRIBER", "STATUS_DEPTH",
           "TOPICS", "ArmNode", "NodeOptions", "PublishingArm"]

log = logging.getLogger("armbench.ros2")

#: Every topic of the node by its role: relative names, so they resolve under the node's
#: namespace (``/`` by default: ``/joint_states``); ``/clock`` is the graph's, absolute.
TOPICS: Final = {
    "joint_states": "joint_states",
    "robot_description": "robot_description",
    "trajectory": "armbench/joint_trajectory",
    "status": "armbench/trajectory_status",
    "commanded": "armbench/commanded",
    "events": "armbench/events",
    "clock": "/clock",
}
#: History kept for ``/joint_states`` (reliable, ``KEEP_LAST``): the most a subscriber that has
#: not yet acknowledged may still get; the oldest of it goes first. Every writer of the node is
#: bounded so: a peer that stops reading cannot fill the node's memory.
JOINT_STATES_DEPTH: Final = 10_000
#: Trajectory statuses kept for a client that matches late (transient local).
STATUS_DEPTH: Final = 50
#: What the node does on virtual time when a reliable subscriber of ``/joint_states`` falls behind:
#: ``pace`` (hold the virtual clock until it has acknowledged, as a simulator in lock-step does)
#: or ``drop`` (run on, the subscriber loses the oldest beyond the history's depth).
SLOW_SUBSCRIBER: Final = ("pace", "drop")
#: Real seconds a paced node waits for a subscriber that acknowledges nothing before it stops
#: waiting for it (the subscriber then loses the oldest, as with ``drop``).
PACE_TIMEOUT_S: Final = 5.0


class PublishingArm(Arm):
    """The driver, telling the node each command it writes (``/armbench/commanded``)."""

    on_command: Callable[[float, Command], None] | None = None

    async def _send(self, command: Command, *, retry: bool = True) -> float:
        t = await super()._send(command, retry=retry)
        if self.on_command is not None:
            self.on_command(t, command)
        return t


@dataclass(frozen=True)
class NodeOptions:
    """``node_name``; ``namespace``: the node's namespace (topics resolve under it; "" is ``/``:
    a second arm or a bench suite's node on the same graph takes one of its own); ``clock``:
    publish ``/clock`` (virtual time); ``max_duty``: fastest duty a trajectory may ask for;
    ``lookahead_s``: streaming look-ahead; ``domain_id``: ROS domain (None: ``ROS_DOMAIN_ID``);
    ``realtime_factor``: on virtual time, at most this many virtual seconds per real second
    (None: as fast as the emulator runs); ``history_depth``: the ``/joint_states`` history
    (:data:`JOINT_STATES_DEPTH`); ``slow_subscriber``: on virtual time, ``pace`` or ``drop``
    (:data:`SLOW_SUBSCRIBER`; real time always drops: the arm does not wait);
    ``pace_timeout_s``: :data:`PACE_TIMEOUT_S`."""

    node_name: str = "armbench"
    namespace: str = ""
    clock: bool = False
    max_duty: int = MAX_DUTY
    lookahead_s: float = LOOKAHEAD_S
    domain_id: int | None = None
    realtime_factor: float | None = None
    history_depth: int = JOINT_STATES_DEPTH
    slow_subscriber: str = "pace"
    pace_timeout_s: float = PACE_TIMEOUT_S

    def __post_init__(self) -> None:
        if not 2 <= self.history_depth <= 1_000_000:
            raise ValueError(f"history_depth {self.history_depth!r} must be 2..1000000")
        if self.slow_subscriber not in SLOW_SUBSCRIBER:
            raise ValueError(f"slow_subscriber {self.slow_subscriber!r} must be one of "
                             f"{', '.join(SLOW_SUBSCRIBER)}")
        if not 0 < self.pace_timeout_s < float("inf"):
            raise ValueError(f"pace_timeout_s {self.pace_timeout_s!r} must be > 0")

    @property
    def paced(self) -> bool:
        """Whether the virtual clock waits for the subscribers of ``/joint_states``."""
        return self.clock and self.slow_subscriber == "pace"


#: A trajectory with more points is refused unread (a peer must not fill the node's memory).
MAX_POINTS: Final = 100_000


@dataclass
class _Request:
    names: list[str]
    positions: list[list[float]]
    times_s: list[float]
    stamp: tuple[int, int]
    too_many: int = 0


def _time_msg(msg: Any, t_s: float) -> None:
    ns = max(0, round(t_s * 1e9))
    msg.sec, msg.nanosec = divmod(ns, 1_000_000_000)


class ArmNode:
    """The node over an open arm; :meth:`run` until cancelled or the link is lost (then returns
    1). ``/armbench/commanded`` needs a :class:`PublishingArm` (over another arm, such as a bench
    run's connection, the topic stays silent: the run's capture has the commands)."""

    def __init__(self, arm: Arm, options: NodeOptions = NodeOptions()) -> None:
        self.arm = arm
        self.options = options
        self.names = [j.name for j in arm.settings.joints]
        self.published = 0
        """``/joint_states`` messages published."""
        self.accepted = 0
        """Trajectories accepted so far."""
        self.last_run: PathRun | None = None
        """The path run of the last trajectory executed to its end."""
        self._loop = asyncio.get_running_loop()
        self._wall_offset_s = 0.0 if options.clock else time.time() - self._loop.time()
        self._slot: _Request | None = None
        self._slot_lock = threading.Lock()
        self._wake = asyncio.Event()
        self._job: asyncio.Task[None] | None = None
        self._job_id = 0
        self._abort_reason: str | None = None
        self._pace0: tuple[float, float] | None = None
        self.paced_s = 0.0
        """Real seconds the loop waited for subscribers of ``/joint_states`` (``pace``)."""
        self.stalls = 0
        """Times a subscriber acknowledged nothing for ``pace_timeout_s`` (``pace``)."""
        self._stalled = False
        self._checked = 0
        self.refused: dict[str, int] = {}
        """Messages the DDS writers refused, by topic role (:data:`TOPICS`)."""
        self._refusing: set[str] = set()
        self._pace_every = max(1, options.history_depth // 2)
        require_rclpy()  # imported here: without the extra this module still imports
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.impl.implementation_singleton import rclpy_implementation
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState as JointStateMsg
        from std_msgs.msg import String
        from trajectory_msgs.msg import JointTrajectory

        self._msg_js, self._msg_string = JointStateMsg, String
        self._rcl_error: type[Exception] = rclpy_implementation.RCLError
        self.context = Context()
        rclpy.init(context=self.context, domain_id=options.domain_id,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(options.node_name, context=self.context,
                                      namespace=options.namespace or None)
        n = self.node
        reliable = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        # bounded (KEEP_LAST): a subscriber that stops acknowledging loses the oldest instead of
        # filling the node's memory or blocking its publish; on virtual time ``pace`` holds the
        # clock every half history until all is acknowledged, so nothing is lost meanwhile
        self._pub_js = n.create_publisher(JointStateMsg, TOPICS["joint_states"], QoSProfile(
            depth=options.history_depth, history=HistoryPolicy.KEEP_LAST,
            reliability=ReliabilityPolicy.RELIABLE))
        self._pub_urdf = n.create_publisher(String, TOPICS["robot_description"], latched)
        self._pub_cmd = n.create_publisher(JointStateMsg, TOPICS["commanded"], 50)
        self._pub_events = n.create_publisher(String, TOPICS["events"], 50)
        # transient local: a client whose reader this writer has not matched yet when a status
        # is published (discovery is not symmetric in time) still gets it when it matches
        self._pub_status = n.create_publisher(String, TOPICS["status"], QoSProfile(
            depth=STATUS_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self._pub_clock = (n.create_publisher(Clock, TOPICS["clock"], reliable)
                           if options.clock else None)
        n.create_subscription(JointTrajectory, TOPICS["trajectory"], self._on_trajectory, 10)
        self._executor = SingleThreadedExecutor(context=self.context)
        self._executor.add_node(n)
        self._thread = threading.Thread(target=self._spin, name="rclpy-executor", daemon=True)
        self._js = JointStateMsg()
        self._js.name = list(self.names)
        self._clock = Clock()
        if isinstance(arm, PublishingArm):
            arm.on_command = self._on_command

    # --- the ROS thread ---------------------------------------------------------------------

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        with contextlib.suppress(ExternalShutdownException):
            self._executor.spin()

    def _on_trajectory(self, msg: Any) -> None:
        """On the executor thread: copy the message, keep the newest, wake the loop."""
        stamp = (int(msg.header.stamp.sec), int(msg.header.stamp.nanosec))
        n = len(msg.points)
        if n > MAX_POINTS:
            req = _Request([], [], [], stamp, n)
        else:
            req = _Request([str(s) for s in msg.joint_names],
                           [[float(v) for v in p.positions] for p in msg.points],
                           [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9
                            for p in msg.points], stamp)
        with self._slot_lock:
            self._slot = req
        with contextlib.suppress(RuntimeError):  # the loop is closed: the node is going away
            self._loop.call_soon_threadsafe(self._wake.set)

    # --- publishing (on the loop) -----------------------------------------------------------

    def stamp_s(self, loop_t_s: float) -> float:
        """ROS time (s) of loop time ``loop_t_s``: virtual seconds, or wall-clock seconds."""
        return loop_t_s + self._wall_offset_s

    @property
    def dropped(self) -> int:
        """``/joint_states`` messages the DDS writer refused (never published to anyone)."""
        return self.refused.get("joint_states", 0)

    def _publish(self, publisher: Any, msg: Any, role: str) -> bool:
        """Publish ``msg`` on the topic of ``role``; a message the DDS writer refuses (a reliable
        subscriber that stopped reading holds its history up) is counted in :attr:`refused`, with
        one warning and one ``dropped`` event per episode, and the node goes on."""
        try:
            publisher.publish(msg)
        except self._rcl_error as exc:
            self.refused[role] = self.refused.get(role, 0) + 1
            if role not in self._refusing:
                self._refusing.add(role)
                log.warning("%s: a message could not be published (%s): dropping while a "
                            "subscriber holds the writer up", TOPICS[role], exc)
                if role != "events":
                    self.event("dropped", topic=TOPICS[role], reason=str(exc))
            return False
        if role in self._refusing:
            self._refusing.discard(role)
            log.warning("%s: publishing again after %d dropped", TOPICS[role],
                        self.refused[role])
        return True

    def publish_state(self, state: JointState) -> None:
        """``/clock`` (virtual time) and ``/joint_states`` for one reply."""
        t = self.stamp_s(state.t_s)
        if self._pub_clock is not None:
            _time_msg(self._clock.clock, t)
            self._publish(self._pub_clock, self._clock, "clock")
        js = self._js
        _time_msg(js.header.stamp, t)
        js.position = list(state.q_rad)
        if self._publish(self._pub_js, js, "joint_states"):
            self.published += 1

    def event(self, kind: str, **fields: Any) -> None:
        """Publish an event on ``/armbench/events`` (JSON: ``t_s``, ``kind`` and ``fields``)."""
        text = json.dumps({"t_s": self.stamp_s(self._loop.time()), "kind": kind, **fields})
        self._publish(self._pub_events, self._msg_string(data=text), "events")

    def _status(self, job: int, state: str, stamp: tuple[int, int], **fields: Any) -> None:
        text = json.dumps({"id": job, "state": state, "stamp": list(stamp), **fields})
        self._publish(self._pub_status, self._msg_string(data=text), "status")

    def _on_command(self, t_s: float, command: Command) -> None:
        msg = self._msg_js()
        _time_msg(msg.header.stamp, self.stamp_s(t_s))
        msg.name = list(self.names)
        msg.position = list(command.angles_rad(self.arm._lower, self.arm._upper))
        self._publish(self._pub_cmd, msg, "commanded")

    # --- the loop ---------------------------------------------------------------------------

    async def run(self, duration_s: float | None = None) -> int:
        """Serve until ``duration_s`` (loop seconds) passes or the task is cancelled: 0; or until
        the port is lost: 1. The arm is stopped on the way out either way."""
        self._thread.start()
        self._publish(self._pub_urdf, self._msg_string(data=robot_urdf(self.arm.settings)),
                      "robot_description")
        self.event("started", port=self.arm.port, joints=self.names)
        log.info("ROS 2 node %r serving %s", self.options.node_name, self.arm.port)
        states = asyncio.ensure_future(self._publish_states())
        jobs = asyncio.ensure_future(self._take_trajectories())
        status = 0
        try:
            done, _ = await asyncio.wait({states, jobs}, timeout=duration_s,
                                         return_when=asyncio.FIRST_COMPLETED)
            for task in done:
                task.result()
        except PortLostError as exc:
            log.error("%s: link lost (%s): the arm could not be told to stop", self.arm.port, exc)
            self.event("link_lost", reason=str(exc))
            status = 1
        finally:
            for running in (states, jobs, self._job):
                if running is not None:
                    running.cancel()
            await asyncio.gather(states, jobs, *([self._job] if self._job else []),
                                 return_exceptions=True)
            if status == 0:
                await self._stop_on_exit()
            self.close()
        return status

    async def _stop_on_exit(self) -> None:
        try:
            state = await asyncio.shield(self.arm.stop())
        except ReplyTimeoutError as exc:
            log.error("%s: shutting down: hold sent, not confirmed (%s)", self.arm.port, exc)
            self.event("stopped", reason="shutdown", confirmed=False)
            return
        except (DriverError, PortLostError, asyncio.CancelledError) as exc:
            log.error("%s: shutting down; the hold could not be sent (%s)", self.arm.port, exc)
            return
        log.warning("%s: node shut down: stopped the arm at %s rad", self.arm.port,
                    [round(q, 4) for q in state.q_rad])
        self.event("stopped", reason="shutdown", q_rad=list(state.q_rad))

    def close(self) -> None:
        """Stop the executor thread and release the node and its context (idempotent)."""
        import rclpy

        if not self.context.ok():
            return
        self._executor.shutdown(timeout_sec=2.0)
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)

    async def _publish_states(self) -> None:
        arm = self.arm
        silent = False
        with arm.record_states() as buf:
            stream = arm.states(include_current=False)
            while True:
                try:
                    await anext(stream)
                except StopAsyncIteration:
                    return
                except ReplyTimeoutError as exc:
                    if not silent:
                        silent = True
                        await self._on_silence(exc)
                    continue
                if silent:
                    silent = False
                    log.warning("%s: replies again", arm.port)
                    self.event("link_back")
                batch = buf[:]
                del buf[:]
                for state in batch:
                    self.publish_state(state)
                if self.options.paced:
                    self._wait_for_subscribers()
                if self.options.realtime_factor is not None:
                    self._pace(batch[-1].t_s if batch else self._loop.time())

    def _wait_for_subscribers(self) -> None:
        """``pace``: every half history, hold the loop (a blocking wait: virtual time must not run
        on) until every reliable subscriber has acknowledged every ``/joint_states``, so the
        history never drops what one has not got. A subscriber that acknowledges nothing for
        ``pace_timeout_s`` is no longer waited for (event ``subscriber_stalled``) until all is
        acknowledged again (``subscriber_back``)."""
        offered = self.published + self.dropped
        if offered - self._checked < self._pace_every:
            return
        self._checked = offered
        from rclpy.duration import Duration

        if self._pub_js.wait_for_all_acked(Duration(nanoseconds=0)):  # no wait: all caught up
            if self._stalled:
                self._stalled = False
                log.warning("/joint_states: every subscriber keeps up again: pacing again")
                self.event("subscriber_back")
            return
        if self._stalled:
            return
        t0 = time.perf_counter()
        acked = self._pub_js.wait_for_all_acked(
            Duration(nanoseconds=round(self.options.pace_timeout_s * 1e9)))
        self.paced_s += time.perf_counter() - t0
        if not acked:
            self._stalled = True
            self.stalls += 1
            log.warning("/joint_states: a subscriber acknowledged nothing for %.3g s: no longer "
                        "waiting for it; it loses the oldest beyond the history of %d",
                        self.options.pace_timeout_s, self.options.history_depth)
            self.event("subscriber_stalled", timeout_s=self.options.pace_timeout_s,
                       history_depth=self.options.history_depth)

    def _pace(self, virtual_s: float) -> None:
        """Hold the loop (a blocking sleep: nothing else may run ahead) so that virtual time runs
        at most ``realtime_factor`` times real time."""
        rtf = self.options.realtime_factor
        assert rtf is not None
        now = time.perf_counter()
        if self._pace0 is None:
            self._pace0 = (virtual_s, now)
            return
        v0, r0 = self._pace0
        ahead = (virtual_s - v0) / rtf - (now - r0)
        if ahead > 0:
            time.sleep(ahead)

    async def _on_silence(self, exc: ReplyTimeoutError) -> None:
        log.error("%s: %s: abandoning the trajectory and holding the arm", self.arm.port, exc)
        self.event("link_silent", reason=str(exc), action="holding the arm")
        if self._job is not None and not self._job.done():
            self._abort_reason = f"the arm fell silent: {exc}"
            self._job.cancel()
        with contextlib.suppress(DriverError, PortLostError):
            await self.arm.stop(wait=False)

    async def _take_trajectories(self) -> None:
        while True:
            await self._wake.wait()
            self._wake.clear()
            with self._slot_lock:
                req, self._slot = self._slot, None
            if req is not None:
                await self._start(req)

    async def _start(self, req: _Request) -> None:
        self._job_id += 1
        job = self._job_id
        running = self._job
        if running is not None and not running.done():
            running.cancel()
            await asyncio.wait({running})
        if req.too_many:
            reason = f"trajectory: {req.too_many} points, more than the {MAX_POINTS} accepted"
            log.error("trajectory %d rejected, nothing moved: %s", job, reason)
            self.event("trajectory_rejected", id=job, reason=reason)
            self._status(job, "rejected", req.stamp, reason=reason)
            return
        if not req.positions:
            try:
                state = await self.arm.stop()
            except DriverError as exc:  # silent: the state task says so and holds
                self._status(job, "aborted", req.stamp, reason=str(exc))
                return
            log.info("trajectory %d: empty: stopped the arm", job)
            self._status(job, "stopped", req.stamp, q_rad=list(state.q_rad))
            return
        try:
            plan = plan_trajectory(req.names, req.positions, req.times_s, self.arm.settings,
                                   self.arm.state.q_rad, max_duty=self.options.max_duty)
        except TrajectoryError as exc:
            log.error("trajectory %d rejected, nothing moved: %s", job, exc)
            self.event("trajectory_rejected", id=job, reason=str(exc))  # before the status:
            self._status(job, "rejected", req.stamp, reason=str(exc))  # a client may stop then
            return
        log.info("trajectory %d accepted: %d points, %.3f s planned", job, plan.points,
                 plan.planned_s)
        self._status(job, "accepted", req.stamp, points=plan.points, planned_s=plan.planned_s)
        self.accepted += 1
        self._job = asyncio.ensure_future(self._execute(job, req.stamp, plan))

    async def _execute(self, job: int, stamp: tuple[int, int], plan: TrajectoryPlan) -> None:
        arm = self.arm
        try:
            seq = arm.state.seq  # start on a reply, as the driver's own paths do
            await arm.wait_state(lambda s: s.seq > seq)
            run = await stream_path(arm, plan.tcp_m, plan.commands, plan.planned_s,
                                    arm.default_tolerance_rad(), self.options.lookahead_s, None)
        except asyncio.CancelledError:
            reason, self._abort_reason = self._abort_reason, None
            if reason is None:
                self._status(job, "preempted", stamp)
            else:
                log.error("trajectory %d aborted: %s", job, reason)
                self._status(job, "aborted", stamp, reason=reason)
            raise
        except (DriverError, PortLostError) as exc:
            log.error("trajectory %d aborted: %s", job, exc)
            self._status(job, "aborted", stamp, reason=str(exc))
            return
        self.last_run = run
        self._status(job, "done", stamp, duration_s=max(0.0, run.duration_s),  # at the goal: 0
                     waypoints=len(run.waypoints),
                     states=len(run.states), q_rad=list(run.states[-1].q_rad)
                     if run.states else list(arm.state.q_rad))

