"""The event-driven joint model (``fakes/twin/joint.py``) against the cycle-by-cycle reference and
the paper: speed law (12), Hall homing, limits, and the physical effects."""

from __future__ import annotations

import copy
import math
from dataclasses import replace
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from joint_reference import ReferenceJoint

from armbench.drivers.model.settings import DEFAULT_JOINTS, JointSettings
from armbench.fakes.twin.joint import (
    CYCLE_S,
    JointModel,
    PhysicalEffects,
    PwmState,
    StopRule,
    Transition,
    step_period_ticks,
)
from armbench.fakes.twin.physics import ideal_joint
from armbench.fakes.twin.stepper import clone_bits

LOOKAHEAD_TICKS = 3_000  # how far the reference checks next_event_tick when the event is far


def snapshot(m: JointModel | ReferenceJoint) -> dict[str, object]:
    """Everything observable that the model and the reference share."""
    if isinstance(m, JointModel):
        return {"tick": m.tick, "state": m.state, "n": m.non_moved_steps,
                "motor_steps": m.motor_steps, "counter": m.counter, "motion": m.motion,
                "pulses": m.pulses, "steps_taken": m.steps_taken,
                "steps_blocked": m.steps_blocked, "homing": m.homing, "at_limit": m.at_limit,
                "target": m.target_counts, "homed_tick": m.homed_tick,
                "transitions": m.drain_transitions()}
    transitions, m.transitions = m.transitions, []
    return {"tick": m.tick, "state": m.state, "n": m.n, "motor_steps": m.motor_steps,
            "counter": m.counter, "motion": m.motion, "pulses": m.pulses,
            "steps_taken": m.steps_taken, "steps_blocked": m.steps_blocked,
            "homing": m.homing_dir != 0, "at_limit": m.at_limit, "target": m.target,
            "homed_tick": m.homed_tick, "transitions": transitions}


def check_next_event(model: JointModel, ref: ReferenceJoint) -> None:
    """The model's next_event_tick is the reference's next motion change or homing completion."""
    predicted = model.next_event_tick()
    probe = copy.deepcopy(ref)
    probe.transitions = []
    homed = probe.homed_tick
    horizon = probe.tick + LOOKAHEAD_TICKS
    stop = horizon if predicted is None else min(predicted, horizon)
    while probe.tick < stop and not probe.transitions and probe.homed_tick == homed:
        probe.cycle()
    events = [t.tick for t in probe.transitions]
    if probe.homed_tick != homed:
        assert probe.homed_tick is not None
        events.append(probe.homed_tick)
    if predicted is None or predicted > horizon:
        assert events == [], f"reference event at {events}, model predicted {predicted}"
    else:
        assert events and min(events) == predicted


@st.composite
def joints(draw: st.DrawFn) -> JointSettings:
    """Small joints (tens to hundreds of steps of travel) with varied encoder ratios."""
    lower = draw(st.floats(-1.2, -0.05))
    upper = draw(st.floats(0.05, 1.2))
    hall = lower + draw(st.floats(0.0, 1.0)) * (upper - lower)
    return JointSettings(
        "jt", draw(st.sampled_from([0.5, 1.0, 1.5])), lower, upper, hall_rad=hall,
        microsteps=draw(st.sampled_from([1, 2, 8])),
        encoder_counts_per_motor_rev=draw(st.sampled_from([2000, 1999, 1000, 500, 4000, 333])))


DUTIES = st.one_of(st.just(0), st.integers(1, 99), st.integers(85, 99))


