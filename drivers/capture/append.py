"""Add an attachment to a finished MCAP file: the run's ``report.html`` is written after the
capture is closed (the report reads the capture's traffic tally from its summary), so it joins
the file afterwards. The file is cut at its ``DataEnd`` record, the attachment written there, and
the summary written again with the attachment in its index and statistics (summary CRC 0: "not
computed", as the MCAP specification allows). A crash in between leaves a file without a summary,
which every reader opens up to its last complete record (as a killed run's)."""

from __future__ import annotations

import os
import struct
from collections import defaultdict
from io import BytesIO
from pathlib import Path

import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    DataEnd,
    Footer,
    McapRecord,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import StreamReader

from armbench.drivers.capture.jsonl import CaptureError
from armbench.drivers.capture.mcap_walk import capture_start_ns

__all__ = ["ZSTD_MEDIA_TYPE", "append_attachment", "zstd_attachment"]

#: Media type of a file attached zstd-compressed (``<name>.zst``).
ZSTD_MEDIA_TYPE = "application/zstd"
#: zstd level of the run's attached files (text: JSON and HTML, written once at the end): zstd's
#: default, much faster than level 9 on a long run's record for somewhat more bytes.
_ZSTD_LEVEL = 3

_MAGIC = b"\x89MCAP0\r\n"
_FOOTER_BYTES = 1 + 8 + 8 + 8 + 4
_DATA_END_BYTES = 1 + 8 + 4


def _summary(summary: bytes) -> list[McapRecord]:
    """The summary section's records (``summary``: the file from the footer's
    ``summary_start``), summary offsets and footer left out (written anew)."""
    reader = StreamReader(BytesIO(summary), skip_magic=True)
    return [r for r in reader.records if not isinstance(r, SummaryOffset | Footer)]


def zstd_attachment(name: str, path: Path) -> tuple[str, bytes]:
    """The attachment name (``name.zst``) and zstd-compressed bytes of the file at ``path``
    (``OSError`` when it cannot be read). Compressed as it is read: a long run's
    ``results.json`` is never in memory whole, only its compressed form."""
    out = BytesIO()
    with path.open("rb") as fh:
        zstandard.ZstdCompressor(level=_ZSTD_LEVEL).copy_stream(
            fh, out, size=os.fstat(fh.fileno()).st_size)
    return name + ".zst", out.getvalue()


def append_attachment(path: Path, name: str, data: bytes, media_type: str,
                      log_time_ns: int | None = None) -> bool:
    """Attach ``data`` as ``name`` to the finished MCAP file at ``path`` (at ``log_time_ns``,
    by default the run's start the capture counts from). False (the file left as it is) when
    the file has no summary to extend (a killed run's) or is not MCAP."""
    if log_time_ns is None:
        try:
            log_time_ns = capture_start_ns(path)
        except CaptureError:
            return False
    with path.open("r+b") as fh:
        size = fh.seek(0, os.SEEK_END)
        if size < 2 * len(_MAGIC) + _FOOTER_BYTES + _DATA_END_BYTES:
            return False
        fh.seek(0)
        head = fh.read(len(_MAGIC))
        fh.seek(size - len(_MAGIC) - _FOOTER_BYTES)
        tail = fh.read()
        if head != _MAGIC or not tail.endswith(_MAGIC) or tail[0] != Opcode.FOOTER:
            return False
        footer = Footer(*struct.unpack_from("<QQI", tail, 9))
        data_end = footer.summary_start - _DATA_END_BYTES
        if footer.summary_start == 0 or data_end <= 0:
            return False
        fh.seek(data_end)  # only the summary is read: the messages before it stay on disk
        rest = fh.read()
        if not rest or rest[0] != Opcode.DATA_END:
            return False
        summary = _summary(rest[_DATA_END_BYTES:])
        out = RecordBuilder()
        attachment = Attachment(log_time_ns, log_time_ns, name, media_type, data)
        attachment.write(out)
        length = out.count
        DataEnd(0).write(out)
        summary_start = data_end + out.count
        groups: dict[int, list[McapRecord]] = defaultdict(list)
        for record in summary:
            if isinstance(record, Statistics):
                record.attachment_count += 1
            groups[_opcode(record)].append(record)
        groups[Opcode.ATTACHMENT_INDEX].append(AttachmentIndex(
            data_end, length, log_time_ns, log_time_ns, len(data), name, media_type))
        offsets: list[SummaryOffset] = []
        for opcode, records in groups.items():
            start = data_end + out.count
            for record in records:
                record.write(out)
            offsets.append(SummaryOffset(opcode, start, data_end + out.count - start))
        offset_start = data_end + out.count
        for offset in offsets:
            offset.write(out)
        Footer(summary_start, offset_start, 0).write(out)
        fh.seek(data_end)
        fh.truncate()
        fh.write(_end(out) + _MAGIC)
    return True


def _opcode(record: McapRecord) -> int:
    """The opcode a summary record is written with (its group)."""
    builder = RecordBuilder()
    record.write(builder)
    return _end(builder)[0]


def _end(builder: RecordBuilder) -> bytes:
    data: bytes = builder.end()  # type: ignore[no-untyped-call]  # mcap has no annotations here
    return data
