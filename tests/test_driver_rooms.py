"""The driver's rooms on their own: the sans-I/O reply stream fed plain bytes, target validation
with its one limit slack, the waiters that each new state is offered to, and the arrival tracker
that moves and paths share."""

from __future__ import annotations

import asyncio
import itertools
import math
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import TypeVar

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armbench.drivers.host import arrival
from armbench.drivers.host.arm import Arm
from armbench.drivers.host.arrival import ArrivalTracker
from armbench.drivers.host.link import ArmLink
from armbench.drivers.host.motion import line
from armbench.drivers.host.move_targets import (
    LIMIT_SLACK_RAD,
    TICK_RAD,
    check_command,
    check_target,
    wire_command,
)
from armbench.drivers.host.replies import ReplyStream
from armbench.drivers.host.state import JointState
from armbench.drivers.host.waiters import Waiters, never
from armbench.drivers.model.errors import JointRangeError
from armbench.drivers.model.protocol import MAX_TICKS, REPLY_LEN, Command, Reply, encode_reply
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.clock.vclock import run_virtual

T = TypeVar("T")
SETTINGS = RobotSettings()
LOWER, UPPER = SETTINGS.lower_rad, SETTINGS.upper_rad
ticks = st.integers(0, MAX_TICKS)
replies = st.tuples(ticks, ticks, ticks, ticks)


def stream() -> ReplyStream:
    return ReplyStream(LOWER, UPPER)


# --- the reply stream ---------------------------------------------------------------------------
def test_one_reply_becomes_one_state() -> None:
    s = stream()
    batch = s.receive(b"$10000,00000,62832,31416#", 2.5)
    assert batch.state is not None and batch.single and batch.states == []
    state = batch.state
    assert (state.t_s, state.ticks, state.seq) == (2.5, Reply(10000, 0, 62832, 31416), 1)
    assert state.q_rad == Reply(10000, 0, 62832, 31416).angles_rad(LOWER, UPPER)
    assert (s.frames_received, s.frames_dropped, s.discarded_bytes, s.synced) == (1, 0, 0, True)


def test_the_short_path_takes_exactly_one_reply_and_nothing_else() -> None:
    s = stream()
    assert s.one(b"$00000,00000,00000,00000", 0.0) is None  # cut short: nothing consumed
    assert s.frames_received == 0 and s.receive(b"", 0.0).state is None
    one = s.one(b"$00001,00002,00003,00004#", 1.0)
    assert one is not None and one.seq == 1 and one.ticks == (1, 2, 3, 4)
    assert s.one(b"$00001,00002,00003,00004#$", 1.0) is None  # longer than one reply
    s.receive(b"$00000,0", 1.5)
    assert s.one(b"0000,00000,00000#$00001,", 2.0) is None  # something is buffered
    assert s.frames_received == 1


def test_garbage_before_the_first_reply_is_synchronisation_after_it_a_drop() -> None:
    s = stream()
    batch = s.receive(b"0,12345#\r\n$00010,00020,00030,00040#", 0.1)  # joined mid-frame
    assert batch.state is not None and batch.state.ticks == (10, 20, 30, 40)
    assert s.frames_dropped == 0 and s.discarded_bytes == len(b"0,12345#")
    batch = s.receive(b"$0001x,00020,00030,00040#$00011,00021,00031,00041#", 0.2)
    assert [type(e).__name__ for e in batch.events] == ["FrameError", "Reply"]
    assert s.frames_dropped == 1 and s.frames_received == 2 and not batch.single
    assert batch.state is not None and batch.state.seq == 2


def test_a_restart_resynchronises_and_keeps_counting() -> None:
    s = stream()
    s.receive(b"$00010,00020,00030,00040#$000", 0.0)
    s.restart()
    assert not s.synced
    batch = s.receive(b"garbage$00011,00021,00031,00041#", 0.1)  # the old partial is gone
    assert batch.state is not None and batch.state.seq == 2 and s.frames_dropped == 0


