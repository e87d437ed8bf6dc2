"""Captures that cost far more to read than they weigh (``measurements/reliability.md``, third
round): a zstd chunk of a few kB that expands to hundreds of MB, one that expands past the size it
claims, a metadata record of tens of MB, an attachment that expands without end. Each file is
built here, small on disk (but for the metadata record, which is its own size); reading it is
refused with an error naming the file, and the memory the reader allocates meanwhile
(``tracemalloc``: every Python allocation, the decompressors' output included) stays far below
what the file claims.

Before: a 28 KB capture with one chunk expanding to 900 MB drove ``twin-check`` to 1.85 GB and
``calibrate --capture`` to 1.88 GB before "holds no traffic"; a 200 MB metadata record cost
675 MB.
"""

from __future__ import annotations

import io
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.records import Attachment, Chunk, DataEnd, Footer, Header, Metadata, MetadataIndex

from armbench.bench.twin_check.tool_point import RECORD_HEAD_BYTES
from armbench.cli.main import main
from armbench.drivers.capture.mcap_walk import (
    MAX_CHUNK_BYTES,
    MAX_METADATA_BYTES,
    MCAP_MAGIC,
    read_attachment,
)
from armbench.drivers.capture.read import open_capture, read_tally
from armbench.drivers.capture.tally import TALLY_METADATA

#: What each bomb expands to: 512 MiB, eight times the chunk bound.
BOMB_BYTES = 512 << 20
#: The most a refused read may allocate at its peak: a quarter of the bomb.
PEAK_BOUND_BYTES = BOMB_BYTES // 4


def _zeros_zstd(size: int) -> bytes:
    """``size`` zero bytes as one zstd frame (a few kB), compressed as a stream."""
    out = io.BytesIO()
    with zstandard.ZstdCompressor(level=1).stream_writer(out, size=size, closefd=False) as w:
        block = bytes(1 << 20)
        for _ in range(size >> 20):
            w.write(block)
    return out.getvalue()


def _mcap(path: Path, *records: Any, summary: Callable[[int], list[Any]] | None = None) -> Path:
    """An MCAP file of ``records`` after its header; with ``summary`` (given the data end's
    offset) closed with those summary records and a footer, else cut short."""
    b = RecordBuilder()
    Header(profile="ros2", library="bomb").write(b)
    offsets = []
    for record in records:
        offsets.append(len(MCAP_MAGIC) + b.count)
        record.write(b)
    if summary is not None:
        DataEnd(0).write(b)
        start = len(MCAP_MAGIC) + b.count
        for record in summary(offsets[0]):
            record.write(b)
        Footer(start, 0, 0).write(b)
    body: bytes = b.end()  # type: ignore[no-untyped-call]  # mcap has no annotations here
    path.write_bytes(MCAP_MAGIC + body + (MCAP_MAGIC if summary is not None else b""))
    return path


def _peak(read: Callable[[], object]) -> int:
    """Peak bytes Python allocated while ``read`` ran."""
    tracemalloc.start()
    try:
        read()
    finally:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    return peak


def _refused_cheaply(capsys: pytest.CaptureFixture[str], path: Path, *argv: str | Path,
                     reason: str) -> None:
    """``armbench ARGV`` refuses ``path`` in one line naming it and ``reason``, exit status 2,
    allocating less than :data:`PEAK_BOUND_BYTES` at its peak."""
    status: list[int] = []
    peak = _peak(lambda: status.append(main([str(a) for a in argv])))
    err = capsys.readouterr().err
    assert status == [2], err
    assert len(err.strip().splitlines()) == 1 and str(path) in err and reason in err, err
    assert peak < PEAK_BOUND_BYTES, f"{peak / 1e6:.0f} MB at the peak"


def _chunk(data: bytes, claimed: int) -> Chunk:
    return Chunk(message_start_time=0, message_end_time=0, uncompressed_size=claimed,
                 uncompressed_crc=0, compression="zstd", data=data)


@pytest.fixture(scope="module")
def bomb_data() -> bytes:
    assert BOMB_BYTES >= 8 * MAX_CHUNK_BYTES
    return _zeros_zstd(BOMB_BYTES)


def test_a_chunk_that_claims_hundreds_of_mb(tmp_path: Path, bomb_data: bytes,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    path = _mcap(tmp_path / "claims.mcap", _chunk(bomb_data, BOMB_BYTES))
    assert path.stat().st_size < 100_000
    for argv in (("twin-check", path), ("calibrate", "--capture", path, "--out",
                                        tmp_path / "fit")):
        _refused_cheaply(capsys, path, *argv, reason=f"claims {BOMB_BYTES} bytes uncompressed")
    assert not (tmp_path / "fit").exists()  # calibrate's --out folder is not left behind


def test_a_chunk_that_expands_past_what_it_claims(tmp_path: Path, bomb_data: bytes,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    path = _mcap(tmp_path / "liar.mcap", _chunk(bomb_data, 1 << 20))
    for argv in (("twin-check", path), ("calibrate", "--capture", path, "--out",
                                        tmp_path / "fit")):
        _refused_cheaply(capsys, path, *argv, reason="expands past the 1048576 bytes it claims")
    assert not (tmp_path / "fit").exists()


def test_a_metadata_record_of_tens_of_mb(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """24 MB on disk (the record is its own size), no traffic: refused before it is read."""
    size = 24 * MAX_METADATA_BYTES
    path = _mcap(tmp_path / "meta.mcap", Metadata(name="junk", metadata={"k": "x" * size}))
    status: list[int] = []
    peak = _peak(lambda: status.append(main(["twin-check", str(path)])))
    err = capsys.readouterr().err
    assert status == [2] and str(path) in err, err
    assert f"more than the {MAX_METADATA_BYTES} a capture's metadata may hold" in err
    assert peak < 2 * MAX_METADATA_BYTES, f"{peak / 1e6:.1f} MB at the peak"


def test_a_stored_tally_larger_than_a_tally_is_not_read(tmp_path: Path) -> None:
    """The report reads a closed capture's tally through the summary's index: one that is
    larger than a tally can be is left unread (the report then counts the records)."""
    size = 24 * MAX_METADATA_BYTES
    meta = Metadata(name=TALLY_METADATA, metadata={"k": "x" * size})
    length = 25 + size + len(TALLY_METADATA)
    path = _mcap(tmp_path / "tally.mcap", meta,
                 summary=lambda at: [MetadataIndex(at, length, TALLY_METADATA)])
    assert _peak(lambda: read_tally(path) is None) < MAX_METADATA_BYTES
    assert read_tally(path) is None


def test_an_attachment_that_expands_without_end(tmp_path: Path, bomb_data: bytes) -> None:
    """``twin-check`` reads an attached ``results.json`` for the arm's model: only its start."""
    path = _mcap(tmp_path / "attached.mcap",
                 Attachment(0, 0, "results.json.zst", "application/zstd", bomb_data))
    got: list[bytes | None] = []
    peak = _peak(lambda: got.append(read_attachment(path, "results.json", RECORD_HEAD_BYTES)))
    assert got == [bytes(RECORD_HEAD_BYTES)]
    assert peak < 4 * RECORD_HEAD_BYTES, f"{peak / 1e6:.1f} MB at the peak"


def test_a_chunk_that_expands_to_what_it_claims_is_read(tmp_path: Path) -> None:
    """The bounds refuse nothing honest: a chunk whose data expands to the size it claims,
    within the bound, is read (zeros hold no message: none is found)."""
    data = _zeros_zstd(1 << 20)
    assert list(open_capture(_mcap(tmp_path / "fair.mcap", _chunk(data, 1 << 20)))) == []
