"""The ``control_msgs/action/FollowJointTrajectory`` server of the node, and the execution of an
accepted trajectory that the action and the topic share.

The server lives at ``/<controller>/follow_joint_trajectory`` (``arm_controller`` by default: the
name MoveIt's simple controller manager and ros2_control use). Every goal is accepted and then
checked whole on the loop (:func:`~.follow.check_goal`) before anything moves: a goal refused is
aborted with ``INVALID_JOINTS``, ``INVALID_GOAL`` or ``OLD_HEADER_TIMESTAMP`` and the trajectory
running goes on. A valid goal replaces the one running (that one: aborted with ``INVALID_GOAL``,
"replaced by ...", the code ros2_control's controller gives it) and is executed by
:func:`execute`: the driver's coordinated streaming
(:func:`armbench.drivers.host.paths.stream_path`) with, beside it, every reply judged against
where the trajectory says the joints are then (``PATH_TOLERANCE_VIOLATED``: the stream is
cancelled and the arm held) and sent as feedback (desired, actual, error, the point aimed at). The
result comes when the arm has arrived within the goal tolerance (``SUCCESSFUL``), or, when it has
not within the trajectory's time plus ``goal_time_tolerance``, ``GOAL_TOLERANCE_VIOLATED`` (held).
A cancel holds the arm at once (the streaming's hold) and the goal ends ``CANCELED``.

rclpy marks a goal cancel-requested only after the cancel callback has returned, on its own
thread, so the node keeps its own record of the cancels it accepted (by goal id): a goal that
was not running yet finds its cancel there, and a goal cancelled on the loop is ended
``CANCELED`` once rclpy has marked it (ending it before would abort it and answer the cancel
with no goal cancelling).

Threads: the action's callbacks run on the node's executor threads (a reentrant callback group on
a multi-threaded executor); each goal's execute callback hands the goal to the loop
(``run_coroutine_threadsafe``) and waits there for its result, so other goals, cancels and the
topics are served meanwhile. Feedback is published from the loop.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import contextlib
import itertools
import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Final, Protocol

from armbench.drivers.host.arm import Arm, JointState, PathRun
from armbench.drivers.host.paths import stream_path
from armbench.drivers.model.errors import DriverError, MoveTimeoutError, PortLostError
from armbench.frontends.ros2_node.follow import (
    GOAL_TOLERANCE_VIOLATED,
    INVALID_GOAL,
    PATH_TOLERANCE_VIOLATED,
    SUCCESSFUL,
    Accepted,
    GoalRefused,
    check_goal,
    copy_goal,
)
from armbench.frontends.ros2_node.jobs import OneJob

__all__ = ["ACTION", "DEFAULT_CONTROLLER", "FollowServer", "NodeSide", "Outcome", "execute"]

log = logging.getLogger("armbench.ros2")

#: The controller name of the action's namespace (MoveIt's and ros2_control's usual one).
DEFAULT_CONTROLLER: Final = "arm_controller"
#: The action's name under the controller.
ACTION: Final = "follow_joint_trajectory"

#: Real seconds the execute callback waits for rclpy to mark a goal whose cancel the node
#: accepted (rclpy marks it right after the cancel callback returns): a guard, not a pace.
CANCEL_MARK_WAIT_S: Final = 10.0

#: What the execution reports on each reply: the time from the start (s), the desired
#: positions and velocities, the state, and the index of the point aimed at.
Feedback = Callable[[float, Sequence[float], Sequence[float], JointState, int], None]


class Options(Protocol):
    """The node's options the execution reads."""

    @property
    def max_duty(self) -> int: ...

    @property
    def lookahead_s(self) -> float: ...


class NodeSide(Protocol):
    """What the action server and the topic's alias use of the node
    (:class:`armbench.frontends.ros2_node.node.ArmNode`)."""

    node: Any
    arm: Arm
    last_run: PathRun | None

    @property
    def options(self) -> Options: ...

    def stamp_s(self, loop_t_s: float) -> float: ...

    def feedback_publisher(self, handle: Any) -> Callable[..., None]: ...


@dataclass(frozen=True)
class Outcome:
    """How an execution ended: the result code, its text, and the driver's run (None when the
    stream did not end at the goal)."""

    code: int
    text: str
    run: PathRun | None = None