@given(st.lists(replies, min_size=1, max_size=12), st.lists(st.integers(0, 400), max_size=6),
       st.binary(max_size=30).filter(lambda b: b"$" not in b))
@settings(max_examples=200, deadline=None)
def test_where_the_chunks_are_cut_changes_nothing(frames: list[tuple[int, int, int, int]],
                                                  cuts: list[int], lead: bytes) -> None:
    """The states of a byte stream (a connection joined at any point, then replies) are the same
    however it is cut into chunks, one per reply, numbered 1, 2, ...; the newest of each chunk is
    the last of its states."""
    wire = lead + b"".join(encode_reply(*f) for f in frames)
    bounds = sorted({0, len(wire), *(c % (len(wire) + 1) for c in cuts)})
    s = stream()
    got: list[JointState] = []
    for k, (a, b) in enumerate(itertools.pairwise(bounds)):
        batch = s.receive(wire[a:b], float(k), every=True)
        got += batch.states
        assert batch.state == (batch.states[-1] if batch.states else None)
    assert [g.ticks for g in got] == [Reply(*f) for f in frames]
    assert [g.seq for g in got] == list(range(1, len(frames) + 1))
    assert all(g.q_rad == Reply(*f).angles_rad(LOWER, UPPER)
               for g, f in zip(got, frames, strict=True))
    assert s.frames_received == len(frames) and s.frames_dropped == 0
    assert s.discarded_bytes == len(lead.replace(b"\r", b"").replace(b"\n", b""))


@given(st.lists(replies, min_size=1, max_size=6))
def test_without_every_only_the_newest_is_decoded(frames: list[tuple[int, int, int, int]]) -> None:
    s = stream()
    batch = s.receive(b"".join(encode_reply(*f) for f in frames), 0.0)
    assert batch.states == [] and batch.single == (len(frames) * REPLY_LEN == REPLY_LEN)
    assert batch.state is not None
    assert (batch.state.ticks, batch.state.seq) == (Reply(*frames[-1]), len(frames))


# --- targets: one limit slack --------------------------------------------------------------------
def test_the_slack_is_half_a_tick() -> None:
    assert TICK_RAD == 1e-4 and LIMIT_SLACK_RAD == 0.5e-4


@pytest.mark.parametrize("joint", range(4))
@pytest.mark.parametrize("bound", ["lower", "upper"])
def test_send_and_moves_share_the_slack(joint: int, bound: str) -> None:
    """A target just inside the slack is accepted and just past it refused, as radians
    (``check_target``, moves) and as a raw command (``check_command``, ``send``) alike."""
    limit = (LOWER if bound == "lower" else UPPER)[joint]
    out = -1.0 if bound == "lower" else 1.0
    for past, ok in ((0.0, True), (0.9 * LIMIT_SLACK_RAD, True), (1.1 * LIMIT_SLACK_RAD, False)):
        q = [0.0, 0.3, 0.3, 0.0]
        q[joint] = limit + out * past
        if ok:
            check_target(q, SETTINGS)
        else:
            with pytest.raises(JointRangeError) as info:
                check_target(q, SETTINGS)
            assert (info.value.joint, info.value.bound) == (joint + 1, bound)
    # raw commands: the wire values around the limit, decoded, judged by the same rule
    k0 = round(limit / TICK_RAD)
    for k in range(k0 - 3, k0 + 4):
        t = [0, 3000, 3000, 0]
        t[joint] = k % (MAX_TICKS + 1)
        cmd = Command((t[0], t[1], t[2], t[3]), (50, 50, 50, 50))
        q_wire = cmd.angles_rad(LOWER, UPPER)
        inside = LOWER[joint] - LIMIT_SLACK_RAD <= q_wire[joint] <= UPPER[joint] + LIMIT_SLACK_RAD
        if inside:
            check_command(cmd, SETTINGS)
            check_target(q_wire, SETTINGS)
        else:
            with pytest.raises(JointRangeError):
                check_command(cmd, SETTINGS)
            with pytest.raises(JointRangeError):
                check_target(q_wire, SETTINGS)


