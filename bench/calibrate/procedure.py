"""The identification procedure of ``armbench calibrate --port``: moves that make the arm show its
parameters, on any port, within a budget of robot time.

Phases, the most informative first (each skipped when what is left of the budget cannot hold it):

1. ``timing`` — the reply period (replies while idle) and the latency from a command to the first
   reply that shows the motion.
2. ``approaches`` — ISO 230-2 style bidirectional approaches of every joint to its Hall position
   (all joints at once): with a truth source the reversal of the link against the motor is the gear
   play, its scatter the stick-slip band; the counter against the motor after a Hall crossing is
   the Hall position's error.
3. ``holds`` (truth only) — rest at poses of different gravity load, every joint approached from
   below: deflection against the model's gravity torque (stiffness) and the true TCP against the
   true joints (DH lengths and joint offsets). Right after the approaches, whose last pose they
   start from.
4. ``suite`` — a held-out block: the accuracy suite's motions (its square's corners at full duty,
   its edges streamed), recorded and never fitted; made again as ``end``, the last phase
   (``bench/calibrate/held_out_moves.py``): the fitted structures replace the prior only where
   they predict both better (``bench/calibrate/held_out.py``).
5. ``ladder`` — per joint, moves at a ladder of duties up and down a gravity-loaded range: the
   effective speed against law (12), i.e. the step loss and where it starts.

Everything reads time from the running loop and waits with asyncio (virtual time against
``fake://``, real time on a pty, TCP or hardware). Observations are saved after every unit of work.
"""

from __future__ import annotations

import asyncio
import itertools
import math
from collections.abc import Callable, Sequence
from typing import Any, Final

import numpy as np

from armbench.bench.calibrate.held_out_moves import (
    BLOCK_SHARE,
    SuiteBlock,
    plan_block,
    run_block,
)
from armbench.bench.calibrate.ladder import (
    LADDER_RANGES,
    ladder_order,
    speed_of,
)
from armbench.bench.calibrate.model import (
    APPROACH_OFFSET_RAD,
    Approach,
    ArmDoesNotMoveError,
    Hold,
    Observations,
    SpeedRun,
)
from armbench.bench.runner.truth import EmulatorTruth
from armbench.bench.suites.base import PoseSource
from armbench.drivers.host.arm import Arm, JointState
from armbench.drivers.host.motion import joint_speed_rad_s
from armbench.drivers.model.errors import WaitTimeoutError
from armbench.drivers.model.protocol import MAX_DUTY
from armbench.drivers.model.settings import RobotSettings

__all__ = ["DEFAULT_BUDGET_S", "FIT_SHARE", "HOLD_POSES_RAD", "PHASES", "Procedure"]

