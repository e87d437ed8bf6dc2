"""The §5.3 codec: encode/decode, angle convention at the edges, and the stream framer."""

from __future__ import annotations

import math
import random
from collections.abc import Sequence

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armbench.drivers.model.protocol import (
    COMMAND_LEN,
    MAX_TICKS,
    REPLY_LEN,
    TICKS_PER_RAD,
    AngleDecoder,
    Command,
    FrameError,
    Framer,
    FrameValueError,
    ProtocolError,
    Reply,
    rad_to_ticks,
    ticks_to_rad,
)
from armbench.drivers.model.settings import RobotSettings

DEFAULT = RobotSettings()
ticks = st.integers(0, MAX_TICKS)
duties = st.integers(0, 99)
replies = st.builds(Reply, ticks, ticks, ticks, ticks)
commands = st.builds(lambda t, d: Command(tuple(t), tuple(d)),
                     st.lists(ticks, min_size=4, max_size=4),
                     st.lists(duties, min_size=4, max_size=4))


def feed_all(framer: Framer, chunks: list[bytes]) -> list[object]:
    out: list[object] = []
    for c in chunks:
        out.extend(framer.feed(c))
    return out


def frames_only(events: Sequence[object]) -> list[object]:
    return [e for e in events if not isinstance(e, FrameError)]


# --- angle convention -----------------------------------------------------------------------

def test_paper_examples_encode_exactly() -> None:
    assert Command((0, 0, 0, 0), (0, 0, 0, 0)).encode() == b"$00000,00,00000,00,00000,00,00000,00#"
    assert Reply(0, 0, 0, 0).encode() == b"$00000,00000,00000,00000#"
    assert len(Command((1, 2, 3, 4), (5, 6, 7, 8)).encode()) == COMMAND_LEN
    assert len(Reply(1, 2, 3, 4).encode()) == REPLY_LEN


@pytest.mark.parametrize(("q", "expected"), [
    (0.0, 0),
    (2 * math.pi, 0),            # a full turn is the same direction as zero
    (-0.00001, 62832),           # wraps to 2π − 1e-5 = 6.28317…, rounds to 62832
    (6.28315, 62832),            # 62831.5 rounds half up
    (6.283149, 62831),
    (0.00004999, 0),
    (0.00005, 1),                # half a tick rounds up
    (-math.pi, 31416),
    (1.0, 10000),
    (4 * math.pi + 0.5, 5000),
])
def test_rad_to_ticks_edges(q: float, expected: int) -> None:
    assert rad_to_ticks(q) == expected


def test_62832_decodes_to_the_zero_direction_in_a_symmetric_joint() -> None:
    j1 = DEFAULT.joints[0]
    q = ticks_to_rad(62832, j1.lower_rad, j1.upper_rad)
    assert q == pytest.approx(62832 / 10_000 - 2 * math.pi)
    assert abs(q) < 2e-5


def test_decode_maps_into_the_joint_window() -> None:
    j2 = DEFAULT.joints[1]  # −45°..70°
    q = ticks_to_rad(rad_to_ticks(math.radians(-40)), j2.lower_rad, j2.upper_rad)
    assert q == pytest.approx(math.radians(-40), abs=1e-4)
    j4 = DEFAULT.joints[3]  # −30°..120°
    q = ticks_to_rad(rad_to_ticks(math.radians(110)), j4.lower_rad, j4.upper_rad)
    assert q == pytest.approx(math.radians(110), abs=1e-4)


@given(q=st.floats(-50, 50, allow_nan=False), which=st.integers(0, 3))
def test_angle_round_trip_within_half_a_tick(q: float, which: int) -> None:
    j = DEFAULT.joints[which]
    mid = 0.5 * (j.lower_rad + j.upper_rad)
    back = ticks_to_rad(rad_to_ticks(q), j.lower_rad, j.upper_rad)
    assert mid - math.pi - 1e-9 <= back <= mid + math.pi + 1e-4
    diff = (back - q + math.pi) % (2 * math.pi) - math.pi
    assert abs(diff) <= 0.5e-4 + 1e-9


