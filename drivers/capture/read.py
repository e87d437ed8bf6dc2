"""One reader for captures of either format: ``capture.mcap``
(:mod:`armbench.drivers.capture.mcap_writer`) and the older JSON Lines ``capture.jsonl``
(:mod:`armbench.drivers.capture.jsonl`).

:func:`open_capture` yields the same :class:`~armbench.drivers.capture.jsonl.CaptureRecord` records
for both, in time order; :func:`capture_lines` gives an MCAP capture as the JSON Lines text the
older format holds (for readers of that text). An MCAP file cut short (a killed run: no summary,
a chunk half written) is read up to its last complete record; a damaged one (a chunk whose bytes
fail to decompress or to match its CRC, a record running past the end of a closed file, a file
named ``.mcap`` that is not MCAP: :mod:`armbench.drivers.capture.mcap_walk`) and frames whose times
run backwards are a :class:`~armbench.drivers.capture.jsonl.CaptureError` naming the file and the
place.
"""

from __future__ import annotations

import functools
import heapq
import json
import re
import struct
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap_ros2._dynamic import generate_dynamic

from armbench.drivers.capture.jsonl import (
    CaptureError,
    CaptureRecord,
    Direction,
    ReplayCommand,
    open_capture_file,
    read_capture,
)
from armbench.drivers.capture.jsonl import capture_stopped as jsonl_stopped
from armbench.drivers.capture.mcap_walk import (
    MAX_CHUNK_BYTES,
    MCAP_MAGIC,
    McapLayout,
    RawMessage,
    capture_start_ns,
    entry_damage,
    iter_messages,
    mcap_layout,
    read_attachment,
    summary_metadata,
)
from armbench.drivers.capture.tally import TALLY_KEY, TALLY_METADATA, TrafficTally
from armbench.drivers.model.protocol import Command, Framer
from armbench.drivers.model.ros2 import BENCH_EVENT, JOINT_STATE, SCHEMAS

__all__ = [
    "MAX_CHUNK_BYTES",
    "MCAP_MAGIC",
    "McapLayout",
    "RawMessage",
    "capture_lines",
    "capture_start_ns",
    "capture_stopped",
    "decode_uart_frames",
    "is_mcap",
    "iter_events",
    "iter_messages",
    "mcap_layout",
    "open_capture",
    "read_attachment",
    "read_joint_states",
    "read_tally",
    "replay_capture",
]

#: Printable ASCII without '"' and '\\': written into a JSON string as it is.
_PLAIN = re.compile(rb'[ !#-\[\]-~]*')


def is_mcap(path: str | Path) -> bool:
    """Whether ``path`` starts with the MCAP magic (else it is taken as JSON Lines)."""
    with open_capture_file(path) as fh:
        try:
            return fh.read(len(MCAP_MAGIC)) == MCAP_MAGIC
        except OSError as exc:
            raise CaptureError(str(path), None, f"cannot read: {exc.strerror or exc}") from exc


def _strings(data: bytes, pos: int) -> tuple[list[bytes], int]:
    """A CDR ``string[]`` at ``pos`` (its count first): its elements as bytes (NUL dropped) and
    the position after it. Elements of one length (frames) are cut with numpy in one go."""
    pos += -(pos - 4) % 4
    (count,) = struct.unpack_from("<I", data, pos)
    pos += 4
    if count == 0:
        return [], pos
    (size,) = struct.unpack_from("<I", data, pos)
    width = 4 + size + (-size % 4)
    end = pos + count * width
    if size > 0 and end - (-size % 4) <= len(data):  # the last element has no padding
        rows = np.frombuffer(data[pos:end].ljust(count * width, b"\x00"),
                             dtype=np.uint8).reshape(count, width)
        if np.all(rows[:, :4].copy().view("<u4").ravel() == size):
            if size == 1:
                return [b""] * count, end
            texts = rows[:, 4:3 + size].copy().view(f"S{size - 1}").ravel().tolist()
            if all(len(t) == size - 1 for t in texts):  # no NUL inside an element
                return texts, end
    out = []
    for _ in range(count):
        pos += -(pos - 4) % 4
        (size,) = struct.unpack_from("<I", data, pos)
        out.append(data[pos + 4:pos + 3 + size])
        pos += 4 + size
    return out, pos


