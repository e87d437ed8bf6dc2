"""Traffic capture as MCAP with ROS 2 messages (``capture.mcap``): what Foxglove, PlotJuggler,
RViz and ``ros2 bag`` open. Layout: ``docs/capture.md``; figures: ``measurements/capture.md``.

Channels (CDR, ``ros2msg`` schemas of :mod:`armbench.drivers.model.ros2`):

- ``/uart/tx``, ``/uart/rx``: every frame host → arm and arm → host, lossless, in
  ``armbench_msgs/msg/UartFrames`` batches of at most :data:`BATCH_FRAMES` frames or
  :data:`BATCH_SPAN_S` seconds, each frame with its own time and the framer's error if any;
- ``/joint_states`` (the reported angles), ``/joint_states/true`` (the emulator's ground truth),
  ``/tf`` (the joints' link frames): sampled from the replies at most every ``display_period_s``
  while they change (and once a second while they do not) — at the full reply rate these would
  be ~25 MB more per hour; the raw frames keep everything;
- ``/joint_states_goal``: every command sent, positions in rad and the PWM duty in ``effort``;
- ``/tf_static``, ``/robot_description`` (the URDF): once, at the run's start;
- ``/bench/events``: trial start/end, faults, power cuts.

Times (``log_time``, ``publish_time`` and each message's stamp) are nanoseconds since the Unix
epoch: the wall-clock time of the run's start (``start_ns``, kept as ``start_ns`` in the
``armbench`` metadata record) plus the run clock (virtual seconds on ``fake://``, real ones on
hardware), so the capture lines up with other recordings of the same hour; readers subtract
``start_ns`` to get the run clock back (:func:`armbench.drivers.capture.read.capture_start_ns`).
The traffic's tally counts on the run clock. Chunks are zstd-compressed; a file
cut short (a killed run) reads up to its last complete chunk (:mod:`armbench.drivers.capture.read`).
Frames come in blocks of capture parts (:mod:`armbench.drivers.capture.part`) and are turned into
messages with numpy, a block at a time; the traffic's tally for the report is counted on the way
(:mod:`armbench.drivers.capture.tally`) and stored as metadata when the file is closed.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import IO, Any, Final

import numpy as np
import numpy.typing as npt
from mcap.writer import CompressionType, IndexType, Writer

from armbench.drivers.capture.jsonl import CaptureError, Direction
from armbench.drivers.capture.mcap_walk import START_KEY, START_METADATA, checked_entry
from armbench.drivers.capture.part import ERROR_FLAG, IN_FLAG, TRUTH_PERIOD_S, read_part
from armbench.drivers.capture.read import decode_uart_frames
from armbench.drivers.capture.tally import TALLY_KEY, TALLY_METADATA, TrafficCounter
from armbench.drivers.model import ros2
from armbench.drivers.model.protocol import REPLY_LEN, AngleDecoder, Reply
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.model.urdf import robot_urdf

__all__ = ["BATCH_FRAMES", "BATCH_SPAN_S", "DISPLAY_PERIOD_S", "START_KEY", "START_METADATA",
           "McapCapture"]

#: Frames per ``UartFrames`` message at most.
BATCH_FRAMES: Final = 256
#: Seconds a ``UartFrames`` message spans at most.
BATCH_SPAN_S: Final = 1.0
#: Seconds between two samples of the derived topics at least (10 Hz).
DISPLAY_PERIOD_S: Final = TRUTH_PERIOD_S
#: Uncompressed bytes of a chunk.
CHUNK_BYTES: Final = 4 << 20
_NS: Final = 1_000_000_000

_TOPICS: Final = {
    "/uart/tx": ros2.UART_FRAMES, "/uart/rx": ros2.UART_FRAMES,
    "/joint_states": ros2.JOINT_STATE, "/joint_states/true": ros2.JOINT_STATE,
    "/joint_states_goal": ros2.JOINT_STATE, "/tf": ros2.TF_MESSAGE,
    "/tf_static": ros2.TF_MESSAGE, "/robot_description": ros2.STRING,
    "/bench/events": ros2.BENCH_EVENT,
}
_ONCE: Final = {"/robot_description", "/tf_static"}
#: Where a reply's four tick counts are: ``$ddddd,ddddd,ddddd,ddddd#``.
_TICK_COLUMNS: Final = np.array([[1 + 6 * j + d for d in range(5)] for j in range(4)])
_TICK_WEIGHTS: Final = np.array([10_000, 1_000, 100, 10, 1])


class _Sampler:
    """Picks the samples of a derived topic: the first value of each ``period_ns`` slot of a
    part's clock, when it differs from the last one written or a new second began since."""

    def __init__(self, period_ns: int) -> None:
        self.period_ns = period_ns
        self._slot = -1
        self._second = -1
        self._value: object = None

    def new_part(self) -> None:
        """The next values are on another part's clock."""
        self._slot = -1

    def pick(self, clock_ns: npt.NDArray[np.int64], t_ns: npt.NDArray[np.int64],
             value: Any) -> list[int]:
        """Indices of the samples among values at part-clock times ``clock_ns`` (in order),
        stamped ``t_ns``; ``value(i)`` is the value at index ``i``."""
        slots = clock_ns // self.period_ns
        first = np.flatnonzero(np.diff(slots, prepend=self._slot) != 0).tolist()
        kept: list[int] = []
        for i in first:
            v = value(i)
            second = int(t_ns[i]) // _NS
            if v != self._value or second != self._second:
                kept.append(i)
                self._value = v
                self._second = second
        if len(slots):
            self._slot = int(slots[-1])
        return kept


