"""The drive train under one joint's firmware, asked at the joint's events: how many pulses of a
run it loses (the step-loss law of the joint's physics, the static-friction effect), whether the
rotor is out of step, which step of a run carries a spurious encoder count, and how far the link
slips past a stop.

The joint model (``fakes/twin/joint.py``) runs the firmware's control loop step-exactly and asks
this when it plans a run or stops; everything random about a joint is drawn here, one seeded PCG64
stream per effect (``docs/robot-model.md``), so a run depends on the seed and the inputs alone.
"""

from __future__ import annotations

from typing import Final

import numpy as np

from armbench.drivers.model.settings import JointSettings
from armbench.fakes.twin.physics import JointPhysics
from armbench.fakes.twin.stepper import CYCLE_S, PhysicalEffects, clone_bits

__all__ = ["STALL_RECHECK_S", "DriveTrain"]

#: How often (s) a joint under ``loss_law = "stall"`` checks its rate against the pull-out (or,
#: humming, the pull-in) rate at its load again, as the load changes under it.
STALL_RECHECK_S: Final = 0.005
_NO_EFFECTS: Final = PhysicalEffects()


class DriveTrain:
    """The motor, gear and link of ``joint`` as the firmware's pulses meet them.

    ``physics``: the joint's drive train and link (None: ideal, no step lost but by ``effects``);
    ``effects``: the static-friction effect; ``seed`` (≥ 0) seeds the draws;
    ``noise_per_count``: chance of a spurious ±1 count per encoder count (0 ≤ p < 1).
    ``humming``: the rotor is out of step (``loss_law = "stall"``) and restarts only at pull-in;
    ``lost_carry``: the fraction of a lost pulse owed but not yet whole (error diffusion).
    """

    __slots__ = (
        "_clean",
        "_joint",
        "effects",
        "humming",
        "lost_carry",
        "miss_bits",
        "noise_bits",
        "physics",
        "stick_bits",
    )

    def __init__(self, joint: JointSettings, physics: JointPhysics | None,
                 effects: PhysicalEffects, seed: int, noise_per_count: float) -> None:
        self._joint = joint
        self.physics = physics
        self.effects = effects
        cps = joint.counts_per_step
        #: Chance that a step that moves the shaft carries no spurious count.
        self._clean = 1.0 - noise_per_count * cps.numerator / cps.denominator
        # one PCG64 stream per effect, None while the effect is off
        self.miss_bits = (np.random.PCG64([seed, 0])
                          if effects.miss_probability
                          or (physics is not None and physics.loss_jitter) else None)
        self.noise_bits = np.random.PCG64([seed, 1]) if self._clean < 1.0 else None
        self.stick_bits = (np.random.PCG64([seed, 2])
                           if physics is not None and physics.stick_rad else None)
        self.lost_carry = 0.0
        self.humming = False

    def clone(self) -> DriveTrain:
        """An independent drive train in the same state: its own bit generators (attribute by
        attribute, as a compiled build has no instance dictionary to copy)."""
        twin = DriveTrain(self._joint, None, _NO_EFFECTS, 0, 0.0)  # draws no stream
        twin.physics = self.physics
        twin.effects = self.effects
        twin._clean = self._clean
        twin.miss_bits = clone_bits(self.miss_bits)
        twin.noise_bits = clone_bits(self.noise_bits)
        twin.stick_bits = clone_bits(self.stick_bits)
        twin.lost_carry = self.lost_carry
        twin.humming = self.humming
        return twin

    def lost_pulses(self, load_nm: float, direction: int, duty: int, period: int,
                    steps: int) -> int:
        """Pulses lost making ``steps`` steps towards ``direction`` at ``duty`` (one every
        ``period`` cycles) against the gravity torque ``load_nm``: the loss law's share
        (``JointPhysics.loss_fraction``; a pulse's fraction carried to the next run, scattered by
        ``loss_jitter``), or the static-friction draw per pulse if that loses more."""
        fx = self.effects
        p_fx = fx.miss_probability if duty > fx.miss_above_duty else 0.0
        physics, joint, bits = self.physics, self._joint, self.miss_bits
        p = 0.0 if physics is None else physics.loss_fraction(
            load_nm, direction, joint.gear_ratio, 1.0 / (period * CYCLE_S),
            joint.steps_per_motor_rev, 101 - period)
        if p_fx > p and bits is not None:
            return int(np.random.Generator(bits).negative_binomial(steps, 1.0 - p_fx))
        if physics is None or p <= 0.0:
            return 0
        if physics.loss_jitter and bits is not None:
            p = physics.jittered(p, float(np.random.Generator(bits).standard_normal()))
        owed = steps * p / (1.0 - p) + self.lost_carry
        misses = int(owed)
        self.lost_carry = owed - misses
        return misses

    def recheck_pulses(self, period: int) -> int:
        """Under ``loss_law = "stall"``: the pulses (one every ``period`` cycles) after which
        the rotor's rate is checked against its load again (:data:`STALL_RECHECK_S`); 0 under
        any other law."""
        physics = self.physics
        if physics is None or physics.loss_law != "stall":
            return 0
        return max(1, round(STALL_RECHECK_S / (period * CYCLE_S)))

    def hums(self, load_nm: float, direction: int, period: int, recheck: int) -> bool:
        """Whether the rotor stands out of step, humming, for a run towards ``direction`` (one
        pulse every ``period`` cycles; ``recheck`` from :meth:`recheck_pulses`): the needed
        torque exceeds the pull-out torque at the rate (a humming rotor's: the pull-in rate).
        Remembered in :attr:`humming`."""
        physics, joint = self.physics, self._joint
        self.humming = recheck > 0 and physics is not None and physics.stalls(
            load_nm, direction, joint.gear_ratio, 1.0 / (period * CYCLE_S),
            joint.steps_per_motor_rev, self.humming)
        return self.humming

    def first_spurious(self, steps: int) -> tuple[int, int]:
        """The steps of a run of ``steps`` up to the first that carries a spurious count, and
        that count (±1, equiprobable); ``(steps, 0)`` when none of them does."""
        if self.noise_bits is None:
            return steps, 0
        noise = np.random.Generator(self.noise_bits)
        first = int(noise.geometric(min(1.0, 1.0 - self._clean)))
        if first <= steps:
            return first, 1 if noise.integers(2) else -1
        return steps, 0

    def stick_steps(self, duty: int, direction: int) -> float | None:
        """Where a link that was moving towards ``direction`` at ``duty`` comes to rest past the
        play's flank when the motor stops (microsteps; uniform within the stick-slip band of that
        approach speed); None without stick-slip (the link stays where it is)."""
        physics, bits = self.physics, self.stick_bits
        if bits is None or physics is None or duty <= 0:
            return None
        band = physics.stick_band_rad(2.0 / (101 - duty)) * self._joint.steps_per_rad
        return -direction * band * float(np.random.Generator(bits).random())
