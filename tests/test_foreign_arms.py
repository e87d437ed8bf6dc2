"""The foreign arms of tests/foreign_arms/: simulators written apart from armbench, served in real
time over TCP; each answers armbench's driver, its plain variant does what law (12) says, and
its hidden behaviour shows where it should (and nowhere else). Deadlines come from the moves'
own durations with a wide margin: the machine may be loaded."""

from __future__ import annotations

import asyncio
import contextlib
import math
import time

import pytest
from foreign_arms.serve import SHARED_MISSING, foreign_arm, shared_arm_script
from foreign_arms.tracker_client import TrackerStream

from armbench.drivers.host.arm import DEFAULT_TOLERANCE_RAD, Arm
from armbench.drivers.host.motion import joint_speed_rad_s
from armbench.drivers.model.errors import MoveTimeoutError
from armbench.drivers.model.settings import RobotSettings

SETTINGS = RobotSettings()


def _move_s(joint: int, way_rad: float, duty: int, gear: float) -> float:
    """Law (12)'s time for ``way_rad`` on ``joint`` with another gear ratio than nominal."""
    speed = joint_speed_rad_s(duty, SETTINGS.joints[joint].steps_per_rad)
    return way_rad / speed * gear / SETTINGS.joints[joint].gear_ratio


async def _timed_move(url: str, q: tuple[float, float, float, float], duty: int) -> float:
    async with Arm.connect(url, SETTINGS) as arm:
        t0 = time.monotonic()
        await arm.move_joints(q, duty, timeout_s=30.0)
        return time.monotonic() - t0


@pytest.mark.parametrize("name", ["stall", "tracker", "jitter", "threshold", "shared"])
def test_plain_arms_follow_law_12(name: str) -> None:
    """Every plain arm (hidden behaviour off) moves joint 3 by 0.6 rad at duty 99 in law (12)'s
    time: not faster than it allows (a little slack for the reply interval), not much slower."""
    plain = {"stall": ["--no-stall"], "jitter": ["--gear-j3", "38", "--interval-ms", "5", "5",
                                                  "--drop", "0"], "tracker": [],
             "threshold": ["--loss", "0,0,0,0"], "shared": []}
    if name == "shared" and shared_arm_script() is None:
        pytest.skip(SHARED_MISSING)
    gear = 36.0 if name == "shared" else 38.0
    with foreign_arm(name, *plain[name]) as arm:
        took = asyncio.run(_timed_move(arm.url, (0.0, 0.0, 0.6, 0.0), 99))
    expected = _move_s(2, 0.6, 99, gear)
    assert 0.95 * expected <= took <= expected + 2.0, (took, expected)


def test_jitter_arm_j3_is_slower_and_its_replies_ragged() -> None:
    """The hidden gear of joint 3 (39.5 for 38): a move takes 3.9 % longer than law (12) with the
    nominal gear; the replies come 5..20 ms apart (12.5 ms on average, not every 5 ms)."""
    with foreign_arm("jitter") as arm:
        async def go() -> tuple[float, list[float]]:
            async with Arm.connect(arm.url, SETTINGS) as a:
                with a.record_states() as states:
                    t0 = time.monotonic()
                    await a.move_joints((0.0, 0.0, 1.0, 0.0), 99, timeout_s=30.0)
                    took = time.monotonic() - t0
                return took, [s.t_s for s in states]
        took, times = asyncio.run(go())
    nominal = _move_s(2, 1.0, 99, 38.0)
    # a starved host or arm only makes the move look longer
    assert took >= nominal * 39.5 / 38 - 0.005, (took, nominal)
    # a host that stalls reads the replies that came meanwhile in one go, stamped close
    # together: the stamps' gaps are the host's, not the link's. What the link guarantees is
    # how many replies came over the span they cover (a starved arm sends fewer, not more)
    mean_gap_s = (times[-1] - times[0]) / (len(times) - 1)
    assert mean_gap_s >= 0.008, (mean_gap_s, len(times))


