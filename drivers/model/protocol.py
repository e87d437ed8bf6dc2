"""Sans-I/O codec for the firmware's UART protocol (paper §5.3).

Bytes in, typed frames out; no I/O, no clocks, so the host driver and the emulator share it.

Wire format::

    command  $PPPPP,VV,PPPPP,VV,PPPPP,VV,PPPPP,VV#   (37 bytes)
    reply    $PPPPP,PPPPP,PPPPP,PPPPP#               (25 bytes)

``PPPPP`` is a joint angle in radians × 10 000, ``00000``..``62832``; ``VV`` is the PWM duty
``00``..``99`` of speed law (12), ``00`` meaning hold.

Angle convention (one rule, both directions):

* encode: wrap the angle into [0, 2π) with ``math.fmod``-style modulo, then round half up to the
  nearest 1e-4 rad: ``ticks = floor(wrapped × 10 000 + 0.5)``. The result lies in 0..62832; 62832
  (2π rounded) is a legal wire value and decodes to ~2π, i.e. the same direction as 0.
  Examples: 2π → 0; −0.00001 rad → 62832; 6.28315 rad → 62832.
* decode: ``ticks / 10 000`` is mapped into the joint's window ``(mid − π, mid + π]`` where ``mid``
  is the centre of its configured limits, so negative joint angles come back negative.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from operator import index
from typing import Final, Literal, NamedTuple, SupportsFloat, SupportsIndex

from armbench.drivers.model.errors import FrameValueError, ProtocolError

__all__ = [
    "COMMAND_LEN",
    "CYCLE_S",
    "JOINTS",
    "MAX_DUTY",
    "MAX_TICKS",
    "REPLY_LEN",
    "TICKS_PER_RAD",
    "AngleDecoder",
    "Command",
    "FrameError",
    "FrameValueError",
    "Framer",
    "ProtocolError",
    "Reply",
    "encode_reply",
    "rad_to_ticks",
    "ticks_to_rad",
]

TICKS_PER_RAD: Final = 10_000
MAX_TICKS: Final = 62_832
MAX_DUTY: Final = 99
#: The firmware's control cycle (its timer interrupt), seconds: a joint at duty ``v`` makes one
#: motor step every ``101 − v`` cycles (speed law (12), :mod:`armbench.drivers.host.motion`).
CYCLE_S: Final = 80e-6
JOINTS: Final = 4
REPLY_LEN: Final = 25
COMMAND_LEN: Final = 37
TWO_PI: Final = 2.0 * math.pi


def rad_to_ticks(q_rad: SupportsFloat, joint: int | None = None) -> int:
    """Wire ticks (0..62832) of an angle in radians; see the module docstring for the rule.

    The angle may be any real number (a numpy integer too: it is made a float here, so the
    compiled build, whose ``float`` takes no numpy integer, reads it as the source does)."""
    if not math.isfinite(q_rad):
        raise FrameValueError(joint, "position", q_rad, "is not a finite angle")
    wrapped = float(q_rad) % TWO_PI
    return math.floor(wrapped * TICKS_PER_RAD + 0.5)


def ticks_to_rad(ticks: SupportsIndex, lower_rad: SupportsFloat = 0.0,
                 upper_rad: SupportsFloat = TWO_PI) -> float:
    """Angle in radians of wire ticks (a whole number: Python's or numpy's), mapped into the
    window centred on the joint's limits."""
    t = index(ticks)
    return t / TICKS_PER_RAD - TWO_PI * _k_of(t, 0.5 * (float(lower_rad) + float(upper_rad)))


