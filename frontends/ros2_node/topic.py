"""``/armbench/joint_trajectory``: a thin alias of the action for clients without control_msgs.

A ``JointTrajectory`` on the topic is a ``FollowJointTrajectory`` goal with the default tolerances:
the same check (:func:`~.follow.check_goal`), the same execution (:func:`~.follow_action.execute`)
and the same one running at a time (:class:`~.jobs.OneJob`: a trajectory from the topic replaces
a goal of the action and the other way round). What the action's result says comes as JSON on
``/armbench/trajectory_status`` (:mod:`.intake` gives every trajectory exactly one final status):
``done`` for ``SUCCESSFUL``; ``rejected`` for a goal refused (nothing moved); ``aborted`` for a
tolerance violated (the arm held), a silent arm, a lost link or the shutdown; ``preempted`` when a
newer trajectory or goal replaced it. An empty trajectory stops the arm (``stopped``).
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any, Protocol

from armbench.drivers.model.errors import DriverError, PortLostError
from armbench.frontends.ros2_node.follow import SUCCESSFUL, Goal, GoalRefused, check_goal
from armbench.frontends.ros2_node.follow_action import NodeSide, Outcome, execute
from armbench.frontends.ros2_node.intake import MAX_POINTS, Intake, Request, Tag
from armbench.frontends.ros2_node.jobs import OneJob

__all__ = ["TopicTrajectories"]

log = logging.getLogger("armbench.ros2")


class TopicSide(NodeSide, Protocol):
    """What the alias uses of the node besides the action's part: the intake, the statuses and
    the events."""

    intake: Intake

    def status(self, tag: Tag, state: str, **fields: Any) -> None: ...

    def event(self, kind: str, **fields: Any) -> None: ...


class TopicTrajectories:
    """Takes the topic's trajectories from the node's intake, one at a time, newest first."""

    def __init__(self, node: TopicSide, jobs: OneJob) -> None:
        self.node = node
        self.jobs = jobs
        self.accepted = 0
        """Trajectories accepted so far."""

    async def serve(self, wake: asyncio.Event) -> None:
        """Take each trajectory the intake holds when ``wake`` is set (until cancelled)."""
        while True:
            await wake.wait()
            wake.clear()
            req = self.node.intake.take()
            if req is None:
                continue
            try:
                await self._start(req)
            except asyncio.CancelledError:  # before its own status: the shutdown's
                self.node.status(req.tag, "aborted", reason="shutdown")
                raise

    async def _start(self, req: Request) -> None:
        """Take ``req`` up: its final status, or ``accepted`` and its execution as the job."""
        node, arm = self.node, self.node.arm
        tag = req.tag
        if req.too_many:
            self._reject(tag, f"trajectory: {req.too_many} points, more than the {MAX_POINTS} "
                              "accepted")
            return
        if not req.positions:
            await self.jobs.replace(f"trajectory {tag.id}")
            try:
                state = await arm.stop()
            except (DriverError, PortLostError) as exc:  # the state task says so and holds
                node.status(tag, "aborted", reason=str(exc))
                return
            log.info("trajectory %d: empty: stopped the arm", tag.id)
            node.status(tag, "stopped", q_rad=list(state.q_rad))
            return
        goal = Goal(tuple(req.names), tuple(map(tuple, req.positions)), tuple(req.times_s),
                    points=len(req.positions))
        try:
            accepted = check_goal(goal, arm.settings, arm.state.q_rad,
                                  node.stamp_s(asyncio.get_running_loop().time()),
                                  arm.default_tolerance_rad(), max_duty=node.options.max_duty)
        except GoalRefused as exc:
            self._reject(tag, exc.reason)
            return
        await self.jobs.replace(f"trajectory {tag.id}")
        plan = accepted.plan
        log.info("trajectory %d accepted: %d points, %.3f s planned", tag.id, plan.points,
                 plan.planned_s)
        node.status(tag, "accepted", points=plan.points, planned_s=plan.planned_s)
        self.accepted += 1
        task = self.jobs.start(execute(arm, accepted, node.options.lookahead_s))
        task.add_done_callback(lambda t: self._ended(tag, t))

    def _reject(self, tag: Tag, reason: str) -> None:
        """Log, event and status of a trajectory refused: ``reason`` echoes the peer's values
        shortened (:mod:`armbench.drivers.model.peer_text`)."""
        log.error("trajectory %d rejected, nothing moved: %s", tag.id, reason)
        self.node.event("trajectory_rejected", id=tag.id, reason=reason)  # before the status:
        self.node.status(tag, "rejected", reason=reason)  # a client may stop then

    def _ended(self, tag: Tag, task: asyncio.Task[Outcome]) -> None:
        """The final status of a job: cancelled (under way, or before it ever ran), failed in
        the driver, or its outcome."""
        node, arm = self.node, self.node.arm
        if task.cancelled():
            state, reason = self.jobs.reason(task)
            state = "aborted" if state == "canceled" else state
            if state == "aborted":
                log.error("trajectory %d aborted: %s", tag.id, reason)
            node.status(tag, state, reason=reason)
            return
        exc = task.exception()
        if exc is not None:
            log.error("trajectory %d aborted: %s", tag.id, exc)
            node.status(tag, "aborted", reason=str(exc))
            return
        outcome = task.result()
        if outcome.code != SUCCESSFUL or outcome.run is None:
            log.error("trajectory %d aborted: %s", tag.id, outcome.text)
            node.status(tag, "aborted", reason=outcome.text, error_code=outcome.code)
            return
        run = outcome.run
        node.last_run = run
        node.status(tag, "done", duration_s=max(0.0, run.duration_s),  # at the goal: 0
                    waypoints=len(run.waypoints), states=len(run.states),
                    q_rad=list(run.states[-1].q_rad if run.states else arm.state.q_rad))