#: Robot time a calibration may take by default (s): the issue's bound of 15 minutes.
DEFAULT_BUDGET_S: Final = 900.0
#: Share of the budget the phases leave for what follows the session within it: the fit and the
#: replays of the held-out blocks (seconds of CPU, more on a loaded machine).
FIT_SHARE: Final = 0.03
PHASES: Final = ("timing", "approaches", "holds", "suite", "ladder", "end")
APPROACH_CYCLES: Final = 10
SETTLE_S: Final = 0.25
IDLE_S: Final = 1.0
LATENCY_MOVES: Final = 4
#: Poses (protocol rad) of the holds: both signs and several magnitudes of gravity torque on joints
#: 2 and 3, joint 1 and 4 spread for the kinematic fit; every pose and its approach point within
#: the default joint limits.
HOLD_POSES_RAD: Final = (
    (0.0, 0.5, 0.4, 0.0), (0.8, 0.9, 0.3, 0.5), (-0.8, -0.6, -0.5, 1.0), (0.4, -0.3, -0.9, 0.2),
    (-0.4, 0.3, 0.9, 1.5), (1.2, 1.0, -0.4, 0.0), (-1.2, -0.7, 0.8, 0.8), (0.0, 0.7, -1.2, 1.8),
    (2.0, 0.2, 0.5, -0.3), (-2.0, -0.2, -0.6, 0.6), (0.6, 1.1, -0.2, 1.2), (-0.6, -0.5, 0.95, 0.4),
)
#: Duties a move is sent again at, in turn, after a joint stalled (a stepper out of synchronism
#: stands until its rate falls below the pull-in rate): each about half the rate of the one
#: before (law (12)), so the duty that moves it is within a factor of two of the fastest that
#: would, and each stall brackets the drive's pull-out rate at that load.
RECOVERY_DUTIES: Final = (97, 93, 85, 70, 60)
#: A joint that moved less than this (rad, about 5 encoder counts) in a watch interval short of
#: its target stands still.
STALL_MOVED_RAD: Final = 3e-4
#: Shortest watch interval (s): long enough for the slowest moving joint of the procedure (duty 60
#: losing 90 % of its steps) to cross ``STALL_MOVED_RAD`` with room for the link's latency.
STALL_WATCH_S: Final = 0.5
#: Steps (rad) joint 2 is raised in when it leaves a pose it could not lift from.
#: How far inside joint 3's limit (rad) the forearm is folded back for that.
FOLD_MARGIN_RAD: Final = 0.05
#: Longest watch interval (s): a drive losing 90 % of its steps at duty 60 still moves
#: :data:`STALL_MOVED_RAD` in a tenth of it.
STALL_WATCH_MAX_S: Final = 1.0
ESCAPE_STEP_RAD: Final = 0.15
#: Standard error of a stalled run's ratio (of 0): it moved at most a few counts.
STALL_SIGMA: Final = 0.01
class Procedure:
    """Run the phases against ``arm`` within ``budget_s`` of robot time, filling ``obs`` and
    calling ``save`` after every unit of work. Raises :class:`ArmDoesNotMoveError` when a joint
    does not follow (after saving)."""

    def __init__(self, arm: Arm, settings: RobotSettings, obs: Observations, *,
                 budget_s: float = DEFAULT_BUDGET_S, save: Callable[[], None] = lambda: None,
                 progress: Callable[[str], None] = lambda message: None,
                 tracker: PoseSource | None = None,
                 capture_origin_s: float | None = None) -> None:
        self.arm = arm
        self.settings = settings
        self.obs = obs
        self.budget_s = budget_s
        self.save = save
        self.progress = progress
        self._loop = asyncio.get_running_loop()
        self._t0 = self._loop.time()
        self._slowdown = 1.6
        self._overhead_s = 0.05
        self._truth: PoseSource | None = (
            tracker if tracker is not None
            else EmulatorTruth(arm) if arm.ground_truth() is not None else None)
        self._tracker = tracker
        obs.truth = self._truth is not None
        sample = arm.ground_truth()
        obs.motor_truth = getattr(sample, "motor_rad", None) is not None
        self._phase = "timing"
        #: Loop time of the session capture's clock origin (None: no capture, no held-out
        #: block); the robot time kept for the end block while the phases before it run.
        self._origin_s = capture_origin_s
        self._reserve_s = 0.0
        self._block: SuiteBlock | None = None
        #: The most a move held and sent again took beyond its plan (s), since the held-out
        #: block began; what the first block's took, the end block's parts fit only with.
        self._stall_s = 0.0
        self._block_stall_s = 0.0
        #: The duty, loop time and angles of the latest attempt of a move (a stalled move is
        #: sent again slower: the run that arrived is that one).
        self._last_attempt: tuple[int, float, list[float]] = (0, 0.0, [0.0] * 4)

    # --- budget --------------------------------------------------------------------------------
    def elapsed_s(self) -> float:
        """Robot time used so far (s)."""
        return self._loop.time() - self._t0

    def _fits(self, estimate_s: float) -> bool:
        return (self.elapsed_s() + estimate_s + self._reserve_s
                <= (1.0 - FIT_SHARE) * self.budget_s)

    def _move_estimate_s(self, start: Sequence[float], target: Sequence[float],
                         duty: int) -> float:
        """Time a move will take by law (12), with room for lost steps and the arrival, both
        as this arm has shown them so far: the slowest ratio of a long move's time to its law
        (12) time (at least 1.6: an arm that loses many steps against gravity is slower than any
        fixed margin) and the longest time a move took beyond that (at least 0.05 s: the
        command's EEPROM record, the arrival)."""
        return self._slowdown * self._law_s(start, target, duty) + self._overhead_s

    def _law_s(self, start: Sequence[float], target: Sequence[float], duty: int) -> float:
        return max(abs(t - s) / joint_speed_rad_s(duty, j.steps_per_rad)
                   for s, t, j in zip(start, target, self.settings.joints, strict=True))

    # --- the phases ----------------------------------------------------------------------------
    async def run(self) -> Observations:
        """Every phase that fits the budget, in order."""
        block_s = self._plan_blocks()
        phases: list[tuple[str, Callable[[], Any], float]] = [
            ("timing", self.timing, IDLE_S + 1.0),
            ("approaches", self.approaches, 6.0),
        ]
        if self._truth is not None:
            phases.append(("holds", self.holds, 8.0))
        else:
            self.obs.phases_skipped["holds"] = "no truth source (deflection and kinematics " \
                                               "need one)"
        if self._block is not None:
            phases.append(("suite", self.suite, block_s))
        phases.append(("ladder", self.ladder, 4.0))
        if self._block is not None:
            phases.append(("end", self.end, 0.0))
        for name, phase, minimum_s in phases:
            if name == "end":
                self._reserve_s = 0.0  # the time kept for it
            if not self._fits(minimum_s):
                self.obs.phases_skipped[name] = (f"budget: {self.budget_s - self.elapsed_s():.1f} "
                                                 f"s left, at least {minimum_s:.0f} s needed")
                continue
            self._phase = name
            self.progress(f"calibrate: {name} ({self.elapsed_s():.1f} s of robot time so far)")
            await phase()
            self.obs.phases_done.append(name)
            self._stamp()
        return self.obs

    def _plan_blocks(self) -> float:
        """The held-out block that fits its share of the budget (None without a capture or
        when not even the square's corners fit: said in ``phases_skipped``), its robot time
        kept for the end block from the start; returns that time."""
        if self._origin_s is None:
            self.obs.phases_skipped["suite"] = "no capture of the session: no held-out block"
            return 0.0
        self._block = plan_block(BLOCK_SHARE * self.budget_s, self.arm, self._move_estimate_s)
        if self._block is None:
            self.obs.phases_skipped["suite"] = self.obs.phases_skipped["end"] = (
                f"budget: the approach to the square and two joints' own moves do not fit a "
                f"held-out block's share ({BLOCK_SHARE:.0%} of {self.budget_s:g} s)")
            return 0.0
        self._reserve_s = self._block.estimate_s
        return self._block.estimate_s

    async def _block_phase(self, name: str) -> None:
        """Make the held-out block ``name``: each part while it fits the budget and the block's
        share of it (a quarter beyond, for what the plan did not foresee: stalls held and sent
        again slower)."""
        assert self._block is not None and self._origin_s is not None
        began = self.elapsed_s()
        cap_s = 1.25 * BLOCK_SHARE * self.budget_s
        self._stall_s = 0.0

        def fits(estimate_s: float) -> bool:
            need_s = estimate_s + self._block_stall_s
            return self._fits(need_s) and self.elapsed_s() - began + need_s <= cap_s

        window, failure = await run_block(self.arm, self._block, name, self._origin_s,
                                          self._move, fits)
        self.obs.held_out.append(window)
        if failure is not None:
            self.obs.phases_skipped[name] = f"the block ended early: {failure}"

    async def suite(self) -> None:
        """A held-out block of the suites' motions; the end block gets as long as it took."""
        began = self.elapsed_s()
        await self._block_phase("suite")
        self._reserve_s = 1.1 * (self.elapsed_s() - began)
        self._block_stall_s = self._stall_s

    async def end(self) -> None:
        """The held-out block again, at the end of the session."""
        await self._block_phase("end")

    def _stamp(self) -> None:
        self.obs.robot_time_s = round(self.elapsed_s(), 6)
        self.save()

    async def timing(self) -> None:
        """Reply period while idle; latency of a command to the first reply that moved."""
        arm = self.arm
        with arm.record_states() as states:
            await asyncio.sleep(IDLE_S)
        self.obs.reply_dt_s = [round(b.t_s - a.t_s, 9) for a, b in itertools.pairwise(states)]
        home = list(arm.state.q_rad)
        for k in range(LATENCY_MOVES):
            target = list(home)
            target[0] = home[0] + (0.02 if k % 2 == 0 else 0.0)
            before = arm.state.ticks[0]
            t_sent = self._loop.time()
            await arm.move_joints(target, MAX_DUTY, wait=False)
            moved = await arm.wait_state(_ticks_changed(before), timeout_s=2.0)
            self.obs.latency_s.append(round(moved.t_s - t_sent, 9))
            await self._move(target, MAX_DUTY)

    async def approaches(self) -> None:
        """ISO 230-2 bidirectional approaches of all joints to their Hall positions."""
        p0 = [min(max(j.hall_rad, j.lower_rad + APPROACH_OFFSET_RAD),
                  j.upper_rad - APPROACH_OFFSET_RAD) for j in self.settings.joints]
        for cycle in range(APPROACH_CYCLES):
            for direction in (1, -1):
                start = [q - direction * APPROACH_OFFSET_RAD for q in p0]
                if not self._fits(2 * self._move_estimate_s(start, p0, MAX_DUTY) + SETTLE_S):
                    self.obs.phases_skipped["approaches"] = f"budget: stopped at cycle {cycle}"
                    return
                await self._move(start, MAX_DUTY)
                await self._move(p0, MAX_DUTY)
                state, truth = await self._rest()
                for j in range(4):
                    self.obs.approaches.append(Approach(
                        j + 1, p0[j], direction, MAX_DUTY, list(state.q_rad), cycle=cycle,
                        **truth))
            self._stamp()

    async def holds(self) -> None:
        """Rest at poses of different gravity load, each joint approached from below."""
        for pose in HOLD_POSES_RAD:
            target = [min(max(q, j.lower_rad + APPROACH_OFFSET_RAD), j.upper_rad)
                      for q, j in zip(pose, self.settings.joints, strict=True)]
            below = [q - APPROACH_OFFSET_RAD for q in target]
            if not self._fits(self._move_estimate_s(self.arm.state.q_rad, below, MAX_DUTY)
                              + self._move_estimate_s(below, target, MAX_DUTY) + SETTLE_S):
                self.obs.phases_skipped["holds"] = "budget: not every pose was held"
                return
            await self._move(below, MAX_DUTY)
            await self._move(target, MAX_DUTY)
            state, truth = await self._rest()
            tcp = self._truth.true_position_m() if self._truth is not None else None
            self.obs.holds.append(Hold(list(state.q_rad), truth.get("true_rad"),
                                       truth.get("motor_rad"),
                                       None if tcp is None else [float(v) for v in tcp],
                                       truth.get("link_rad")))
            self._stamp()

    async def ladder(self) -> None:
        """Moves at a ladder of duties, up and down, per joint: effective speed vs duty."""
        dropped: set[int] = set()
        for joint, duty in ladder_order():
            base, high, low = LADDER_RANGES[joint]
            if joint in dropped:
                continue
            for a, b in ((high, low), (low, high)):
                start = list(base)
                start[joint - 1] = a
                target = list(base)
                target[joint - 1] = b
                need = (self._move_estimate_s(self.arm.state.q_rad, start, MAX_DUTY)
                        + self._move_estimate_s(start, target, duty))
                if not self._fits(need):
                    self.obs.phases_skipped["ladder"] = (f"budget: stopped before duty {duty}"
                                                         f" of joint {joint}")
                    return
                stalls = len(self.obs.stalls)
                try:
                    await self._move(start, MAX_DUTY)
                    await self._speed_run(joint, start, target, duty)
                except ArmDoesNotMoveError as exc:
                    if len(self.obs.stalls) == stalls:
                        raise  # blocked, not stalled: nothing here explains it
                    # the drive stalls here at every duty tried (the stalls are
                    # observations): leave this joint's ladder, and the pose if the arm can
                    why = (f"joint {exc.joint} stalled at every duty down to "
                           f"{RECOVERY_DUTIES[-1]} (at {exc.reached_rad:+.4f} rad, commanded "
                           f"{exc.target_rad:+.4f} rad)")
                    self.progress(f"calibrate: {why}")
                    dropped.add(joint)
                    if not await self._escape():
                        self.obs.phases_skipped["ladder"] = (
                            why + ": the ladder stopped there, and the arm was left at "
                            "that pose")
                        self._stamp()
                        return
                    self.obs.phases_skipped[f"ladder j{joint}"] = why + ": its ladder " \
                        "was left; the arm folded its forearm back and was raised slowly"
                    break
            self._stamp()

    async def _escape(self) -> bool:
        """Bring the arm from a pose joint 2 cannot lift from back to the zero pose: the forearm
        folded back over joint 2 first (towards q2 + q3 = ∓π/2, as far as joint 3's limit
        allows: its weight then counters the upper arm's, the least torque joint 2 can carry
        there), then joint 2 up in steps of :data:`ESCAPE_STEP_RAD` (each at the highest
        recovery duty that moves it), then the rest. False when that stalls too."""
        q = list(self.arm.state.q_rad)
        spec = self.settings.joints[2]
        fold = q.copy()
        back = -q[1] - math.copysign(math.pi / 2, q[1])
        fold[2] = min(max(back, spec.lower_rad + FOLD_MARGIN_RAD), spec.upper_rad - FOLD_MARGIN_RAD)
        try:
            await self._move(fold, RECOVERY_DUTIES[0])
            # up in steps, the first tried at the highest recovery duty, each next one a level
            # above the duty that moved the one before: the load lightens on the way up
            steps = max(1, math.ceil(abs(fold[1]) / ESCAPE_STEP_RAD))
            duty = RECOVERY_DUTIES[0]
            for k in range(steps - 1, -1, -1):
                up = fold.copy()
                up[1] = fold[1] * k / steps
                await self._move(up, duty)
                moved = self._last_attempt[0]
                higher = [d for d in RECOVERY_DUTIES if d > moved]
                duty = min(higher) if higher else moved
            await self._move([0.0, 0.0, 0.0, 0.0], RECOVERY_DUTIES[0])
        except ArmDoesNotMoveError:
            return False
        return True

    async def _speed_run(self, joint: int, start: list[float], target: list[float],
                         duty: int) -> None:
        arm = self.arm
        j = joint - 1
        spec = self.settings.joints[j]
        law = joint_speed_rad_s(duty, spec.steps_per_rad)
        direction = 1 if target[j] > start[j] else -1
        steps = abs(target[j] - start[j]) * spec.steps_per_rad
        before = len(self.obs.stalls)
        try:
            with arm.record_states() as states:
                stalled = await self._move(target, duty)
        except ArmDoesNotMoveError:
            stalled = True
            raise
        finally:
            # every duty this run stalled at is a run of ratio 0 (the rotor stood, humming)
            for stall in self.obs.stalls[before:]:
                if stall["joint"] == joint and stall["duty"] <= duty:
                    d = int(stall["duty"])
                    self.obs.speeds.append(SpeedRun(
                        joint, d, direction, [float(v) for v in start],
                        joint_speed_rad_s(d, spec.steps_per_rad), 0.0, 0, steps,
                        STALL_SIGMA * joint_speed_rad_s(d, spec.steps_per_rad)))
        if stalled:
            # the attempt that arrived, at a lower duty, from where the joint had stood: a run
            # too (the duty where the drive keeps up brackets the stall from below)
            d_final, t_from, q_from = self._last_attempt
            after = [st for st in states if st.t_s >= t_from]
            again = speed_of(after, j, q_from[j], target[j])
            if d_final < duty and again is not None:
                rate, n, sigma = again
                self.obs.speeds.append(SpeedRun(
                    joint, d_final, direction, [float(v) for v in q_from],
                    joint_speed_rad_s(d_final, spec.steps_per_rad), rate, n,
                    abs(target[j] - q_from[j]) * spec.steps_per_rad, sigma))
            return
        run = speed_of(states, j, start[j], target[j])
        if run is None:
            return
        rate, n, sigma = run
        self.obs.speeds.append(SpeedRun(joint, duty, direction, [float(v) for v in start],
                                        law, rate, n, steps, sigma))

    # --- primitives ----------------------------------------------------------------------------
    async def _move(self, target: Sequence[float], duty: int) -> bool:
        """Move to ``target`` at ``duty``. A joint that stops dead on the way (a stepper that lost
        synchronism stands humming until its rate falls) is held and sent again at the next
        lower of :data:`RECOVERY_DUTIES`; the stall is recorded. Returns whether the move stalled
        at ``duty``. Raises :class:`ArmDoesNotMoveError` when no duty moves it."""
        stalled_at_duty = False
        began_s = self.elapsed_s()
        planned_s = self._move_estimate_s(self.arm.state.q_rad, target, duty)
        # the first retry is at the same duty: a command lost on the link looks like a stall
        for attempt, d in enumerate((duty, duty, *(x for x in RECOVERY_DUTIES if x < duty))):
            stuck = await self._move_once(target, d)
            if stuck is None:
                if attempt:  # held and sent again: what that cost beyond the plan
                    self._stall_s = max(self._stall_s,
                                        self.elapsed_s() - began_s - planned_s)
                return stalled_at_duty
            if attempt == 0:
                continue
            stalled_at_duty = stalled_at_duty or d == duty
            j, now = stuck
            self.obs.stalls.append({"phase": self._phase, "joint": j + 1, "duty": d,
                                    "at_rad": [float(v) for v in now],
                                    "target_rad": [float(v) for v in target]})
            self.progress(f"calibrate: joint {j + 1} stalled at duty {d} ({self._phase}); "
                          "held, sent again slower")
        now = list(self.arm.state.q_rad)
        errors = [abs(t - q) for t, q in zip(target, now, strict=True)]
        j = int(np.argmax(errors))
        self._stamp()
        raise ArmDoesNotMoveError(j + 1, float(target[j]), float(now[j]), self._phase)

    async def _move_once(self, target: Sequence[float],
                         duty: int) -> tuple[int, list[float]] | None:
        """One attempt: None on arrival, ``(joint, angles)`` when a joint stood still for a whole
        watch interval short of its target (after a hold was sent). A joint still moving, however
        slowly, is given ten times its law (12) time plus 2 s (the drive may lose up to 90 % of
        its steps against a load) before :class:`ArmDoesNotMoveError`."""
        arm = self.arm
        start = list(arm.state.q_rad)
        law_s = self._law_s(start, target, duty)
        deadline_s = 10.0 * self._move_estimate_s(start, target, duty) + 2.0
        watch_s = min(max(STALL_WATCH_S, 0.25 * law_s), STALL_WATCH_MAX_S)
        tol = [t + 1e-4 for t in arm.default_tolerance_rad()]
        goal = list(target)

        def arrived(state: JointState) -> bool:
            return all(abs(q - g) <= e for q, g, e in zip(state.q_rad, goal, tol, strict=True))

        began_s = self._loop.time()
        self._last_attempt = (duty, began_s, start)
        await arm.move_joints(goal, duty, wait=False)
        last = start
        while True:
            chunk_s = self._loop.time()
            try:
                state = await arm.wait_state(arrived, timeout_s=watch_s)
                break
            except WaitTimeoutError:
                if arm.state.t_s < chunk_s + 0.5 * watch_s:
                    continue  # no fresh reply (a stalled host or link): not evidence
                now = list(arm.state.q_rad)
                left = [abs(g - q) > e for q, g, e in zip(now, goal, tol, strict=True)]
                still = [k for k in range(4)
                         if left[k] and abs(now[k] - last[k]) < STALL_MOVED_RAD]
                if still:
                    await arm.stop()
                    return still[0], now
                if self._loop.time() - began_s > deadline_s:
                    j = int(np.argmax([abs(g - q) for q, g in zip(now, goal, strict=True)]))
                    self._stamp()
                    raise ArmDoesNotMoveError(j + 1, float(goal[j]), float(now[j]),
                                              self._phase) from None
                last = now
        took_s = self._loop.time() - began_s
        if law_s > 0.2:
            self._slowdown = max(self._slowdown, (took_s - self._overhead_s) / law_s)
        self._overhead_s = max(self._overhead_s, took_s - self._slowdown * law_s)
        del state
        return None

    async def _rest(self) -> tuple[JointState, dict[str, list[float]]]:
        """Wait the settling time; the first reply after it and the truth beside it."""
        await asyncio.sleep(SETTLE_S)
        t = self._loop.time()
        state = await self.arm.wait_state(lambda s: s.t_s >= t, timeout_s=2.0)
        truth = truth_of(self.arm)
        if self._tracker is not None:
            q = self._tracker.true_joints_rad()
            truth = {} if q is None else {"true_rad": [float(v) for v in q]}
        return state, truth


def _ticks_changed(before: int) -> Callable[[JointState], bool]:
    """A predicate: joint 1's wire value is no longer ``before``."""
    return lambda state: state.ticks[0] != before


def truth_of(arm: Arm) -> dict[str, list[float]]:
    """The emulator's truth beside the newest reply (empty without one): ``true_rad``,
    ``link_rad``, ``motor_rad``, ``firmware_rad`` as far as the sample has them."""
    sample = arm.ground_truth()
    if sample is None:
        return {}
    out: dict[str, list[float]] = {"true_rad": [float(v) for v in sample.true_rad]}
    for name in ("link_rad", "motor_rad", "firmware_rad"):
        value = getattr(sample, name, None)
        if value is not None:
            out[name] = [float(v) for v in value]
    return out