@st.composite
def scenarios(draw: st.DrawFn) -> tuple[JointSettings, dict[str, int | str | None], list[tuple[
        int, tuple[object, ...]]]]:
    """A joint, the model's start arguments, and timed inputs (≤ 40 000 cycles in all)."""
    joint = draw(joints())
    lo = round(joint.lower_rad * joint.steps_per_rad)
    hi = round(joint.upper_rad * joint.steps_per_rad)
    c_lo = math.floor(lo * joint.counts_per_step) - 40
    c_hi = math.floor(hi * joint.counts_per_step) + 40
    start: dict[str, int | str | None] = {
        "motor_steps": draw(st.integers(lo, hi)),
        "counter": draw(st.none() | st.integers(c_lo, c_hi)),
        "tick": draw(st.integers(0, 10**6)),
        "deadband_counts": draw(st.sampled_from([0, 1, 1, 1, 2, 3])),
        "stop_rule": draw(st.sampled_from(["window", "reach"])),
    }
    action = st.one_of(
        st.tuples(st.just("ref"), st.integers(c_lo, c_hi), DUTIES),
        st.tuples(st.just("ref"), st.integers(c_lo, c_hi), DUTIES),
        st.tuples(st.just("query")),
        st.tuples(st.just("stall"), st.booleans()),
        st.tuples(st.just("home"), st.sampled_from([1, -1]), st.integers(1, 99)),
    )
    events = draw(st.lists(st.tuples(st.integers(0, 3_000), action), min_size=1, max_size=20))
    budget, timed = 40_000, list[tuple[int, tuple[object, ...]]]()
    for dt, act in events:
        budget -= dt
        if budget < 0:
            break
        timed.append((dt, act))
    return joint, start, timed


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenarios())
def test_model_matches_the_cycle_by_cycle_reference(
        scenario: tuple[JointSettings, dict[str, int | str | None],
                        list[tuple[int, tuple[object, ...]]]],
) -> None:
    joint, start, events = scenario
    model = JointModel(joint, **start)  # type: ignore[arg-type]
    ref = ReferenceJoint(joint, **start)  # type: ignore[arg-type]
    tick = model.tick
    assert snapshot(model) == snapshot(ref)
    for dt, act in [*events, (2_000, ("query",))]:
        tick += dt
        model.advance(tick)
        ref.advance(tick)
        assert snapshot(model) == snapshot(ref)
        check_next_event(model, ref)
        kind = act[0]
        if kind == "ref":
            _, target, duty = act
            assert isinstance(target, int) and isinstance(duty, int)
            if ref.homing_dir:
                with pytest.raises(RuntimeError):
                    model.set_reference(tick, target, duty)
            else:
                model.set_reference(tick, target, duty)
                ref.set_reference(tick, target, duty)
        elif kind == "stall":
            assert isinstance(act[1], bool)
            model.stall(tick, act[1])
            ref.stall(tick, act[1])
        elif kind == "home":
            _, direction, duty = act
            assert isinstance(direction, int) and isinstance(duty, int)
            model.home(tick, direction, duty)
            ref.home(tick, direction, duty)
        assert snapshot(model) == snapshot(ref)


@settings(max_examples=60, deadline=None)
@given(joints(), st.integers(-300, 300), DUTIES, st.lists(st.integers(1, 500), max_size=30))
def test_pulses_in_every_interval_match_whatever_the_query_ticks(
        joint: JointSettings, target: int, duty: int, gaps: list[int]) -> None:
    model, ref = JointModel(joint), ReferenceJoint(joint)
    model.set_reference(0, target, duty)
    ref.set_reference(0, target, duty)
    tick = 0
    for gap in gaps:
        before = (model.pulses, ref.pulses)
        tick += gap
        model.advance(tick)
        ref.advance(tick)
        assert model.pulses - before[0] == ref.pulses - before[1]
        assert (model.motor_steps, model.counter) == (ref.motor_steps, ref.counter)


def test_a_mid_move_reversal_matches_the_reference() -> None:
    joint = replace(DEFAULT_JOINTS[2], gear_ratio=2.0)
    model, ref = JointModel(joint), ReferenceJoint(joint)
    for m in (model, ref):
        m.set_reference(0, 400, 99)
        m.set_reference(301, -77, 60)  # reversal in PWM_LOW, through the Hall at 0
        m.set_reference(5_000, -77, 0)  # hold mid-move
        m.set_reference(5_100, 30, 99)
        m.advance(20_000)
    assert snapshot(model) == snapshot(ref)
    assert model.motion == "stopped" and abs(model.counter - 30) <= 1


# --- speed law (12) --------------------------------------------------------------------------


