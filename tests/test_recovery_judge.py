"""The start-up recovery's judge of each reply (``bench/suites/recovery_judge.py``, compiled in
the release build) and the truth it asks (``bench/suites/truth_probe.py``): which replies count,
when the arm is back, what it is compared with. Run against both builds (``build_flavour``).

The arm and the instrument are stand-ins with the two attributes the judge reads (an emulator's
truth history, a tracker's reading): the suite's own runs on ``fake://`` are in
``test_startup.py``."""

from __future__ import annotations

import math
import random
from collections import deque
from types import SimpleNamespace
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from armbench.bench.suites.base import SuiteContext
from armbench.bench.suites.recovery_judge import STILL_RAD, TRACE_PERIOD_S, RecoveryJudge
from armbench.bench.suites.truth_probe import BELIEF_TOL_RAD, TRUTH_SEARCH, TruthProbe
from armbench.drivers.host.state import JointState
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.twin.physics import TruthSample
from armbench.record.limits import LimitsConfig

SETTINGS = RobotSettings()
Vec4 = tuple[float, float, float, float]


class _Tracker:
    """An instrument that reads ``joints`` (or nothing) and a TCP position."""

    def __init__(self, joints: tuple[float, ...] | None) -> None:
        self.joints = joints

    def true_position_m(self) -> tuple[float, float, float] | None:
        return (0.1, 0.2, 0.3)

    def true_joints_rad(self) -> tuple[float, ...] | None:
        return self.joints


def _probe(truth: Any = None, history: deque[TruthSample] | None = None) -> TruthProbe:
    emulator = None if history is None else SimpleNamespace(truth=history)
    arm = SimpleNamespace(emulator=emulator)
    return TruthProbe(SuiteContext(arm=arm, settings=SETTINGS,  # type: ignore[arg-type]
                                   limits=LimitsConfig(), params={}, rng=random.Random(0),
                                   truth=truth))


def _state(seq: int, t_s: float, q: Vec4) -> JointState:
    return JointState(t_s, q, (0, 0, 0, 0), seq)


def _judge(probe: TruthProbe, log: list[dict[str, Any]], *, expected: Vec4 = (0.0,) * 4,
           t_on: float = 1.0, still_s: float = 0.5, seen: int = 0) -> RecoveryJudge:
    def keep(**event: Any) -> None:
        log.append(event)

    return RecoveryJudge(probe, expected, 0.01, 0.002, SETTINGS, t_on, still_s, seen, keep)


def test_the_arm_is_back_once_within_tolerance_and_still_for_still_s() -> None:
    """Replies before power-on and replies seen before are not judged; a reply out of tolerance
    ends the window, one that moved by more than ``STILL_RAD`` starts it again; the recovery
    time is the final window's start, from power-on."""
    events: list[dict[str, Any]] = []
    judge = _judge(_probe(), events, seen=1)
    moved = 2.0 * STILL_RAD
    replies = [
        (_state(1, 1.05, (0.0,) * 4), False),            # seen before the watch began
        (_state(2, 0.95, (0.0,) * 4), False),            # before power-on
        (_state(3, 1.00, (0.1, 0.0, 0.0, 0.0)), False),  # first reply: out of tolerance
        (_state(4, 1.10, (0.0, 0.0, 0.0, 0.0)), False),  # the window opens
        (_state(5, 1.30, (0.0, moved, 0.0, 0.0)), False),  # moved: it opens again
        (_state(5, 2.00, (0.0, moved, 0.0, 0.0)), False),  # the same reply again: not judged
        (_state(6, 1.70, (0.0, moved, 0.0, 0.0)), False),  # still, 0.4 s of 0.5
        (_state(7, 1.80, (0.0, moved, 0.0, 0.0)), True),   # still for 0.5 s: back
    ]
    for state, back in replies:
        assert judge.take(state) is back, state
    assert judge.first_reply_s == 0.0
    assert judge.recovered_s == 0.3
    assert judge.compared_with == "expected_rad"
    assert judge.error_rad == moved
    assert judge.last == replies[-1][0]
    names = [e["event"] for e in events]
    assert names[0] == "ready" and names[-1] == "recovered"
    checks = [e for e in events if e["event"] == "position_check"]
    # one trace line per TRACE_PERIOD_S of replies: at 1.0, 1.1, 1.3, 1.7 and 1.8 s
    assert len(checks) == 5 and TRACE_PERIOD_S == 0.1
    assert [c["within"] for c in checks] == [False, True, True, True, True]
    assert checks[0]["error_mrad"] == 100.0


def test_a_reply_is_judged_against_its_own_truth_sample() -> None:
    """With an instrument and an emulator, a reply is compared with the motor side of the
    newest truth sample printed before it whose firmware angles are the reply's; a sample
    printed after the reply, or one the firmware believed otherwise, is not it."""
    q = (0.2, -0.1, 0.3, 0.0)
    own = TruthSample(1.0, q, q, (0.2, -0.1, 0.3, 0.004))
    other = TruthSample(1.001, q, (0.2, -0.1, 0.3 + 2 * BELIEF_TOL_RAD, 0.0), q)
    later = TruthSample(1.5, q, q, (0.0, 0.0, 0.0, 0.0))
    history = deque([own, other, later])
    probe = _probe(_Tracker(None), history)
    state = _state(1, 1.2, q)
    assert probe.joints(state, motor=True) == own.motor_rad
    assert probe.joints(state) == own.true_rad
    judge = _judge(probe, [], expected=(1.0,) * 4)
    assert judge.error(state) == (0.004, True, "truth_rad")


def test_without_a_matching_sample_the_instrument_reading_counts() -> None:
    """A reply whose truth sample is older than the newest :data:`TRUTH_SEARCH` (or missing)
    is judged against what the instrument reads now: its joints, else its TCP position."""
    q = (0.2, -0.1, 0.3, 0.0)
    history = deque([TruthSample(0.0, q, q, q)]
                    + [TruthSample(0.1, q, (0.0,) * 4, q)] * TRUTH_SEARCH)
    reading = (0.2, -0.1, 0.3, 0.02)
    state = _state(1, 1.0, q)
    joints = _judge(_probe(_Tracker(reading), history), [])
    assert joints.error(state) == (0.02, False, "truth_rad")
    tcp = _judge(_probe(_Tracker(None), history), [])
    e, within, what = tcp.error(state)
    assert what == "truth_m" and not within
    assert math.isclose(e, math.dist(state.tcp_m(SETTINGS), (0.1, 0.2, 0.3)))
    assert _probe().joints(state) is None and _probe().position(state) is None


angles = st.floats(-3.0, 3.0, allow_nan=False)


@given(st.tuples(angles, angles, angles, angles), st.tuples(angles, angles, angles, angles))
def test_the_error_is_the_largest_joint_difference(q: Vec4, expected: Vec4) -> None:
    """Against the expected angles, the error is the largest ``|q - expected|`` over the
    joints, as ``max`` picks it, within tolerance exactly when it is at most 0.01 rad."""
    e, within, what = _judge(_probe(), [], expected=expected).error(_state(1, 1.0, q))
    largest = max(abs(a - b) for a, b in zip(q, expected, strict=True))
    assert (e, within, what) == (largest, largest <= 0.01, "expected_rad")
