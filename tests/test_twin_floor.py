"""The floor of twin-check counts every timing scatter the capture shows: how much the arm's own
replies disagree on when a move started (a loaded host reading them late by different amounts),
the tail of the replies' timing scatter (not only its robust core), and a first move whose
pose before the command was read in one go (a host busy at the connection); and the alignment of
moves the host read around a stall (a command stamped late, a move read in one go before the
next command)."""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import numpy as np
import pytest
from test_twin_check import IDEAL, _lap, _records, _write

from armbench.bench.calibrate import load_capture
from armbench.bench.calibrate.align import (
    MAX_SHIFT_S,
    MEDIAN_EFFICIENCY,
    ONSET_REPLIES,
    SEEN_LATE,
    TICK_RAD,
    Track,
    move_shifts,
    silent_s,
    timing_rms_s,
    timing_scatter_s,
)
from armbench.bench.twin_check.check import twin_check
from armbench.drivers.host.arm import Arm
from armbench.drivers.host.motion import joint_speed_rad_s
from armbench.drivers.model.protocol import Command
from armbench.fakes.clock.vclock import run_virtual

PERIOD_S = 0.005
START_S = 0.2        # the joint leaves its pose here (the command is at 0.1 s)


def _ramp(delays_s: dict[int, float] | None = None) -> tuple[Track, Command]:
    """Joint 3 at rest at 0, then moving at full duty from :data:`START_S`: a reply every 5 ms,
    exact (no quantisation), each stamped late by ``delays_s[i]`` (reply index) where given."""
    command = Command.from_rad((0.0, 0.0, -1.0, 0.0), 99)
    speed = joint_speed_rad_s(99, IDEAL.joints[2].steps_per_rad)
    t = np.arange(0.0, 0.6, PERIOD_S)
    q = np.zeros((len(t), 4))
    q[:, 2] = -speed * np.clip(t - START_S, 0.0, None)
    for i, d in (delays_s or {}).items():
        t[i] += d
    return Track(t, q), command


def test_a_start_read_late_by_different_amounts_has_a_standard_error() -> None:
    """The arm's start is the median of its first replies traced back along the motion; where
    the host read them late by different amounts they disagree, and the start is that
    uncertain: the standard error of a median of their spread (wire quantisation aside). The
    twin's exact stream gives none, and neither does an arm read on time."""
    exact, command = _ramp()
    shifts = move_shifts(exact, exact, [(0.1, command)], IDEAL)
    assert shifts.onset_se_s is not None
    assert float(np.max(shifts.onset_se_s)) < 1e-6
    first = int(np.searchsorted(exact.t_s, START_S)) + 1   # the first reply 4 ticks away
    lateness = [0.0, 2e-3, 0.5e-3, 3e-3, 1e-3]
    late, _ = _ramp({first + k: d for k, d in enumerate(lateness)})
    shifts = move_shifts(late, exact, [(0.1, command)], IDEAL)
    assert shifts.onset_se_s is not None
    spread = np.asarray(lateness) - np.median(lateness)
    expected = math.sqrt(np.sum(spread ** 2) / (ONSET_REPLIES - 1) * MEDIAN_EFFICIENCY
                         / ONSET_REPLIES)
    # the speed they are traced back with is their own, which the late stamps bend a little
    assert shifts.onset_se_s[0, 2] == pytest.approx(expected, rel=0.3)
    assert shifts.onset_se_s[0, 0] == 0.0                  # a joint that did not move


def test_the_arms_lag_is_the_arms_whatever_the_twin_did() -> None:
    """The arm's reaction to a command (its start less the command's stamp: what finds the
    commands a stalled host stamped late) comes from the arm's replies alone. A twin that was
    still moving at the command, or never moved, measures no start shift there, and used to
    leave the arm's lag unmeasured too: which commands counted as stamped late then hung on the
    twin's other joints, and so did every joint's figure."""
    arm, command = _ramp()
    still = Track(arm.t_s, np.zeros_like(arm.q_rad))             # a twin that never moved
    drifting = Track(arm.t_s, arm.q_rad.copy())
    drifting.q_rad[:, 2] = -0.5 * arm.t_s                          # moving at the command
    for twin in (arm, still, drifting):
        shifts = move_shifts(arm, twin, [(0.1, command)], IDEAL)
        assert shifts.arm_lag_s is not None
        assert shifts.arm_lag_s[0] == pytest.approx(START_S - 0.1, abs=1e-3)
    assert move_shifts(arm, still, [(0.1, command)], IDEAL).measured == []
    assert move_shifts(arm, drifting, [(0.1, command)], IDEAL).measured == []