def test_threshold_arm_loses_steps_from_its_duty_on() -> None:
    """The threshold arm's joint 2 loses a quarter of its pulses at duty 97 and above, whatever
    the way and the load: 0.4 rad at duty 99 takes 4/3 of law (12)'s time, at duty 96 no longer
    than law (12) allows (a starved host or arm only makes a move look longer: the fast move's
    bound is from below, the slow move's from above with a wide margin)."""
    async def go(url: str) -> tuple[float, float]:
        async with Arm.connect(url, SETTINGS) as a:
            t0 = time.monotonic()
            await a.move_joints((0.0, 0.4, 0.0, 0.0), 99, timeout_s=30.0)
            lossy = time.monotonic() - t0
            t0 = time.monotonic()
            await a.move_joints((0.0, 0.0, 0.0, 0.0), 96, timeout_s=30.0)
            return lossy, time.monotonic() - t0
    with foreign_arm("threshold") as arm:
        lossy, plain = asyncio.run(go(arm.url))
    assert lossy >= 0.95 * _move_s(1, 0.4, 99, 50.0) / 0.75, lossy
    assert 0.95 * _move_s(1, 0.4, 96, 50.0) <= plain <= _move_s(1, 0.4, 96, 50.0) + 2.0, plain


def test_stall_arm_stalls_lifting_fast_and_not_slow() -> None:
    """Lifting the upper arm from 0.5 rad (lowered, forward) at duty 99 exceeds the loaded
    pull-out rate: the joint stays where it is (the move times out); at duty 93 it lifts."""
    async def go(url: str, duty: int) -> float:
        async with Arm.connect(url, SETTINGS) as a:
            await a.move_joints((0.0, 0.5, 0.0, 0.0), 95, timeout_s=30.0)
            with pytest.raises(MoveTimeoutError) if duty == 99 else contextlib.nullcontext():
                await a.move_joints((0.0, 0.0, 0.0, 0.0), duty, timeout_s=3.0 if duty == 99
                                    else 30.0)
            return a.state.q_rad[1]
    with foreign_arm("stall") as arm:
        # a move returns once every joint is within the arrival tolerance (the arm's reply then
        # may still be one protocol unit short of the target)
        within = DEFAULT_TOLERANCE_RAD + 1e-4
        assert asyncio.run(go(arm.url, 99)) == pytest.approx(0.5, abs=within)
        assert asyncio.run(go(arm.url, 93)) == pytest.approx(0.0, abs=within)


def test_tracker_arm_truth_beside_the_replies() -> None:
    """The reported angles are the motor's, whatever the hidden errors; the tracker sees the
    offsets, the play (lagging by half of it after a move) and the link lengths."""
    args = ["--play-deg", "1,1,1,1", "--offset-deg", "0.3,-0.4,0.4,0", "--a2-error-mm", "4"]
    with foreign_arm("tracker", *args) as arm:
        assert arm.tracker is not None
        host, port = arm.tracker

        async def go() -> tuple[tuple[float, ...], list[float]]:
            async with TrackerStream(host, port) as tracker, \
                    Arm.connect(arm.url, SETTINGS) as a:
                await a.move_joints((0.2, 0.3, -0.3, 0.4), 99, timeout_s=30.0)
                # the move returns within the arrival tolerance, the motor may still take its
                # last steps: compare once two replies 0.2 s apart agree, with a tracker line
                # newer than both
                settled = a.state.q_rad
                for _ in range(50):
                    await asyncio.sleep(0.2)
                    if a.state.q_rad == settled:
                        break
                    settled = a.state.q_rad
                else:
                    pytest.fail(f"the arm did not come to rest: {settled}")
                t_settled = time.monotonic()
                async with asyncio.timeout(10.0):
                    while tracker.samples[-1][0] <= t_settled:
                        await asyncio.sleep(0.01)
                return settled, list(tracker.samples[-1][4:])
        q, truth = asyncio.run(go())
    half = math.radians(0.5)
    expected = [q[0] - half + math.radians(0.3), q[1] - half - math.radians(0.4),
                q[2] + half + math.radians(0.4), q[3] - half]
    assert truth == pytest.approx(expected, abs=2e-4)
