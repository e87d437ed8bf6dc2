"""A bounded summary of a traffic capture (``capture.mcap``, or an older run's ``capture.jsonl``,
beside ``results.json``) for the report: frame rates over time, framing errors by reason,
resynchronisations and short excerpts.

A closed ``capture.mcap`` holds its tally (counted as the run wrote it,
:mod:`armbench.drivers.capture.tally`): it is read from the file's summary, not from its 1.5 M
records. Otherwise the capture is read as JSON Lines ``{"t_s": ..., "dir": "in" | "out",
"frame": "<ascii>", "error": reason | null}`` (an MCAP file cut short is given in that text by
:func:`armbench.drivers.capture.read.capture_lines`), streamed once; at most
:data:`MAX_RECORDS` records are analysed, lines that are not such records are counted and
skipped (a capture cut short by a crash still reports), and only a few records are kept as text.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from array import array
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from armbench.drivers.capture.read import capture_lines, read_tally
from armbench.drivers.capture.tally import (
    HEAD_LINES,
    MAX_BINS,
    TEXT_LIMIT,
    TrafficTally,
    short_text,
    tally,
)
from armbench.drivers.capture.tally import TrafficLine as CaptureLine

__all__ = ["MAX_BINS", "MAX_RECORDS", "TEXT_LIMIT", "CaptureLine", "CaptureSummary",
           "summarize_capture"]

#: Records analysed at most (the rest of a longer capture is counted as skipped).
MAX_RECORDS = 2_000_000

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class CaptureSummary(TrafficTally):
    """What the report shows of a capture: its tally (``events``: what the capture says of
    itself, ``"capture stopped: ..."`` at its size bound), the file, and what was not read."""

    path: Path
    size_bytes: int
    skipped_records: int
    bad_lines: int

    @property
    def rate_in(self) -> FloatArray:
        """Arm → host frames per second in each bin."""
        return self.count_in / self.bin_s

    @property
    def rate_out(self) -> FloatArray:
        """Host → arm frames per second in each bin."""
        return self.count_out / self.bin_s


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


def _summary(path: Path, size: int, t: TrafficTally, skipped: int, bad: int) -> CaptureSummary:
    fields = {f.name: getattr(t, f.name) for f in dataclasses.fields(t)}
    return CaptureSummary(**fields, path=path, size_bytes=size, skipped_records=skipped,
                          bad_lines=bad)


def summarize_capture(path: str | Path, *, max_records: int = MAX_RECORDS,
                      head: int = HEAD_LINES, errors: int = HEAD_LINES,
                      stored: bool = True) -> CaptureSummary:
    """Summarise ``path``: a closed MCAP capture's stored tally (unless ``stored`` is False, or
    another excerpt is asked for), else the records read (streamed, bounded); OSError if it
    cannot be opened."""
    p = Path(path)
    size = p.stat().st_size
    tallied = read_tally(p) if stored and head == errors == HEAD_LINES else None
    if tallied is not None and tallied.records <= max_records:
        return _summary(p, size, tallied, 0, 0)
    times = array("d")
    kinds = array("b")  # 0 out frame, 1 in frame, 2 out error, 3 in error
    reasons: Counter[str] = Counter()
    first: list[CaptureLine] = []
    first_errors: list[CaptureLine] = []
    bad = 0
    events: list[str] = []
    with capture_lines(p) as fh:  # either format (armbench.drivers.capture.read)
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
                if error is not None:
                    reasons[short_text(error)] += 1
                times.append(float(t))
                kinds.append((1 if d == "in" else 0) + (2 if error is not None else 0))
                if len(first) < head or (error is not None and len(first_errors) < errors):
                    line = CaptureLine(number, float(t), d, short_text(frame),
                                       None if error is None else short_text(error))
                    if len(first) < head:
                        first.append(line)
                    elif error is not None:
                        first_errors.append(line)
        skipped = sum(1 for _ in fh)
    t_arr = np.frombuffer(times, dtype=np.float64) if len(times) else np.zeros(0)
    k_arr = np.frombuffer(kinds, dtype=np.int8) if len(kinds) else np.zeros(0, dtype=np.int8)
    return _summary(p, size, tally(t_arr, k_arr, reasons, first, first_errors, events),
                    skipped, bad)
