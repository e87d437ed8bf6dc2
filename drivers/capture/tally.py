"""What a capture's traffic adds up to (frames each way, framing errors by reason,
resynchronisations, frame rates over time, an excerpt): :func:`tally` over the records in order,
shared by the report's reading of a capture and by the MCAP writer, which counts the frames as
it adds them (:class:`TrafficCounter`) and stores the tally in the file (metadata
:data:`TALLY_METADATA`), so the report does not read 1.5 M records back.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from typing import Any, Final

import numpy as np
import numpy.typing as npt
import zstandard

__all__ = ["HEAD_LINES", "MAX_BINS", "TALLY_KEY", "TALLY_METADATA", "TEXT_LIMIT", "TrafficCounter",
           "TrafficLine", "TrafficTally", "nice_bin", "short_text", "tally"]

#: Bins of the frame-rate plot at most.
MAX_BINS: Final = 100
#: Characters of a frame or reason kept in an excerpt.
TEXT_LIMIT: Final = 96
#: Records of the excerpt, and framing errors after it, kept as text.
HEAD_LINES: Final = 20
#: The MCAP metadata record holding the tally (under :data:`TALLY_KEY`: its JSON).
TALLY_METADATA: Final = "armbench.traffic"
#: The key of that record's entry holding the tally (JSON), written with its check.
TALLY_KEY: Final = "tally"

FloatArray = npt.NDArray[np.float64]
#: Kind of a record: 0 host → arm frame, 1 arm → host frame, 2 and 3 the same with an error.
KindArray = npt.NDArray[np.int8]


@dataclass(frozen=True, slots=True)
class TrafficLine:
    """One record of an excerpt: its line number (from 1) and fields, text shortened."""

    line: int
    t_s: float
    dir: str
    frame: str
    error: str | None


@dataclass(frozen=True, slots=True)
class TrafficTally:
    """What a capture adds up to. Counts per bin of ``bin_s`` seconds from ``bin_start_s[0]``;
    ``resyncs`` counts valid frames that followed an error in the same direction."""

    records: int
    frames_in: int
    frames_out: int
    errors_in: int
    errors_out: int
    resyncs: int
    duration_s: float
    reasons: list[tuple[str, int]]
    bin_s: float
    bin_start_s: FloatArray
    count_in: FloatArray
    count_out: FloatArray
    errors_per_bin: FloatArray
    resyncs_per_bin: FloatArray
    head: list[TrafficLine]
    first_errors: list[TrafficLine]
    events: list[str]

    def to_json(self) -> str:
        data = asdict(self)
        for name, value in data.items():
            if isinstance(value, np.ndarray):
                data[name] = value.tolist()
        return json.dumps(data)

    @classmethod
    def from_json(cls, text: str) -> TrafficTally:
        """The tally :meth:`to_json` wrote; ValueError if ``text`` is not one."""
        try:
            data: dict[str, Any] = json.loads(text)
            for name in ("bin_start_s", "count_in", "count_out", "errors_per_bin",
                         "resyncs_per_bin"):
                data[name] = np.asarray(data[name], dtype=np.float64)
            data["reasons"] = [(str(r), int(n)) for r, n in data["reasons"]]
            for name in ("head", "first_errors"):
                data[name] = [TrafficLine(**x) for x in data[name]]
            return cls(**data)
        except (TypeError, KeyError, AttributeError) as exc:
            raise ValueError(f"not a traffic tally: {exc}") from None


def short_text(text: str) -> str:
    """``text`` cut to :data:`TEXT_LIMIT` characters."""
    return text if len(text) <= TEXT_LIMIT else text[: TEXT_LIMIT - 1] + "…"


def nice_bin(span_s: float, max_bins: int) -> float:
    """The smallest 1-2-5 bin width (s) giving at most ``max_bins`` bins over ``span_s``."""
    raw = max(span_s / max_bins, 1e-3)
    exp = math.floor(math.log10(raw))
    for m in (1.0, 2.0, 5.0, 10.0):
        width = m * 10.0**exp
        if width >= raw * (1 - 1e-9):
            return width
    return 10.0 ** (exp + 1)  # pragma: no cover


def _resyncs(kinds: KindArray) -> npt.NDArray[np.bool_]:
    """Per record (in order): a valid frame right after an error of its direction."""
    out = np.zeros(len(kinds), dtype=np.bool_)
    for direction in (0, 1):
        idx = np.flatnonzero((kinds & 1) == direction)
        err = kinds[idx] >= 2
        out[idx[1:]] = ~err[1:] & err[:-1]
    return out


@dataclass(frozen=True, slots=True)
class _Binning:
    """The bins of a tally over records from ``t0`` to ``t1`` (s)."""

    t0: float
    t1: float
    bin_s: float
    start: float
    n_bins: int

    @classmethod
    def over(cls, t0: float, t1: float) -> _Binning:
        bin_s = nice_bin(max(t1 - t0, 1e-3), MAX_BINS)
        start = math.floor(t0 / bin_s) * bin_s
        return cls(t0, t1, bin_s, start, max(1, math.floor((t1 - start) / bin_s) + 1))

    def index(self, times_s: FloatArray) -> npt.NDArray[np.int64]:
        """The bin of each time."""
        return np.clip(((times_s - self.start) / self.bin_s).astype(np.int64), 0,
                       self.n_bins - 1)

    def count(self, idx: npt.NDArray[np.int64], mask: npt.NDArray[np.bool_]) -> FloatArray:
        return np.bincount(idx[mask], minlength=self.n_bins).astype(np.float64)


def _assemble(b: _Binning, totals: npt.NDArray[np.int64], per_bin: FloatArray, resyncs: int,
              reasons: Counter[str], head: list[TrafficLine], first_errors: list[TrafficLine],
              events: list[str]) -> TrafficTally:
    """The tally of counts by kind (``totals``, 4) and per bin (``per_bin``, rows: in frames,
    out frames, errors, resyncs)."""
    return TrafficTally(
        records=int(totals.sum()),
        frames_in=int(totals[1]),
        frames_out=int(totals[0]),
        errors_in=int(totals[3]),
        errors_out=int(totals[2]),
        resyncs=resyncs,
        duration_s=b.t1 - b.t0,
        reasons=reasons.most_common(10),
        bin_s=b.bin_s,
        bin_start_s=b.start + b.bin_s * np.arange(b.n_bins, dtype=np.float64),
        count_in=per_bin[0],
        count_out=per_bin[1],
        errors_per_bin=per_bin[2],
        resyncs_per_bin=per_bin[3],
        head=head,
        first_errors=first_errors,
        events=events,
    )


def _bin_counts(b: _Binning, times_s: FloatArray, kinds: KindArray,
                resync: npt.NDArray[np.bool_] | None) -> FloatArray:
    """Per bin: in frames, out frames, errors, resyncs (zeros without ``resync``)."""
    idx = b.index(times_s)
    out = np.zeros((4, b.n_bins), dtype=np.float64)
    out[0] = b.count(idx, kinds == 1)
    out[1] = b.count(idx, kinds == 0)
    out[2] = b.count(idx, kinds >= 2)
    if resync is not None:
        out[3] = b.count(idx, resync)
    return out


def tally(times_s: FloatArray, kinds: KindArray, reasons: Counter[str],
          head: list[TrafficLine], first_errors: list[TrafficLine],
          events: list[str]) -> TrafficTally:
    """The tally of the records ``times_s``/``kinds`` (in the capture's order)."""
    resync = _resyncs(kinds)
    if len(times_s):
        b = _Binning.over(float(times_s.min()), float(times_s.max()))
    else:
        b = _Binning.over(0.0, 0.0)
    totals = np.bincount(kinds, minlength=4)[:4].astype(np.int64)
    return _assemble(b, totals, _bin_counts(b, times_s, kinds, resync),
                     int(np.count_nonzero(resync)), reasons, head, first_errors, events)


@dataclass(frozen=True, slots=True)
class _StoredBlock:
    """A block of records as the counter keeps it: times as zstd-compressed differences (mostly
    the same reply period, so a small fraction of 8 bytes a record), kinds compressed, the
    extreme times."""

    count: int
    t_min: int
    t_max: int
    first_ns: int
    deltas: bytes
    kinds: bytes

    @classmethod
    def of(cls, t_ns: npt.NDArray[np.int64], kinds: KindArray) -> _StoredBlock:
        if not len(t_ns):
            return cls(0, 0, 0, 0, b"", b"")
        return cls(len(t_ns), int(t_ns.min()), int(t_ns.max()), int(t_ns[0]),
                   zstandard.compress(np.diff(t_ns).tobytes(), 1),
                   zstandard.compress(np.ascontiguousarray(kinds, dtype=np.int8).tobytes(), 1))

    def records(self) -> tuple[npt.NDArray[np.int64], KindArray]:
        """The times (ns) and kinds, as they were added."""
        if not self.count:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int8)
        deltas = np.frombuffer(zstandard.decompress(self.deltas), dtype=np.int64)
        t_ns = np.empty(self.count, dtype=np.int64)
        t_ns[0] = self.first_ns
        np.cumsum(deltas, out=t_ns[1:])
        t_ns[1:] += self.first_ns
        return t_ns, np.frombuffer(zstandard.decompress(self.kinds), dtype=np.int8)