@pytest.mark.parametrize(("duty", "period"), [(1, 100), (50, 51), (99, 2)])
def test_speed_law_12_over_a_long_move(duty: int, period: int) -> None:
    joint = DEFAULT_JOINTS[0]  # 12 732 steps/rad: 20 000 steps are 1.57 rad, inside ±140°
    assert step_period_ticks(duty) == period
    model = JointModel(joint)
    model.set_reference(0, 25_000, duty)  # 20 000 steps at 5/4 count per step
    # STOP -> PWM_HIGH in cycle 0; pulse k in cycle 1 + k·period.
    for k in (0, 1, 2, 777, 9_999, 19_999):
        model.advance(1 + k * period)
        assert model.pulses == k
        model.advance(2 + k * period)
        assert model.pulses == k + 1 and model.motor_steps == k + 1
    model.advance(1 + 20_001 * period)
    cw, stopped = model.drain_transitions()
    assert cw == Transition(1, "cw", 0)
    assert stopped == Transition(2 + 20_000 * period, "stopped", 25_000)
    assert model.steps_taken == 20_000
    seconds = Fraction(stopped.tick - 2, 1) * Fraction(CYCLE_S)
    assert Fraction(model.steps_taken) / seconds == pytest.approx(1e6 / (80 * (101 - duty)))


def test_duty_out_of_range_is_refused() -> None:
    model = JointModel(DEFAULT_JOINTS[1])
    with pytest.raises(ValueError, match="duty"):
        model.set_reference(0, 10, 100)
    with pytest.raises(ValueError, match="duty"):
        model.home(0, 1, 0)
    model.advance(10)
    with pytest.raises(ValueError, match="before"):
        model.advance(9)


# --- Hall, homing and limits -----------------------------------------------------------------


def test_homing_towards_the_hall_resets_the_counter_and_stops_there() -> None:
    joint = DEFAULT_JOINTS[1]  # Hall at 0 rad
    model = JointModel(joint, motor_steps=5_000, counter=77)  # counter lost at power-off
    model.home(10, -1, 99)
    assert model.homing and model.next_event_tick() == 11
    model.advance(11)
    assert model.drain_transitions() == [Transition(11, "ccw", 77)]
    last_pulse = 11 + 4_999 * 2  # 5 000 steps, period 2
    assert model.next_event_tick() == last_pulse + 1
    model.advance(last_pulse + 1)
    assert not model.homing and model.homed_tick == last_pulse + 1
    assert (model.motor_steps, model.counter) == (model.hall_step, model.hall_count)
    assert model.target_counts == model.hall_count
    model.advance(last_pulse + 10)
    assert model.drain_transitions() == [Transition(last_pulse + 3, "stopped", model.hall_count)]
    assert model.next_event_tick() is None


def test_homing_away_from_the_hall_ends_stalled_at_the_limit() -> None:
    joint = DEFAULT_JOINTS[3]  # limits −30°..120°, Hall at 0
    model = JointModel(joint, motor_steps=1_000, counter=5)
    model.home(0, 1, 99)
    model.advance(10_000_000)
    assert model.homing and model.at_limit and model.homing_failed
    assert model.motor_steps == model.upper_steps
    assert model.steps_blocked > 0 and model.homed_tick is None
    assert model.motion == "cw" and model.next_event_tick() is None
    with pytest.raises(RuntimeError, match="homing"):
        model.set_reference(10_000_001, 0, 50)
    model.home(10_000_001, -1, 99)  # the retry the other way succeeds
    model.advance(20_000_000)
    assert not model.homing and model.motion == "stopped" and model.counter == model.hall_count


def test_homing_on_the_hall_completes_at_once() -> None:
    model = JointModel(DEFAULT_JOINTS[1], counter=999)
    model.home(5, 1, 10)
    assert not model.homing and model.homed_tick == 5 and model.counter == model.hall_count
    assert model.next_event_tick() is None


def test_a_move_into_a_limit_stalls_there_and_keeps_pulsing() -> None:
    joint = replace(DEFAULT_JOINTS[1], gear_ratio=1.0)  # end stop 70° + 1° = 316 steps
    model = JointModel(joint)
    model.set_reference(0, 10_000, 99)
    model.advance(100_000)
    assert model.motor_steps == model.upper_steps == 316 and model.at_limit
    assert model.counter == math.floor(316 * Fraction(5, 4))
    assert model.pulses == model.steps_taken + model.steps_blocked
    assert model.state in (PwmState.PWM_HIGH, PwmState.PWM_LOW)
    assert model.next_event_tick() is None
    model.set_reference(100_000, 0, 99)  # backing out works
    model.advance(200_000)
    assert model.motion == "stopped" and (model.motor_steps, model.counter) == (1, 1)  # deadband


