"""The reply stream: bytes from the arm in, joint states and framing errors out; no I/O.

The driver's reader hands every chunk it reads to one :class:`ReplyStream` with the loop time it
read it at; the stream frames it (:class:`~armbench.drivers.model.protocol.Framer`), decodes the
replies into :class:`~armbench.drivers.host.state.JointState` and keeps the counters. What to do
with the result (wake waiters, write the capture, fill recorders) is the caller's, so the stream is
tested with
plain bytes, in the style of h11::

    stream = ReplyStream(settings.lower_rad, settings.upper_rad)
    batch = stream.receive(b"$00000,00000,00000,00000#", 0.0)
    batch.state.q_rad                                   # (0.0, 0.0, 0.0, 0.0)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final, NamedTuple

from armbench.drivers.host.state import JointState
from armbench.drivers.model.protocol import (
    REPLY_LEN,
    AngleDecoder,
    Event,
    FrameError,
    Framer,
    Reply,
)

__all__ = ["Batch", "ReplyStream"]

_new: Final = tuple.__new__  # Final: a C global where mypyc compiles, not a dict lookup


class Batch(NamedTuple):
    """What one chunk completed.

    ``events``: the replies and framing errors, in stream order. ``states``: one state per reply
    (only when asked for ``every``; else empty). ``state``: the newest state (None when the chunk
    completed no reply). ``single``: the chunk was exactly one frame long and started a frame, so
    a reply in it is the chunk's own bytes.
    """

    events: list[Event]
    states: list[JointState]
    state: JointState | None
    single: bool


class ReplyStream:
    """Frames and decodes the replies of one link (a new stream for each reconnection).

    Counters: :attr:`frames_received` (valid replies), :attr:`frames_dropped` (framer error
    events once the stream was in sync: errors before the first reply are synchronisation) and
    :attr:`discarded_bytes` (bytes thrown away, CR/LF excluded). States are numbered from
    ``seq0 + 1`` on; :meth:`restart` starts a new link.
    """

    __slots__ = ("_angles", "_decode", "_framer", "_reply", "discarded_bytes", "frames_dropped",
                 "frames_received", "seq", "synced")

    def __init__(self, lower_rad: Sequence[float], upper_rad: Sequence[float],
                 seq0: int = 0) -> None:
        self._framer = Framer("reply")
        self._decode = AngleDecoder(lower_rad, upper_rad)
        self._reply: Reply | None = None
        # tuple[float, ...], not the four-float tuple angles() returns: compiled, that one is
        # held as four C doubles and boxed again on every read
        self._angles: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
        self.seq = seq0
        """Number of the newest state."""
        self.synced = False
        """True once a valid reply has been seen."""
        self.frames_received = 0
        self.frames_dropped = 0
        self.discarded_bytes = 0

    def restart(self) -> None:
        """A new link (reconnection): a fresh framer, so its first bytes are synchronisation
        again; the counters and the numbering go on."""
        self._framer = Framer("reply")
        self.synced = False

    def one(self, data: bytes, t_s: float) -> JointState | None:
        """The state of ``data`` if it is exactly one valid reply and nothing is buffered (how a
        fake:// or a quiet line delivers them), counted as :meth:`receive` would; otherwise None
        and nothing is consumed: :meth:`receive` the chunk."""
        reply = self._framer.one_reply(data)
        if reply is None:
            return None
        if reply is not self._reply:  # the framer returns a repeated reply as the same object
            self._reply, self._angles = reply, self._decode.angles(reply)
        self.synced = True
        self.seq = seq = self.seq + 1
        self.frames_received += 1
        return _new(JointState, (t_s, self._angles, reply, seq))

    def receive(self, data: bytes, t_s: float, *, every: bool = False) -> Batch:
        """Feed a chunk read at loop time ``t_s``; with ``every`` decode each reply it completes
        (for recorders), else only the newest."""
        framer = self._framer
        single = len(data) == REPLY_LEN and not framer.buffered
        before = framer.discarded_bytes
        events = framer.feed(data)
        self.discarded_bytes += framer.discarded_bytes - before
        decoder = self._decode
        states: list[JointState] = []
        last: Reply | None = None
        n = 0
        for ev in events:
            if type(ev) is Reply:
                n += 1
                last = ev
                self.synced = True
                if every:
                    states.append(_new(JointState, (t_s, decoder.angles(ev), ev, self.seq + n)))
            elif self.synced and isinstance(ev, FrameError):
                self.frames_dropped += 1
        if last is None:
            return Batch(events, states, None, single)
        self.seq += n
        self.frames_received += n
        state = states[-1] if states else _new(
            JointState, (t_s, decoder.angles(last), last, self.seq))
        return Batch(events, states, state, single)
