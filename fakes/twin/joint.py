"""Pure, event-driven model of one joint board's motion control (paper §5.1–§5.2, Fig. 7, (12)).

No asyncio and no clocks: time is an integer count of 80 µs control cycles ("ticks"); the caller
converts (``CYCLE_S``). The model is step-exact against the firmware's per-cycle state machine yet
never loops per cycle or per step: between events (a stop, a reversal, the Hall reset, a hard
limit, a spurious encoder count, a new reference) the steps are computed arithmetically, so a move
of 200 000 steps costs a handful of loop iterations (``iterations`` counts them).

Conventions (``docs/emulator.md`` has them in full, with the firmware's per-cycle state
machine): the state *at tick t* is the state when cycle t begins, so a reference set at tick t is
seen by cycle t's action and a transition made by that action is stamped t + 1; a moving joint
steps every 101 − v cycles (speed law (12)); ``counter = offset + floor(motor_steps × c)`` with
``c = counts_per_step`` exact, the Hall reset and spurious counts changing ``offset``. What the
mechanism does to the pulses (lost steps, spurious counts, stick-slip) the joint's drive train
answers (``fakes/twin/drive_train.py``); the link's play and its load are the model's state.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import replace
from typing import Final

from armbench.drivers.model.protocol import MAX_DUTY
from armbench.drivers.model.settings import JointSettings
from armbench.fakes.twin.drive_train import DriveTrain
from armbench.fakes.twin.physics import JointPhysics, end_stop_steps
from armbench.fakes.twin.stepper import (
    CYCLE_S,
    FOREVER,
    PWM_HIGH,
    PWM_LOW,
    STOP,
    STOP_RULES,
    Motion,
    PhysicalEffects,
    PwmState,
    Run,
    StopRule,
    Transition,
    step_period_ticks,
)

__all__ = ["CYCLE_S", "JointModel", "Motion", "PhysicalEffects", "PwmState", "StopRule",
           "Transition", "step_period_ticks"]

#: What :meth:`JointModel.__copy__` copies (all but the ``Final`` ``_CONSTANTS``); with them the
#: ``__slots__``, so an attribute not named here fails at once (tests/test_compiled.py).
_FIELDS = ("_joint", "_num", "_den", "_steps_per_rad", "_drive", "_deadband", "_reach",
           "_half_play", "_now", "_state", "_n", "_dir", "_s", "_offset", "_gap", "_target",
           "_duty", "_homing_dir", "_homed_tick", "_stalled", "_run", "_idle", "_physics",
           "_load", "_load_nm", "_preload", "_stick", "_glitched", "transitions", "pulses",
           "steps_taken", "steps_missed", "steps_blocked", "spurious_counts", "iterations")
_CONSTANTS = ("hall_step", "hall_count", "lower_steps", "upper_steps")


class JointModel:
    """One joint board's control loop, encoder, Hall sensor and drive, event-driven.

    ``joint`` gives the drive train (``counts_per_step``, ``steps_per_rad``), the Hall position and
    the limits (the end stops beyond them); ``motor_steps`` is the start position of the motor in
    microsteps (0 = joint angle 0), ``counter`` the start value of the position counter in encoder
    counts (default: the encoder position ``floor(motor_steps × counts_per_step)``), ``tick`` the
    start time in control cycles. ``deadband_counts`` (≥ 0) is the firmware's position tolerance in
    counts and ``stop_rule`` when a moving joint stops: ``"window"``, once inside the deadband;
    ``"reach"``, once its counter meets or passes the target (it starts only beyond the deadband).
    ``seed`` (≥ 0) makes the physical effects reproducible. ``physics`` is the joint's drive train
    and link (``fakes/twin/physics.py``; None: ideal) and ``load`` the gravity torque on it (N·m,
    positive towards +q) as a function of its own link angle, read at each event (run planned,
    stop). ``noise_per_count``: chance of a spurious ±1 count per encoder count. What the drive
    train does to the pulses (losses, spurious counts, stick-slip) it answers
    (``fakes/twin/drive_train.py``).
    """

    __slots__ = _FIELDS + _CONSTANTS

    def __init__(self, joint: JointSettings, *, effects: PhysicalEffects | None = None,
                 seed: int = 0, deadband_counts: int = 1, stop_rule: StopRule = "window",
                 motor_steps: int = 0, counter: int | None = None, tick: int = 0,
                 physics: JointPhysics | None = None, load: Callable[[float], float] | None = None,
                 noise_per_count: float = 0.0) -> None:
        self._joint = joint
        cps = joint.counts_per_step
        self._num, self._den = cps.numerator, cps.denominator
        self._steps_per_rad = joint.steps_per_rad
        hall_error = 0.0 if physics is None else physics.hall_error_rad
        #: Motor position of the Hall sensor, microsteps (where it really is: ``hall_error_rad``).
        self.hall_step: Final = round((joint.hall_rad + hall_error) * joint.steps_per_rad)
        #: Counter value the Hall sensor sets, encoder counts.
        self.hall_count: Final = round(joint.hall_rad * joint.counts_per_rad)
        #: Hard limits of the motor position, microsteps (inclusive): the end stops.
        self.lower_steps: Final = end_stop_steps(joint)[0]
        self.upper_steps: Final = end_stop_steps(joint)[1]
        if not self.lower_steps <= motor_steps <= self.upper_steps:
            raise ValueError(f"motor_steps {motor_steps} outside the limits "
                             f"{self.lower_steps}..{self.upper_steps}")
        if deadband_counts < 0:
            raise ValueError(f"deadband_counts {deadband_counts} is negative")
        if stop_rule not in STOP_RULES:
            raise ValueError(f"stop_rule {stop_rule!r} is not one of {', '.join(STOP_RULES)}")
        if seed < 0:
            raise ValueError(f"seed {seed} is negative")
        if not 0.0 <= noise_per_count < 1.0:
            raise ValueError(f"noise_per_count {noise_per_count!r} is not in [0, 1)")
        self._drive = DriveTrain(joint, physics, effects if effects is not None
                                 else PhysicalEffects(), seed, noise_per_count)
        self._deadband = deadband_counts
        self._reach = stop_rule == "reach"
        self._physics = physics
        self._load = load
        self._load_nm = 0.0
        self._preload = 0  # side (±1) gravity holds the link on within the play; 0: play operator
        self._stick = 0.0  # link behind the play's flank after a stop (stick-slip), microsteps
        self._glitched = False  # the last run ended at a spurious count: the next one continues it
        backlash = 0.0 if physics is None else physics.backlash_rad
        self._half_play = backlash * joint.steps_per_rad / 2.0

        self._now = tick
        self._state = STOP
        self._n = 0
        self._dir = 0
        self._s = motor_steps
        self._offset = 0 if counter is None else counter - self._encoder(motor_steps)
        self._gap = 0.0  # motor minus joint position in microsteps (backlash), |gap| ≤ half play
        self._target = self.counter
        self._duty = 0
        self._homing_dir = 0
        self._homed_tick: int | None = None
        self._stalled = False
        self._run: Run | None = None
        self._idle = False  # STOP with nothing to do: until an input, time passes and that is all
        self.transitions: list[Transition] = []
        """Motion changes not yet taken by :meth:`drain_transitions`, oldest first (the boards
        poll its truth: no call)."""
        #: Step pulses the firmware issued (PWM_HIGH actions that stepped).
        self.pulses = 0
        #: Pulses that moved the shaft.
        self.steps_taken = 0
        #: Pulses lost to the missed-step effect.
        self.steps_missed = 0
        #: Pulses that could not move the shaft: hard limit or stall fault.
        self.steps_blocked = 0
        #: Spurious encoder counts made so far (each ±1).
        self.spurious_counts = 0
        #: Iterations of the event loop so far (behaviour tests of the O(events) cost).
        self.iterations = 0

    # --- observation -------------------------------------------------------------------------

    @property
    def tick(self) -> int:
        """The model's time in control cycles (the state is the one when this cycle begins)."""
        return self._now

    @property
    def counter(self) -> int:
        """The position counter, encoder counts: what the firmware reports."""
        return self._offset + self._s * self._num // self._den  # _encoder, inline: hot

    @property
    def motor_steps(self) -> int:
        """Motor shaft position, microsteps (0 = joint angle 0, ignoring backlash)."""
        return self._s

    @property
    def state(self) -> PwmState:
        """The state machine's state."""
        return self._state

    @property
    def non_moved_steps(self) -> int:
        """The firmware's ``non_moved_steps`` (cycles spent in PWM_LOW since the last step)."""
        return self._n

    @property
    def motion(self) -> Motion:
        """'stopped' in STOP, else the direction of the current movement ('cw' counts up)."""
        if self._state is STOP:
            return "stopped"
        return "cw" if self._dir > 0 else "ccw"

    @property
    def target_counts(self) -> int:
        """The position reference, encoder counts (not used while homing)."""
        return self._target

    @property
    def duty(self) -> int:
        """The velocity reference, PWM duty 0..99."""
        return self._duty

    @property
    def homing(self) -> bool:
        """True while a ``home`` drive has not reached the Hall sensor."""
        return self._homing_dir != 0

    @property
    def homed_tick(self) -> int | None:
        """Tick at which the last homing completed (None if none has)."""
        return self._homed_tick

    @property
    def at_limit(self) -> bool:
        """True while the machine drives into the hard limit the motor sits at."""
        limit = self.upper_steps if self._dir > 0 else self.lower_steps
        return self._state is not STOP and self._s == limit

    @property
    def homing_failed(self) -> bool:
        """True when a homing drive is stuck at a hard limit: it can never reach the Hall."""
        return self.homing and self.at_limit

    @property
    def stalled(self) -> bool:
        """True while the stall fault holds the joint."""
        return self._stalled

    def true_angle_rad(self) -> float:
        """Joint angle in radians after the gear play and stick-slip (what a laser tracker sees,
        but for the link's deflection under load, which the arm adds)."""
        return (self._s - self._gap - self._stick) / self._steps_per_rad

    def loaded_angle_rad(self) -> float:
        """Joint angle (rad) on the play's loaded flank before the stick-slip: where gravity is
        evaluated (the random stick-slip, < 0.1 % of the torque, stays out of the step loss)."""
        return (self._s - self._gap) / self._steps_per_rad

    @property
    def load_nm(self) -> float:
        """The gravity torque on the joint at its last event (N·m, positive towards +q)."""
        return self._load_nm

    def drain_transitions(self) -> list[Transition]:
        """The motion changes since the last call, oldest first (the board writes EEPROM)."""
        out, self.transitions = self.transitions, []
        return out

    def __copy__(self) -> JointModel:
        """A twin in the same state, sharing the mutable parts (run, drive train, transitions):
        attribute by attribute, as a compiled build has no instance dictionary to copy."""
        twin = JointModel(self._joint, motor_steps=self._s)
        for name in _FIELDS:
            setattr(twin, name, getattr(self, name))
        return twin

    def __deepcopy__(self, memo: dict[int, object]) -> JointModel:
        """An independent twin in the same state: its own run, drive train (bit generators) and
        transitions (the joint settings and physics, immutable, are shared)."""
        twin = copy.copy(self)
        twin.transitions = list(self.transitions)
        twin._run = None if self._run is None else replace(self._run)
        twin._drive = self._drive.clone()
        return twin

    def next_event_tick(self) -> int | None:
        """First tick at which ``motion`` will have changed or homing completed, assuming no new
        reference; None if nothing is pending (idle, or against a limit or a stall for ever)."""
        probe = copy.deepcopy(self)
        probe.transitions = []  # the first one it records is the answer
        return probe._run_until(FOREVER, probe=True)

    # --- inputs ------------------------------------------------------------------------------

    def advance(self, tick: int) -> None:
        """Bring the state to ``tick`` (control cycles, not before the model's time)."""
        if tick < self._now:
            raise ValueError(f"tick {tick} is before the model's time {self._now}")
        self.sample(tick)

    def sample(self, tick: int) -> tuple[int, float, float]:
        """The counter, :meth:`true_angle_rad` and the motor angle (rad) at ``tick``, or at the
        model's time if that is later (never backwards): a board's position report and the truth
        beside it, advancing and reading in one call (the boards make four per main loop)."""
        if tick > self._now:
            run = self._run
            if self._idle:
                self._now = tick
            elif run is not None and run.done > 0 and run.pulses is not None:
                # Fast path, a board sampling a moving joint: inside a stepping run that does not
                # end before ``tick`` only steps happen; do what _execute/_pulse do for that case
                # inline (no Hall, no limit, no motion change).
                period = run.period
                # the pulses at start + k·period < tick, and the cycles since the last of them
                done, lows = divmod(tick - 1 - run.start, period)
                done += 1
                if done < run.pulses:
                    prev = run.done
                    if done > prev:
                        if run.steps == run.pulses:  # no missed steps: steps_after is identity
                            after, moved = done, done - prev
                        else:
                            after = done * run.steps // run.pulses
                            moved = after - prev * run.steps // run.pulses
                            self.steps_missed += done - prev - moved
                        self.pulses += done - prev
                        self.steps_taken += moved
                        run.done = done
                        self._s = run.s0 + run.direction * after
                        play = self._half_play
                        if play and not self._preload:  # backlash as a play operator
                            gap = self._gap + run.direction * moved
                            self._gap = play if gap > play else -play if gap < -play else gap
                    self._now = tick
                    if lows >= period - 1:
                        self._state = PWM_HIGH
                        self._n = period - 1
                    else:
                        self._state = PWM_LOW
                        self._n = lows
                else:
                    self._run_until(tick, probe=False)
            else:
                self._run_until(tick, probe=False)
        s = self._s
        spr = self._steps_per_rad
        return (self._offset + s * self._num // self._den, (s - self._gap - self._stick) / spr,
                s / spr)

    def set_reference(self, tick: int, target_counts: int, duty: object) -> None:
        """New position (encoder counts) and velocity (duty 0..99) reference from tick on.

        Raises RuntimeError while homing: the firmware takes no reference before its
        initialisation is done (paper §5.2); ValueError for a duty that is not a whole number
        0..99 (of any type: ``object``, as in :func:`step_period_ticks`)."""
        if isinstance(duty, bool) or not isinstance(duty, int) or not 0 <= duty <= MAX_DUTY:
            raise ValueError(f"duty {duty!r} is not a whole number 0..{MAX_DUTY}")
        self.advance(tick)
        if self.homing:
            raise RuntimeError("the joint is homing; it takes no reference until it is done")
        if (target_counts, duty) != (self._target, self._duty):
            self._target, self._duty = target_counts, duty
            self._run = None
            self._idle = False
            self._glitched = False

    def home(self, tick: int, direction: int, duty: int) -> None:
        """Start the startup recovery at ``tick``: drive ``direction`` (+1 CW, −1 CCW) at ``duty``
        until the motor steps onto the Hall position, where the counter becomes ``hall_count`` and
        the target too (the joint stops there); on the Hall position already, at once."""
        if direction not in (1, -1):
            raise ValueError(f"direction {direction!r} is not +1 or -1")
        step_period_ticks(duty)  # validates 1..99: duty 0 would never move
        self.advance(tick)
        self._run = None
        self._idle = False
        self._duty = duty
        if self._s == self.hall_step:
            self._finish_homing(tick)
        else:
            self._homing_dir = direction

    def stall(self, tick: int, stalled: bool) -> None:
        """Fault injection from ``tick`` on: while ``stalled`` no pulse moves the shaft."""
        self.advance(tick)
        if stalled != self._stalled:
            self._stalled = stalled
            self._run = None
            self._idle = False

    # --- the event loop ----------------------------------------------------------------------

    def _encoder(self, steps: int) -> int:
        return steps * self._num // self._den

    def _error(self, moving: bool = False) -> int:
        if self._homing_dir:
            return self._homing_dir
        err = self._target - self.counter
        if moving and self._reach:  # on until the target is met or passed
            return err if err * self._dir > 0 else 0
        return 0 if abs(err) <= self._deadband else err

    def _record(self, tick: int, counter: int) -> None:
        self.transitions.append(Transition(tick, self.motion, counter))

    def _finish_homing(self, tick: int) -> None:
        self._homing_dir = 0
        self._offset = self.hall_count - self._encoder(self._s)
        self._target = self.hall_count
        self._homed_tick = tick

    def _run_until(self, until: int, *, probe: bool) -> int | None:
        """Execute the cycles before ``until``. With ``probe``, stop at the first motion change or
        homing completion and return its tick, or return None as soon as nothing can happen."""
        homed = self._homed_tick
        while self._now < until:
            self.iterations += 1
            run = self._run
            if run is not None:
                if probe and run.pulses is None and run.direction == self._dir:
                    return None  # pushing against a limit or stall: nothing will change
                self._execute(run, until)
            elif self._state is STOP:
                err = self._error()
                if self._duty > 0 and err != 0:
                    self._state = PWM_HIGH
                    self._dir = 1 if err > 0 else -1
                    self._stick = 0.0
                    self._now += 1
                    self._record(self._now, self.counter)
                elif probe:
                    return None
                else:
                    self._now = until
                    self._idle = True
            elif self._state is PWM_LOW:
                wait = max(1, 100 - self._duty - self._n)
                if self._now + wait <= until:
                    self._now += wait
                    self._n += wait
                    self._state = PWM_HIGH
                else:
                    self._n += until - self._now
                    self._now = until
            else:
                err = self._error(moving=True)
                if self._duty == 0 or err == 0:
                    self._state = STOP
                    self._glitched = False
                    self._drive.humming = False  # at rest a stepper is in step again
                    if self._physics is not None:
                        self._settle()
                    self._now += 1
                    self._record(self._now, self.counter)
                else:
                    self._run = self._plan(1 if err > 0 else -1)
            if probe:
                if self.transitions:
                    return self.transitions[0].tick
                if self._homed_tick != homed:
                    return self._homed_tick
        return None

    def _update_load(self) -> None:
        """Read the gravity torque now; above the hold torque the link rests on the flank of the
        play gravity pushes it to (a sign change crosses the play)."""
        physics = self._physics
        assert physics is not None
        load = self._load
        tau = 0.0 if load is None else load(self.loaded_angle_rad())
        self._load_nm = tau
        side = 1 if tau > physics.hold_nm else -1 if tau < -physics.hold_nm else 0
        self._preload = side
        if side:
            self._gap = -side * self._half_play

    def _settle(self) -> None:
        """The motor stops: the link comes to rest on the play's loaded side, and, carried by its
        momentum, up to a stick-slip band further on in the direction of travel (the band grows
        with the approach speed)."""
        self._update_load()
        stick = self._drive.stick_steps(self._duty, self._dir)
        if stick is not None:
            self._stick = stick

    def _plan(self, d: int) -> Run:
        """The run starting with the PWM_HIGH action due now, towards ``d``; the drive train draws
        its effects."""
        period = 101 - self._duty
        if self._physics is not None and not (self._glitched and d == self._dir):
            self._update_load()
        self._glitched = False
        limit = self.upper_steps if d > 0 else self.lower_steps
        drive = self._drive
        # loss_law "stall": the rotor stands, humming; load and rate are read again every
        # STALL_RECHECK_S (drive_train.py), moving or not (other joints' motion changes the load)
        recheck = drive.recheck_pulses(period)
        hum = drive.hums(self._load_nm, d, period, recheck)
        if self._stalled or self._s == limit or hum:
            return Run(self._now, period, d, recheck if hum else None, 0, self._s, self._offset,
                       self._offset, 0, False)
        steps = d * (limit - self._s)
        if recheck:
            steps = min(steps, recheck)
        hall = d * (self.hall_step - self._s)
        if hall > 0:
            steps = min(steps, hall)
        if not self._homing_dir:
            steps = min(steps, self._steps_to_deadband(d))
        steps, glitch = drive.first_spurious(steps)
        hall_at_end = hall == steps
        offset_end = self._offset + glitch
        if hall_at_end:
            offset_end = self.hall_count - self._encoder(self.hall_step)
        misses = drive.lost_pulses(self._load_nm, d, self._duty, period, steps)
        return Run(self._now, period, d, steps + misses, steps, self._s, self._offset,
                    offset_end, glitch, hall_at_end)

    def _steps_to_deadband(self, d: int) -> int:
        """Steps towards ``d`` before a PWM_HIGH check finds the error no longer beyond the
        deadband on side ``d`` (≥ 1 when called: the current check passed)."""
        base, band = self._target - self._offset, 0 if self._reach else self._deadband
        if d > 0:  # continue while floor(s·c) < base − band
            return -(-(base - band) * self._den // self._num) - self._s
        # continue while floor(s·c) ≥ base + band + 1
        return self._s + (-(base + band + 1) * self._den // self._num) + 1

    def _execute(self, run: Run, until: int) -> None:
        """Apply the run's pulses before ``until`` and land on the state at ``until`` (or at the
        PWM_HIGH after the run's last pulse, which ends the run)."""
        period = run.period
        done = -((run.start - until) // period)  # pulses at start + k·period < until
        if run.pulses is not None:
            done = min(done, run.pulses)
        if done > run.done:
            self._pulse(run, done)
        last = run.start + (done - 1) * period
        end = until
        if done == run.pulses:
            end = min(until, last + period)
            if end == last + period:
                self._run = None
        self._now = end
        lows = end - 1 - last
        if lows >= period - 1:
            self._state = PWM_HIGH
            self._n = period - 1
        else:
            self._state = PWM_LOW
            self._n = lows

    def _pulse(self, run: Run, done: int) -> None:
        """Apply pulses ``run.done`` .. ``done − 1`` of the run."""
        before = run.steps_after(run.done)
        after = run.steps_after(done)
        count = done - run.done
        self.pulses += count
        if run.pulses is None or not run.steps:  # a limit, a stall fault, a humming rotor
            self.steps_blocked += count
        else:
            self.steps_taken += after - before
            self.steps_missed += count - (after - before)
        if run.done == 0 and run.direction != self._dir:
            self._dir = run.direction
            first = run.s0 + run.direction * run.steps_after(1)
            self._record(run.start + 1, run.offset_after(1) + self._encoder(first))
        run.done = done
        self._s = run.s0 + run.direction * after
        self._offset = run.offset_after(done)
        if not self._preload:
            self._gap = min(self._half_play,
                            max(-self._half_play, self._gap + run.direction * (after - before)))
        if done == run.pulses:
            self.spurious_counts += abs(run.glitch)
            # a spurious count splits a motion: its step loss stays the one of its start
            self._glitched = run.glitch != 0
            if run.hall_at_end and self._homing_dir:
                self._finish_homing(run.start + (done - 1) * run.period + 1)