@given(replies)
def test_reply_round_trip(r: Reply) -> None:
    assert Framer("reply").feed(r.encode()) == [r]


@given(commands)
def test_command_round_trip(c: Command) -> None:
    assert Framer("command").feed(c.encode()) == [c]


@given(st.lists(st.floats(-3, 3), min_size=4, max_size=4), st.integers(0, 99))
def test_command_from_rad_round_trip(q: list[float], duty: int) -> None:
    c = Command.from_rad(q, duty)
    (back,) = Framer("command").feed(c.encode())
    assert isinstance(back, Command)
    angles = back.angles_rad(DEFAULT.lower_rad, DEFAULT.upper_rad)
    for a, b in zip(angles, q, strict=True):
        assert abs((a - b + math.pi) % (2 * math.pi) - math.pi) <= 0.5e-4 + 1e-12
    assert back.duties == (duty,) * 4


# --- building commands from bad values --------------------------------------------------------

@pytest.mark.parametrize(("q", "duty", "joint", "value"), [
    ([0.0, math.nan, 0.0, 0.0], 10, 2, "nan"),
    ([0.0, 0.0, 0.0, math.inf], 10, 4, "inf"),
    ([0.0, 0.0, 0.0, 0.0], [10, 10, 100, 10], 3, "100"),
    ([0.0, 0.0, 0.0, 0.0], [-1, 10, 10, 10], 1, "-1"),
    ([0.0, 0.0, 0.0, 0.0], [10, 10, 10, 2.5], 4, "2.5"),
])
def test_bad_values_name_joint_and_value(q: list[float], duty: object, joint: int,
                                         value: str) -> None:
    with pytest.raises(FrameValueError) as info:
        Command.from_rad(q, duty)  # type: ignore[arg-type]
    assert info.value.joint == joint
    assert f"joint {joint}" in str(info.value)
    assert value in str(info.value)
    assert isinstance(info.value, ValueError) and isinstance(info.value, ProtocolError)


def test_wrong_joint_count() -> None:
    with pytest.raises(FrameValueError, match="3 values"):
        Command.from_rad([0.0, 0.0, 0.0], 5)
    with pytest.raises(FrameValueError, match="5 values"):
        Command.from_rad([0.0] * 4, [1, 2, 3, 4, 5])
    with pytest.raises(FrameValueError, match="joint 2 position"):
        Reply.from_ticks([0, 62833, 0, 0])


# --- the framer ------------------------------------------------------------------------------

def test_chunks_split_anywhere_several_per_chunk_and_crlf() -> None:
    frames = [Reply(i, 2 * i, 3 * i, MAX_TICKS - i) for i in range(50)]
    stream = b"".join(f.encode() + (b"\r\n" if i % 2 else b"") for i, f in enumerate(frames))
    rng = random.Random(4)
    for _ in range(20):
        cuts = sorted(rng.sample(range(1, len(stream)), 40))
        chunks = [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]
        framer = Framer()
        assert feed_all(framer, chunks) == frames
        assert framer.errors == 0 and framer.discarded_bytes == 0


def test_every_frame_byte_by_byte() -> None:
    frames = [Reply(i, i, i, i) for i in range(0, 60000, 997)]
    framer = Framer()
    stream = b"".join(f.encode() for f in frames)
    assert feed_all(framer, [bytes([b]) for b in stream]) == frames
    assert framer.frames == len(frames)


def test_dollar_storm_then_frame() -> None:
    framer = Framer()
    good = Reply(1, 2, 3, 4)
    events = feed_all(framer, [b"$" * 5000, good.encode()])
    assert frames_only(events) == [good]
    assert framer.discarded_bytes == 5000
    assert framer.buffered == 0


def test_hash_storm_then_frame() -> None:
    framer = Framer()
    good = Reply(1, 2, 3, 4)
    events = feed_all(framer, [b"#" * 5000, good.encode(), b"#" * 7])
    assert frames_only(events) == [good]
    assert framer.discarded_bytes == 5007