class AngleDecoder:
    """Decodes replies of one arm: ``reply.angles_rad(lower_rad, upper_rad)``, bit for bit, in one
    call per reply (the driver makes one per reply, hundreds a second).

    :func:`ticks_to_rad` subtracts ``2π · k`` with ``k = ceil((ticks / 10 000 − mid − π) / 2π)``:
    a monotonic step function of the ticks that takes at most three values on 0..MAX_TICKS. So
    ``k`` is its value at 0 plus one for each threshold (found here once per joint, by bisection
    on that very expression) the ticks have reached.
    """

    __slots__ = ("_a1", "_a2", "_a3", "_a4", "_b1", "_b2", "_b3", "_b4",
                 "_k1", "_k2", "_k3", "_k4")

    def __init__(self, lower_rad: Sequence[SupportsFloat],
                 upper_rad: Sequence[SupportsFloat]) -> None:
        _check_count("lower_rad", lower_rad)
        _check_count("upper_rad", upper_rad)
        steps = [_k_steps(0.5 * (float(lo) + float(up)))
                 for lo, up in zip(lower_rad, upper_rad, strict=True)]
        (self._k1, self._a1, self._b1), (self._k2, self._a2, self._b2) = steps[0], steps[1]
        (self._k3, self._a3, self._b3), (self._k4, self._a4, self._b4) = steps[2], steps[3]

    def __call__(self, reply: Reply) -> tuple[float, float, float, float]:
        """The reply's joint angles (rad), each in its joint's window."""
        return self.angles(reply)

    def angles(self, reply: Reply) -> tuple[float, float, float, float]:
        """:meth:`__call__` by name: compiled, a call by name is a direct C call, where calling
        the instance goes through Python's call protocol."""
        t1, t2, t3, t4 = reply
        return (t1 / TICKS_PER_RAD - TWO_PI * (self._k1 + (t1 >= self._a1) + (t1 >= self._b1)),
                t2 / TICKS_PER_RAD - TWO_PI * (self._k2 + (t2 >= self._a2) + (t2 >= self._b2)),
                t3 / TICKS_PER_RAD - TWO_PI * (self._k3 + (t3 >= self._a3) + (t3 >= self._b3)),
                t4 / TICKS_PER_RAD - TWO_PI * (self._k4 + (t4 >= self._a4) + (t4 >= self._b4)))


def _k_of(ticks: int, mid: float) -> int:
    """The whole turns :func:`ticks_to_rad` subtracts to bring ``ticks`` into the window centred
    on ``mid`` (rad)."""
    return math.ceil((ticks / TICKS_PER_RAD - mid - math.pi) / TWO_PI)


def _k_steps(mid: float) -> tuple[int, int, int]:
    """``k`` at tick 0 and the first ticks where it has grown by one and by two (``MAX_TICKS +
    1`` where it never does)."""
    k0 = _k_of(0, mid)
    thresholds = [MAX_TICKS + 1, MAX_TICKS + 1]
    for n in range(_k_of(MAX_TICKS, mid) - k0):  # the first ticks with k >= k0 + n + 1
        a, b = 0, MAX_TICKS
        while a < b:
            m = (a + b) // 2
            if _k_of(m, mid) > k0 + n:
                b = m
            else:
                a = m + 1
        thresholds[n] = a
    return k0, thresholds[0], thresholds[1]


def _check_duty(value: object, joint: int) -> int:
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise FrameValueError(joint, "duty", value, "is not a whole number 0..99")
    duty = value
    if not 0 <= duty <= MAX_DUTY:
        raise FrameValueError(joint, "duty", duty, f"is outside 0..{MAX_DUTY}")
    return duty


def _check_count(name: str, values: Sequence[object]) -> None:
    if len(values) != JOINTS:
        raise FrameValueError(None, name, tuple(values),
                              f"has {len(values)} values; the arm has {JOINTS} joints")


def _check_ticks(ticks: Sequence[object]) -> tuple[int, int, int, int]:
    # values of any type (Sequence[object]: a compiled ``int`` would raise a TypeError on them
    # before this check could name the joint)
    _check_count("positions", ticks)
    valid: list[int] = []
    for i, t in enumerate(ticks, 1):
        if isinstance(t, bool) or not isinstance(t, int) or not 0 <= t <= MAX_TICKS:
            raise FrameValueError(i, "position", t, f"is not a tick count 0..{MAX_TICKS}")
        valid.append(t)
    return (valid[0], valid[1], valid[2], valid[3])


#: The digits of a tick count as pieces of a reply: its first two digits, and its last three
#: with the separator that follows them (``encode_reply``: one join instead of a ``%`` format,
#: which parses its format and makes a str of each number on every call).
_HIGH_DIGITS: Final = tuple(b"%02d" % k for k in range(100))
_LOW_DIGITS_COMMA: Final = tuple(b"%03d," % k for k in range(1000))
_LOW_DIGITS_END: Final = tuple(b"%03d#" % k for k in range(1000))


