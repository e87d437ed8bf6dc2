"""Trajectories as they reach the node, each answered with exactly one final status (no ROS import).

The node's subscription callback runs on rclpy's executor thread and hands every message, with
its ``MessageInfo``, to :meth:`Intake.receive`. That copies it into a :class:`Request` with an id
of its own (per node, in order of arrival) and its :class:`Source` (the publisher's GID and the
message's publication sequence number, when the middleware gives them: what tells two clients'
trajectories apart whatever their ``header.stamp``). The newest request waits in a slot of one for
the loop (:meth:`Intake.take`: a peer cannot queue work); one replaced there before the loop took
it is answered ``preempted`` at once, and a gap in a publisher's sequence numbers (messages the
node's subscription queue dropped in a flood, or the publisher's own history lost) is answered
``rejected`` in one status naming the whole gap. After :meth:`Intake.close` (shutdown) the one
waiting is handed back and every later one answered ``aborted``. What the loop takes it answers
itself (``accepted``, then ``done``, ``preempted``, ``aborted``; or ``rejected``, ``stopped``).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Final, Protocol

__all__ = ["MAX_POINTS", "MAX_PUBLISHERS", "Answer", "Intake", "Request", "Source", "Tag",
           "copy_request", "source_of"]

#: A trajectory with more points is refused unread (a peer must not fill the node's memory).
MAX_POINTS: Final = 100_000
#: Publishers whose sequence numbers are followed (the ones heard from last); an older one that
#: comes back starts afresh (a gap before that is not seen).
MAX_PUBLISHERS: Final = 256
#: What rmw gives as a sequence number it does not support (``UINT64_MAX``), and above.
_NO_SEQUENCE: Final = 2**63


@dataclass(frozen=True)
class Source:
    """Who sent a trajectory: the publisher's GID (hex) and the message's publication sequence
    number (1 for a publisher's first message); ``seq_last`` for a gap of several."""

    gid: str
    seq: int
    seq_last: int | None = None

    def as_json(self) -> dict[str, Any]:
        """The status field ``source``."""
        out: dict[str, Any] = {"gid": self.gid, "seq": self.seq}
        if self.seq_last is not None:
            out["seq_last"] = self.seq_last
        return out


@dataclass(frozen=True)
class Tag:
    """What identifies a trajectory in its statuses: the node's ``id`` (None for a lost one), the
    message's ``header.stamp`` ``(sec, nanosec)`` (None when unknown) and its :class:`Source`."""

    id: int | None
    stamp: tuple[int, int] | None
    source: Source | None


@dataclass
class Request:
    """A trajectory as received: joint names, each point's positions (rad) and
    ``time_from_start`` (s), its :class:`Tag`; ``too_many``: the point count of one refused
    unread (then nothing else is copied)."""

    names: list[str]
    positions: list[list[float]]
    times_s: list[float]
    tag: Tag
    too_many: int = 0


class Answer(Protocol):
    """Publishes a trajectory's status (the node's, thread-safe)."""

    def __call__(self, tag: Tag, state: str, **fields: Any) -> None: ...


def source_of(info: Mapping[str, Any] | None) -> Source | None:
    """The :class:`Source` in rclpy's ``MessageInfo``, or None when the middleware gives none."""
    if not info:
        return None
    gid, seq = info.get("publisher_gid"), info.get("publication_sequence_number")
    if not gid or not isinstance(seq, int) or not 0 < seq < _NO_SEQUENCE:
        return None
    return Source(bytes(gid["data"]).hex(), seq)


def copy_request(msg: Any, tag: Tag) -> Request:
    """A ``JointTrajectory`` copied into plain Python values (points beyond :data:`MAX_POINTS`:
    nothing copied)."""
    n = len(msg.points)
    if n > MAX_POINTS:
        return Request([], [], [], tag, n)
    return Request([str(s) for s in msg.joint_names],
                   [[float(v) for v in p.positions] for p in msg.points],
                   [p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in msg.points],
                   tag)


@dataclass
class Intake:
    """The hand-over from the executor thread to the loop (see the module doc). ``answer``
    publishes a status; ``wake`` tells the loop a request waits (both called on the executor
    thread)."""

    answer: Answer
    wake: Callable[[], None]
    received: int = 0
    """Trajectories received."""
    _slot: Request | None = None
    _closed: bool = False
    _last_seq: OrderedDict[str, int] = field(default_factory=OrderedDict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def receive(self, msg: Any, info: Mapping[str, Any] | None) -> None:
        """On the executor thread: one message and its ``MessageInfo``."""
        source = source_of(info)
        stamp = (int(msg.header.stamp.sec), int(msg.header.stamp.nanosec))
        with self._lock:
            self.received += 1
            ident = self.received
        req = copy_request(msg, Tag(ident, stamp, source))  # not holding up the loop's take
        lost = self._gap(source)
        with self._lock:
            closed = self._closed
            replaced, self._slot = self._slot, (None if closed else req)
        if lost is not None:
            assert lost.seq_last is not None
            self.answer(Tag(None, None, lost), "rejected",
                        reason=f"lost before the node took it: {lost.seq_last - lost.seq + 1} "
                               f"trajectories of this publisher (sequence numbers {lost.seq}.."
                               f"{lost.seq_last}) never reached the node (its queue overflowed: "
                               "too many at once); nothing moved")
        if replaced is not None:
            self.answer(replaced.tag, "preempted",
                        reason=f"replaced by trajectory {req.tag.id} before it started")
        if closed:
            self.answer(req.tag, "aborted", reason="shutdown")
        else:
            self.wake()

    def _gap(self, source: Source | None) -> Source | None:
        """The sequence numbers of ``source``'s publisher skipped since its last message (on the
        executor thread only)."""
        if source is None:
            return None
        last = self._last_seq.pop(source.gid, None)
        self._last_seq[source.gid] = max(source.seq, last or 0)
        if len(self._last_seq) > MAX_PUBLISHERS:
            self._last_seq.popitem(last=False)
        if last is None or source.seq <= last + 1:
            return None
        return Source(source.gid, last + 1, source.seq - 1)

    def take(self) -> Request | None:
        """On the loop: the request waiting, if any (the loop answers it from now on)."""
        with self._lock:
            req, self._slot = self._slot, None
        return req

    def close(self) -> Request | None:
        """On the loop, at shutdown: the request waiting (for the loop to answer); every later
        one is answered ``aborted`` by :meth:`receive`."""
        with self._lock:
            self._closed = True
            req, self._slot = self._slot, None
        return req
