"""The ROS 2 node of ``armbench ros2``: the driver's arm on a ROS 2 graph (real rclpy, Fast DDS).

Topics (under the node's namespace, ``/`` by default; ``docs/ros.md``):

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
on an executor thread of its own. Publishing is done from the loop (rcl's publish is thread-safe),
but for the statuses :mod:`.intake` publishes on the executor thread. The subscription callback
only hands the message to :class:`~.intake.Intake`, which copies it into plain Python values,
keeps the newest one in a slot of one and wakes the loop with ``call_soon_threadsafe``, so a peer
cannot queue work without bound; every trajectory the node hears of gets exactly one final
status. On virtual time the loop waits for ROS only to pace ``/joint_states`` (:mod:`.pacing`);
otherwise the clock jumps to the next timer of the emulator as always and a trajectory is taken up
at whatever virtual time it arrives; a waker from another thread is served at the next iteration.
Every writer's history is bounded (``KEEP_LAST``), and a message a writer refuses is counted and
dropped, never raised: a peer cannot fill the node or stop it.

Stamps are loop time on virtual time (and ``/clock`` carries the same time, published before each
``/joint_states``), else wall-clock time of the reply's arrival (``time.time()`` offset to loop
time once at start).

Safety: a refused trajectory moves nothing; an empty one stops the arm; a new one replaces the one
running (as ros_control does). When the arm falls silent the trajectory is abandoned and a hold is
sent; when the port is lost, or the node is shut down, the arm is stopped where it can be and the
node logs and publishes what it did (a trajectory cut short by the shutdown: ``aborted``, reason
``shutdown``).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Final

from armbench.drivers.host.arm import Arm, JointState, PathRun, ReplyTimeoutError
from armbench.drivers.host.paths import LOOKAHEAD_S
from armbench.drivers.model.errors import DriverError, PortLostError
from armbench.drivers.model.protocol import MAX_DUTY, Command
from armbench.frontends.ros2_node import require_rclpy
from armbench.frontends.ros2_node.follow_action import DEFAULT_CONTROLLER, FollowServer
from armbench.frontends.ros2_node.intake import MAX_POINTS, Intake, Tag
from armbench.frontends.ros2_node.jobs import OneJob
from armbench.frontends.ros2_node.msgs_build import ensure_messages
from armbench.frontends.ros2_node.names import TOPICS, namespace_problem, node_name_problem
from armbench.frontends.ros2_node.pacing import RealtimePacer, SubscriberPacer
from armbench.frontends.ros2_node.state_topics import (
    StateMessages,
    fill_feedback,
    node_urdf,
    time_msg,
)
from armbench.frontends.ros2_node.topic import TopicTrajectories

__all__ = ["FINAL", "JOINT_STATES_DEPTH", "MAX_POINTS", "PACE_TIMEOUT_S", "SLOW_SUBSCRIBER",
           "STATUS_DEPTH", "TOPICS", "ArmNode", "NodeOptions", "PublishingArm"]

log = logging.getLogger("armbench.ros2")

#: History kept for ``/joint_states`` (reliable, ``KEEP_LAST``): the most a subscriber that has
#: not yet acknowledged may still get; the oldest of it goes first. Every writer of the node is
#: bounded so: a peer that stops reading cannot fill the node's memory.
JOINT_STATES_DEPTH: Final = 10_000
#: Trajectory statuses kept for a client that has not acknowledged them yet, or that matches late
#: (transient local): a flood of trajectories gets two statuses each (accepted, final), and a
#: status the history drops before a client has it never reaches it.
STATUS_DEPTH: Final = 1000
#: Real seconds the node waits at shutdown for its last statuses to be acknowledged.
STATUS_FLUSH_S: Final = 1.0
#: The final states of a trajectory's status: each trajectory gets exactly one of them.
FINAL: Final = ("done", "preempted", "aborted", "rejected", "stopped")
#: Threads of the node's executor: goals executing (each waits on one), and the rest.
EXECUTOR_THREADS: Final = 4
#: What the node does on virtual time when a reliable subscriber of ``/joint_states`` falls behind:
#: ``pace`` (hold the virtual clock until it has acknowledged, as a simulator in lock-step does)
#: or ``drop`` (run on, the subscriber loses the oldest beyond the history's depth).
SLOW_SUBSCRIBER: Final = ("pace", "drop")
#: Real seconds a paced node waits for a subscriber that acknowledges nothing before it stops
#: waiting for it (the subscriber then loses the oldest, as with ``drop``).
PACE_TIMEOUT_S: Final = 5.0


class PublishingArm(Arm):
    """The driver, telling the node each command it writes (``/joint_states_goal``)."""

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
    ``pace_timeout_s``: :data:`PACE_TIMEOUT_S`; ``controller``: the action's namespace
    (``/<controller>/follow_joint_trajectory``)."""

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
    controller: str = DEFAULT_CONTROLLER

    def __post_init__(self) -> None:
        for name, value, problem in (("node_name", self.node_name, node_name_problem),
                                     ("namespace", self.namespace, namespace_problem),
                                     ("controller", self.controller, node_name_problem)):
            why = problem(value)
            if why is not None:
                raise ValueError(f"{name} {value!r} {why}")
        if self.realtime_factor is not None and not 0 < self.realtime_factor < float("inf"):
            raise ValueError(f"realtime_factor {self.realtime_factor!r} must be > 0")
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


