"""The records of an MCAP file, walked and checked: what :mod:`armbench.drivers.capture.read`
reads captures with.

Every record of the data section is parsed as what its opcode says, every chunk decompressed and
held to its size and CRC, and a closed file's chunks counted against its summary, so damage
(a flipped byte, bytes missing in the middle, a file named ``.mcap`` that is not MCAP) is a
:class:`~armbench.drivers.capture.jsonl.CaptureError` naming the file and the byte where it is,
never
another exception and never records silently left out. A file cut short (a killed run: no
summary, a record half written) is read up to its last complete record.
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
import zlib
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import IO, Any, Final, NamedTuple, cast

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from armbench.drivers.capture.jsonl import CaptureError, open_capture_file

__all__ = ["MAX_CHUNK_BYTES", "MAX_METADATA_BYTES", "MAX_RECORD_BYTES", "MCAP_MAGIC", "START_KEY",
           "START_METADATA", "AttachmentAt", "McapLayout", "RawMessage", "capture_start_ns",
           "check_key", "checked_entry", "entry_damage", "iter_messages", "mcap_layout",
           "mcap_records", "read_attachment", "summary_metadata"]

MCAP_MAGIC: Final = b"\x89MCAP0\r\n"
#: The metadata record holding the run's identity and, under :data:`START_KEY`, the wall-clock
#: nanoseconds since the epoch of the run's start: the zero of the run clock, which every time
#: in the capture counts from.
START_METADATA: Final = "armbench"
START_KEY: Final = "start_ns"
_OP_MESSAGE: Final = int(Opcode.MESSAGE)
_OP_CHANNEL: Final = int(Opcode.CHANNEL)
_OP_CHUNK: Final = int(Opcode.CHUNK)
_OP_DATA_END: Final = int(Opcode.DATA_END)
_OP_FOOTER: Final = int(Opcode.FOOTER)
_OP_STATISTICS: Final = int(Opcode.STATISTICS)
_OP_ATTACHMENT: Final = int(Opcode.ATTACHMENT)
_OP_METADATA: Final = int(Opcode.METADATA)
_OP_METADATA_INDEX: Final = int(Opcode.METADATA_INDEX)
#: The MCAP records and their parsers: every record of the data section is parsed as what its
#: opcode says (a flipped opcode then fails to parse, or is caught by the summary's chunk count);
#: an opcode outside these (reserved, or user-defined, which armbench never writes) is damage.
_PARSERS: Final[dict[int, Any]] = {int(op): cls for op, cls in (
    (Opcode.HEADER, Header), (Opcode.FOOTER, Footer), (Opcode.SCHEMA, Schema),
    (Opcode.CHANNEL, Channel), (Opcode.MESSAGE, Message), (Opcode.CHUNK, Chunk),
    (Opcode.MESSAGE_INDEX, MessageIndex), (Opcode.CHUNK_INDEX, ChunkIndex),
    (Opcode.ATTACHMENT, Attachment), (Opcode.ATTACHMENT_INDEX, AttachmentIndex),
    (Opcode.STATISTICS, Statistics), (Opcode.METADATA, Metadata),
    (Opcode.METADATA_INDEX, MetadataIndex), (Opcode.SUMMARY_OFFSET, SummaryOffset),
    (Opcode.DATA_END, DataEnd))}
#: Uncompressed bytes of a chunk at most: 16 times armbench's chunks (4 MiB). A chunk that
#: claims more, or whose data expands to more than it claims (a compression bomb: a few kB of
#: zstd that expand to a gigabyte), is refused; decompression stops at the claimed size, so no
#: more than this is ever held.
MAX_CHUNK_BYTES: Final = 64 << 20
#: Bytes of a metadata record at most: armbench's two are a few kB (the run's identity, the
#: traffic tally of at most 100 bins). A metadata record is read whole, so it is bounded.
MAX_METADATA_BYTES: Final = 1 << 20
#: Bytes of any other record read whole at most (chunks are bounded by :data:`MAX_CHUNK_BYTES`;
#: an attachment's data is never read by the walk, only where it lies: :class:`AttachmentAt`).
MAX_RECORD_BYTES: Final = 16 << 20
#: A footer record's bytes (opcode, length, two offsets, CRC).
_FOOTER_BYTES: Final = 1 + 8 + 8 + 8 + 4
_HEAD: Final = struct.Struct("<BQ")  # a record's opcode and length
_U64: Final = struct.Struct("<Q")
_U32: Final = struct.Struct("<I")
_MESSAGE_HEAD: Final = struct.Struct("<HIQQ")  # channel, sequence, log time, publish time


class RawMessage(NamedTuple):
    """One message of an MCAP file: its topic, log time (ns) and CDR bytes."""

    topic: str
    log_time_ns: int
    data: bytes


class AttachmentAt(NamedTuple):
    """An attachment of an MCAP file as the walk finds it: its name and media type and where
    its data lies (byte offset and length), the data left unread."""

    name: str
    media_type: str
    data_offset: int
    data_length: int


class McapLayout(NamedTuple):
    """What an MCAP file holds, before its messages are read: its complete chunks, and whether it
    was closed (its footer and closing magic are there) or cut short (a killed run)."""

    chunks: int
    closed: bool




def _damaged(path: Path, pos: int, what: str, problem: object) -> CaptureError:
    return CaptureError(str(path), None, f"{what} at byte {pos} is corrupt: {problem}")


def _closed(fh: IO[bytes]) -> bool:
    """Whether the file ends with the closing magic after at least the opening one."""
    size = os.fstat(fh.fileno()).st_size
    fh.seek(max(0, size - len(MCAP_MAGIC)))
    return size >= 2 * len(MCAP_MAGIC) and fh.read() == MCAP_MAGIC


def _parse(path: Path, pos: int, opcode: int, body: bytes) -> McapRecord:
    cls = _PARSERS[opcode]
    stream = ReadDataStream(io.BytesIO(body))
    try:
        record: McapRecord = (Message.read(stream, len(body)) if cls is Message
                              else cls.read(stream))
        return record
    except (McapError, EOFError, struct.error, ValueError, OverflowError, MemoryError) as exc:
        raise _damaged(path, pos, Opcode(opcode).name.lower(), str(exc) or type(exc).__name__
                       ) from None


def _summary_records(path: Path, fh: IO[bytes], size: int) -> Iterator[tuple[int, int, int]]:
    """(byte offset, opcode, length) of each record of a closed file's summary section (none
    when it has none), ``fh`` at the record's body when each is yielded."""
    at = size - len(MCAP_MAGIC) - _FOOTER_BYTES
    fh.seek(at)
    head = fh.read(_FOOTER_BYTES)
    opcode, length = _HEAD.unpack_from(head)
    if opcode != _OP_FOOTER or length != _FOOTER_BYTES - _HEAD.size:
        raise _damaged(path, at, "footer", f"opcode 0x{opcode:02x}, length {length}")
    footer = Footer.read(ReadDataStream(io.BytesIO(head[_HEAD.size:])))
    pos = footer.summary_start
    if pos == 0:
        return
    if not len(MCAP_MAGIC) <= pos <= at:
        raise _damaged(path, at, "footer", f"its summary starts at byte {pos}")
    while pos + _HEAD.size <= at:
        fh.seek(pos)
        opcode, length = _HEAD.unpack(fh.read(_HEAD.size))
        if pos + _HEAD.size + length > at:
            raise _damaged(path, pos, "summary record", "it runs past the footer")
        yield pos, opcode, length
        pos += _HEAD.size + length


