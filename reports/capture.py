"""A bounded summary of a traffic capture (``capture.jsonl`` beside ``results.json``) for the
report: frame rates over time, framing errors by reason, resynchronisations and short excerpts.

The format is the driver's (``drivers/capture.py``), read here on its own so the report never
imports the driver: JSON Lines ``{"t_s": ..., "dir": "in" | "out", "frame": "<ascii>", "error":
reason | null}``. The file is streamed once; at most :data:`MAX_RECORDS` records are analysed,
lines that are not such records are counted and skipped (a capture cut short by a crash still
reports), and only a few records are kept as text.
"""

from __future__ import annotations

import itertools
import json
import math
from array import array
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["MAX_RECORDS", "CaptureLine", "CaptureSummary", "summarize_capture"]

#: Records analysed at most (the rest of a longer capture is counted as skipped).
MAX_RECORDS = 2_000_000
#: Bins of the frame-rate plot at most.
MAX_BINS = 100
#: Characters of a frame or reason kept in an excerpt.
TEXT_LIMIT = 96

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class CaptureLine:
    """One record of an excerpt: its line number (from 1) and fields, text shortened."""

    line: int
    t_s: float
    dir: str
    frame: str
    error: str | None


@dataclass(frozen=True, slots=True)
class CaptureSummary:
    """What the report shows of a capture. Rates are frames per second per bin of ``bin_s``
    seconds starting at ``bin_start_s``; ``resyncs`` counts valid frames that followed an error
    in the same direction (the framer found its feet again)."""

    path: Path
    size_bytes: int
    records: int
    skipped_records: int
    bad_lines: int
    frames_in: int
    frames_out: int
    errors_in: int
    errors_out: int
    resyncs: int
    duration_s: float
    reasons: list[tuple[str, int]]
    bin_s: float
    bin_start_s: FloatArray
    rate_in: FloatArray
    rate_out: FloatArray
    errors_per_bin: FloatArray
    resyncs_per_bin: FloatArray
    head: list[CaptureLine]
    first_errors: list[CaptureLine]
    events: list[str] = field(default_factory=list)
    """What the capture says of itself (``"capture stopped: ..."`` at its size bound)."""


#: Lines parsed at a time: one C-level json.loads of a chunk as a JSON array, not one per line.
_CHUNK = 20_000


def _parse_chunk(lines: list[bytes]) -> list[dict[str, Any] | bool | None]:
    """Per line: its record, None when the line is not a JSON object, False when blank. One
    ``json.loads`` of the whole chunk as an array when every line looks like one object; line
    by line otherwise or when the counts do not match."""
    stripped = [line.strip() for line in lines]
    kept = [line for line in stripped if line]
    objs: list[Any] | None = None
    if all(line[:1] == b"{" and line[-1:] == b"}" for line in kept):
        try:
            objs = json.loads(b"[" + b",".join(kept) + b"]")
        except (ValueError, UnicodeDecodeError):
            objs = None
        if objs is not None and len(objs) != len(kept):
            objs = None
    if objs is None:
        objs = [_one(line) for line in kept]
    it = iter(objs)
    return [next(it) if line else False for line in stripped]


def _one(line: bytes) -> Any:
    try:
        return json.loads(line)
    except (ValueError, UnicodeDecodeError):
        return None


def _short(text: str) -> str:
    return text if len(text) <= TEXT_LIMIT else text[: TEXT_LIMIT - 1] + "…"


def _nice_bin(span_s: float, max_bins: int) -> float:
    """The smallest 1-2-5 bin width (s) giving at most ``max_bins`` bins over ``span_s``."""
    raw = max(span_s / max_bins, 1e-3)
    exp = math.floor(math.log10(raw))
    for m in (1.0, 2.0, 5.0, 10.0):
        width = m * 10.0**exp
        if width >= raw * (1 - 1e-9):
            return width
    return 10.0 ** (exp + 1)  # pragma: no cover