def encode_reply(j1: int, j2: int, j3: int, j4: int) -> bytes:
    """The 25 wire bytes of a reply from four tick counts already known to be valid (0..62832):
    the firmware's side of :meth:`Reply.encode`, without building a frame object."""
    if 0 <= j1 < 100_000 and 0 <= j2 < 100_000 and 0 <= j3 < 100_000 and 0 <= j4 < 100_000:
        high, low, end = _HIGH_DIGITS, _LOW_DIGITS_COMMA, _LOW_DIGITS_END
        return b"".join((b"$", high[j1 // 1000], low[j1 % 1000], high[j2 // 1000],
                         low[j2 % 1000], high[j3 // 1000], low[j3 % 1000], high[j4 // 1000],
                         end[j4 % 1000]))
    return b"$%05d,%05d,%05d,%05d#" % (j1, j2, j3, j4)


class Reply(NamedTuple):
    """The master's reply: current joint positions in wire ticks, joints 1..4."""

    j1: int
    j2: int
    j3: int
    j4: int

    @classmethod
    def from_ticks(cls, ticks: Sequence[object]) -> Reply:
        """A validated reply from four tick counts."""
        return cls(*_check_ticks(ticks))

    @classmethod
    def from_rad(cls, q_rad: Sequence[SupportsFloat]) -> Reply:
        """A reply from four joint angles in radians (wrapped and rounded as documented)."""
        _check_count("positions", q_rad)
        return cls(*(rad_to_ticks(q, i) for i, q in enumerate(q_rad, 1)))

    def angles_rad(self, lower_rad: Sequence[SupportsFloat],
                   upper_rad: Sequence[SupportsFloat]) -> tuple[float, float, float, float]:
        """Joint angles in radians, each mapped into its joint's window."""
        return (ticks_to_rad(self.j1, lower_rad[0], upper_rad[0]),
                ticks_to_rad(self.j2, lower_rad[1], upper_rad[1]),
                ticks_to_rad(self.j3, lower_rad[2], upper_rad[2]),
                ticks_to_rad(self.j4, lower_rad[3], upper_rad[3]))

    def encode(self) -> bytes:
        """The 25 wire bytes of this reply."""
        return encode_reply(self.j1, self.j2, self.j3, self.j4)


@dataclass(frozen=True, slots=True)
class Command:
    """A host command: target positions in wire ticks and PWM duties, joints 1..4."""

    ticks: tuple[int, int, int, int]
    duties: tuple[int, int, int, int]

    def __post_init__(self) -> None:
        _check_ticks(self.ticks)
        _check_count("duties", self.duties)
        for i, d in enumerate(self.duties, 1):
            _check_duty(d, i)

    @classmethod
    def from_rad(cls, q_rad: Sequence[SupportsFloat], duty: int | Sequence[int]) -> Command:
        """Build from joint angles in radians and one duty for all joints or one per joint.

        Raises :class:`FrameValueError` naming the joint for NaN/inf angles, duties outside
        0..99 and a wrong number of joints.
        """
        _check_count("positions", q_rad)
        # values of any type: checked one by one below, with an error naming the joint (as
        # ``object``: narrowed to ``int``, the compiled build would make a boolean 0 or 1)
        value: object = duty
        duties: list[object] = [*value] if isinstance(value, Iterable) else [value] * JOINTS
        _check_count("duties", duties)
        ticks = tuple(rad_to_ticks(q, i) for i, q in enumerate(q_rad, 1))
        d = tuple(_check_duty(v, i) for i, v in enumerate(duties, 1))
        return cls((ticks[0], ticks[1], ticks[2], ticks[3]), (d[0], d[1], d[2], d[3]))

    def angles_rad(self, lower_rad: Sequence[SupportsFloat],
                   upper_rad: Sequence[SupportsFloat]) -> tuple[float, float, float, float]:
        """Target angles in radians, each mapped into its joint's window."""
        return Reply(*self.ticks).angles_rad(lower_rad, upper_rad)

    def encode(self) -> bytes:
        """The 37 wire bytes of this command."""
        t, d = self.ticks, self.duties
        return b"$%05d,%02d,%05d,%02d,%05d,%02d,%05d,%02d#" % (
            t[0], d[0], t[1], d[1], t[2], d[2], t[3], d[3])


class FrameError(NamedTuple):
    """A stretch of the stream that was not a valid frame: reported, counted and skipped.

    ``raw`` holds at most the first 64 bytes of it; ``size`` is its full length in bytes.
    """

    reason: str
    raw: bytes
    size: int


FrameKind = Literal["reply", "command"]
Event = Reply | Command | FrameError

# 0..62832 as five digits, so range errors fall out of the fast path into the careful one.
_T = rb"((?:[0-5]\d|6[01])\d{3}|62[0-7]\d\d|628[0-2]\d|6283[0-2])"
_REPLY_RE = re.compile(rb"\$" + rb",".join([_T] * 4) + rb"#")
_COMMAND_RE = re.compile(rb"\$" + rb",".join([_T + rb",(\d\d)"] * 4) + rb"#")
_CANDIDATE_RE = re.compile(rb"\$([^$#]*)#")
_RAW_KEEP = 64
_new: Final = tuple.__new__  # Final: a C global where mypyc compiles, not a dict lookup


def _command(f: tuple[bytes, ...]) -> Command:
    return Command((int(f[0]), int(f[2]), int(f[4]), int(f[6])),
                   (int(f[1]), int(f[3]), int(f[5]), int(f[7])))


def _digits5(data: bytes, i: int) -> int:
    """The number the five ASCII digits at ``data[i:i + 5]`` write, or -1 if one is no digit."""
    d0, d1, d2 = data[i] - 48, data[i + 1] - 48, data[i + 2] - 48
    d3, d4 = data[i + 3] - 48, data[i + 4] - 48
    if not (0 <= d0 <= 9 and 0 <= d1 <= 9 and 0 <= d2 <= 9 and 0 <= d3 <= 9 and 0 <= d4 <= 9):
        return -1
    return (((d0 * 10 + d1) * 10 + d2) * 10 + d3) * 10 + d4


def _one_reply(data: bytes) -> Reply | None:
    """The reply the :data:`REPLY_LEN` bytes ``data`` are, or None: what ``_REPLY_RE`` matches
    (``$``, four fields of five ASCII digits up to :data:`MAX_TICKS` between commas, ``#``),
    read byte by byte instead of by the regular expression or by slices and ``int``: compiled,
    a byte is a C array read, where a slice is a new object and ``int`` a parser (a reply is
    decoded hundreds of times a second)."""
    if data[0] != 36 or data[6] != 44 or data[12] != 44 or data[18] != 44 or data[24] != 35:
        return None  # '$', ',', ',', ',', '#'
    t1, t2, t3, t4 = _digits5(data, 1), _digits5(data, 7), _digits5(data, 13), _digits5(data, 19)
    if not (0 <= t1 <= MAX_TICKS and 0 <= t2 <= MAX_TICKS and 0 <= t3 <= MAX_TICKS
            and 0 <= t4 <= MAX_TICKS):
        return None
    return _new(Reply, (t1, t2, t3, t4))


def _gap_reason(gap: bytes) -> str:
    return "frame cut short by a new '$'" if b"$" in gap else "bytes outside a frame"


def _garbage_size(data: bytes) -> int:
    """Bytes of ``data`` that are neither CR nor LF (line ends after '#' are not garbage)."""
    return len(data) - data.count(b"\r") - data.count(b"\n")


class Framer:
    """Turns arbitrary chunks of a byte stream into frames of one kind.

    ``feed`` never raises on wire bytes: anything that is not a valid frame becomes a
    :class:`FrameError` event and is counted. The buffer never holds more than one frame's length,
    so a stream without ``#`` cannot grow memory. CR/LF between frames are accepted silently.
    """

    __slots__ = ("_buf", "_fast", "_last_data", "_last_reply", "_len", "_replies",
                 "discarded_bytes", "errors", "frames", "kind")

    def __init__(self, kind: FrameKind = "reply") -> None:
        if kind not in ("reply", "command"):
            raise ValueError(f"kind: {kind!r} is not 'reply' or 'command'")
        self.kind: FrameKind = kind
        self._len = REPLY_LEN if kind == "reply" else COMMAND_LEN
        self._fast = (_REPLY_RE if kind == "reply" else _COMMAND_RE).findall
        self._replies = kind == "reply"
        self._buf = b""
        self._last_data = b""
        self._last_reply: Reply | None = None
        self.frames = 0
        """Valid frames decoded."""
        self.errors = 0
        """Error events emitted (malformed frames and runs of garbage)."""
        self.discarded_bytes = 0
        """Bytes thrown away, CR/LF excluded."""

    @property
    def buffered(self) -> int:
        """Bytes held while waiting for the rest of a frame (never more than one frame)."""
        return len(self._buf)

    def one_reply(self, data: bytes) -> Reply | None:
        """The reply ``data`` is, if it is exactly one valid reply and nothing is buffered (how
        a fake:// or a quiet line delivers them): counted as :meth:`feed` would. Otherwise None,
        and nothing is consumed: :meth:`feed` the chunk."""
        if self._replies and not self._buf and len(data) == REPLY_LEN:
            if data == self._last_data:  # an arm at rest repeats its reply: the same Reply
                self.frames += 1
                return self._last_reply
            reply = _one_reply(data)
            if reply is not None:
                self.frames += 1
                self._last_data, self._last_reply = data, reply
            return reply
        return None

    def feed(self, data: bytes) -> list[Event]:
        """Add bytes from the wire; return the frames and errors they complete, in stream order."""
        one = self.one_reply(data)
        if one is not None:
            return [one]
        buf = self._buf + data if self._buf else bytes(data)
        end = buf.rfind(b"#") + 1
        events: list[Event] = []
        if end:
            found = self._fast(buf, 0, end)
            n = len(found)
            flen = self._len
            # The matches tile the region exactly (optionally with CR LF pairs between them):
            # every byte up to the last '#' belongs to a valid frame.
            if end == flen * n or end - flen * n == 2 * buf.count(b"\r\n", 0, end):
                app = events.append
                if flen == REPLY_LEN:
                    for a, b, c, d in found:
                        app(_new(Reply, (int(a), int(b), int(c), int(d))))
                else:
                    for f in found:
                        app(_command(f))
                self.frames += n
            else:
                self._careful(buf[:end], events)
        self._keep_tail(buf[end:], events)
        return events

    def _garbage(self, data: bytes, events: list[Event], reason: str) -> None:
        size = _garbage_size(data)
        if size:
            self.discarded_bytes += size
            self.errors += 1
            events.append(FrameError(reason, data[:_RAW_KEEP], len(data)))

    def _careful(self, region: bytes, events: list[Event]) -> None:
        """Slow path for a region ending in '#' that is not a clean run of frames."""
        pos = 0
        strict = _REPLY_RE if self.kind == "reply" else _COMMAND_RE
        for m in _CANDIDATE_RE.finditer(region):
            self._garbage(region[pos:m.start()], events, _gap_reason(region[pos:m.start()]))
            pos = m.end()
            frame = region[m.start():pos]
            valid = strict.fullmatch(frame)
            if valid is not None:
                g = valid.groups()
                self.frames += 1
                events.append(Reply(int(g[0]), int(g[1]), int(g[2]), int(g[3]))
                              if self.kind == "reply" else _command(g))
                continue
            self.discarded_bytes += len(frame)
            self.errors += 1
            events.append(FrameError(self._why(frame), frame[:_RAW_KEEP], len(frame)))
        self._garbage(region[pos:], events, _gap_reason(region[pos:]))

    def _why(self, frame: bytes) -> str:
        body = frame[1:-1].split(b",")
        widths = (5,) * JOINTS if self.kind == "reply" else (5, 2) * JOINTS
        if len(body) != len(widths):
            return f"{len(body)} fields where a {self.kind} has {len(widths)}"
        for i, (f, w) in enumerate(zip(body, widths, strict=True)):
            joint = i + 1 if self.kind == "reply" else i // 2 + 1
            what = "position" if w == 5 else "duty"
            if len(f) != w or not f.isdigit():
                return f"joint {joint} {what} {f!r} is not {w} digits"
            if w == 5 and int(f) > MAX_TICKS:
                return f"joint {joint} position {int(f)} is above {MAX_TICKS}"
        return "malformed frame"

    def _keep_tail(self, tail: bytes, events: list[Event]) -> None:
        """Keep a possible frame start after the last '#'; discard what cannot be a frame."""
        start = tail.rfind(b"$")
        if start < 0:
            self._garbage(tail, events, "bytes outside a frame")
            self._buf = b""
            return
        if start:
            self._garbage(tail[:start], events, _gap_reason(tail[:start]))
            tail = tail[start:]
        if len(tail) >= self._len:
            self._garbage(tail, events, f"no '#' within {self._len} bytes of '$'")
            self._buf = b""
        else:
            self._buf = tail

    def flush(self) -> list[Event]:
        """End of stream: report a pending partial frame as an error."""
        events: list[Event] = []
        if self._buf:
            self._garbage(self._buf, events, "stream ended inside a frame")
            self._buf = b""
        return events
