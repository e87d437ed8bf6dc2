"""A connection's capture part: what the process measuring a trial writes (frames, the
emulator's ground truth, bench events), binary and cheap per frame, which the runner adds to the
run's ``capture.mcap`` (:meth:`armbench.drivers.capture.mcap_writer.McapCapture.add_part`).

Layout (little-endian), one block per batch: ``ABP2``, record count n, frame bytes, extra bytes,
truth rows m, joints j (``<4sIIIII``); then n float64 times, n flag bytes (``1`` arm → host, ``2``
a framing error), n uint16 frame lengths, the frames, m float64 truth times, m×j float64 truth
angles (rad), and the extra records (events, the errors' reasons by index) as JSON lines. A part
cut short ends at its last whole block.
"""

from __future__ import annotations

import json
import struct
from array import array
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import IO, Any, Final, NamedTuple

import numpy as np
import numpy.typing as npt

from armbench.drivers.capture.jsonl import CaptureError, CaptureWriter, Direction
from armbench.drivers.capture.open_block import IN_FLAG, OpenBlock

__all__ = ["BLOCK_RECORDS", "BLOCK_S", "ERROR_FLAG", "IN_FLAG", "TRUTH_PERIOD_S", "PartBlock",
           "PartWriter", "first_part_time", "part_span", "read_part"]

#: Records of a block at most, and loop seconds after which a block is written even if not
#: full. Large: each block costs a write here and numpy calls in the runner, and a part is read
#: only once its trial is in the record (a part cut short belongs to a trial measured again).
BLOCK_RECORDS: Final = 8192
BLOCK_S: Final = 20.0

#: Seconds between two truth samples at least (the derived topics' rate, 10 Hz).
TRUTH_PERIOD_S: Final = 0.1
#: Flag bit of a record with a framing error (``IN_FLAG``: arm → host).
ERROR_FLAG: Final = 2

#: Loop seconds a reply's due check runs early, before a slot boundary or a flush interval ends:
#: far more than the rounding of the exact checks it guards, which then decide as before.
_DUE_EARLY_S: Final = 1e-6

_BLOCK: Final = struct.Struct("<4sIIIII")
_BLOCK_MAGIC: Final = b"ABP2"


class PartBlock(NamedTuple):
    """One block of a capture part: times (loop seconds less the part's ``t0_s``), flags, the
    frames (``blob[starts[i]:starts[i] + lengths[i]]``), the truth (times and angles in rad, one
    row each) and the extra records (events, the errors' reasons by index) as dicts."""

    t_s: npt.NDArray[np.float64]
    flags: npt.NDArray[np.uint8]
    blob: bytes
    starts: npt.NDArray[np.int64]
    lengths: npt.NDArray[np.int64]
    truth_t_s: npt.NDArray[np.float64]
    truth_rad: npt.NDArray[np.float64]
    extra: list[dict[str, Any]]