def _summary_chunks(path: Path, fh: IO[bytes], size: int) -> int | None:
    """The chunk count of a closed file's summary statistics (None: it has none)."""
    for pos, opcode, length in _summary_records(path, fh, size):
        if opcode == _OP_STATISTICS:
            _check_length(path, pos, opcode, length)
            stats = _parse(path, pos, opcode, fh.read(length))
            assert isinstance(stats, Statistics)
            return int(stats.chunk_count)
    return None


def summary_metadata(path: str | Path, name: str) -> Metadata | None:
    """The metadata record ``name`` of a closed MCAP file, found through its summary's metadata
    index (the chunks are not read); None for a file cut short, one without that record, or one
    whose record is larger than :data:`MAX_METADATA_BYTES` (not read). A damaged summary is a
    :class:`CaptureError`."""
    p = Path(path)
    with open_capture_file(p) as fh:
        size = os.fstat(fh.fileno()).st_size
        if not _closed(fh):
            return None
        for pos, opcode, length in _summary_records(p, fh, size):
            if opcode != _OP_METADATA_INDEX:
                continue
            _check_length(p, pos, opcode, length)
            index = _parse(p, pos, opcode, fh.read(length))
            assert isinstance(index, MetadataIndex)
            if index.name != name:
                continue
            if not _HEAD.size <= index.length <= _HEAD.size + MAX_METADATA_BYTES or \
                    index.offset + index.length > size:
                return None
            fh.seek(index.offset)
            opcode, length = _HEAD.unpack(fh.read(_HEAD.size))
            if opcode != _OP_METADATA or length != index.length - _HEAD.size:
                raise _damaged(p, index.offset, "metadata", "not where its index says")
            record = _parse(p, index.offset, opcode, fh.read(length))
            assert isinstance(record, Metadata)
            return record
    return None