@given(st.tuples(*(st.floats(lo - LIMIT_SLACK_RAD, hi + LIMIT_SLACK_RAD)
                   for lo, hi in zip(LOWER, UPPER, strict=True))),
       st.integers(1, 99))
def test_an_accepted_target_never_aims_past_a_limit(q: tuple[float, float, float, float],
                                                     duty: int) -> None:
    """Whatever the slack lets through, the command put on the wire aims inside the limits, is
    within one and a half ticks of the target (half a tick of rounding, one of the nudge) and is
    accepted by ``send``, as is a raw command built from a target within the limits."""
    target = check_target(q, SETTINGS)
    cmd = wire_command(target, (duty,) * 4, SETTINGS)
    wire = cmd.angles_rad(LOWER, UPPER)
    for w, t, lo, hi in zip(wire, target, LOWER, UPPER, strict=True):
        assert lo - 1e-12 <= w <= hi + 1e-12
        assert abs(w - t) <= 1.5 * TICK_RAD + 1e-12
    check_command(cmd, SETTINGS)
    inside = [min(max(t, lo), hi) for t, lo, hi in zip(target, LOWER, UPPER, strict=True)]
    check_command(Command.from_rad(inside, duty), SETTINGS)  # a raw command built on a limit


# --- the arrival tracker -------------------------------------------------------------------------
def state(q: tuple[float, float, float, float], t_s: float = 0.0) -> JointState:
    return JointState(t_s, q, Reply.from_rad(q), 1)


GOAL = (0.1, 0.4, 0.8, 0.0)
TOL = (3e-4, 3e-4, 3e-4, 3e-4)


@given(st.tuples(*(st.floats(g - 0.01, g + 0.01) for g in GOAL)))
def test_arrival_is_every_joint_within_tolerance(q: tuple[float, float, float, float]) -> None:
    tracker = ArrivalTracker(ArmLink("fake://"), TOL, 1.0, 1.0, 0, 0.0)
    tracker.aim(Command.from_rad(GOAL, 50), GOAL, 0.0)
    assert tracker.reached(state(q)) == all(
        abs(a - b) <= tol for a, b, tol in zip(q, GOAL, TOL, strict=True))


def test_a_path_waypoint_counts_as_reached_a_look_ahead_early() -> None:
    """At duty 99 (period 2 cycles of 80 µs) joint 1 covers 0.005 rad in ~10 ms: reached with a
    10 ms look-ahead, not without one; progress is what makes a resend wait."""
    link = ArmLink("fake://")
    spr = SETTINGS.joints[0].steps_per_rad
    away_s = 0.008
    q = (GOAL[0] - away_s / (spr * 2 * 80e-6), *GOAL[1:])
    cmd = Command.from_rad(GOAL, 99)
    plain = ArrivalTracker(link, TOL, 1.0, 1.0, 0, 0.0)
    plain.aim(cmd, GOAL, 0.0)
    ahead = ArrivalTracker(link, TOL, 1.0, 1.0, 0, 0.0)
    ahead.aim(cmd, GOAL, 0.0, ahead_s=0.010)
    assert ahead.reached(state(q, 0.2)) and not plain.reached(state(q, 0.2))
    assert plain._last_progress == 0.2  # first distance seen: progress
    assert not plain.reached(state(q, 0.3)) and plain._last_progress == 0.2  # none since