class PartWriter(CaptureWriter):
    """A connection's capture part, written where the trial runs (a worker process, or the
    runner): the driver's frames (the :class:`~armbench.drivers.capture.jsonl.CaptureWriter`
    calls; the replies go straight to the compiled open block, :meth:`reply_sink`), the ground
    truth beside the replies (sampled every ``period_s`` from ``truth``, a callable giving the
    newest truth in rad or None) and bench events. The truth is taken at the first reply of each
    ``period_s`` slot of the part's clock, where
    :class:`~armbench.drivers.capture.mcap_writer.McapCapture` samples the replies, so the two
    stand side by side."""

    def __init__(self, path: str | Path, t0_s: float, *,
                 truth: Callable[[], tuple[float, ...] | None] | None = None,
                 period_s: float = TRUTH_PERIOD_S, batch_records: int = BLOCK_RECORDS,
                 batch_interval_s: float = BLOCK_S) -> None:
        # not CaptureWriter.__init__: that one opens a text file
        self.path = Path(path)
        self.t0_s = t0_s
        self.batch_records = max(1, batch_records)
        self.batch_interval_s = batch_interval_s
        self.batches = 0
        self._written = 0
        self._last_flush = t0_s
        self._block = OpenBlock(t0_s, self.batch_records, self._due)
        self._truth_t = array("d")
        self._truth_q = array("d")
        self._joints = 0
        self._extra: list[dict[str, Any]] = []
        self._truth = truth
        self._period_s = period_s
        self._slot = -1.0
        try:
            self._bin: IO[bytes] | None = self.path.open("wb")
        except OSError as exc:
            raise CaptureError(str(self.path), None,
                               f"cannot write: {exc.strerror or exc}") from exc

    @property
    def records(self) -> int:  # type: ignore[override]
        """Records accepted so far."""
        return self._written + len(self._block.frames)

    @property
    def buffered(self) -> int:
        return len(self._block.frames)

    def reply(self, t_s: float, data: bytes) -> None:
        self._block.reply(t_s, data)

    def reply_sink(self) -> OpenBlock:
        """The open block: its compiled ``reply`` is :meth:`reply` without a Python call."""
        return self._block

    def _due(self, t_s: float) -> None:
        """The checks of a reply at ``t_s`` (a new truth slot, a block to write), which a reply
        runs only from the block's ``due_s`` on: most replies fall inside a slot and a block's
        interval."""
        if self._truth is not None and (t_s - self.t0_s) // self._period_s != self._slot:
            self._sample_truth(t_s)
        if (len(self._block.frames) >= self.batch_records
                or t_s - self._last_flush >= self.batch_interval_s):
            self.flush(t_s)
        self._set_due()

    def _set_due(self) -> None:
        """The loop time at which the next slot or the next block's interval begins, a little
        early; a slot whose truth was missing is due at once, so that the next reply tries again."""
        due = self._last_flush + self.batch_interval_s
        if self._truth is not None:
            due = min(due, self.t0_s + (self._slot + 1.0) * self._period_s)
        self._block.due_s = due - _DUE_EARLY_S

    def _sample_truth(self, t_s: float) -> None:
        assert self._truth is not None
        q = self._truth()
        if q is not None and (not self._joints or len(q) == self._joints):
            self._joints = len(q)
            self._slot = (t_s - self.t0_s) // self._period_s
            self._truth_t.append(t_s - self.t0_s)
            self._truth_q.extend(q)

    def frame(self, t_s: float, direction: Direction, frame: str) -> None:
        data = frame.encode("utf-8", "backslashreplace")
        if direction == "in":
            self.reply(t_s, data)
            return
        self._block.add(t_s, 0, data)
        if (len(self._block.frames) >= self.batch_records
                or t_s - self._last_flush >= self.batch_interval_s):
            self.flush(t_s)

    def write(self, t_s: float, direction: Direction, frame: str, error: str | None) -> None:
        if error is None:
            self.frame(t_s, direction, frame)
            return
        self._extra.append({"i": len(self._block.frames), "error": error})
        self._block.add(t_s, (IN_FLAG if direction == "in" else 0) | ERROR_FLAG,
                        frame.encode("utf-8", "backslashreplace"))

    def event(self, t_s: float, kind: str, suite: str = "", trial: int = -1,
              detail: Mapping[str, Any] | None = None) -> None:
        """A bench event at ``t_s`` (loop seconds)."""
        self._extra.append({"t_s": t_s - self.t0_s, "event": kind, "suite": suite,
                            "trial": trial, "detail": dict(detail or {})})

    def flush(self, t_s: float | None = None) -> None:
        if self._bin is None or not (self._block.frames or self._extra or self._truth_t):
            return
        times, flags, frames = self._block.take()
        lengths = np.fromiter(map(len, frames), dtype="<u2", count=len(frames))
        extra = "".join(json.dumps(x) + "\n" for x in self._extra).encode()
        blob = b"".join(frames)
        self._bin.write(b"".join((
            _BLOCK.pack(_BLOCK_MAGIC, len(frames), len(blob), len(extra), len(self._truth_t),
                        self._joints),
            array("d", times).tobytes(), bytes(flags), lengths.tobytes(), blob,
            self._truth_t.tobytes(), self._truth_q.tobytes(), extra)))
        self._bin.flush()
        self._written += len(frames)
        self._truth_t = array("d")
        self._truth_q = array("d")
        self._extra = []
        self.batches += 1
        if t_s is not None:
            self._last_flush = t_s
            self._set_due()

    def close(self) -> None:
        if self._bin is None:
            return
        try:
            self.flush()
        finally:
            self._bin.close()
            self._bin = None


def read_part(path: str | Path) -> Iterator[PartBlock]:
    """The blocks of a :class:`PartWriter` file; a block cut short ends it."""
    with Path(path).open("rb") as fh:
        while True:
            head = fh.read(_BLOCK.size)
            if len(head) < _BLOCK.size:
                return
            magic, n, frame_bytes, extra_bytes, m, joints = _BLOCK.unpack(head)
            size = 11 * n + frame_bytes + 8 * m * (1 + joints) + extra_bytes
            body = fh.read(size)
            if magic != _BLOCK_MAGIC or len(body) < size:
                return
            t = np.frombuffer(body, dtype="<f8", count=n)
            flags = np.frombuffer(body, dtype=np.uint8, count=n, offset=8 * n)
            lengths = np.frombuffer(body, dtype="<u2", count=n, offset=9 * n).astype(np.int64)
            pos = 11 * n
            blob = body[pos:pos + frame_bytes]
            starts = np.cumsum(lengths) - lengths
            pos += frame_bytes
            truth_t = np.frombuffer(body, dtype="<f8", count=m, offset=pos)
            truth_q = np.frombuffer(body, dtype="<f8", count=m * joints,
                                    offset=pos + 8 * m).reshape(m, joints)
            extra = [json.loads(line) for line in
                     body[pos + 8 * m * (1 + joints):].decode().splitlines() if line]
            yield PartBlock(t, flags, blob, starts, lengths, truth_t, truth_q, extra)


def first_part_time(path: str | Path) -> float | None:
    """The time of the first frame of a part (seconds, the part's clock), None if it has none
    readable: what the runner's resume looks at."""
    try:
        for block in read_part(path):
            if len(block.t_s):
                return float(block.t_s[0])
    except (OSError, ValueError):
        return None
    return None


def part_span(path: str | Path) -> tuple[float, float] | None:
    """The times of the first and the last frame of a part (seconds, the part's clock), None if
    it has none readable: which recorded trials a recovered part holds."""
    first: float | None = None
    last = 0.0
    try:
        for block in read_part(path):
            if len(block.t_s):
                if first is None:
                    first = float(block.t_s[0])
                last = max(last, float(block.t_s.max()))
    except (OSError, ValueError):
        pass
    return None if first is None else (first, max(first, last))
