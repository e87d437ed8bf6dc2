"""What a failing twin's divergence looks like (``armbench.bench.twin_check.diagnosis``), on
synthetic reply streams with one known effect each: a joint moving from rest to rest, lifting and
lowering
back by about as much (the way step loss shows on a lifting joint), at the arm's reply rate, the
arm's stream with a count of noise; the twin's stream the same motion with the effect, or the
arm's with it (play, step loss: the arm has what the twin lacks). The streams are made here,
not by the emulator: the effects are known exactly only so."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armbench.bench.twin_check.diagnosis import KINDS, diagnose, diagnose_joints, failing_joints
from armbench.record import Measurement
from armbench.record.limits import Limit

FloatArray = npt.NDArray[np.float64]
REPLY_S = 0.0025
TICK_COUNTS = 1.6          # one wire tick (1e-4 rad) of joint 2's encoder
NOISE_COUNTS = 1.0
#: Per kind, the range of the effect's size drawn: each well above a count of noise.
SIZES = {"offset": (5.0, 200.0), "timing": (0.005, 0.05), "scale": (0.01, 0.1),
         "step_loss": (0.03, 0.3), "play": (5.0, 100.0)}
Move = tuple[float, float, float]   # command time (s), target (counts), speed (counts/s)


def _moves(rng: np.random.Generator, n: int = 8) -> tuple[list[Move], float]:
    """``n`` commands: up by 2000..12000 counts, down by 0.8..1.25 times that, each at its own
    speed, each after the move before arrived with room to spare (a rest of 0.2..0.6 s)."""
    out: list[Move] = []
    t, pos, way, speed = 0.3, 0.0, 0.0, 0.0
    for k in range(n):
        if k % 2 == 0:
            way, speed = rng.uniform(2000, 12000), rng.uniform(3000, 8000)
        else:
            way = -way * rng.uniform(0.8, 1.25)
        out.append((t, pos + way, speed))
        pos += way
        t += abs(way) / speed * 1.5 + rng.uniform(0.2, 0.6)
    return out, t + 0.3


def _render(t: FloatArray, moves: list[Move], factor: Callable[[int], float] = lambda k: 1.0,
            reach: Callable[[int], float] = lambda k: 1.0) -> FloatArray:
    """The joint's angle (counts) at the times ``t``: each command's move at its speed times
    ``factor(k)``, stopping at its target or at ``reach(k)`` of the way there (a stall: it stays
    there until the next command)."""
    q = np.zeros(len(t))
    pos = 0.0
    ends = [m[0] for m in moves[1:]] + [np.inf]
    for k, ((t0, target, speed), t1) in enumerate(zip(moves, ends, strict=True)):
        way = (target - pos) * reach(k)
        v = speed * factor(k)
        inside = (t >= t0) & (t < t1)
        q[inside] = pos + np.sign(way) * np.minimum(v * (t[inside] - t0), abs(way))
        if np.isfinite(t1):
            pos += np.sign(way) * min(v * (t1 - t0), abs(way))
    return q


def _play(motor: FloatArray, width: float) -> FloatArray:
    """A link behind a play of ``width`` (counts): it follows the motor only when pushed."""
    out = np.empty_like(motor)
    link = motor[0]
    for i, m in enumerate(motor):
        link = min(max(link, m - width / 2), m + width / 2)
        out[i] = link
    return out


def _streams(kind: str, size: float, sign: float, seed: int
             ) -> tuple[FloatArray, FloatArray, FloatArray, list[float]]:
    """Times, the arm's and the twin's stream (counts) and the commands' times, the twin off
    by one effect of ``size`` (signed by ``sign`` where the effect has a sign; for play and
    step loss: which stream has it)."""
    rng = np.random.default_rng(seed)
    moves, end = _moves(rng)
    t = np.arange(0.0, end, REPLY_S)
    arm = _render(t, moves)
    twin = arm.copy()
    if kind == "offset":
        twin = arm + sign * size
    elif kind == "timing":
        twin = np.interp(t - sign * size, t, arm)
    elif kind == "scale":
        twin = _render(t, moves, factor=lambda k: 1.0 + sign * size)
    elif kind == "step_loss":    # the lifting moves lose a share; perhaps one of them stalls
        stall = int(rng.integers(0, 4)) * 2 if rng.random() < 0.5 else -1
        lossy = _render(t, moves, factor=lambda k: 1.0 - size if k % 2 == 0 else 1.0,
                        reach=lambda k: 0.5 if k == stall else 1.0)
        arm, twin = (lossy, arm) if sign > 0 else (arm, lossy)
    elif kind == "play":
        arm, twin = (_play(arm, size), arm) if sign > 0 else (arm, _play(arm, size))
    noisy = np.round(arm + rng.normal(0.0, NOISE_COUNTS, len(t)))
    return t, noisy, np.round(twin), [m[0] for m in moves]


@settings(max_examples=60, deadline=None)
@given(kind=st.sampled_from(sorted(SIZES)), share=st.floats(0.0, 1.0),
       sign=st.sampled_from([-1.0, 1.0]), seed=st.integers(0, 2 ** 32 - 1))
def test_a_known_effect_is_named(kind: str, share: float, sign: float, seed: int) -> None:
    """Each effect, of any size in its range and either sign, on any motion drawn: the
    diagnosis names it, and it explains most of the divergence."""
    low, high = SIZES[kind]
    t, arm, twin, commands = _streams(kind, low + share * (high - low), sign, seed)
    d = diagnose(2, t, arm, twin, commands, TICK_COUNTS)
    assert d.kind == kind, (d.kind, d.fractions)
    assert d.explained >= 0.5
    assert set(d.fractions) == set(KINDS)


@pytest.mark.parametrize(("kind", "looks", "step"), [
    ("offset", "a constant -40.0 counts", "--tracker"),
    ("timing", "the twin behind by 20.0 ms", "--realtime-factor"),
    ("scale", "the twin moves 5.0% faster than the arm", "joints.j2.gear_ratio"),
    ("step_loss", "the arm behind along the motion (it loses steps", "j2.loss_law"),
    ("play", "the arm lags the other after each reversal", "--tracker"),
])
def test_the_text_says_the_size_and_the_next_step(kind: str, looks: str, step: str) -> None:
    """The sentence gives the fitted size with its sense (which stream is ahead, faster,
    lagging), and the next step is the one for the kind."""
    size = {"offset": 40.0, "timing": 0.02, "scale": 0.05, "step_loss": 0.2, "play": 40.0}[kind]
    sign = -1.0 if kind == "offset" else 1.0
    t, arm, twin, commands = _streams(kind, size, sign, 7)
    d = diagnose(2, t, arm, twin, commands, TICK_COUNTS)
    assert d.kind == kind, d.fractions
    assert looks in d.looks, d.looks
    assert step in d.next_step, d.next_step
    text = "\n".join(d.lines())
    assert text.startswith(f"diagnosis: {KINDS[kind]}: ") and "\nnext: " in text
    a, b = d.span_s
    assert t[0] <= a <= b <= t[-1]
    body = d.to_json()
    assert {"kind", "explained", "span_s", "next_step"} <= set(body)


def test_the_span_holds_the_largest_divergence() -> None:
    """The span reported is around the largest divergence: for a scale error, the end of the
    longest move, where the twin is furthest ahead."""
    t, arm, twin, commands = _streams("scale", 0.05, 1.0, 3)
    d = diagnose(2, t, arm, twin, commands, TICK_COUNTS)
    peak = float(t[int(np.argmax(np.abs(twin - arm)))])
    a, b = d.span_s
    assert a <= peak <= b
    assert b - a < 0.5 * (t[-1] - t[0])


@pytest.mark.parametrize("what", ["white noise", "a slow sine"])
def test_what_no_known_effect_explains_is_said_so(what: str) -> None:
    """A divergence none of the effects has (noise, a wave unrelated to the motion) is not
    given a kind: none explains it, a model the evidence did not support."""
    rng = np.random.default_rng(11)
    moves, end = _moves(rng)
    t = np.arange(0.0, end, REPLY_S)
    arm = _render(t, moves)
    off = (rng.normal(0.0, 30.0, len(t)) if what == "white noise"
           else 50.0 * np.sin(2 * np.pi * 0.7 * t + 1.0))
    d = diagnose(2, t, arm, np.round(arm + off), [m[0] for m in moves], TICK_COUNTS)
    assert d.kind == "unexplained", d.fractions
    assert d.explained < 0.5
    assert d.looks.startswith("none of the known effects explains it (the best, ")
    assert "a model the evidence did not support" in d.next_step
    assert d.lines()[0].startswith("diagnosis: none of the known effects explains it")


def test_only_failing_joints_are_diagnosed() -> None:
    """The joints with a ``twin.jN.*`` figure outside its limit get a diagnosis, the others
    None; figures of the whole check do not name a joint."""
    limit = Limit("twin.*", "", high=1.0)
    measurements = [Measurement("twin.j1.rms_per_allowed", 0.5, "", limit, "pass", "lower"),
                    Measurement("twin.j3.settled_per_allowed", 2.0, "", limit, "fail", "lower"),
                    Measurement("twin.arrival.rms_per_allowed", 3.0, "", limit, "fail", "lower")]
    assert failing_joints(measurements) == [3]
    t, arm, twin, commands = _streams("scale", 0.05, 1.0, 5)
    counts = np.asarray([TICK_COUNTS * 1e4] * 4)
    arm_rad = np.column_stack([arm / counts[0]] * 4)
    twin_rad = np.column_stack([twin / counts[0]] * 4)
    out = diagnose_joints(t, arm_rad, twin_rad, counts, commands, 1e-4, [3])
    assert [d is None for d in out] == [True, True, False, True]
    assert out[2] is not None and out[2].joint == 3 and out[2].kind == "scale"
    assert "joints.j3.gear_ratio" in out[2].next_step