def test_the_stall_fault_blocks_steps_until_released() -> None:
    model = JointModel(DEFAULT_JOINTS[2])
    model.set_reference(0, 1_000, 99)
    model.stall(100, True)
    model.advance(10_000)
    assert model.stalled and model.motor_steps == 50 and model.steps_blocked > 4_000
    assert model.drain_transitions()[-1].motion == "cw" and model.next_event_tick() is None
    model.stall(10_000, False)
    model.advance(20_000)
    # pulses in cycles 1, 3, 5, … throughout; the PWM_HIGH after the last one stops
    assert model.steps_taken == 800
    assert model.drain_transitions() == [Transition(2 * model.pulses + 2, "stopped", 1_000)]


# --- event-driven cost (a behaviour, not a stopwatch) -----------------------------------------

BIG_JOINT = replace(DEFAULT_JOINTS[0], gear_ratio=500.0)  # ±311 000 steps of travel


def test_a_200000_step_move_costs_a_bounded_number_of_iterations() -> None:
    model = JointModel(BIG_JOINT, motor_steps=-100_000)
    model.set_reference(0, 125_000, 99)  # crosses the Hall at 0
    model.advance(10**7)
    assert model.steps_taken == 200_000 and model.motion == "stopped"
    assert model.iterations <= 10
    assert model.counter == 125_000


def test_queries_cost_a_bounded_number_of_iterations_each() -> None:
    model = JointModel(BIG_JOINT)
    model.set_reference(0, 250_000, 50)
    for tick in range(0, 10**7, 100_000):
        model.advance(tick)
        model.next_event_tick()
    assert model.iterations <= 3 * 100 + 10


# --- physical effects ------------------------------------------------------------------------

def imperfect(joint: JointSettings, seed: int) -> JointModel:
    """Missed steps, a play of 0.01 rad and encoder noise (about 2 spurious counts per second of
    stepping at full duty: 2 Hz × 160 µs per step over 1.25 counts per step)."""
    return JointModel(joint, effects=PhysicalEffects(miss_probability=0.2, miss_above_duty=40),
                      physics=ideal_joint(backlash_rad=0.01), noise_per_count=2.56e-4, seed=seed)


def run_moves(model: JointModel, poll_every: int | None) -> tuple[object, ...]:
    """Three moves; the model is polled (advance + next_event_tick) every ``poll_every`` cycles."""
    script = [(0, 60_000, 99), (600_000, -20_000, 70), (1_500_000, 3_000, 41)]
    end = 3_000_000
    polls = range(0, end, poll_every) if poll_every else range(0)
    inputs = sorted([(t, (target, duty)) for t, target, duty in script]
                    + [(t, None) for t in polls], key=lambda x: x[0])
    for tick, ref in inputs:
        if ref is None:
            model.advance(tick)
            model.next_event_tick()
        else:
            model.set_reference(tick, *ref)
    model.advance(end)
    return (model.counter, model.motor_steps, model.true_angle_rad(), model.pulses,
            model.steps_missed, model.spurious_counts, tuple(model.drain_transitions()))


def test_same_seed_same_run_whatever_the_polling() -> None:
    joint = DEFAULT_JOINTS[0]
    first = run_moves(imperfect(joint, 7), None)
    again = run_moves(imperfect(joint, 7), 3_337)
    other = run_moves(imperfect(joint, 8), None)
    assert first == again
    assert first != other


def observe(m: JointModel) -> tuple[object, ...]:
    """Everything a run with effects can be compared on."""
    return (m.tick, m.state, m.non_moved_steps, m.motor_steps, m.counter, m.motion,
            m.true_angle_rad(), m.pulses, m.steps_taken, m.steps_missed, m.steps_blocked,
            m.spurious_counts, m.homing, m.homed_tick, tuple(m.drain_transitions()))