def _check_length(path: Path, pos: int, opcode: int, length: int) -> None:
    """Refuse a record longer than its kind may be (it would be read whole)."""
    bound = {_OP_CHUNK: 2 * MAX_CHUNK_BYTES, _OP_METADATA: MAX_METADATA_BYTES}.get(
        opcode, MAX_RECORD_BYTES)
    if length > bound:
        what = Opcode(opcode).name.lower().replace("_", " ")
        raise CaptureError(str(path), None, f"{what} at byte {pos} holds {length} bytes, more "
                                            f"than the {bound} a capture's {what} may hold: "
                                            "not read")


def _attachment_at(path: Path, fh: IO[bytes], pos: int, length: int) -> AttachmentAt:
    """The attachment record at ``pos`` (``length`` bytes after its opcode and length), its
    fields before the data parsed and the data skipped."""
    body = pos + _HEAD.size
    head = fh.read(min(length, 1 << 16))
    try:
        at = 16  # log time, create time
        (n,) = _U32.unpack_from(head, at)
        name = head[at + 4:at + 4 + n].decode("utf-8")
        at += 4 + n
        (n,) = _U32.unpack_from(head, at)
        media_type = head[at + 4:at + 4 + n].decode("utf-8")
        at += 4 + n
        (data_length,) = _U64.unpack_from(head, at)
        at += 8
    except (struct.error, UnicodeDecodeError) as exc:
        raise _damaged(path, pos, "attachment", exc) from None
    if at + data_length + 4 != length:
        raise _damaged(path, pos, "attachment", f"its data of {data_length} bytes does not fit "
                                                f"its record of {length}")
    return AttachmentAt(name, media_type, body + at, data_length)


def mcap_records(path: str | Path) -> Iterator[tuple[int, McapRecord | AttachmentAt]]:
    """(byte offset, record) of each record of an MCAP file's data section, checked as
    :func:`iter_messages` checks them (attachments as :class:`AttachmentAt`, their data
    unread)."""
    p = Path(path)
    with open_capture_file(p) as fh:
        yield from _records(p, fh)


def _records(path: Path, fh: IO[bytes]) -> Iterator[tuple[int, McapRecord | AttachmentAt]]:
    """(byte offset, record) of each record of the data section, parsed as its opcode says. A
    record cut short by the end of the file ends the walk when the file was not closed (a killed
    run's last record); in a closed file it is damage, as an unknown opcode, a record that does
    not parse, or fewer chunks than the summary counts are."""
    size = os.fstat(fh.fileno()).st_size
    closed = _closed(fh)
    fh.seek(0)
    magic = fh.read(len(MCAP_MAGIC))
    if magic != MCAP_MAGIC:
        if MCAP_MAGIC.startswith(magic) and not closed:
            return  # killed while the magic was written
        raise CaptureError(str(path), None, "is not an MCAP file: it does not begin with the "
                                            "MCAP magic")
    pos = len(MCAP_MAGIC)
    chunks = 0
    while True:
        head = fh.read(_HEAD.size)
        if len(head) < _HEAD.size:
            if closed:
                raise _damaged(path, pos, "record", "the file ends inside its header")
            return
        opcode, length = _HEAD.unpack(head)
        if opcode not in _PARSERS:
            raise _damaged(path, pos, "record", f"opcode 0x{opcode:02x} is not an MCAP record")
        end = pos + _HEAD.size + length
        if end > size:
            if closed:
                raise _damaged(path, pos, "record", f"its length ({length} bytes) runs past "
                                                    f"the end of the file ({size} bytes)")
            return  # cut short: the record was being written
        if opcode == _OP_ATTACHMENT:
            yield pos, _attachment_at(path, fh, pos, length)
            fh.seek(end)
            pos = end
            continue
        _check_length(path, pos, opcode, length)
        record = _parse(path, pos, opcode, fh.read(length))
        if opcode in (_OP_DATA_END, _OP_FOOTER):
            break
        chunks += opcode == _OP_CHUNK
        yield pos, record
        pos = end
    if closed:
        expected = _summary_chunks(path, fh, size)
        if expected is not None and expected != chunks:
            raise CaptureError(str(path), None, f"is corrupt: its data section holds {chunks} "
                                                f"chunks up to byte {pos}, its summary counts "
                                                f"{expected}")


