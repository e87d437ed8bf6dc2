"""Cycle-by-cycle reference of one joint board's control loop, the oracle of
``armbench.fakes.twin.joint``.

Deliberately naive: one Python iteration per 80 µs control cycle, the counter kept incrementally
as the firmware's encoder interrupt would, no physical effects. Same time convention as the model:
the state at tick t is the state when cycle t begins; a transition made by cycle t is stamped t + 1.
"""

from __future__ import annotations

import math

from armbench.drivers.model.settings import JointSettings
from armbench.fakes.twin.joint import Motion, PwmState, Transition
from armbench.fakes.twin.physics import end_stop_steps


class ReferenceJoint:
    """The Fig. 7 state machine run one control cycle at a time (see ``docs/emulator.md``)."""

    def __init__(self, joint: JointSettings, *, deadband_counts: int = 1,
                 stop_rule: str = "window", motor_steps: int = 0, counter: int | None = None,
                 tick: int = 0) -> None:
        self.cps = joint.counts_per_step
        self.hall_step = round(joint.hall_rad * joint.steps_per_rad)
        self.hall_count = round(joint.hall_rad * joint.counts_per_rad)
        self.lower_steps, self.upper_steps = end_stop_steps(joint)
        self.deadband = deadband_counts
        self.reach = stop_rule == "reach"
        self.tick = tick
        self.state = PwmState.STOP
        self.n = 0
        self.direction = 0
        self.motor_steps = motor_steps
        self.counter = self.encoder(motor_steps) if counter is None else counter
        self.target = self.counter
        self.duty = 0
        self.homing_dir = 0
        self.homed_tick: int | None = None
        self.stalled = False
        self.pulses = 0
        self.steps_taken = 0
        self.steps_blocked = 0
        self.transitions: list[Transition] = []

    def encoder(self, steps: int) -> int:
        """Encoder position of a motor position: floor(steps × counts_per_step)."""
        return math.floor(steps * self.cps)

    @property
    def motion(self) -> Motion:
        """'stopped' in STOP, else the direction of the current movement."""
        if self.state is PwmState.STOP:
            return "stopped"
        return "cw" if self.direction > 0 else "ccw"

    @property
    def at_limit(self) -> bool:
        """Driving into the hard limit the motor sits at."""
        limit = self.upper_steps if self.direction > 0 else self.lower_steps
        return self.state is not PwmState.STOP and self.motor_steps == limit

    def error(self, moving: bool = False) -> int:
        """Position error as the firmware sees it: 0 inside the deadband, and, ``moving`` under
        the ``reach`` rule, 0 once the counter has met or passed the target."""
        if self.homing_dir:
            return self.homing_dir
        err = self.target - self.counter
        if moving and self.reach:
            return err if err * self.direction > 0 else 0
        return 0 if abs(err) <= self.deadband else err

    def cycle(self) -> None:
        """Run the action of control cycle ``self.tick``."""
        t = self.tick
        self.tick += 1
        if self.state is PwmState.STOP:
            err = self.error()
            if self.duty > 0 and err != 0:
                self.state = PwmState.PWM_HIGH
                self.direction = 1 if err > 0 else -1
                self.transitions.append(Transition(t + 1, self.motion, self.counter))
        elif self.state is PwmState.PWM_HIGH:
            err = self.error(moving=True)
            if self.duty == 0 or err == 0:
                self.state = PwmState.STOP
                self.transitions.append(Transition(t + 1, "stopped", self.counter))
                return
            d = 1 if err > 0 else -1
            self.pulses += 1
            new = self.motor_steps + d
            if self.stalled or not self.lower_steps <= new <= self.upper_steps:
                self.steps_blocked += 1
            else:
                self.steps_taken += 1
                self.counter += self.encoder(new) - self.encoder(self.motor_steps)
                self.motor_steps = new
                if new == self.hall_step:
                    self.counter = self.hall_count
                    if self.homing_dir:
                        self.homing_dir = 0
                        self.target = self.hall_count
                        self.homed_tick = t + 1
            self.state = PwmState.PWM_LOW
            self.n = 0
            if d != self.direction:
                self.direction = d
                self.transitions.append(Transition(t + 1, self.motion, self.counter))
        else:
            self.n += 1
            if self.n >= 100 - self.duty:
                self.state = PwmState.PWM_HIGH

    def advance(self, tick: int) -> None:
        """Run every cycle before ``tick``."""
        while self.tick < tick:
            self.cycle()

    def set_reference(self, tick: int, target: int, duty: int) -> None:
        """New reference seen from cycle ``tick`` on; refused while homing."""
        self.advance(tick)
        if self.homing_dir:
            raise RuntimeError("homing")
        self.target, self.duty = target, duty

    def home(self, tick: int, direction: int, duty: int) -> None:
        """Drive ``direction`` at ``duty`` until the Hall reset (at once if on the Hall)."""
        self.advance(tick)
        self.duty = duty
        if self.motor_steps == self.hall_step:
            self.counter = self.target = self.hall_count
            self.homed_tick = tick
        else:
            self.homing_dir = direction

    def stall(self, tick: int, stalled: bool) -> None:
        """Stall fault from cycle ``tick`` on."""
        self.advance(tick)
        self.stalled = stalled