def test_frame_cut_by_new_dollar() -> None:
    framer = Framer()
    good = Reply(11, 22, 33, 44)
    events = framer.feed(b"$12345,678" + good.encode())
    assert frames_only(events) == [good]
    errors = [e for e in events if isinstance(e, FrameError)]
    assert len(errors) == 1 and "cut short" in errors[0].reason
    assert errors[0].raw == b"$12345,678"


def test_100kb_of_garbage_is_bounded_and_counted() -> None:
    framer = Framer()
    rng = random.Random(1)
    garbage = bytes(rng.choice(b"0123456789,abc \x00\xff") for _ in range(100_000))
    good = Reply(9, 8, 7, 6)
    events: list[object] = []
    for i in range(0, len(garbage), 4096):
        events.extend(framer.feed(garbage[i:i + 4096]))
        assert framer.buffered < REPLY_LEN
    events.extend(framer.feed(good.encode()))
    assert frames_only(events) == [good]
    assert framer.discarded_bytes == 100_000


def test_no_hash_stream_never_grows_the_buffer() -> None:
    framer = Framer()
    for _ in range(1000):
        framer.feed(b"$" + b"1" * 63)
        assert framer.buffered < REPLY_LEN


@pytest.mark.parametrize(("bad", "why"), [
    (b"$1234,00000,00000,00000#", "joint 1 position b'1234' is not 5 digits"),
    (b"$123456,00000,00000,00000#", "joint 1 position b'123456' is not 5 digits"),
    (b"$00000,00000,00000,6283#", "joint 4 position"),
    (b"$00000,00000,62833,00000#", "joint 3 position 62833 is above 62832"),
    (b"$00000,00000,00000#", "3 fields"),
    (b"$00000,+0000,00000,00000#", "joint 2 position"),
])
def test_malformed_frame_is_an_error_event_and_stream_resyncs(bad: bytes, why: str) -> None:
    framer = Framer()
    good = Reply(5, 6, 7, 8)
    events = framer.feed(good.encode() + bad + good.encode())
    assert events[0] == good and events[-1] == good
    errors = [e for e in events if isinstance(e, FrameError)]
    assert len(errors) == 1
    assert why in errors[0].reason
    assert framer.errors == 1


def test_command_framer_rejects_replies_and_bad_duty() -> None:
    framer = Framer("command")
    events = framer.feed(Reply(1, 2, 3, 4).encode() + b"$00000,0,00000,00,00000,00,00000,00#")
    assert all(isinstance(e, FrameError) for e in events) and len(events) == 2
    assert "joint 1 duty" in events[1].reason  # type: ignore[union-attr]


def test_flush_reports_a_pending_partial_frame() -> None:
    framer = Framer()
    assert framer.feed(b"$00001,0") == []
    (err,) = framer.flush()
    assert isinstance(err, FrameError) and "ended inside" in err.reason


@settings(max_examples=300)
@given(st.lists(st.binary(max_size=200), max_size=30))
def test_any_byte_stream_never_crashes_and_stays_bounded(chunks: list[bytes]) -> None:
    framer = Framer()
    for c in chunks:
        for e in framer.feed(c):
            assert isinstance(e, Reply | FrameError)
        assert framer.buffered < REPLY_LEN
    framer.flush()


noise = st.binary(max_size=40).map(lambda b: b.replace(b"$", b"").replace(b"#", b""))


@settings(max_examples=200)
@given(st.lists(st.tuples(noise, replies), min_size=1, max_size=20), st.integers(1, 80),
       st.booleans())
def test_valid_frames_in_noise_are_all_recovered(pairs: list[tuple[bytes, Reply]],
                                                 chunk: int, hash_noise: bool) -> None:
    # Noise without '$' cannot start a frame; with '#' in it, it cannot end one that started.
    stream = b"".join((n + b"#" if hash_noise else n) + r.encode() for n, r in pairs)
    framer = Framer()
    events = feed_all(framer, [stream[i:i + chunk] for i in range(0, len(stream), chunk)])
    assert frames_only(events) == [r for _, r in pairs]
    assert framer.frames == len(pairs)