def mcap_layout(path: str | Path) -> McapLayout:
    """The complete chunks of an MCAP file and whether it was closed (the chunks are not
    decompressed); a :class:`CaptureError` if the file is damaged or not MCAP."""
    p = Path(path)
    with open_capture_file(p) as fh:
        chunks = sum(isinstance(r, Chunk) for _, r in _records(p, fh))
        return McapLayout(chunks, _closed(fh))


def check_key(key: str) -> str:
    """The key of the check of metadata entry ``key``: ``{key}_crc32``."""
    return f"{key}_crc32"


def checked_entry(key: str, value: str) -> dict[str, str]:
    """A metadata entry with its check (:func:`check_key`): the CRC-32 of the value, 8 hex
    digits. A metadata record has no checksum of its own, and a flipped digit of the run's start
    would move every time of the capture."""
    return {key: value, check_key(key): _crc_hex(value)}


def entry_damage(metadata: Mapping[str, str], key: str) -> str | None:
    """What is wrong with ``metadata``'s ``key`` against its check (:func:`checked_entry`);
    None when it matches, or has no check (written before entries had one)."""
    check = metadata.get(check_key(key))
    if check is None or check == _crc_hex(metadata.get(key, "")):
        return None
    return f"{key} {metadata.get(key)!r} does not match its check {check!r}"


def _crc_hex(text: str) -> str:
    return f"{zlib.crc32(text.encode('utf-8')):08x}"


def capture_start_ns(path: str | Path) -> int:
    """The wall-clock nanoseconds of the run's start that a capture's times count from (its
    ``armbench`` metadata record, written before any message); 0 for a capture written before
    the times were on the wall clock (they count from 0) or one cut short before it. A start
    that does not match its check (captures written before it have none) is damage."""
    p = Path(path)
    with open_capture_file(p) as fh:
        for pos, record in _records(p, fh):
            if isinstance(record, Metadata) and record.name == START_METADATA:
                meta = record.metadata
                if (problem := entry_damage(meta, START_KEY)) is not None:
                    raise _damaged(p, pos, "metadata", problem)
                try:
                    return max(0, int(meta.get(START_KEY, "0")))
                except ValueError:
                    raise CaptureError(str(p), None, f"metadata {START_KEY} "
                                       f"{meta[START_KEY]!r} is not a "
                                       "number of nanoseconds") from None
            if isinstance(record, (Chunk, Message)):
                break
    return 0


def iter_messages(path: str | Path, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
    """The messages of an MCAP file in file order (optionally only ``topics``), streamed; a file
    cut short ends at its last complete record. Records and chunks are walked here (``mcap``
    parses each record and decompresses); only the wanted messages are copied out. A damaged
    file is a :class:`CaptureError` naming the byte where the damage is."""
    wanted = None if topics is None else set(topics)
    channels: dict[int, str] = {}
    p = Path(path)
    with open_capture_file(p) as fh:
        for pos, record in _records(p, fh):
            if isinstance(record, Chunk):
                yield from _chunk_messages(p, pos, record, channels, wanted)
            elif isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message):
                topic = channels.get(record.channel_id)
                if topic is None:
                    raise _damaged(p, pos, "message", f"channel {record.channel_id} was never "
                                                      "declared")
                if wanted is None or topic in wanted:
                    yield RawMessage(topic, record.log_time, record.data)


def _chunk_messages(path: Path, at: int, chunk: Chunk, channels: dict[int, str],
                    wanted: set[str] | None) -> Iterator[RawMessage]:
    data, size = _chunk_data(path, at, chunk)
    pos = 0
    unpack = _MESSAGE_HEAD.unpack_from
    while pos + 9 <= size:
        opcode = data[pos]
        (length,) = _U64.unpack_from(data, pos + 1)
        body = pos + 9
        pos = body + length
        if pos > size:
            raise _damaged(path, at, "chunk", f"a record inside runs past its end ({size} bytes)")
        if opcode == _OP_MESSAGE:
            if length < _MESSAGE_HEAD.size:
                raise _damaged(path, at, "chunk", f"a message inside has {length} bytes")
            channel_id, _, log_time, _ = unpack(data, body)
            topic = channels.get(channel_id, "")
            if wanted is None or topic in wanted:
                yield RawMessage(topic, log_time, data[body + 22:pos])
        elif opcode == _OP_CHANNEL:
            try:
                channel = Channel.read(ReadDataStream(io.BytesIO(data[body:pos])))
            except (McapError, EOFError, struct.error, ValueError) as exc:
                raise _damaged(path, at, "chunk", f"a channel inside: {exc}") from None
            channels[channel.id] = channel.topic


