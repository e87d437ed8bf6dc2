"""The traffic tally a capture stores (``TrafficCounter``, counted block by block as the writer
adds them) is the tally of the records in the readers' order: blocks in any order, overlapping
in time, with ties, with and without framing errors."""

from __future__ import annotations

import dataclasses
from collections import Counter

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armbench.drivers.capture.tally import HEAD_LINES, TrafficCounter, TrafficTally, tally

block = st.lists(st.tuples(st.integers(min_value=0, max_value=40),  # time, ms: many ties
                           st.integers(min_value=0, max_value=1),   # 1 arm -> host
                           st.booleans()),                          # a framing error
                 min_size=0, max_size=30)


def _counted(blocks: list[list[tuple[int, int, bool]]]) -> TrafficCounter:
    counter = TrafficCounter()
    offset = 0
    for b in blocks:
        def frame(i: int, first: int = offset) -> bytes:  # names the record: its order added
            return f"$frame{first + i:05d}#".encode()
        offset += len(b)
        t_ns = np.array([t * 1_000_000 + 7 for t, _, _ in b], dtype=np.int64)
        flags = np.array([d | (2 if e else 0) for _, d, e in b], dtype=np.uint8)
        errors = {i: "bytes outside a frame" for i, (_, _, e) in enumerate(b) if e}
        counter.add(t_ns, flags, frame, errors)
    return counter


def _reference(blocks: list[list[tuple[int, int, bool]]]) -> TrafficTally:
    """Every record sorted as a reader sorts them (time, arm -> host first, order added)."""
    rows = [(t, 1 - d, k, (d | (2 if e else 0))) for k, (t, d, e) in
            enumerate(r for b in blocks for r in b)]
    rows.sort()
    reasons: Counter[str] = Counter({"bytes outside a frame": sum(r[3] >= 2 for r in rows)})
    reasons = +reasons
    times = np.array([(t * 1_000_000 + 7) / 1e9 for t, _, _, _ in rows], dtype=np.float64)
    kinds = np.array([k for _, _, _, k in rows], dtype=np.int8)
    return tally(times, kinds, reasons, [], [], [])


def _clean(blocks: list[list[tuple[int, int, bool]]],
           with_errors: bool) -> list[list[tuple[int, int, bool]]]:
    """``blocks``, without their errors unless ``with_errors``: a run without framing errors
    is the common case, counted without sorting."""
    return blocks if with_errors else [[(t, d, False) for t, d, _ in b] for b in blocks]


@settings(max_examples=200, deadline=None)
@given(blocks=st.lists(block, min_size=0, max_size=6), with_errors=st.booleans())
def test_the_stored_tally_is_the_readers(blocks: list[list[tuple[int, int, bool]]],
                                         with_errors: bool) -> None:
    blocks = _clean(blocks, with_errors)
    got = _counted(blocks).tally()
    want = _reference(blocks)
    for field in dataclasses.fields(got):
        if field.name in ("head", "first_errors"):
            continue
        u, v = getattr(got, field.name), getattr(want, field.name)
        assert np.array_equal(u, v) if isinstance(u, np.ndarray) else u == v, field.name


@settings(max_examples=200, deadline=None)
@given(blocks=st.lists(block, min_size=1, max_size=6), with_errors=st.booleans())
def test_excerpt_lines_are_numbered_in_the_readers_order(
        blocks: list[list[tuple[int, int, bool]]], with_errors: bool) -> None:
    blocks = _clean(blocks, with_errors)
    rows = sorted((t, 1 - d, k) for k, (t, d, _) in enumerate(r for b in blocks for r in b))
    line_of = {k: n + 1 for n, (_, _, k) in enumerate(rows)}
    got = _counted(blocks).tally()
    assert [x.line for x in got.head] == list(range(1, min(HEAD_LINES, len(rows)) + 1))
    for line in (*got.head, *got.first_errors):
        assert line_of[int(line.frame[6:11])] == line.line, line


def test_the_excerpt_reads_only_the_blocks_at_the_runs_start(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A long run: the excerpt's line numbers need the blocks its first records are in, not a
    pass over every block for each of its lines (what closing a default run's capture spent
    most of its time on)."""
    from armbench.drivers.capture import tally as tally_module

    blocks = [[(40 * k + t, t % 2, False) for t in range(40)] for k in range(50)]
    counter = _counted([[(t, d, e) for t, d, e in b] for b in blocks])
    reads: list[int] = []
    records = tally_module._StoredBlock.records

    def counted(self: tally_module._StoredBlock) -> tuple[object, object]:
        reads.append(self.count)
        return records(self)

    monkeypatch.setattr(tally_module._StoredBlock, "records", counted)
    got = counter.tally()
    assert [x.line for x in got.head] == list(range(1, HEAD_LINES + 1))
    assert len(reads) <= len(blocks) + 2  # the counts' pass, and the first block for the lines
