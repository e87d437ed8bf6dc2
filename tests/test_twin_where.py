"""What twin-check says about what it could not explain: every part of a capture judged on its
own (``bench/twin_check/parts.py``), and where a joint's divergence grows
(``bench/twin_check/where.py``). On synthetic streams made here, with one known factor each: the
effects are known exactly only so."""

from __future__ import annotations

import itertools

import numpy as np
import numpy.typing as npt
from hypothesis import example, given, settings
from hypothesis import strategies as st

from armbench.bench.twin_check.figures import part_measurements, verdict_of
from armbench.bench.twin_check.parts import PART_S, cut_parts, part_figures
from armbench.bench.twin_check.where import FACTORS, growth, since_reversal_s

FloatArray = npt.NDArray[np.float64]
REPLY_S = 0.005
COUNTS = 15915.0               # joint 2's encoder counts per rad


def _factors(t: FloatArray, duty: FloatArray, rng: np.random.Generator
             ) -> dict[str, FloatArray]:
    """Factors that say nothing but the duty: a speed, a load and reversals drawn at random."""
    return {"duty": duty, "speed": rng.uniform(0, 8000, len(t)),
            "load": rng.normal(0, 2, len(t)), "reversal": np.full(len(t), -np.inf),
            "time": t - t[0]}


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 10_000), st.floats(5.0, 100.0))
@example(1896, 81.0)  # time into the session, split at its last 5 %, was once named first
def test_a_loss_above_a_duty_is_named_with_its_times(seed: int, size: float) -> None:
    """Commands at duties 80..99 for a second each; the twin diverges by ``size`` counts (and a
    count of noise) only where the duty is 97 or more: the duty is named first, its threshold
    above the highest duty below 97 and at most the lowest from 97 on, the spans it gives are
    those seconds, and it resembles a step loss above a duty."""
    rng = np.random.default_rng(seed)
    duties = rng.integers(80, 100, 30).astype(float)
    t = np.arange(0.0, 30.0, REPLY_S)
    duty = duties[(t // 1.0).astype(int)]
    r = rng.normal(0, 1.0, len(t)) + np.where(duty >= 97, size, 0.0)
    if not (duty >= 97).any() or (duty >= 97).mean() < 0.1:
        return
    found = growth(t, r, _factors(t, duty, rng), 2.0)
    assert found and found[0].factor == "duty", found
    assert duty[duty < 97].max() < found[0].threshold <= duty[duty >= 97].min()
    assert "duty" in found[0].resembles
    for a, b in found[0].spans_s:
        assert np.all(duty[(t >= a) & (t <= b)] >= 97)


def test_a_drift_is_named_as_time_into_the_session() -> None:
    """A divergence that grows with the time since the session began (the arm warming up):
    named as time into the session, and said to resemble drift, none of the twin's effects."""
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 40.0, REPLY_S)
    r = rng.normal(0, 1.0, len(t)) + 0.02 * t ** 2
    found = growth(t, r, _factors(t, rng.integers(80, 100, len(t)).astype(float), rng), 2.0)
    assert found[0].factor == "time", found
    assert "drift" in found[0].resembles and found[0].threshold > 20.0


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 10_000))
def test_noise_grows_nowhere(seed: int) -> None:
    """A twin that diverges by the link's noise alone: no factor is named."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 30.0, REPLY_S)
    r = rng.normal(0, 1.0, len(t))
    assert growth(t, r, _factors(t, rng.integers(80, 100, len(t)).astype(float), rng),
                  2.0) == []


def test_a_reversal_is_dated() -> None:
    """The time since the joint's direction last flipped, within half a second of it."""
    t = np.arange(0.0, 2.0, 0.1)
    direction = np.array([0, 0, 1, 1, 1, 1, -1, -1, -1, -1, -1, -1, -1, -1, 1, 1, 1, 1, 1, 1.0])
    ago = since_reversal_s(t, direction)
    assert np.isneginf(ago[:6]).all()
    assert np.allclose(ago[6:11], -(t[6:11] - t[6]))
    assert abs(ago[11] + 0.5) < 1e-9 and np.isneginf(ago[12:14]).all() and ago[14] == 0.0


def test_every_part_is_judged_not_only_the_whole() -> None:
    """A 40 s capture whose twin is right but for 5 s where it lags by 12 counts (floor 1
    count, allowed 3 x 1 + 2 on the whole): the whole's RMS (4.2 counts) is within its
    allowance (5), the part's is not (12 against 5 x 1 + 2): the verdict fails on that joint
    and says where."""
    t = np.arange(0.0, 40.0, REPLY_S)
    commands = list(np.arange(0.0, 40.0, 1.0))
    diff = np.zeros((len(t), 4))
    bad = (t >= 20.0) & (t < 25.0)
    diff[bad, 1] = 12.0 / COUNTS
    floor2 = np.full((len(t), 4), (1.0 / COUNTS) ** 2)
    counts = np.full(4, COUNTS)
    whole = float(np.sqrt(np.mean(diff[:, 1] ** 2)) * COUNTS)
    assert whole < 3 * 1.0 + 2.0
    parts = part_figures(t, diff, floor2, counts, (5.0, 2.0), commands)
    assert all(p.end_s - p.start_s >= PART_S - REPLY_S for p in parts)
    worst = max(parts, key=lambda p: p.per_allowed(1))
    assert worst.start_s <= 20.0 and worst.end_s >= 24.9
    assert worst.per_allowed(1) > 1.0 and worst.per_allowed(0) == 0.0
    measured = {m.name: m for m in part_measurements(parts, None)}
    assert measured["twin.j2.worst_part_counts"].value == worst.rms_counts[1]
    assert measured["twin.parts"].value == len(parts)


def test_parts_begin_at_commands_and_cover_every_reply() -> None:
    """The parts cover the compared replies once, in order, each beginning at a command, each
    but possibly none shorter than :data:`PART_S` (a short end joins the part before)."""
    t = np.arange(0.0, 23.0, REPLY_S)
    commands = [0.0, 3.0, 4.0, 9.5, 15.0, 21.0, 22.0]
    parts = cut_parts(t, commands)
    assert parts[0][0] == 0 and parts[-1][1] == len(t)
    assert all(a == b for (_, a), (b, _) in itertools.pairwise(parts))
    assert all(t[a] in commands for a, _ in parts)
    assert all(t[b - 1] - t[a] >= PART_S - REPLY_S for a, b in parts)


def test_every_factor_says_what_it_resembles() -> None:
    """Each factor's text names its high side and a known effect."""
    assert set(FACTORS) == {"duty", "load", "speed", "reversal", "time"}
    assert all(len(v) == 2 and "{" in v[0] for v in FACTORS.values())


def test_verdict_fails_on_a_part() -> None:
    """The part figures are judged: a part over its allowance fails the verdict."""
    from armbench.bench.twin_check.check import DEFAULT_CONFIG
    from armbench.record.limits import load_limits

    t = np.arange(0.0, 12.0, REPLY_S)
    diff = np.zeros((len(t), 4))
    diff[t > 6.0, 2] = 30.0 / COUNTS
    parts = part_figures(t, diff, np.full((len(t), 4), (1.0 / COUNTS) ** 2),
                         np.full(4, COUNTS), (5.0, 2.0), [0.0, 6.0])
    measured = part_measurements(parts, load_limits(DEFAULT_CONFIG))
    assert verdict_of(measured) == "fail"
    assert [m.name for m in measured if m.outcome == "fail"] == ["twin.j3.worst_part_per_allowed"]