async def execute(arm: Arm, accepted: Accepted, lookahead_s: float,
                  feedback: Feedback | None = None) -> Outcome:
    """Stream ``accepted`` on ``arm`` and judge every reply (see the module doc). Cancelled, the
    arm is held (by the streaming) and the cancellation goes on up."""
    names = [j.name for j in arm.settings.joints]
    loop = asyncio.get_running_loop()
    if accepted.start_delay_s > 0:  # a stamp in the future: start then
        await asyncio.sleep(accepted.start_delay_s)
    seq = arm.state.seq  # start on a reply, as the driver's own paths do
    await arm.wait_state(lambda s: s.seq > seq)
    plan = accepted.plan
    tol = tuple(e if e is not None else 1e9 for e in accepted.goal_rad)
    t0 = loop.time()
    stream = asyncio.ensure_future(stream_path(
        arm, plan.tcp_m, plan.commands, plan.planned_s, (tol[0], tol[1], tol[2], tol[3]),
        lookahead_s, accepted.end_s + accepted.goal_time_s))
    try:
        violation = await _watch(arm, accepted, names, t0, stream, feedback)
    except BaseException:
        await _end(stream)
        raise
    if violation is not None:  # the stream was cancelled: it held the arm
        await _end(stream)
        return Outcome(PATH_TOLERANCE_VIOLATED, f"{violation}; the arm is held")
    try:
        run = stream.result()
    except MoveTimeoutError as exc:
        return Outcome(GOAL_TOLERANCE_VIOLATED,
                       f"not at the goal {accepted.end_s + accepted.goal_time_s:.4g} s after the "
                       f"start (the trajectory's time plus goal_time_tolerance): {exc}; the arm "
                       "is held")
    # judged on the reply the streaming took for the arrival (the last one of the run)
    arrival = [st for st in run.states if st.t_s <= run.t_end_s]
    q = arrival[-1].q_rad if arrival else arm.state.q_rad
    off = accepted.goal_violation(names, q)
    if off is not None:
        return Outcome(GOAL_TOLERANCE_VIOLATED, off, run)
    return Outcome(SUCCESSFUL, f"at the goal after {run.duration_s:.4g} s", run)


async def _watch(arm: Arm, accepted: Accepted, names: list[str], t0: float,
                 stream: asyncio.Future[PathRun], feedback: Feedback | None) -> str | None:
    """Judge every reply until ``stream`` ends (None) or a joint leaves its path tolerance (the
    violation; ``stream`` cancelled)."""
    with arm.record_states() as states:
        while not stream.done():
            waiter: asyncio.Future[Any] = asyncio.ensure_future(_next_reply(arm, states))
            pending: set[asyncio.Future[Any]] = {stream, waiter}
            try:
                await asyncio.wait(pending, return_when=asyncio.FIRST_COMPLETED)
            finally:
                waiter.cancel()
            batch = states[:]
            del states[:]
            for state in batch:
                t = state.t_s - t0
                want, speed, index = accepted.desired(t)
                if feedback is not None:
                    feedback(t, want, speed, state, index)
                violation = accepted.path_violation(names, t, state.q_rad)
                if violation is not None and not stream.done():
                    stream.cancel()
                    return violation
    return None


async def _end(stream: asyncio.Future[PathRun]) -> None:
    """Cancel ``stream`` (it holds the arm) and wait for it; how it ended is not asked for."""
    stream.cancel()
    await asyncio.wait({stream})
    if not stream.cancelled():
        stream.exception()  # retrieved: a silent arm is the node's to report


async def _next_reply(arm: Arm, states: list[JointState]) -> None:
    """Until a reply is recorded in ``states``; a silent arm ends the wait too (the node holds
    the arm and cancels the job then)."""
    with contextlib.suppress(DriverError):
        await arm.wait_state(lambda s: bool(states))