def test_the_timing_rms_counts_the_tail() -> None:
    """A few replies read a little late (not enough to be left out) barely move the robust
    spread, but a perfect twin's RMS divergence meets them in full: the floor's timing part is
    their RMS."""
    exact, _ = _ramp()
    rng = np.random.default_rng(1)
    moving = np.flatnonzero(exact.t_s > START_S + 0.02)[:-2]
    picked = rng.choice(moving, size=len(moving) // 10, replace=False)
    tail, _ = _ramp({int(i): 0.4e-3 for i in picked})
    robust = timing_scatter_s(tail, [0.1])
    rms = timing_rms_s(tail, [0.1])
    assert rms is not None
    assert robust < 1e-6
    assert rms > 1e-4
    assert timing_rms_s(exact, [0.1]) == pytest.approx(0.0, abs=1e-9)


@pytest.fixture(scope="module")
def ideal_capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("ideal") / "capture.jsonl"
    run_virtual(_lap("fake://?profile=ideal", path))
    return path


def test_a_first_move_after_a_burst_is_aligned(ideal_capture: Path, tmp_path: Path) -> None:
    """A loaded host read the arm's replies before the first command in one go, and the arm
    reacts to that command 20 ms later than its twin. The burst's replies still say the pose
    the first move starts from, so that move's start is timed and aligned as every other's
    (before, its start was not timed, and the whole first move diverged by the delay times
    the speed: tens of counts RMS). A twin 4 % off still fails."""
    records = _records(ideal_capture)
    first = next(r["t_s"] for r in records if r["dir"] == "out")
    replies = [r for r in records if r["dir"] == "in"]
    after = [r for r in replies if r["t_s"] > first]
    before = [r for r in replies if r["t_s"] <= first]
    assert 1 <= len(before) < 100
    before.append(dict(before[-1]))
    for k, r in enumerate(before):
        r["t_s"] = round(first - 1e-4 - 1e-6 * (len(before) - k), 9)
    second = next(r["t_s"] for r in records if r["dir"] == "out" and r["t_s"] > first)
    for r in after:                   # the first move's replies, but its last 20 ms at rest
        if r["t_s"] < second:
            r["t_s"] = round(r["t_s"] + 0.02, 9)
    after = [r for r in after if not second <= r["t_s"] < second + 0.02]
    records = [r for r in records if r["dir"] != "in"] + before + after
    path = _write(sorted(records, key=lambda r: r["t_s"]), tmp_path / "late.jsonl")
    result = twin_check(load_capture(path, IDEAL), IDEAL)
    assert result.sessions == 1
    assert max(result.rms_counts) <= 2.0, result.rms_counts
    assert result.joint_shifts_s is not None
    assert result.joint_shifts_s[0, 2] == pytest.approx(0.02, abs=1e-3)
    assert result.verdict == "pass", result.to_json()


def _quantised(period_s: float, phase_s: float, speed_rad_s: float) -> Track:
    """Joint 1 at rest at 0, then moving at ``speed_rad_s`` from 0.1005 s, as the wire reports
    it (rounded to the tick), a reply every ``period_s`` from ``phase_s``."""
    t = np.arange(phase_s, 0.4, period_s)
    q = np.zeros((len(t), 4))
    q[:, 0] = np.round(-speed_rad_s * np.clip(t - 0.1005, 0.0, None) / TICK_RAD) * TICK_RAD
    return Track(t, q)


@pytest.mark.parametrize("duty", [90, 70])
@pytest.mark.parametrize("phase_s", [0.0, 0.0011, 0.0023, 0.0037])
def test_a_slow_joints_start_is_timed_through_the_rounding(phase_s: float, duty: int) -> None:
    """A slow joint moves a few ticks between two replies, so neighbouring replies' slopes
    are rounded by a tick in five (up to 25 %), and a start traced back at their median speed
    was off by up to two ticks' time (2 ms), more than the whole move's timing scatter: the
    arm (a reply every 5.24 ms) and the twin (every 2.38 ms) that started at the same instant
    were aligned that far apart. The speed is now the median slope between every two of the first
    replies (at duty 70 the twin's replies are less than a tick apart)."""
    command = Command.from_rad((-0.2, 0.0, 0.0, 0.0), (duty, 0, 0, 0))
    speed = joint_speed_rad_s(duty, IDEAL.joints[0].steps_per_rad)
    arm, twin = _quantised(0.00524, phase_s, speed), _quantised(0.00238, 0.0, speed)
    shifts = move_shifts(arm, twin, [(0.1, command)], IDEAL)
    assert shifts.measured
    # within the time of half a tick (the rounding of the pose a start is traced back from)
    assert abs(shifts.per_joint_s[0, 0]) < 0.5 * TICK_RAD / speed, shifts.per_joint_s[0, 0]


def test_an_arm_silent_at_a_command_may_start_as_late_as_it_was_silent() -> None:
    """An arm whose loop stalled across a command (a starved process: no reply from just before
    the command until it woke) acts on the command when it wakes: its start 90 ms after the
    twin's is a timing matter, and the shift is measured in full, not cut at the 60 ms that
    bound an arm that answered all along (the right twin of the threshold arm, its process paused
    for 20–300 ms at random, failed by the 30 ms cut off: 80 counts on joint 1 over the whole
    move). An arm that answered all along and started that late is held to 60 ms. How late it
    woke is no reaction of the arm: the start is not one of the measured shifts whose spread
    is the arm's reaction scatter."""
    arm, command = _ramp()                      # leaves its pose at 0.2 s; command at 0.1 s
    twin = Track(arm.t_s - (START_S - 0.11), arm.q_rad)   # left it at 0.11 s
    late = move_shifts(arm, twin, [(0.1, command)], IDEAL)
    assert late.per_joint_s[0, 2] == pytest.approx(MAX_SHIFT_S)
    assert len(late.measured) == 1
    quiet = (arm.t_s > 0.095) & (arm.t_s < 0.2)
    silent = Track(arm.t_s[~quiet], arm.q_rad[~quiet])
    woke = move_shifts(silent, twin, [(0.1, command)], IDEAL)
    assert woke.per_joint_s[0, 2] == pytest.approx(START_S - 0.11, abs=1e-3)
    assert woke.measured == []
    assert silent_s(silent, 0.1, START_S, PERIOD_S) == pytest.approx(0.1, abs=1e-3)
    # a host that stalled reads every reply, late and in one go: no silence
    burst = arm.t_s.copy()
    burst[quiet] = 0.2 - 1e-5 * np.arange(int(quiet.sum()))[::-1]
    assert silent_s(Track(burst, arm.q_rad), 0.1, START_S, PERIOD_S) == 0.0
    # a silence that began well before the command counts from the command on: an arm that
    # woke 15 ms after it was silent all that time (its start is no reaction to the command)
    gap = (arm.t_s > 0.02) & (arm.t_s < 0.135)
    assert silent_s(Track(arm.t_s[~gap], arm.q_rad[~gap]), 0.12, 0.135, PERIOD_S) == \
        pytest.approx(0.015, abs=1e-6)
    # a pause of a few intervals is a sender's jitter, not a silence
    short = (arm.t_s > 0.1) & (arm.t_s < 0.1 + SEEN_LATE * PERIOD_S)
    assert silent_s(Track(arm.t_s[~short], arm.q_rad[~short]), 0.1, 0.13, PERIOD_S) == 0.0


def test_commands_that_came_while_the_arm_was_silent_reach_it_together() -> None:
    """A command the arm did not hear (its loop stalled) followed by the host's next one: the
    arm wakes, reads both, and its start answers the first. Timed against the first command's
    twin start (looked for up to the next command the arm replied before), not left
    unmeasured for want of a start before the second: the twin, moving by then, would have
    been 300 ms ahead for the whole move (the right twin of the jitter arm failed by 500
    counts on joints 2 and 4 so)."""
    arm, command = _ramp()
    twin = Track(arm.t_s - (START_S - 0.11), arm.q_rad)
    quiet = (arm.t_s > 0.095) & (arm.t_s < 0.2)
    silent = Track(arm.t_s[~quiet], arm.q_rad[~quiet])
    again = [(0.1, command), (0.15, command)]
    shifts = move_shifts(silent, twin, again, IDEAL)
    assert shifts.per_joint_s[:, 2] == pytest.approx([START_S - 0.11] * 2, abs=1e-3)
    # an arm that answered between the two commands heard the first alone: its start, after the
    # second, is looked for only until then, and the first measures none
    shifts = move_shifts(arm, twin, again, IDEAL)
    assert shifts.per_joint_s[0, 2] == 0.0


def test_a_command_stamped_late_is_replayed_when_the_arm_got_it(ideal_capture: Path,
                                                               tmp_path: Path) -> None:
    """A host stalled for 80 ms while writing a command, stamped it after the stall and then
    read the replies of that time in one go: the arm's first replies it timed show it already
    on its way. Replayed at its stamp the twin started 80 ms late, more than a start shift is
    allowed to align, and the move diverged by the rest times the speed (30 counts RMS on j1
    over the lap). Found from the arm's own replies, the command is now replayed when the arm
    got it, and the right twin passes."""
    records = _records(ideal_capture)
    out = [r for r in records if r["dir"] == "out"]
    k = max(range(1, len(out) - 1), key=lambda i: out[i]["t_s"] - out[i - 1]["t_s"])
    assert out[k + 1]["t_s"] - out[k]["t_s"] > 0.3          # a move from rest, to its end
    sent = out[k]["t_s"]
    out[k]["t_s"] = round(sent + 0.08, 9)
    stalled = [r for r in records if r["dir"] == "in" and sent < r["t_s"] < sent + 0.08]
    for i, r in enumerate(stalled):
        r["t_s"] = round(sent + 0.08 + 1e-6 * (i + 1), 9)
    path = _write(sorted(records, key=lambda r: r["t_s"]), tmp_path / "stamped.jsonl")
    result = twin_check(load_capture(path, IDEAL), IDEAL)
    # (replayed at its stamp: j1 31 counts RMS, fail; the time it is moved by comes from the
    # arm's reaction to its other commands, a few counts of this one's start left)
    assert max(result.rms_counts) <= 5.0, result.rms_counts
    assert result.verdict == "pass", result.to_json()


async def _two_moves(port: str, capture: Path) -> None:
    """From rest, joints 1 and 2 a little on at different speeds, a rest, and as far on again
    (the first two points of the accuracy suite's streamed path, where a foreign arm's lap met
    a host stall)."""
    async with Arm.connect(port, IDEAL, capture=capture) as arm:
        await arm.move_joints((0.0, 0.0, -1.0, 0.0))
        await asyncio.sleep(0.3)
        await arm.send(Command.from_rad((0.0127, 0.0027, -1.0, 0.0), (93, 65, 99, 99)))
        await asyncio.sleep(0.16)
        await arm.send(Command.from_rad((0.0254, 0.0052, -1.0, 0.0), (93, 62, 99, 99)))
        await asyncio.sleep(2.0)


def test_a_move_read_in_one_go_before_the_next_command_is_not_that_commands_start(
        tmp_path: Path) -> None:
    """A host stalled from just after a command until just before the next and then read the
    replies of that time in one go (left out for their stamps): the newest reply it timed
    before the second command showed the pose from before the first one's move. The second
    move's start was traced back from that pose, came before its command, and the twin was read
    60 ms ahead for as long as that start shift was carried (the right twin of a foreign arm
    failed its lap on a loaded machine). Where a joint was at a command now comes from every
    reply read before it, whatever its stamp, and the right twin passes."""
    path = tmp_path / "capture.jsonl"
    run_virtual(_two_moves("fake://?profile=ideal", path))
    records = _records(path)
    first, second = (r["t_s"] for r in [r for r in records if r["dir"] == "out"][-2:])
    stalled = [r for r in records if r["dir"] == "in" and first + 0.002 < r["t_s"] < second]
    assert len(stalled) > 20
    for i, r in enumerate(stalled):
        r["t_s"] = round(second - 1e-4 + 1e-6 * (i + 1) / len(stalled), 9)
    burst = _write(sorted(records, key=lambda r: r["t_s"]), tmp_path / "burst.jsonl")
    result = twin_check(load_capture(burst, IDEAL), IDEAL)
    # (from the pose before the stall: j1's start shift -60 ms, j1 15 counts RMS, fail)
    assert max(abs(s) for s in result.shifts_s) < 0.001, result.shifts_s
    assert max(result.rms_counts) <= 1.0, result.rms_counts
    assert result.verdict == "pass", result.to_json()