def _chunk_data(path: Path, at: int, chunk: Chunk) -> tuple[bytes, int]:
    """The chunk's records, decompressed and checked against the chunk's size and CRC; never
    more than the size the chunk claims, at most :data:`MAX_CHUNK_BYTES`, is decompressed."""
    claimed = chunk.uncompressed_size
    if claimed > MAX_CHUNK_BYTES:
        raise _damaged(path, at, "chunk", f"it claims {claimed} bytes uncompressed (at most "
                                          f"{MAX_CHUNK_BYTES} are read)")
    try:
        data = _decompressed(chunk.compression, chunk.data, claimed + 1)
    except (zstandard.ZstdError, McapError, EOFError, ValueError, RuntimeError, OverflowError,
            MemoryError) as exc:
        raise _damaged(path, at, "chunk", f"{chunk.compression} data: "
                                          f"{str(exc) or type(exc).__name__}") from None
    if len(data) != claimed:
        raise _damaged(path, at, "chunk", "its data expands past the "
                       f"{claimed} bytes it claims (a compression bomb?); not read further"
                       if len(data) > claimed else
                       f"{len(data)} bytes decompressed, {claimed} expected")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise _damaged(path, at, "chunk", "its CRC does not match its records")
    return data, len(data)


class _Range:
    """``length`` bytes of the open file ``fh`` from where it stands, as a stream: what a
    decompressor reads of one attachment, and no further."""

    def __init__(self, fh: IO[bytes], length: int) -> None:
        self._fh = fh
        self._left = length

    def read(self, size: int = -1) -> bytes:
        data = self._fh.read(self._left if size < 0 else min(size, self._left))
        self._left -= len(data)
        return data


def read_attachment(path: str | Path, name: str, max_bytes: int = MAX_CHUNK_BYTES
                    ) -> bytes | None:
    """The attachment ``name`` of an MCAP file (``name.zst`` decompressed when only that is
    there), at most its first ``max_bytes`` bytes (decompressed as they are read: a bomb costs
    no more); None if it has neither, or the compressed one does not decompress. A damaged file
    is read up to the damage."""
    p = Path(path)
    found: dict[str, AttachmentAt] = {}
    with open_capture_file(p) as fh:
        with contextlib.suppress(CaptureError):
            for _, record in _records(p, fh):
                if isinstance(record, AttachmentAt) and record.name in (name, name + ".zst"):
                    found[record.name] = record
        at = found.get(name) or found.get(name + ".zst")
        if at is None:
            return None
        fh.seek(at.data_offset)
        if at.name == name:
            return fh.read(min(at.data_length, max_bytes))
        out = bytearray()
        try:
            source = cast(IO[bytes], _Range(fh, at.data_length))  # read() is all it needs
            with zstandard.ZstdDecompressor().stream_reader(source, closefd=False) as reader:
                while len(out) < max_bytes and (
                        piece := reader.read(min(max_bytes - len(out), 1 << 20))):
                    out += piece
        except zstandard.ZstdError:
            return None
        return bytes(out)


def _decompressed(compression: str, data: bytes, limit: int) -> bytes:
    """``data`` decompressed as ``compression`` says, streamed, at most ``limit`` bytes of it:
    what a chunk or an attachment expands to is never held beyond the bound."""
    if compression == "":
        return data[:limit]
    if compression == "zstd":
        with zstandard.ZstdDecompressor().stream_reader(data, read_across_frames=True) as reader:
            out = bytearray()
            while len(out) < limit and (piece := reader.read(min(limit - len(out), 1 << 20))):
                out += piece
            return bytes(out)
    if compression == "lz4":
        import lz4.frame  # type: ignore[import-untyped]  # a foreign writer's chunks only

        return bytes(lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=limit))
    raise McapError(f"unknown compression {compression!r}")
