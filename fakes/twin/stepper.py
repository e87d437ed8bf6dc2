"""The stepper drive's vocabulary, shared by the joint model and its callers: the 80 µs control
cycle, the PWM states of the paper's Fig. 7, speed law (12), a run of step pulses, and the
drive's static-friction effect (``docs/robot-model.md``)."""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Final, Literal, NamedTuple

import numpy as np

from armbench.drivers.model.protocol import MAX_DUTY

__all__ = [
    "CYCLE_S",
    "FOREVER",
    "PWM_HIGH",
    "PWM_LOW",
    "STOP",
    "STOP_RULES",
    "Motion",
    "PhysicalEffects",
    "PwmState",
    "Run",
    "StopRule",
    "Transition",
    "clone_bits",
    "step_period_ticks",
]

#: Seconds per control cycle (one tick): the firmware's 80 µs timer interrupt.
CYCLE_S: Final = 80e-6

#: Macro state the EEPROM logic stores (paper §5.2): stopped, moving CW, moving CCW.
Motion = Literal["stopped", "cw", "ccw"]

#: When a moving joint stops (``docs/emulator.md``): ``window``, as soon as its error is within
#: the deadband; ``reach``, once its counter meets or passes the target (the paper's "position
#: error is null"; it starts only beyond the deadband, so with a deadband of a count or more a
#: counter that skips the target does not hunt).
StopRule = Literal["window", "reach"]
STOP_RULES: Final[tuple[StopRule, ...]] = ("window", "reach")

FOREVER: Final = 1 << 62  # horizon of next_event_tick's look-ahead; never reached in practice


class PwmState(enum.Enum):
    """The states of the firmware's position-control state machine (paper Fig. 7)."""

    STOP = "STOP"
    PWM_HIGH = "PWM_HIGH"
    PWM_LOW = "PWM_LOW"


# The members as module constants: reading one off the Enum class costs ~0.1 µs, on the hot path.
STOP, PWM_HIGH, PWM_LOW = PwmState.STOP, PwmState.PWM_HIGH, PwmState.PWM_LOW


class Transition(NamedTuple):
    """A change of ``motion``: first tick it is observed, the new motion, the counter then."""

    tick: int
    motion: Motion
    counter: int


def step_period_ticks(duty: object) -> int:
    """Control cycles between two steps of a moving joint at ``duty`` 1..99: ``101 − duty``.

    Speed law (12): ``1e6 / (80 × (101 − v))`` steps per second. ``duty`` is checked here, so it
    is annotated ``object``: a compiled ``int`` would take a boolean as 0 or 1 and reject
    anything else with mypyc's ``TypeError`` before this check names it.
    """
    if isinstance(duty, bool) or not isinstance(duty, int) or not 1 <= duty <= MAX_DUTY:
        raise ValueError(f"duty {duty!r} is not a whole number 1..{MAX_DUTY}")
    return 101 - duty


@dataclass(frozen=True, slots=True)
class PhysicalEffects:
    """The static-friction effect of the drive (``[emulator.effects]``, in either profile); off by
    default. The arm's play and encoder noise are its physics (``[emulator.physics]``).

    ``miss_probability``: chance (0 ≤ p < 1) that a step pulse is lost (the shaft does not move),
    applied only to pulses issued at a duty above ``miss_above_duty`` (the start duty: a stepper
    with high static friction keeps up below its pull-in rate and loses steps above it).
    """

    miss_probability: float = 0.0
    miss_above_duty: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.miss_probability < 1.0:
            raise ValueError(f"miss_probability {self.miss_probability!r} is not in [0, 1)")
        if not 0 <= self.miss_above_duty <= MAX_DUTY:
            raise ValueError(f"miss_above_duty {self.miss_above_duty!r} is not in 0..{MAX_DUTY}")


@dataclass(slots=True)
class Run:
    """Pulses ``start, start + period, …`` in one direction with nothing special in between.

    ``pulses`` is None for a blocked run (hard limit or stall fault): pulses forever, no step.
    Otherwise the run issues ``pulses`` pulses of which ``steps`` move the shaft (the misses are
    spread evenly, the last pulse always steps); ``offset_end`` is the counter offset after the
    last pulse (Hall reset, spurious count), ``glitch`` the spurious count made with it.
    """

    start: int
    period: int
    direction: int
    pulses: int | None
    steps: int
    s0: int
    offset0: int
    offset_end: int
    glitch: int
    hall_at_end: bool
    done: int = 0

    def steps_after(self, pulses: int) -> int:
        """Shaft steps made by the first ``pulses`` pulses."""
        return 0 if self.pulses is None else pulses * self.steps // self.pulses

    def offset_after(self, pulses: int) -> int:
        """Counter offset after the first ``pulses`` pulses."""
        return self.offset_end if pulses == self.pulses else self.offset0


#: What a clone's bit generator is made from before it takes the original's state: any fixed
#: seed does (an unseeded one reads the system's entropy first, which costs more than the rest).
_CLONE_SEED: Final = np.random.SeedSequence(0)


def clone_bits(bits: np.random.PCG64 | None) -> np.random.PCG64 | None:
    """An independent bit generator in the same state (cheaper than a deep copy)."""
    if bits is None:
        return None
    twin = np.random.PCG64(_CLONE_SEED)
    twin.state = bits.state
    return twin