class McapCapture:
    """Writes one capture file. Times given to its methods are seconds on the capture's clock
    (``t0_s`` is its zero); they are stored as nanoseconds since the epoch, ``start_ns`` (the
    wall-clock time of the run's start) plus the capture's clock. ``metadata`` (run id, seed,
    settings, ...) and ``start_ns`` become the ``armbench`` metadata record."""

    def __init__(self, path: str | Path, settings: RobotSettings, *, t0_s: float = 0.0,
                 start_ns: int = 0, metadata: Mapping[str, str] | None = None,
                 display_period_s: float = DISPLAY_PERIOD_S,
                 chunk_bytes: int = CHUNK_BYTES) -> None:
        self.path = Path(path)
        self.settings = settings
        self.t0_s = t0_s
        if start_ns < 0:
            raise ValueError(f"start_ns {start_ns} is before the epoch")
        self.start_ns = start_ns
        try:
            self._fh: IO[bytes] | None = self.path.open("wb")
        except OSError as exc:
            raise CaptureError(str(self.path), None,
                               f"cannot write: {exc.strerror or exc}") from exc
        self.chunk_bytes = chunk_bytes
        self.chunks = 0
        """Chunks written so far (this class ends them: :meth:`flush`)."""
        self._open_bytes = 0
        self._writer = Writer(self._fh, chunk_size=1 << 62,
                              compression=CompressionType.ZSTD,
                              index_types=IndexType.CHUNK | IndexType.ATTACHMENT
                              | IndexType.METADATA)
        self._writer.start(profile="ros2", library="armbench")
        schema_ids = {name: self._writer.register_schema(name, "ros2msg", text.encode())
                      for name, text in ros2.SCHEMAS.items()}
        self._channels = {topic: self._writer.register_channel(topic, "cdr", schema_ids[name])
                          for topic, name in _TOPICS.items()}
        self._decode = AngleDecoder(settings.lower_rad, settings.upper_rad)
        self._lower, self._upper = settings.lower_rad, settings.upper_rad
        self._js = ros2.JointStateEncoder()
        self._goal = ros2.JointStateEncoder(with_effort=True)
        self._tf = ros2.TfEncoder(ros2.MOVING_PAIRS)
        period_ns = max(1, round(display_period_s * 1e9))
        self._reported = _Sampler(period_ns)
        self._true = _Sampler(period_ns)
        self.traffic = TrafficCounter()
        """The frames' tally so far (stored in the file by :meth:`close`)."""
        self.frames = 0
        """Frames written so far (both directions)."""
        self.messages: dict[str, int] = dict.fromkeys(_TOPICS, 0)
        """Messages written so far per topic."""
        self._writer.add_metadata(START_METADATA, {**(metadata or {}),
                                                   **checked_entry(START_KEY, str(start_ns))})
        self._add("/robot_description", start_ns, ros2.encode_string(robot_urdf(settings)))
        self._add("/tf_static", start_ns, ros2.TfEncoder(ros2.STATIC_PAIRS).encode(
            start_ns, ros2.static_transforms(settings)))

    # -- messages ---------------------------------------------------------------------------

    def _ns(self, t_s: float) -> int:
        """Nanoseconds since the epoch of capture-clock second ``t_s``."""
        return self.start_ns + max(0, round((t_s - self.t0_s) * 1e9))

    def _add(self, topic: str, t_ns: int, data: bytes) -> None:
        if self._fh is None:
            return
        self._writer.add_message(self._channels[topic], t_ns, data, t_ns)
        self.messages[topic] += 1
        self._open_bytes += len(data) + 31
        if self._open_bytes >= self.chunk_bytes:
            self._end_chunk()

    def _end_chunk(self) -> None:
        """Compress and write the chunk in progress (the file is flushed too)."""
        if self._open_bytes:
            self._writer.flush()  # type: ignore[no-untyped-call]
            self._open_bytes = 0
            self.chunks += 1

    def event(self, t_s: float, kind: str, suite: str = "", trial: int = -1,
              detail: Mapping[str, Any] | None = None) -> None:
        """A bench event on ``/bench/events``."""
        t_ns = self._ns(t_s)
        self._add("/bench/events", t_ns, ros2.encode_event(t_ns, kind, suite, trial,
                                                           dict(detail or {})))

    def stop(self, t_s: float, reason: str) -> None:
        """The capture stops here (its size bound): a ``capture_stopped`` event, and the
        reason among the tally's events."""
        self.event(t_s, "capture_stopped", detail={"reason": reason})
        self.traffic.events.append(f"capture stopped: {reason}")

    # -- parts --------------------------------------------------------------------------------

    def add_part(self, path: str | Path, offset_s: float = 0.0) -> int:
        """Add a :class:`~armbench.drivers.capture.part.PartWriter` file, its times moved by
        ``offset_s`` (onto this capture's clock); returns the frames read."""
        count = 0
        shift = offset_s - self.t0_s
        self._reported.new_part()
        self._true.new_part()
        for block in read_part(path):
            t_ns = np.maximum(np.rint((block.t_s + shift) * 1e9), 0).astype(np.int64) \
                + self.start_ns
            errors = {int(x["i"]): str(x["error"]) for x in block.extra if "error" in x}
            self._frames(t_ns, block.flags, _Frames(block.blob, block.starts, block.lengths),
                         errors, _clock_ns(block.t_s))
            if len(block.truth_t_s):
                self._truth(np.maximum(np.rint((block.truth_t_s + shift) * 1e9), 0)
                            .astype(np.int64) + self.start_ns, block.truth_rad,
                            _clock_ns(block.truth_t_s))
            for x in block.extra:
                if "event" in x and "t_s" in x:
                    self.event(float(x["t_s"]) + offset_s, str(x["event"]),
                               str(x.get("suite", "")), int(x.get("trial", -1)),
                               x.get("detail") or {})
            count += len(block.t_s)
        return count

    def _frames(self, t_ns: npt.NDArray[np.int64], flags: npt.NDArray[np.uint8],
                frames: _Frames, errors: dict[int, str],
                clock_ns: npt.NDArray[np.int64]) -> None:
        """A block of frames in time order (``t_ns`` since the epoch; ``clock_ns`` on their
        part's clock): raw batches per direction, goals, reported states."""
        if not len(t_ns):
            return
        self.traffic.add(t_ns - self.start_ns, flags, frames.get, errors)
        self.frames += len(t_ns)
        inbound = (flags & IN_FLAG) != 0
        valid = (flags & ERROR_FLAG) == 0
        sides: tuple[tuple[Direction, npt.NDArray[np.bool_]], ...] = (("out", ~inbound),
                                                                       ("in", inbound))
        for direction, mask in sides:
            idx = np.flatnonzero(mask)
            if len(idx):
                self._uart(direction, t_ns[idx], frames, idx,
                           [errors.get(i, "") for i in idx.tolist()] if errors else None)
        for i in np.flatnonzero(~inbound & valid).tolist():
            self._command(int(t_ns[i]), frames.get(i).decode("ascii", "backslashreplace"))
        idx = np.flatnonzero(inbound & valid)
        if len(idx):
            self._states(t_ns[idx], frames, idx, clock_ns[idx])

    def _uart(self, direction: Direction, t_ns: npt.NDArray[np.int64], frames: _Frames,
              idx: npt.NDArray[np.intp], errors: list[str] | None) -> None:
        """Frames ``idx`` (one direction) as ``UartFrames`` messages of :data:`BATCH_FRAMES`
        frames or :data:`BATCH_SPAN_S` at most."""
        topic = "/uart/rx" if direction == "in" else "/uart/tx"
        rows = frames.rows(idx) if errors is None else None
        span_ns = round(BATCH_SPAN_S * 1e9)
        start, n = 0, len(idx)
        while start < n:
            end = min(start + BATCH_FRAMES,
                      int(np.searchsorted(t_ns, t_ns[start] + span_ns, side="right")))
            end = max(end, start + 1)
            t0 = int(t_ns[start])
            offsets = t_ns[start:end] - t0
            if rows is not None:
                data = ros2.encode_uart_frames_bytes(t0, offsets, rows[start:end])
            elif errors is None or not any(errors[start:end]):
                data = ros2.encode_uart_frames_bytes(t0, offsets, frames.list(idx[start:end]))
            else:
                data = ros2.encode_uart_frames(
                    t0, offsets, [f.decode("utf-8", "backslashreplace")
                                  for f in frames.list(idx[start:end])], errors[start:end])
            self._add(topic, t0, data)
            start = end

    def _command(self, t_ns: int, frame: str) -> None:
        fields = _ticks(frame, 8)
        if fields is None:
            return
        q = Reply(*fields[0::2]).angles_rad(self._lower, self._upper)
        self._add("/joint_states_goal", t_ns,
                  self._goal.encode(t_ns, q, [float(d) for d in fields[1::2]]))

    def _states(self, t_ns: npt.NDArray[np.int64], frames: _Frames,
                idx: npt.NDArray[np.intp], clock_ns: npt.NDArray[np.int64]) -> None:
        """The sampled replies ``idx`` as ``/joint_states`` and ``/tf``."""
        rows = frames.rows(idx)
        if rows is not None and rows.shape[1] == REPLY_LEN:
            kept = self._reported.pick(clock_ns, t_ns, lambda i: rows[i].tobytes())
            ticks = _reply_ticks(rows[kept])
        else:
            replies = frames.list(idx)
            kept = self._reported.pick(clock_ns, t_ns, replies.__getitem__)
            ticks = [_ticks(replies[i].decode("ascii", "backslashreplace"), 4) for i in kept]
        samples = [(int(t_ns[i]), self._decode(Reply(*t)))
                   for i, t in zip(kept, ticks, strict=True) if t is not None]
        if not samples:
            return
        t = np.array([r[0] for r in samples], dtype=np.int64)
        q = np.array([r[1] for r in samples], dtype=np.float64)
        states = self._js.encode_many(t, q)
        poses = self._tf.encode_many(t, ros2.link_transforms_many(q, self.settings))
        for k, t_k in enumerate(t.tolist()):
            self._add("/joint_states", t_k, states[k])
            self._add("/tf", t_k, poses[k])

    def _truth(self, t_ns: npt.NDArray[np.int64], q_rad: npt.NDArray[np.float64],
               clock_ns: npt.NDArray[np.int64]) -> None:
        """The ground truth (rad), sampled as the reported angles are."""
        kept = self._true.pick(clock_ns, t_ns, lambda i: q_rad[i].tobytes())
        if kept:
            for t_k, data in zip(t_ns[kept].tolist(), self._js.encode_many(t_ns[kept],
                                                                           q_rad[kept]),
                                 strict=True):
                self._add("/joint_states/true", t_k, data)

    def copy_messages(self, messages: Iterable[Any]) -> None:
        """Add the messages of an earlier capture (``RawMessage``s of
        :func:`armbench.drivers.capture.read.iter_messages`) as they are, but for the ones this
        file starts with (``/robot_description``, ``/tf_static``); their frames are counted. The
        earlier capture must have this one's ``start_ns`` (a resumed run's does: it is the
        run's start)."""
        for msg in messages:
            if msg.topic in self._channels and msg.topic not in _ONCE:
                self._add(msg.topic, msg.log_time_ns, msg.data)
                if msg.topic in ("/uart/rx", "/uart/tx"):
                    times, frames, errors = decode_uart_frames(msg.data)
                    flags = np.array([(IN_FLAG if msg.topic == "/uart/rx" else 0)
                                      | (ERROR_FLAG if e else 0) for e in errors], dtype=np.uint8)
                    self.traffic.add(np.array(times, dtype=np.int64) - self.start_ns, flags,
                                     frames.__getitem__,
                                     {i: e.decode("utf-8", "backslashreplace")
                                      for i, e in enumerate(errors) if e})
                    self.frames += len(frames)

    # -- end ----------------------------------------------------------------------------------

    def attach(self, name: str, data: bytes, media_type: str, t_s: float | None = None) -> None:
        """Attach a file (``results.json``, ``report.html``)."""
        if self._fh is None:
            return
        t_ns = self.start_ns if t_s is None else self._ns(t_s)
        self._writer.add_attachment(t_ns, t_ns, name, media_type, data)

    def flush(self) -> None:
        """Write the chunk in progress."""
        if self._fh is not None:
            self._end_chunk()

    def close(self) -> None:
        """Store the traffic's tally, write the summary and close (idempotent)."""
        if self._fh is None:
            return
        try:
            self._writer.add_metadata(TALLY_METADATA,
                                      checked_entry(TALLY_KEY, self.traffic.tally().to_json()))
            self._writer.finish()  # type: ignore[no-untyped-call]
        finally:
            self._fh.close()
            self._fh = None