class ArmNode:
    """The node over an open arm; :meth:`run` until cancelled or the link is lost (then returns
    1). ``/joint_states_goal`` needs a :class:`PublishingArm` (over another arm, such as a bench
    run's connection, the topic stays silent: the run's capture has the commands). Builds the
    message support of control_msgs and tf2_msgs first if this environment has none
    (:mod:`.msgs_build`: about a minute, once)."""

    def __init__(self, arm: Arm, options: NodeOptions = NodeOptions()) -> None:
        self.arm = arm
        self.options = options
        self.names = [j.name for j in arm.settings.joints]
        self.published = 0
        """``/joint_states`` messages published."""
        self.last_run: PathRun | None = None
        """The path run of the last trajectory executed to its end."""
        self._loop = asyncio.get_running_loop()
        self._wall_offset_s = 0.0 if options.clock else time.time() - self._loop.time()
        self._wake = asyncio.Event()
        self.intake = Intake(self.status, self._wake_threadsafe)
        """Where the trajectories arrive (:class:`~.intake.Intake`)."""
        self.jobs = OneJob()
        """The trajectory running (from the action or the topic)."""
        self.finals: dict[str, int] = {}
        """Final statuses published, by state (``done``, ``preempted``, ...)."""
        self.refused: dict[str, int] = {}
        """Messages the DDS writers refused, by topic role (:data:`TOPICS`)."""
        self._refusing: set[str] = set()
        self._books = threading.Lock()  # the two above, and finals: statuses come from 2 threads
        self._realtime = (RealtimePacer(options.realtime_factor)
                          if options.realtime_factor is not None else None)
        require_rclpy()  # imported here: without the extra this module still imports
        ensure_messages(progress=log.warning)
        import rclpy
        from control_msgs.action import FollowJointTrajectory
        from geometry_msgs.msg import TransformStamped
        from rclpy.context import Context
        from rclpy.executors import MultiThreadedExecutor
        from rclpy.impl.implementation_singleton import rclpy_implementation
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState as JointStateMsg
        from std_msgs.msg import String
        from tf2_msgs.msg import TFMessage
        from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

        self._msg_js, self._msg_string = JointStateMsg, String
        self._msg_feedback, self._msg_point = FollowJointTrajectory.Feedback, JointTrajectoryPoint
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
        self._pub_tf = n.create_publisher(TFMessage, TOPICS["tf"], QoSProfile(
            depth=100, reliability=ReliabilityPolicy.RELIABLE))
        self._pub_tf_static = n.create_publisher(TFMessage, TOPICS["tf_static"], latched)
        self._pub_events = n.create_publisher(String, TOPICS["events"], 50)
        # transient local: a client whose reader this writer has not matched yet when a status
        # is published (discovery is not symmetric in time) still gets it when it matches
        self._pub_status = n.create_publisher(String, TOPICS["status"], QoSProfile(
            depth=STATUS_DEPTH, reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self._pub_clock = (n.create_publisher(Clock, TOPICS["clock"], reliable)
                           if options.clock else None)
        # KEEP_ALL: the node's queue never drops one, so the last trajectory of a client is
        # never lost in another's flood (the middleware bounds it, 5000 with Fast DDS, and then
        # stops acknowledging: a flooding writer's own history drops its oldest, which the
        # node sees as a gap in its sequence numbers and answers, :mod:`.intake`)
        n.create_subscription(JointTrajectory, TOPICS["trajectory"], self.intake.receive,
                              QoSProfile(depth=1, history=HistoryPolicy.KEEP_ALL,
                                         reliability=ReliabilityPolicy.RELIABLE))
        self.topic = TopicTrajectories(self, self.jobs)
        """The trajectories of the topic (:mod:`.topic`)."""
        self.action = FollowServer(self, options.controller, self.jobs)
        """The ``FollowJointTrajectory`` server (:mod:`.follow_action`)."""
        # threads: an action goal's execute callback waits for its result on one of them
        self._executor = MultiThreadedExecutor(num_threads=EXECUTOR_THREADS, context=self.context)
        self._executor.add_node(n)
        self._thread = threading.Thread(target=self._spin, name="rclpy-executor", daemon=True)
        self._states = StateMessages(arm.settings, JointStateMsg, TFMessage, TransformStamped)
        self._clock = Clock()
        self._subscribers = SubscriberPacer(self._pub_js, max(1, options.history_depth // 2),
                                            options.pace_timeout_s, options.history_depth,
                                            self.event)
        if isinstance(arm, PublishingArm):
            arm.on_command = self._on_command

    # --- the ROS thread ---------------------------------------------------------------------

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        with contextlib.suppress(ExternalShutdownException):
            self._executor.spin()

    def _wake_threadsafe(self) -> None:
        with contextlib.suppress(RuntimeError):  # the loop is closed: the node is going away
            self._loop.call_soon_threadsafe(self._wake.set)

    # --- publishing (on the loop) -----------------------------------------------------------

    def stamp_s(self, loop_t_s: float) -> float:
        """ROS time (s) of loop time ``loop_t_s``: virtual seconds, or wall-clock seconds."""
        return loop_t_s + self._wall_offset_s

    @property
    def accepted(self) -> int:
        """Trajectories of the topic accepted so far."""
        return self.topic.accepted

    @property
    def dropped(self) -> int:
        """``/joint_states`` messages the DDS writer refused (never published to anyone)."""
        return self.refused.get("joint_states", 0)

    @property
    def paced_s(self) -> float:
        """Real seconds the loop waited for subscribers of ``/joint_states`` (``pace``)."""
        return self._subscribers.paced_s

    @property
    def stalls(self) -> int:
        """Times a subscriber acknowledged nothing for ``pace_timeout_s`` (``pace``)."""
        return self._subscribers.stalls

    def _publish(self, publisher: Any, msg: Any, role: str) -> bool:
        """Publish ``msg`` on the topic of ``role``; a message the DDS writer refuses (a reliable
        subscriber that stopped reading holds its history up) is counted in :attr:`refused`, with
        one warning and one ``dropped`` event per episode, and the node goes on."""
        try:
            publisher.publish(msg)
        except self._rcl_error as exc:
            with self._books:
                self.refused[role] = self.refused.get(role, 0) + 1
                first = role not in self._refusing
                self._refusing.add(role)
            if first:
                log.warning("%s: a message could not be published (%s): dropping while a "
                            "subscriber holds the writer up", TOPICS[role], exc)
                if role != "events":
                    self.event("dropped", topic=TOPICS[role], reason=str(exc))
            return False
        if role in self._refusing:
            with self._books:
                self._refusing.discard(role)
            log.warning("%s: publishing again after %d dropped", TOPICS[role],
                        self.refused[role])
        return True

    def publish_state(self, state: JointState) -> None:
        """``/clock`` (virtual time), ``/joint_states`` and ``/tf`` for one reply."""
        t = self.stamp_s(state.t_s)
        if self._pub_clock is not None:
            time_msg(self._clock.clock, t)
            self._publish(self._pub_clock, self._clock, "clock")
        self._states.fill(state, t)
        if self._publish(self._pub_js, self._states.joint_state, "joint_states"):
            self.published += 1
        self._publish(self._pub_tf, self._states.tf, "tf")

    def feedback_publisher(self, handle: Any) -> Callable[..., None]:
        """What an action goal's execution calls on each reply: its feedback, published."""
        names = self.names

        def publish(t_s: float, desired: Sequence[float], speed: Sequence[float],
                    state: JointState, index: int) -> None:
            msg = self._msg_feedback()
            fill_feedback(msg, self._msg_point, names, self.stamp_s(state.t_s), desired, speed,
                          state, self._states.velocity(state), index, t_s)
            handle.publish_feedback(msg)

        return publish

    def event(self, kind: str, **fields: Any) -> None:
        """Publish an event on ``/armbench/events`` (JSON: ``t_s``, ``kind`` and ``fields``)."""
        text = json.dumps({"t_s": self.stamp_s(self._loop.time()), "kind": kind, **fields})
        self._publish(self._pub_events, self._msg_string(data=text), "events")

    def status(self, tag: Tag, state: str, **fields: Any) -> None:
        """Publish a status of the trajectory ``tag`` (from the loop or the executor thread)."""
        text = json.dumps({"id": tag.id, "state": state,
                           "stamp": None if tag.stamp is None else list(tag.stamp),
                           "source": None if tag.source is None else tag.source.as_json(),
                           **fields})
        if state in FINAL:
            with self._books:
                self.finals[state] = self.finals.get(state, 0) + 1
        self._publish(self._pub_status, self._msg_string(data=text), "status")

    def _on_command(self, t_s: float, command: Command) -> None:
        msg = self._msg_js()
        time_msg(msg.header.stamp, self.stamp_s(t_s))
        msg.name = list(self.names)
        msg.position = list(command.angles_rad(self.arm._lower, self.arm._upper))
        msg.effort = [float(d) for d in command.duties]  # as the capture's: the PWM duty in %
        self._publish(self._pub_cmd, msg, "commanded")

    # --- the loop ---------------------------------------------------------------------------

    async def run(self, duration_s: float | None = None) -> int:
        """Serve until ``duration_s`` (loop seconds) passes or the task is cancelled: 0; or until
        the port is lost: 1. The arm is stopped on the way out either way."""
        self._thread.start()
        self._publish(self._pub_urdf, self._msg_string(data=node_urdf(self.arm.settings)),
                      "robot_description")
        self._publish(self._pub_tf_static, self._states.tf_static(self.stamp_s(self._loop.time())),
                      "tf_static")
        self.event("started", port=self.arm.port, joints=self.names)
        log.info("ROS 2 node %r serving %s", self.options.node_name, self.arm.port)
        states = asyncio.ensure_future(self._publish_states())
        jobs = asyncio.ensure_future(self.topic.serve(self._wake))
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
            why = "shutdown" if status == 0 else "the link was lost"
            self.jobs.cancel("aborted", why)
            for running in (states, jobs):
                running.cancel()
            await asyncio.gather(states, jobs, *([self.jobs.task] if self.jobs.task else []),
                                 return_exceptions=True)
            await self.action.drain()  # every goal answered before the executor goes
            waiting = self.intake.close()  # from now on the intake answers what comes itself
            if waiting is not None:
                self.status(waiting.tag, "aborted", reason=why)
            if status == 0:
                await self._stop_on_exit()
            self.close()
        return status

    async def _stop_on_exit(self) -> None:
        """The hold of a shutdown, logged and published."""
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
        from rclpy.duration import Duration

        self._executor.shutdown(timeout_sec=2.0)
        self.action.destroy()
        # the last statuses (the shutdown's aborts) reach a client before the writer goes
        self._pub_status.wait_for_all_acked(Duration(nanoseconds=round(STATUS_FLUSH_S * 1e9)))
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
                    await self._subscribers.check(self.published + self.dropped)
                if self._realtime is not None:
                    await self._realtime.pace(batch[-1].t_s if batch else self._loop.time())

    async def _on_silence(self, exc: ReplyTimeoutError) -> None:
        log.error("%s: %s: abandoning the trajectory and holding the arm", self.arm.port, exc)
        self.event("link_silent", reason=str(exc), action="holding the arm")
        self.jobs.cancel("aborted", f"the arm fell silent: {exc}")
        with contextlib.suppress(DriverError, PortLostError):
            await self.arm.stop(wait=False)