def check_prediction(m: JointModel) -> None:
    """next_event_tick names the first tick at which motion or homing has changed."""
    predicted = m.next_event_tick()
    if predicted is None:
        return
    probe = copy.deepcopy(m)
    probe.drain_transitions()
    homed = probe.homed_tick
    probe.advance(predicted - 1)
    assert probe.drain_transitions() == [] and probe.homed_tick == homed
    probe.advance(predicted)
    assert probe.drain_transitions() != [] or probe.homed_tick == predicted


@settings(max_examples=80, deadline=None)
@given(joints(), st.integers(0, 2**64),
       st.builds(PhysicalEffects, st.floats(0.0, 0.6), st.integers(0, 99)),
       st.floats(0.0, 0.05), st.sampled_from([0.0, 1e-3, 0.03, 0.5]),
       st.lists(st.tuples(st.integers(0, 20_000), st.integers(-400, 400), DUTIES), min_size=1,
                max_size=8),
       st.integers(97, 5_000))
def test_effects_are_reproducible_whatever_the_polling(
        joint: JointSettings, seed: int, effects: PhysicalEffects, play_rad: float, noise: float,
        refs: list[tuple[int, int, int]], poll_every: int) -> None:
    quiet, polled = (JointModel(joint, effects=effects, seed=seed,
                                physics=ideal_joint(backlash_rad=play_rad), noise_per_count=noise)
                     for _ in range(2))
    tick = 0
    for dt, target, duty in refs:
        tick += dt
        quiet.set_reference(tick, target, duty)
        while polled.tick + poll_every < tick:
            polled.advance(polled.tick + poll_every)
            check_prediction(polled)
        polled.set_reference(tick, target, duty)
        check_prediction(polled)
    quiet.advance(tick + 50_000)
    polled.advance(tick + 50_000)
    assert observe(quiet) == observe(polled)
    assert quiet.pulses == quiet.steps_taken + quiet.steps_missed + quiet.steps_blocked


def test_missed_steps_make_moves_longer_but_end_at_the_same_place() -> None:
    joint = DEFAULT_JOINTS[0]
    clean = JointModel(joint)
    lossy = JointModel(joint, effects=PhysicalEffects(miss_probability=0.25), seed=3)
    for m in (clean, lossy):
        m.set_reference(0, 30_000, 99)
        m.advance(10**6)
    (_, stop_clean), (_, stop_lossy) = clean.drain_transitions(), lossy.drain_transitions()
    assert (lossy.counter, lossy.motor_steps) == (clean.counter, clean.motor_steps)
    assert stop_lossy.tick > stop_clean.tick
    assert lossy.steps_taken == clean.steps_taken == 24_000
    assert lossy.steps_missed / lossy.pulses == pytest.approx(0.25, abs=0.01)
    assert stop_lossy.tick - 2 == 2 * lossy.pulses  # pulses stay on the period-2 grid


def test_no_missed_steps_at_or_below_the_start_duty() -> None:
    model = JointModel(DEFAULT_JOINTS[0], effects=PhysicalEffects(0.5, miss_above_duty=60))
    model.set_reference(0, 1_000, 60)
    model.advance(10**6)
    assert model.steps_missed == 0 and model.steps_taken == 800


def test_backlash_changes_only_the_true_angle() -> None:
    joint = DEFAULT_JOINTS[2]
    b = 0.004
    clean = JointModel(joint)
    play = JointModel(joint, physics=ideal_joint(backlash_rad=b))
    motor = joint.steps_per_rad
    true_angles = []
    for target, tick in ((5_000, 0), (-5_000, 200_000), (-4_990, 400_000)):
        for m in (clean, play):
            m.set_reference(tick, target, 99)
            m.advance(tick + 100_000)
        assert (play.counter, play.motor_steps, play.pulses) == (
            clean.counter, clean.motor_steps, clean.pulses)
        assert clean.true_angle_rad() == play.motor_steps / motor
        true_angles.append((play.motor_steps, play.true_angle_rad()))
    # after a long move the joint trails the motor by half the play
    (s1, q1), (s2, q2), (s3, q3) = true_angles
    assert (s1, s2, s3) == (4_000, -3_999, -3_992)
    assert q1 == pytest.approx(s1 / motor - b / 2)
    assert q2 == pytest.approx(s2 / motor + b / 2)
    # a short reversal (7 steps, less than the play of 39 steps) leaves the joint where it was
    assert q3 == q2