def _clock_ns(t_s: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
    """Seconds of a part's clock as whole nanoseconds."""
    return np.rint(t_s * 1e9).astype(np.int64)


def _ticks(frame: str, count: int) -> list[int] | None:
    """The ``count`` comma-separated numbers of a ``$...#`` frame, None if it is not one."""
    try:
        values = [int(v) for v in frame[1:-1].split(",")]
    except ValueError:
        return None
    return values if len(values) == count and frame[:1] == "$" else None


def _reply_ticks(rows: npt.NDArray[np.uint8]) -> list[list[int] | None]:
    """The four tick counts of each reply (``$ddddd,ddddd,ddddd,ddddd#``, one per row), None
    for one that is not such a reply."""
    digits = rows[:, _TICK_COLUMNS].astype(np.int64) - 48
    ok = ((digits >= 0) & (digits <= 9)).all(axis=(1, 2)) & (rows[:, 0] == ord("$"))
    values = (digits @ _TICK_WEIGHTS).tolist()
    return [v if good else None for v, good in zip(values, ok.tolist(), strict=True)]


class _Frames:
    """The frames of a part's block, kept as its bytes: a frame, a list, or the rows of a 2-D
    array (frames of one length) are cut out when asked for."""

    def __init__(self, blob: bytes, starts: npt.NDArray[np.int64],
                 lengths: npt.NDArray[np.int64]) -> None:
        self.blob = blob
        self.starts = starts
        self.lengths = lengths
        self._cached: tuple[bytes, npt.NDArray[np.uint8] | None] | None = None

    def get(self, i: int) -> bytes:
        start = int(self.starts[i])
        return self.blob[start:start + int(self.lengths[i])]

    def list(self, idx: npt.NDArray[np.intp]) -> list[bytes]:
        return [self.get(i) for i in idx.tolist()]

    def rows(self, idx: npt.NDArray[np.intp]) -> npt.NDArray[np.uint8] | None:
        """Frames ``idx`` (in order) as rows, None unless all have one length. Cut out by a
        mask over the bytes, cached for the last ``idx`` asked for."""
        key = idx.tobytes()
        if self._cached is not None and self._cached[0] == key:
            return self._cached[1]
        lengths = self.lengths[idx]
        size = int(lengths[0]) if len(lengths) else 0
        rows: npt.NDArray[np.uint8] | None = None
        if size and not (lengths != size).any():
            chosen = np.zeros(len(self.lengths), dtype=np.bool_)
            chosen[idx] = True
            buf = np.frombuffer(self.blob, dtype=np.uint8)
            rows = buf[np.repeat(chosen, self.lengths)].reshape(len(idx), size)
        self._cached = (key, rows)
        return rows
