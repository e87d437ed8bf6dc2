"""The link's per-reply path (``drivers.host.intake``) with plain bytes, and the repeated reply
the framer and the reply stream take without decoding it again."""

from __future__ import annotations

import asyncio
import math

import pytest

from armbench.drivers.host.arm import Arm
from armbench.drivers.host.intake import ReplyIntake
from armbench.drivers.host.link_outages import OutageLog
from armbench.drivers.host.replies import ReplyStream
from armbench.drivers.host.state import JointState
from armbench.drivers.host.waiters import Waiters
from armbench.drivers.model.protocol import Framer, Reply
from armbench.fakes.clock.vclock import run_virtual

REST = b"$10000,20000,30000,40000#"
MOVED = b"$10001,20000,30000,40000#"


class _Capture:
    def __init__(self) -> None:
        self.replies: list[tuple[float, bytes]] = []

    def reply(self, t_s: float, data: bytes) -> None:
        self.replies.append((t_s, data))


class _Bench:
    """An intake on a clock the test sets, with a recorder and a capture."""

    def __init__(self, reply_timeout_s: float = 0.5) -> None:
        self.now_s = 0.0
        self.chunks: list[tuple[bytes, float]] = []
        self.failures: list[Exception] = []
        self.stream = ReplyStream((-math.pi,) * 4, (math.pi,) * 4)
        self.intake = ReplyIntake(self.stream, Waiters(), OutageLog(reply_timeout_s),
                                  reply_timeout_s, self._chunk, self.failures.append)
        self.intake.clock = lambda: self.now_s
        self.capture = _Capture()
        self.intake.capture = self.capture
        self.recorded: list[JointState] = []
        self.intake.recorders.append(self.recorded)

    def _chunk(self, data: bytes, t_s: float) -> None:
        self.chunks.append((data, t_s))
        batch = self.stream.receive(data, t_s)
        if batch.state is not None:
            self.intake.took(batch.state, t_s)

    def push(self, data: bytes, t_s: float) -> None:
        self.now_s = t_s
        self.intake.push(data)


def test_a_single_reply_reaches_the_state_the_recorder_and_the_capture() -> None:
    bench = _Bench()
    bench.intake.tx_since_rx = 3
    bench.push(REST, 1.25)
    state = bench.intake.state
    assert state is not None
    assert state.ticks == (10000, 20000, 30000, 40000)
    assert state.q_rad == pytest.approx((1.0, 2.0, 3.0, 4.0 - 2 * math.pi))
    assert (state.t_s, state.seq) == (1.25, 1)
    assert bench.intake.last_rx_s == 1.25 and bench.intake.tx_since_rx == 0
    assert bench.recorded == [state]
    assert bench.capture.replies == [(1.25, REST)]
    assert bench.chunks == []  # the general path saw nothing


def test_any_other_chunk_goes_to_the_general_path() -> None:
    bench = _Bench()
    bench.push(REST + MOVED, 0.5)
    bench.push(REST[:10], 0.6)
    assert bench.chunks == [(REST + MOVED, 0.5), (REST[:10], 0.6)]
    state = bench.intake.state
    assert state is not None and state.ticks == (10001, 20000, 30000, 40000) and state.seq == 2
    assert bench.capture.replies == []  # the link's general path writes those itself


def test_a_repeated_reply_is_a_new_state_of_the_same_reply() -> None:
    bench = _Bench()
    bench.push(REST, 0.1)
    bench.push(bytes(bytearray(REST)), 0.2)  # equal bytes, another object
    bench.push(MOVED, 0.3)
    first, again, moved = bench.recorded
    assert again.ticks is first.ticks and again.q_rad is first.q_rad
    assert (again.t_s, again.seq) == (0.2, 2)
    assert moved.ticks == (10001, 20000, 30000, 40000) and moved.seq == 3
    assert bench.stream.frames_received == 3
    assert [t for t, _ in bench.capture.replies] == [0.1, 0.2, 0.3]


def test_a_gap_longer_than_the_reply_timeout_is_a_silence() -> None:
    bench = _Bench(reply_timeout_s=0.5)
    bench.push(REST, 1.0)
    bench.push(REST, 1.4)
    assert bench.intake.outages.count == 0
    bench.push(REST, 2.0)
    (silence,) = bench.intake.outages.between(0.0, 2.0, 2.0)
    assert silence.kind == "reply silence" and silence.ended_s == 2.0


def test_a_closed_link_drops_what_is_pushed() -> None:
    bench = _Bench()
    bench.intake.live = False
    bench.push(REST, 0.1)
    assert bench.intake.state is None and bench.recorded == [] and bench.capture.replies == []


def test_a_failing_consumer_is_reported_not_raised_into_the_peer() -> None:
    bench = _Bench()

    class Broken:
        def reply(self, t_s: float, data: bytes) -> None:
            raise RuntimeError("capture broke")

    bench.intake.capture = Broken()
    bench.push(REST, 0.1)
    assert [str(e) for e in bench.failures] == ["capture broke"]


def test_the_waiters_get_each_new_state() -> None:
    async def session() -> JointState | None:
        bench = _Bench()
        waiter = bench.intake.waiters.add(lambda s: s.ticks[0] == 10001, math.inf)
        bench.push(REST, 0.1)
        assert not waiter.future.done()
        bench.push(MOVED, 0.2)
        state: JointState | None = await waiter.future
        return state

    state = run_virtual(session())
    assert state is not None and state.seq == 2


def test_the_link_keeps_its_reply_timeout_in_the_intake() -> None:
    arm = Arm("fake://", reply_timeout_s=0.7)
    intake = arm._intake
    assert intake.reply_timeout_s == 0.7
    arm.reply_timeout_s = 2.0
    assert intake.reply_timeout_s == 2.0 and arm.reply_timeout_s == 2.0


def test_the_framer_hands_a_repeated_reply_back_as_the_same_object() -> None:
    framer = Framer("reply")
    first = framer.one_reply(REST)
    assert first == Reply(10000, 20000, 30000, 40000)
    assert framer.one_reply(bytes(bytearray(REST))) is first
    assert framer.one_reply(MOVED) == Reply(10001, 20000, 30000, 40000)
    assert framer.one_reply(b"$10000,20000,30000,4000x#") is None
    assert framer.frames == 3


def test_fake_arm_moves_through_the_intake() -> None:
    async def session() -> tuple[JointState, int]:
        async with Arm.connect("fake://") as arm:
            with arm.record_states() as states:
                done = await arm.move_joints((0.2, 0.1, 0.3, 0.4), duty=99)
                await asyncio.sleep(0.05)
            assert done is not None
            return done, len(states)

    done, recorded = run_virtual(session())
    assert done.q_rad == pytest.approx((0.2, 0.1, 0.3, 0.4), abs=3e-4)
    assert recorded > 10