class TrafficCounter:
    """Counts records as a writer adds them, in blocks in any order, and gives their
    :func:`tally` in the readers' order (time, arm → host first on equal times, then the order
    added) without keeping more text than the excerpt needs."""

    def __init__(self) -> None:
        self._blocks: list[_StoredBlock] = []
        self._errors = 0
        self._count = 0
        self._texts: list[tuple[int, int, int, str, str | None]] = []
        """Records that may be in the excerpt: (t ns, 1 host → arm else 0, index added, frame,
        error), so that they sort in the readers' order."""
        self._reasons: Counter[str] = Counter()
        self._latest_head_ns = 2**63 - 1
        """A block starting after this (ns) and without errors holds no record of the excerpt."""
        self._read: tuple[_StoredBlock, npt.NDArray[np.int64], KindArray] | None = None
        """The block :meth:`_line_number` read last, its records."""
        self.events: list[str] = []

    def add(self, t_ns: npt.NDArray[np.int64], flags: npt.NDArray[np.uint8],
            frame: Callable[[int], bytes], errors: dict[int, str]) -> None:
        """A block of records: times (ns), flags (1 arm → host, 2 an error), each frame's
        bytes by index (asked for those of the excerpt only) and the errors' reasons by
        index."""
        n = len(t_ns)
        kinds = (flags & 3).astype(np.int8)
        self._blocks.append(_StoredBlock.of(np.asarray(t_ns, dtype=np.int64), kinds))
        self._errors += int(np.count_nonzero(kinds >= 2))
        for reason in errors.values():
            self._reasons[short_text(reason)] += 1
        if not errors and n and int(t_ns[0]) > self._latest_head_ns:  # nothing for the excerpt
            self._count += n
            return
        order = np.lexsort((np.arange(n), 1 - (kinds & 1), t_ns))
        keep = {int(i) for i in order[:2 * HEAD_LINES]}
        keep.update(sorted(errors, key=lambda i: (int(t_ns[i]), 1 - int(kinds[i] & 1), i))
                    [:3 * HEAD_LINES])
        for i in keep:
            self._texts.append((int(t_ns[i]), 1 - int(kinds[i] & 1), self._count + i,
                                frame(i).decode("utf-8", "backslashreplace"), errors.get(i)))
        self._count += n
        if len(self._texts) > 20 * HEAD_LINES:
            self._texts = self._excerpt_candidates()

    def _excerpt_candidates(self) -> list[tuple[int, int, int, str, str | None]]:
        texts = sorted(self._texts)
        errors = [x for x in texts if x[4] is not None]
        if len(texts) >= 2 * HEAD_LINES:  # later records (times in order) cannot be in the head
            self._latest_head_ns = texts[2 * HEAD_LINES - 1][0] - 1
        return sorted({*texts[:2 * HEAD_LINES], *errors[:3 * HEAD_LINES]})

    def tally(self) -> TrafficTally:
        """The tally of every record added: counted block by block (a long run holds millions
        of records); sorted into the readers' order only for the resynchronisations, which
        need it, when there are errors, and never for the excerpt's line numbers."""
        if self._errors:
            return self._tally_sorted()
        filled = [block for block in self._blocks if block.count]
        b = _Binning.over(min(block.t_min for block in filled) / 1e9,
                          max(block.t_max for block in filled) / 1e9) if filled \
            else _Binning.over(0.0, 0.0)
        totals = np.zeros(4, dtype=np.int64)
        per_bin = np.zeros((4, b.n_bins), dtype=np.float64)
        for t_ns, kinds in self._records():
            totals += np.bincount(kinds, minlength=4)[:4]
            per_bin += _bin_counts(b, t_ns / 1e9, kinds, None)
        head, first_errors = self._excerpt(self._line_number)
        self._read = None
        return _assemble(b, totals, per_bin, 0, self._reasons, head, first_errors,
                         list(self.events))

    def _records(self) -> Iterator[tuple[npt.NDArray[np.int64], KindArray]]:
        """Each block's times (ns) and kinds, in the order added."""
        for block in self._blocks:
            yield block.records()

    def _line_number(self, t_ns: int, out_later: int, index: int) -> int:
        """The line (from 1) of the record added as ``index`` in the readers' order: one more
        than the records before it (earlier, or as early and arm → host first, or as early,
        same direction and added before). A block wholly before ``t_ns`` counts whole and one
        wholly after it not at all, unread: the excerpt's records are the run's first, so
        only the blocks at its start are read."""
        before, offset = 0, 0
        for block in self._blocks:
            if block.t_max < t_ns:
                before += block.count
            elif block.t_min <= t_ns:
                if self._read is None or self._read[0] is not block:  # the lines share blocks
                    self._read = (block, *block.records())
                _, times, kinds = self._read
                later = 1 - (kinds & 1)
                same = times == t_ns
                before += int(np.count_nonzero(times < t_ns))
                before += int(np.count_nonzero(same & (later < out_later)))
                first = max(0, min(len(times), index - offset))
                before += int(np.count_nonzero(same[:first] & (later[:first] == out_later)))
            offset += block.count
        return before + 1

    def _excerpt(self, line: Callable[[int, int, int], int]) -> tuple[list[TrafficLine],
                                                                     list[TrafficLine]]:
        """The excerpt's first lines and first errors, numbered by ``line``."""
        head: list[TrafficLine] = []
        first_errors: list[TrafficLine] = []
        for t, out_later, index, frame, error in self._excerpt_candidates():
            if len(head) >= HEAD_LINES and (error is None or len(first_errors) >= HEAD_LINES):
                continue
            row = TrafficLine(line(t, out_later, index), t / 1e9, "out" if out_later else "in",
                              short_text(frame), None if error is None else short_text(error))
            if len(head) < HEAD_LINES:
                head.append(row)
            else:
                first_errors.append(row)
        return head, first_errors

    def _tally_sorted(self) -> TrafficTally:
        """The tally with every record in the readers' order (for the resynchronisations)."""
        blocks = list(self._records())
        t_ns = np.concatenate([t for t, _ in blocks]) if blocks else np.zeros(0, dtype=np.int64)
        kinds = np.concatenate([k for _, k in blocks]) if blocks else np.zeros(0, dtype=np.int8)
        del blocks
        order = np.lexsort((1 - (kinds & 1), t_ns))  # stable: the order added on ties
        rank = np.empty(len(order), dtype=np.int64)
        rank[order] = np.arange(1, len(order) + 1)
        head, first_errors = self._excerpt(lambda _t, _o, index: int(rank[index]))
        return tally(t_ns[order] / 1e9, kinds[order], self._reasons, head, first_errors,
                     list(self.events))