class FollowServer:
    """The action server on ``node`` (see the module doc)."""

    def __init__(self, node: NodeSide, controller: str, jobs: OneJob) -> None:
        from control_msgs.action import FollowJointTrajectory
        from rclpy.action import ActionServer, CancelResponse
        from rclpy.callback_groups import ReentrantCallbackGroup

        self.node = node
        self.jobs = jobs
        self._action = FollowJointTrajectory
        self._cancel_ok = CancelResponse.ACCEPT
        self._loop = asyncio.get_running_loop()
        self._ids = itertools.count(1)
        self._running: dict[bytes, asyncio.Task[Any]] = {}
        self._cancels: set[bytes] = set()
        """The running or waiting goals (ids) whose cancel the node accepted; written on the
        executor's threads, under ``_cancels_lock``."""
        self._cancels_lock = threading.Lock()
        self.name = f"{controller}/{ACTION}"
        self._runs: set[asyncio.Task[Any]] = set()
        self.closed = False
        """Set at shutdown: goals from then on are aborted at once."""
        self.results: dict[int, int] = {}
        """The result code of each goal ended, by its number (in order of arrival)."""
        self.cancelled_at: dict[int, float] = {}
        """Loop time at which the node took up each cancel of a running goal, by goal number."""
        self._numbers: dict[bytes, int] = {}
        self.server = ActionServer(node.node, FollowJointTrajectory, self.name,
                                   execute_callback=self._execute,
                                   cancel_callback=self._cancel,
                                   callback_group=ReentrantCallbackGroup())

    async def drain(self) -> None:
        """At shutdown (the job cancelled): wait until every goal has its answer, so that no
        executor thread waits on the loop any longer."""
        self.closed = True
        while self._runs:
            await asyncio.wait(set(self._runs))

    def destroy(self) -> None:
        """Release the server (before its node)."""
        self.server.destroy()

    # --- the executor threads -----------------------------------------------------------------

    def _cancel(self, handle: Any) -> Any:
        key = _key(handle)
        with self._cancels_lock:  # a goal already ended leaves no entry behind
            if handle.is_active:  # before the loop hears of it: a goal not yet running finds it
                self._cancels.add(key)
        self._loop.call_soon_threadsafe(self._cancel_on_loop, key)
        return self._cancel_ok

    def _execute(self, handle: Any) -> Any:
        number, key = next(self._ids), _key(handle)
        goal = copy_goal(handle.request)
        try:
            future = asyncio.run_coroutine_threadsafe(
                self._run(number, key, goal, handle), self._loop)
            state, code, text = future.result()
        except (concurrent.futures.CancelledError, RuntimeError):
            state, code, text = "aborted", GOAL_TOLERANCE_VIOLATED, "the node shut down"
        result = self._action.Result(error_code=code, error_string=text)
        self.results[number] = code
        if state == "canceled" and _cancel_marked(handle):
            handle.canceled()
        elif code == SUCCESSFUL and state == "done":
            handle.succeed()
        else:
            handle.abort()
        with self._cancels_lock:  # the goal is ended: a cancel from now on adds nothing
            self._cancels.discard(key)
        return result

    # --- the loop -----------------------------------------------------------------------------

    def _cancel_on_loop(self, key: bytes) -> None:
        task = self._running.get(key)
        if task is not None and not task.done():
            self.cancelled_at[self._numbers[key]] = self._loop.time()
            self.jobs.cancel("canceled", "cancelled by its client", task)

    async def _run(self, number: int, key: bytes, goal: Any,
                   handle: Any) -> tuple[str, int, str]:
        run = asyncio.current_task()
        assert run is not None
        self._runs.add(run)
        try:
            return await self._follow(number, key, goal, handle)
        finally:
            self._runs.discard(run)

    async def _follow(self, number: int, key: bytes, goal: Any,
                      handle: Any) -> tuple[str, int, str]:
        node, arm = self.node, self.node.arm
        if self.closed:
            return "aborted", PATH_TOLERANCE_VIOLATED, "the node is shutting down"
        try:
            accepted = check_goal(goal, arm.settings, arm.state.q_rad,
                                  node.stamp_s(self._loop.time()), arm.default_tolerance_rad(),
                                  max_duty=node.options.max_duty)
        except GoalRefused as exc:
            log.error("goal %d refused, nothing moved: %s", number, exc.reason)
            return "aborted", exc.code, exc.reason
        if key in self._cancels:
            return "canceled", SUCCESSFUL, "cancelled before it started"
        await self.jobs.replace(f"goal {number} of {self.name}")
        log.info("goal %d accepted: %d points, %.3f s planned", number, accepted.plan.points,
                 accepted.plan.planned_s)
        task = self.jobs.start(execute(arm, accepted, node.options.lookahead_s,
                                       node.feedback_publisher(handle)))
        self._running[key], self._numbers[key] = task, number
        if key in self._cancels:  # came while the one before was being replaced
            self._cancel_on_loop(key)
        try:
            await asyncio.wait({task})
        finally:
            self._running.pop(key, None)
            self._numbers.pop(key, None)
        if task.cancelled():
            state, text = self.jobs.reason(task)
            held = f"{text}; the arm holds at {[round(q, 4) for q in arm.state.q_rad]} rad"
            # as ros2_control's controller: a goal replaced ends with INVALID_GOAL; one the node
            # gave up (shutdown, a silent arm) did not follow its path to the end
            code = {"canceled": SUCCESSFUL, "preempted": INVALID_GOAL}.get(
                state, PATH_TOLERANCE_VIOLATED)
            return state, code, held
        try:
            outcome: Outcome = task.result()
        except (DriverError, PortLostError) as exc:
            return "aborted", PATH_TOLERANCE_VIOLATED, f"the driver: {exc}"
        if outcome.run is not None:
            node.last_run = outcome.run
        log.info("goal %d: %s (%d)", number, outcome.text, outcome.code)
        return ("done" if outcome.code == SUCCESSFUL else "aborted"), outcome.code, outcome.text


def _key(handle: Any) -> bytes:
    """A goal's id: unique for the server's life (an object's ``id`` is reused)."""
    return bytes(handle.goal_id.uuid)


def _cancel_marked(handle: Any) -> bool:
    """Wait (on the executor's thread) until rclpy has marked ``handle`` cancel-requested, which
    it does once the node's cancel callback has returned; False if it has not in
    :data:`CANCEL_MARK_WAIT_S` (the goal is then aborted)."""
    deadline = time.monotonic() + CANCEL_MARK_WAIT_S
    while not handle.is_cancel_requested:
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.001)
    return True
