"""Replies read late at a move's start (``align._stale_at_start``, a part of
:func:`~armbench.bench.calibrate.align.late_stamps`): the vectorised rule against a naive
reference, one Python iteration per reply and joint as the rule is written, on streams of a
joint at rest that starts to move with some replies read late; and its cost on a capture's
length, which a twin check pays ten times per replay (``twin_check``: three rounds each)."""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from hypothesis import given, settings
from hypothesis import strategies as st

from armbench.bench.calibrate.align import (
    LATE_SIGMAS,
    LATE_TICKS,
    ONSET_REPLIES,
    REST_TICKS,
    SAME_INSTANT_S,
    STEADY_TICKS,
    TICK_RAD,
    _stale_at_start,
)

FloatArray = npt.NDArray[np.float64]
PERIOD_S = 0.0027
"""The emulator's reply interval (s)."""
MOVE_S = 0.3
"""How long each move of a stream lasts (s)."""


def reference(t: FloatArray, q: FloatArray, command_times: Sequence[float],
              scatter_s: float) -> npt.NDArray[np.bool_]:
    """The rule of ``_stale_at_start`` reply by reply and joint by joint (deliberately naive)."""
    out = np.zeros(max(0, len(t) - 2), dtype=bool)
    ct = np.asarray(sorted(command_times)) + SAME_INSTANT_S
    n = ONSET_REPLIES
    for i in range(1, len(t) - n):
        nxt = slice(i + 1, i + 1 + n)
        if np.searchsorted(ct, t[i]) != np.searchsorted(ct, t[i + n]):
            continue
        dt = np.diff(t[nxt])
        if np.any(dt <= 0):
            continue
        for j in range(q.shape[1]):
            if abs(q[i, j] - q[i - 1, j]) > REST_TICKS * TICK_RAD:
                continue
            way = q[nxt, j] - q[i, j]
            if abs(way[-1]) < STEADY_TICKS * TICK_RAD or np.any(way * way[-1] < 0):
                continue
            speed = float(np.median(np.abs(np.diff(q[nxt, j])) / dt))
            if speed <= 0:
                continue
            left = float(np.median(t[nxt] - np.abs(way) / speed))
            limit = max(LATE_SIGMAS * scatter_s * speed, LATE_TICKS * TICK_RAD)
            if (t[i] - left) * speed > limit:
                out[i - 1] = True
                break
    return out


def stream(moves: Sequence[tuple[int, float, float]], late: dict[int, float], n: int,
           jitter_s: float, seed: int) -> tuple[FloatArray, FloatArray, list[float]]:
    """``n`` replies, one every :data:`PERIOD_S`, their stamps scattered by ``jitter_s``; each
    move ``(joint, start_s, speed_rad_s)`` takes its joint from rest at its start for
    :data:`MOVE_S` (the command a little before), the angles quantised to wire ticks;
    ``late[k]``: reply ``k`` stamped that much later with its angles as they were (composed
    before the joint left, read after)."""
    rng = np.random.default_rng(seed)
    steps = np.zeros((n + 1, 4))   # each joint's speed, from one reply to the next, as steps
    for joint, start_s, speed in moves:
        first = min(n, int(start_s / PERIOD_S))
        steps[first, joint] += speed
        steps[min(n, first + round(MOVE_S / PERIOD_S)), joint] -= speed
    q = np.zeros((n, 4))
    q[1:] = np.cumsum(np.cumsum(steps, axis=0)[:n - 1] * PERIOD_S, axis=0)
    q = np.round(q / TICK_RAD) * TICK_RAD
    t = np.arange(n) * PERIOD_S + rng.normal(0.0, jitter_s, n)
    for k, delay_s in late.items():
        if k < n:
            t[k] += delay_s
    commands = [start_s - 0.02 for _, start_s, _ in moves]
    return t, q, commands


def test_a_start_read_late_is_found_as_the_reference_finds_it() -> None:
    """Joint 2 leaves its pose at 0.1 s; the reply there, read 4 ms late, still shows the pose:
    stale, and only it (the oracle for the rule itself, so the comparison below compares
    something)."""
    start = int(0.1 / PERIOD_S)     # the last reply at rest
    t, q, commands = stream([(2, 0.1, 1.0)], {start: 0.004}, 120, 0.0, 0)
    got = _stale_at_start(t, q, commands, 1e-4)
    assert np.array_equal(got, reference(t, q, commands, 1e-4))
    assert np.flatnonzero(got).tolist() == [start - 1]


@settings(max_examples=60, deadline=None)
@given(moves=st.lists(st.tuples(st.integers(0, 3), st.floats(0.02, 0.5),
                                st.floats(-3.0, 3.0).filter(lambda v: abs(v) > 0.05)),
                      min_size=1, max_size=4),
       late=st.dictionaries(st.integers(0, 199), st.floats(0.0, 0.01), max_size=12),
       jitter_s=st.sampled_from([0.0, 1e-5, 3e-4]),
       scatter_s=st.sampled_from([0.0, 1e-5, 1e-4, 1e-3]),
       seed=st.integers(0, 2**16))
def test_the_vectorised_rule_equals_the_reference(
        moves: list[tuple[int, float, float]], late: dict[int, float], jitter_s: float,
        scatter_s: float, seed: int) -> None:
    """Any moves, replies read late, stamp scatter (replies out of order among them): the same
    replies, bit for bit."""
    t, q, commands = stream(moves, late, 200, jitter_s, seed)
    assert np.array_equal(_stale_at_start(t, q, commands, scatter_s),
                          reference(t, q, commands, scatter_s))


def test_short_streams() -> None:
    """Fewer replies than a start is traced back from: nothing stale, the right length."""
    for n in range(ONSET_REPLIES + 3):
        t, q, commands = stream([(0, 0.0, 1.0)], {}, n, 0.0, 0)
        got = _stale_at_start(t, q, commands, 1e-4)
        assert got.shape == (max(0, n - 2),) and not got.any()
        assert np.array_equal(got, reference(t, q, commands, 1e-4))


def test_a_capture_of_an_hour_costs_well_under_a_second() -> None:
    """10⁶ replies (45 minutes of the arm's stream), a thousand moves, replies read late: under
    3 s of CPU (the reference takes about a minute: one Python iteration per reply and joint)."""
    n = 1_000_000
    rng = np.random.default_rng(1)
    starts = np.sort(rng.uniform(0.0, n * PERIOD_S, 1000))
    moves = [(int(rng.integers(0, 4)), float(s), float(rng.choice([-1.0, 1.0])))
             for s in starts]
    late = {int(k): 0.004 for k in rng.integers(0, n, 2000)}
    t, q, commands = stream(moves, late, n, 1e-5, 1)
    began = time.process_time()
    got = _stale_at_start(t, q, commands, 1e-4)
    assert time.process_time() - began < 3.0
    assert got.any()