def summarize_capture(path: str | Path, *, max_records: int = MAX_RECORDS, head: int = 20,
                      errors: int = 20) -> CaptureSummary:
    """Read ``path`` (streamed, bounded) and summarise it; OSError if it cannot be opened."""
    p = Path(path)
    size = p.stat().st_size
    times = array("d")
    kinds = array("b")  # 0 out frame, 1 in frame, 2 out error, 3 in error, +4 when a resync
    reasons: Counter[str] = Counter()
    first: list[CaptureLine] = []
    first_errors: list[CaptureLine] = []
    bad = 0
    events: list[str] = []
    after_error = {"in": False, "out": False}
    with p.open("rb") as fh:
        number = 0
        while len(times) < max_records:
            chunk = list(itertools.islice(fh, min(_CHUNK, max_records - len(times))))
            if not chunk:
                break
            for obj in _parse_chunk(chunk):
                number += 1
                if obj is False:
                    continue
                if not isinstance(obj, dict):
                    bad += 1
                    continue
                if isinstance(obj.get("event"), str) and "dir" not in obj:
                    events.append(obj["event"])
                    continue
                t, d, frame, error = (obj.get("t_s"), obj.get("dir"), obj.get("frame"),
                                      obj.get("error"))
                if (isinstance(t, bool) or not isinstance(t, (int, float))
                        or not math.isfinite(t) or d not in ("in", "out")
                        or not isinstance(frame, str)
                        or not (error is None or isinstance(error, str))):
                    bad += 1
                    continue
                kind = (1 if d == "in" else 0) + (2 if error is not None else 0)
                if error is not None:
                    reasons[_short(error)] += 1
                    after_error[d] = True
                elif after_error[d]:
                    after_error[d] = False
                    kind += 4
                times.append(float(t))
                kinds.append(kind)
                if len(first) < head or (error is not None and len(first_errors) < errors):
                    line = CaptureLine(number, float(t), d, _short(frame),
                                       None if error is None else _short(error))
                    if len(first) < head:
                        first.append(line)
                    elif error is not None:
                        first_errors.append(line)
        skipped = sum(1 for _ in fh)
    t_arr = np.frombuffer(times, dtype=np.float64) if len(times) else np.zeros(0)
    k_arr = np.frombuffer(kinds, dtype=np.int8) if len(kinds) else np.zeros(0, dtype=np.int8)
    base = k_arr & 3
    resync = (k_arr & 4) != 0
    if len(t_arr):
        t0, t1 = float(t_arr.min()), float(t_arr.max())
    else:
        t0 = t1 = 0.0
    span = max(t1 - t0, 1e-3)
    bin_s = _nice_bin(span, MAX_BINS)
    start = math.floor(t0 / bin_s) * bin_s
    n_bins = max(1, math.floor((t1 - start) / bin_s) + 1)
    idx = np.clip(((t_arr - start) / bin_s).astype(np.int64), 0, n_bins - 1)

    def per_bin(mask: npt.NDArray[np.bool_]) -> FloatArray:
        return np.bincount(idx[mask], minlength=n_bins).astype(np.float64)

    return CaptureSummary(
        path=p,
        size_bytes=size,
        records=len(t_arr),
        skipped_records=skipped,
        bad_lines=bad,
        frames_in=int(np.count_nonzero(base == 1)),
        frames_out=int(np.count_nonzero(base == 0)),
        errors_in=int(np.count_nonzero(base == 3)),
        errors_out=int(np.count_nonzero(base == 2)),
        resyncs=int(np.count_nonzero(resync)),
        duration_s=t1 - t0,
        reasons=reasons.most_common(10),
        bin_s=bin_s,
        bin_start_s=start + bin_s * np.arange(n_bins, dtype=np.float64),
        rate_in=per_bin(base == 1) / bin_s,
        rate_out=per_bin(base == 0) / bin_s,
        errors_per_bin=per_bin(base >= 2),
        resyncs_per_bin=per_bin(resync),
        head=first,
        first_errors=first_errors,
        events=events,
    )