@given(st.one_of(replies.map(Reply.encode), st.binary(max_size=40)), st.binary(max_size=30))
def test_one_reply_is_feed_for_one_whole_reply_and_consumes_nothing_else(
        data: bytes, before: bytes) -> None:
    """``Framer.one_reply`` (the driver's short path) gives what ``feed`` gives for a chunk that
    is exactly one reply with nothing buffered, and None, consuming nothing, for anything else."""
    fast, plain = Framer("reply"), Framer("reply")
    fast.feed(before)
    plain.feed(before)
    one = fast.one_reply(data)
    if one is None:
        assert fast.frames == plain.frames and fast.buffered == plain.buffered
        assert fast.feed(data) == plain.feed(data)
    else:
        assert not plain.buffered and len(data) == REPLY_LEN
        assert plain.feed(data) == [one]
        assert fast.frames == plain.frames
    assert Framer("command").one_reply(Reply(1, 2, 3, 4).encode()) is None


_NEAR_REPLY = st.builds(
    lambda head, fields, seps, tail: head + b"".join(
        f + sep for f, sep in zip(fields, [*seps, b""], strict=True)) + tail,
    st.sampled_from([b"$"] * 6 + [b"#", b"0"]),
    st.lists(st.one_of(st.sampled_from([b"00000", b"62832", b"62833", b"62829", b"62799",
                                        b"61999", b"99999", b"07000", b"63000"]),
                       st.binary(min_size=5, max_size=5),
                       st.text("0123456789/: +-_\t", min_size=5, max_size=5).map(str.encode)),
             min_size=4, max_size=4),
    st.lists(st.sampled_from([b","] * 12 + [b";", b"#"]), min_size=3, max_size=3),
    st.sampled_from([b"#"] * 6 + [b"$", b","]))


@settings(max_examples=400)
@given(_NEAR_REPLY)
def test_one_reply_accepts_what_the_reply_pattern_matches(data: bytes) -> None:
    """The short path reads a reply byte by byte: the same replies as the frame pattern (five
    ASCII digits up to the largest tick count, commas, ``$`` and ``#``), nothing else (not the
    bytes either side of the digits, ``/`` and ``:``, nor `` 1234``, ``+1234`` or ``1_234``)."""
    from armbench.drivers.model.protocol import _REPLY_RE

    assert len(data) == REPLY_LEN
    m = _REPLY_RE.fullmatch(data)
    want = None if m is None else Reply(*(int(g) for g in m.groups()))
    assert Framer("reply").one_reply(data) == want


# --- the driver's decoder -------------------------------------------------------------------------

def test_angle_decoder_is_angles_rad_on_every_tick_of_the_default_arm() -> None:
    """Bit for bit, on all 62 833 wire values of each joint (its thresholds included)."""
    decode = AngleDecoder(DEFAULT.lower_rad, DEFAULT.upper_rad)
    for t in range(MAX_TICKS + 1):
        reply = Reply(t, t, t, t)
        assert decode(reply) == reply.angles_rad(DEFAULT.lower_rad, DEFAULT.upper_rad), t


@given(st.lists(st.tuples(st.floats(-20, 20), st.floats(0, 2 * math.pi)), min_size=4, max_size=4),
       st.lists(st.integers(0, MAX_TICKS), min_size=4, max_size=4))
def test_angle_decoder_is_angles_rad_in_any_window(windows: list[tuple[float, float]],
                                                   ticks: list[int]) -> None:
    lower = [lo for lo, _ in windows]
    upper = [lo + width for lo, width in windows]
    decode = AngleDecoder(lower, upper)
    reply = Reply(*ticks)
    assert decode(reply) == reply.angles_rad(lower, upper)
    for k, t in enumerate(ticks):  # and at the window's edge, where k steps
        mid = 0.5 * (lower[k] + upper[k])
        edge = max(0, min(MAX_TICKS, math.floor((mid + math.pi) % (2 * math.pi) * TICKS_PER_RAD)))
        for e in (edge - 1, edge, edge + 1):
            if 0 <= e <= MAX_TICKS:
                probe = Reply(*(e if i == k else t for i, t in enumerate(ticks)))
                assert decode(probe) == probe.angles_rad(lower, upper)