def decode_uart_frames(data: bytes) -> tuple[list[int], list[bytes], list[bytes]]:
    """Times (ns), frames and errors (empty: none) of an ``armbench_msgs/msg/UartFrames``
    message; :class:`ValueError` if it is not one."""
    try:
        sec, nsec, n = struct.unpack_from("<iII", data, 4)
        pos = 16 + (4 if n else 0)
        offsets = np.frombuffer(data, dtype="<i8", count=n, offset=pos)
        frames, pos = _strings(data, pos + 8 * n)
        errors, pos = _strings(data, pos)
    except struct.error as exc:
        raise ValueError(f"UartFrames cut short: {exc}") from None
    if len(frames) != n or len(errors) != n:
        raise ValueError(f"UartFrames of {n} times, {len(frames)} frames, {len(errors)} errors")
    t0 = sec * 1_000_000_000 + nsec
    return (offsets + t0).tolist(), frames, errors


def _batches(path: Path, topic: str) -> Iterator[tuple[list[int], list[bytes], list[bytes]]]:
    """Each ``UartFrames`` message of ``topic`` as (run-clock ns, frames, errors): its stamps
    less the run's start (:func:`capture_start_ns`)."""
    start_ns = capture_start_ns(path)
    for msg in iter_messages(path, (topic,)):
        try:
            times, frames, errors = decode_uart_frames(msg.data)
        except ValueError as exc:
            raise CaptureError(str(path), None, f"{topic} at {msg.log_time_ns} ns: {exc}") from None
        yield [t - start_ns for t in times] if start_ns else times, frames, errors


def _direction(path: Path, topic: str) -> Iterator[CaptureRecord]:
    direction: Direction = "in" if topic == "/uart/rx" else "out"
    last_ns = -1
    for times, frames, errors in _batches(path, topic):
        for t_ns, frame, error in zip(times, frames, errors, strict=True):
            if t_ns < last_ns:
                raise CaptureError(str(path), None, f"{topic}: time {t_ns * 1e-9:.9g} s before "
                                                    f"the previous {last_ns * 1e-9:.9g} s")
            last_ns = t_ns
            yield CaptureRecord(t_ns / 1e9, direction, frame.decode("utf-8", "backslashreplace"),
                                error.decode("utf-8", "backslashreplace") or None)


def open_capture(path: str | Path) -> Iterator[CaptureRecord]:
    """Every frame record of a capture of either format, in time order (streamed; of an MCAP
    capture's records with equal times, arm → host first). Times that run backwards, a damaged
    MCAP file, a line of JSON Lines that is not a record: :class:`CaptureError`."""
    p = Path(path)
    if not is_mcap(p):
        if p.suffix.lower() == ".mcap":
            yield from _direction(p, "/uart/rx")  # not MCAP, or cut short inside its magic
            return
        yield from read_capture(p)
        return
    yield from heapq.merge(_direction(p, "/uart/rx"), _direction(p, "/uart/tx"),
                           key=lambda r: r.t_s)