def test_encoder_noise_is_reproducible_and_the_loop_still_settles() -> None:
    # 5 spurious counts per second of stepping at full duty (160 µs, 1.25 counts per step)
    noisy = [JointModel(BIG_JOINT, noise_per_count=5.0 * 160e-6 / 1.25, seed=11)
             for _ in range(2)]
    for m in noisy:
        m.set_reference(0, 125_000, 99)  # 100 000 steps, 16 s of stepping
        m.advance(10**6)
    a, b = noisy
    assert (a.counter, a.motor_steps, a.spurious_counts) == (
        b.counter, b.motor_steps, b.spurious_counts)
    assert 40 <= a.spurious_counts <= 130  # 5 Hz × 16 s = 80 expected
    assert a.motion == "stopped" and abs(a.counter - 125_000) <= 1
    assert a.motor_steps != 100_000  # the firmware trusted the glitches
    assert a.iterations <= 10 + 3 * a.spurious_counts


@pytest.mark.parametrize("deadband", [1, 2])
def test_the_reach_rule_stops_on_or_just_past_the_target_and_stays(deadband: int) -> None:
    """With 5/4 counts per microstep the counter skips one value in five: ``reach`` stops on the
    target or the count after it (never short, and with a deadband of a count or more never
    hunting), ``window`` inside its deadband (with a deadband of 0 both rules hunt about a
    skipped count)."""
    joint = DEFAULT_JOINTS[0]
    assert joint.counts_per_step == Fraction(5, 4)
    rules: tuple[StopRule, ...] = ("window", "reach")
    for rule in rules:
        hunting = JointModel(joint, stop_rule=rule, deadband_counts=0, motor_steps=0)
        hunting.set_reference(0, 1004, 99)  # never a value of the counter counting up from 0
        hunting.advance(200_000)
        assert hunting.pulses > 1000 > abs(hunting.counter - 1004)
    for rule in rules:
        for target in range(1000, 1020):
            for direction in (1, -1):
                start = target - direction * 500
                model = JointModel(joint, stop_rule=rule, deadband_counts=deadband,
                                   motor_steps=round(start / joint.counts_per_step))
                model.set_reference(0, target, 99)
                model.advance(200_000)
                assert model.motion == "stopped", (rule, target, direction)
                past = (model.counter - target) * direction
                if rule == "reach":
                    assert past in (0, 1), (target, direction, past)
                else:
                    assert abs(past) <= deadband
                pulses = model.pulses
                model.advance(400_000)
                assert model.pulses == pulses  # at rest for good


def test_the_reach_rule_restarts_only_beyond_the_deadband() -> None:
    """At rest one count past the target (the skipped count) a ``reach`` joint stays; a target
    moved beyond the deadband starts it again, towards the target."""
    joint = DEFAULT_JOINTS[0]
    model = JointModel(joint, stop_rule="reach", motor_steps=0, counter=1)
    model.set_reference(0, 0, 99)
    model.advance(10_000)
    assert (model.pulses, model.counter) == (0, 1)
    model.set_reference(model.tick, -5, 99)
    model.advance(model.tick + 10_000)
    assert model.motion == "stopped" and model.counter in (-5, -6) and model.pulses > 0


def test_an_unknown_stop_rule_is_refused() -> None:
    with pytest.raises(ValueError, match="stop_rule 'exact'"):
        JointModel(DEFAULT_JOINTS[0], stop_rule="exact")  # type: ignore[arg-type]


@given(st.integers(0, 2**64), st.integers(0, 50))
def test_a_cloned_bit_generator_goes_on_alone_from_the_same_state(seed: int, drawn: int) -> None:
    """A clone draws what its original would have drawn next, and drawing from one leaves the
    other where it was (a joint's prediction draws on its clone's streams only)."""
    bits = np.random.PCG64([seed, 1])
    np.random.Generator(bits).random(drawn)
    twin = clone_bits(bits)
    assert twin is not None and twin is not bits and clone_bits(None) is None
    ahead = np.random.Generator(twin).random(5)
    assert list(np.random.Generator(bits).random(5)) == list(ahead)
    assert twin.state == bits.state