def test_moves_and_paths_wait_with_the_same_tracker(monkeypatch: pytest.MonkeyPatch,
                                                    tmp_path: Path) -> None:
    """One move and one path over ``fake://`` with the line to the arm dead for a while: both
    arrive through ``ArrivalTracker.arrive`` (once per move, once per streamed waypoint) and
    both resend through it."""
    calls: list[int] = []
    real = ArrivalTracker.arrive

    async def arrive(self: ArrivalTracker) -> JointState:
        calls.append(id(self))
        return await real(self)

    monkeypatch.setattr(arrival.ArrivalTracker, "arrive", arrive)
    faults = tmp_path / "faults.toml"
    faults.write_text("""
[[faults]]
kind = "uart_drop"
direction = "to_robot"
at_s = 0.0
duration_s = 0.4
probability = 1.0
[[faults]]
kind = "uart_drop"
direction = "to_robot"
at_s = 3.0
duration_s = 0.4
probability = 1.0
""")

    async def within(aw: Awaitable[T]) -> T:
        async with asyncio.timeout(20.0):
            return await aw

    async def body() -> None:
        loop = asyncio.get_running_loop()
        async with Arm.connect(f"fake://?faults={faults}&seed=3") as arm:
            await within(asyncio.sleep(0.1))
            st0 = await within(arm.move_joints((0.0, 0.4, 0.8, 0.0), 99))  # lost, then resent
            assert st0 is not None and arm.resends >= 1 and len(calls) == 1
            resends = arm.resends
            a = arm.state.tcp_m(arm.settings)
            b = (a[0], a[1] + 0.04, a[2])
            await within(asyncio.sleep(max(0.0, 2.9 - loop.time())))
            calls.clear()
            run = await within(arm.follow_path(line(a, b), speed_m_s=0.02))
            streamed = len(run.waypoints)
            assert streamed >= 8 and len(calls) == 1 + streamed  # the approach is a move
            assert len(set(calls[1:])) == 1  # one tracker for the whole path
            assert run.resends >= 1 and arm.resends - resends == run.resends
            assert math.dist(arm.state.tcp_m(arm.settings), b) < 1e-3

    run_virtual(body())


# --- the waiters ---------------------------------------------------------------------------------


def _state(k: int, q1: float) -> JointState:
    return JointState(0.01 * k, (q1, 0.0, 0.0, 0.0), Reply(0, 0, 0, 0), k)


def _past(mark: float) -> Callable[[JointState], bool]:
    return lambda state: state.q_rad[0] >= mark


@settings(max_examples=60, deadline=None)
@given(marks=st.lists(st.floats(-2.0, 2.0), min_size=1, max_size=5),
       q1s=st.lists(st.floats(-2.0, 2.0), max_size=10))
def test_each_waiter_gets_the_first_state_past_its_mark(marks: list[float],
                                                       q1s: list[float]) -> None:
    """Offered states in turn, each waiter is resolved with the first that satisfies it, and
    only the unresolved ones stay; a deadline never reached resolves nothing."""

    async def session() -> None:
        waiters = Waiters()
        added = [waiters.add(_past(m), math.inf) for m in marks]
        states = [_state(k, q) for k, q in enumerate(q1s)]
        for state in states:
            waiters.offer(state)
        for mark, w in zip(marks, added, strict=True):
            first = next((s for s in states if s.q_rad[0] >= mark), None)
            assert w.future.done() == (first is not None)
            if first is not None:
                assert w.future.result() is first
        assert bool(waiters) == any(not w.future.done() for w in added)
        waiters.close()
        assert all(w.future.done() for w in added) and not waiters

    run_virtual(session())


def test_a_waiter_wakes_at_its_deadline_and_one_alarm_serves_them_all() -> None:
    async def session() -> None:
        loop = asyncio.get_running_loop()
        waiters = Waiters()
        t0 = loop.time()
        late, early = waiters.add(never, t0 + 2.0), waiters.add(never, t0 + 1.0)
        assert await early.future is None and loop.time() == pytest.approx(t0 + 1.0)
        assert not late.future.done() and not early.woken
        assert await late.future is None and loop.time() == pytest.approx(t0 + 2.0)
        assert not waiters

    run_virtual(session())


def test_a_predicate_that_raises_fails_its_own_waiter_only() -> None:
    async def session() -> None:
        waiters = Waiters()

        def broken(state: JointState) -> bool:
            raise ValueError(f"cannot judge state {state.seq}")

        bad, good = waiters.add(broken, math.inf), waiters.add(lambda s: True, math.inf)
        waiters.offer(_state(3, 0.0))
        with pytest.raises(ValueError, match="cannot judge state 3"):
            bad.future.result()
        hit = good.future.result()
        assert hit is not None and hit.seq == 3 and not waiters

    run_virtual(session())