def _line_stream(path: Path, topic: str) -> Iterator[tuple[int, bytes]]:
    """(time ns, JSON line) of each frame of one direction, as the JSON Lines writer writes."""
    direction = "in" if topic == "/uart/rx" else "out"
    fmt = b'{"t_s": %d.%09d, "dir": "' + direction.encode() + b'", "frame": "%s", "error": null}\n'
    for times, frames, errors in _batches(path, topic):
        if not any(errors) and _PLAIN.fullmatch(b"".join(frames)):
            yield from zip(times, [fmt % (t // 1_000_000_000, t % 1_000_000_000, f)
                                   for t, f in zip(times, frames, strict=True)], strict=True)
            continue
        for t_ns, frame, error in zip(times, frames, errors, strict=True):
            text = json.dumps({"t_s": t_ns / 1e9, "dir": direction,
                               "frame": frame.decode("utf-8", "backslashreplace"),
                               "error": error.decode("utf-8", "backslashreplace") or None})
            yield t_ns, text.encode() + b"\n"


def _lines(path: Path) -> Iterator[bytes]:
    for _, line in heapq.merge(_line_stream(path, "/uart/rx"), _line_stream(path, "/uart/tx")):
        yield line


def read_tally(path: str | Path) -> TrafficTally | None:
    """The traffic's tally an MCAP capture stores when it is closed
    (:class:`~armbench.drivers.capture.tally.TrafficCounter`); None for a JSON Lines capture, a
    file cut short or one without it (or with it damaged, or larger than a tally can be). Read
    through the summary's metadata index: the chunks are not read."""
    p = Path(path)
    if not is_mcap(p):
        return None
    try:
        meta = summary_metadata(p, TALLY_METADATA)
        if meta is None or entry_damage(meta.metadata, TALLY_KEY) is not None:
            return None  # damaged: the caller counts the records instead
        return TrafficTally.from_json(meta.metadata[TALLY_KEY])
    except (CaptureError, ValueError, KeyError):
        return None


def capture_stopped(path: str | Path) -> bool:
    """Whether the capture (either format) stopped at its size bound: a ``capture_stopped``
    event on ``/bench/events``, or the JSON Lines stop event."""
    p = Path(path)
    if not is_mcap(p):
        return jsonl_stopped(p)
    return any(event.kind == "capture_stopped" for event in iter_events(p))


def iter_events(path: str | Path) -> Iterator[Any]:
    """The bench events (``armbench_msgs/msg/BenchEvent``: ``kind``, ``suite``, ``trial``,
    ``detail``) on ``/bench/events`` of an MCAP capture, in file order, decoded (their stamps on
    the wall clock: less :func:`capture_start_ns` they are on the run clock)."""
    decode = _event_decoder()
    for msg in iter_messages(path, ("/bench/events",)):
        yield decode(msg.data)


def read_joint_states(path: str | Path,
                      topic: str = "/joint_states/true") -> list[tuple[float, tuple[float, ...]]]:
    """The (run-clock s, positions rad) of every ``sensor_msgs/msg/JointState`` on ``topic`` of
    an MCAP capture (by default the truth beside the replies): its log time less the run's start;
    empty for a JSON Lines capture, which carries no truth."""
    p = Path(path)
    if not is_mcap(p):
        return []
    decode = _joint_state_decoder()
    start_ns = capture_start_ns(p)
    return [((msg.log_time_ns - start_ns) * 1e-9,
             tuple(float(v) for v in decode(msg.data).position))
            for msg in iter_messages(p, (topic,))]


@functools.cache
def _joint_state_decoder() -> Callable[[bytes], Any]:
    decoder: Callable[[bytes], Any] = generate_dynamic(JOINT_STATE, SCHEMAS[JOINT_STATE])[
        JOINT_STATE]
    return decoder


@functools.cache
def _event_decoder() -> Callable[[bytes], Any]:
    decoder: Callable[[bytes], Any] = generate_dynamic(BENCH_EVENT, SCHEMAS[BENCH_EVENT])[
        BENCH_EVENT]
    return decoder


@contextmanager
def capture_lines(path: str | Path) -> Iterator[Iterator[bytes] | IO[bytes]]:
    """The capture as JSON Lines bytes, line by line: the file itself for JSON Lines, the
    records of an MCAP capture in that text otherwise."""
    p = Path(path)
    if is_mcap(p):
        yield _lines(p)
        return
    with open_capture_file(p) as fh:
        yield fh


def replay_capture(path: str | Path) -> Iterator[ReplayCommand]:
    """The host → arm commands of a capture (either format), with their times relative to the
    first one.

    Records with an ``error`` and ``in`` records are skipped; an ``out`` frame that is not a valid
    command is a :class:`CaptureError` (the driver only ever writes valid commands).
    """
    t0: float | None = None
    for n, rec in enumerate(open_capture(path), 1):
        if rec.dir != "out" or rec.error is not None:
            continue
        framer = Framer("command")
        events = framer.feed(rec.frame.encode("ascii", "backslashreplace"))
        if len(events) != 1 or not isinstance(events[0], Command):
            raise CaptureError(str(path), None,
                               f"record {n}: out frame {rec.frame!r} is not one command")
        if t0 is None:
            t0 = rec.t_s
        yield ReplayCommand(rec.t_s - t0, events[0], rec.t_s)
