"""atheris harness: ``armbench.drivers.model.protocol.Framer`` (both kinds) on arbitrary bytes in
arbitrary chunks.

Input layout (``atheris.FuzzedDataProvider`` takes integers from the end, bytes from the front)::

    <stream bytes> <chunk sizes: n bytes, each 1 + b % 64, used cyclically> <n = last byte % 16>

n = 0 feeds the stream in one piece. The same stream goes through a ``reply`` and a ``command``
framer, each fed once whole and once in the chunks. Invariants (any violation is a crash):

* ``feed``/``flush`` never raise; events are frames of the framer's kind or ``FrameError``;
* ``buffered < frame length`` after every feed, 0 after ``flush``;
* the frames are the same whole and chunked, in order, and each re-encodes to bytes found in the
  stream (in order, not overlapping);
* ``discarded_bytes <= len(stream)``; byte accounting closes: every byte that is not CR/LF is in a
  frame, discarded or buffered, and nothing is counted twice;
* ``frames``/``errors`` match the events; every ``FrameError.raw`` is a piece of the stream of at
  most 64 bytes and ``size >= len(raw)``.

Run: ``python fuzz/fuzz_framer.py -max_total_time=60 -rss_limit_mb=512 fuzz/corpus/framer``
"""

from __future__ import annotations

from collections.abc import Sequence

import atheris
from _harness import fuzz_main, split

with atheris.instrument_imports(include=["drivers"]):
    from armbench.drivers.model.protocol import (
        COMMAND_LEN,
        REPLY_LEN,
        Command,
        Event,
        FrameError,
        FrameKind,
        Framer,
        Reply,
    )

MAX_CHUNKS = 15


def _feed(kind: FrameKind, chunks: Sequence[bytes]) -> tuple[Framer, list[Event]]:
    framer = Framer(kind)
    flen = REPLY_LEN if kind == "reply" else COMMAND_LEN
    frame_type = Reply if kind == "reply" else Command
    events: list[Event] = []
    for chunk in chunks:
        new = framer.feed(chunk)
        for e in new:
            assert isinstance(e, frame_type | FrameError), (kind, e)
        assert framer.buffered < flen, (kind, framer.buffered)
        events += new
    return framer, events


def check_kind(kind: FrameKind, stream: bytes, chunks: Sequence[bytes]) -> None:
    """All invariants of one framer kind on one stream."""
    flen = REPLY_LEN if kind == "reply" else COMMAND_LEN
    whole, whole_events = _feed(kind, [stream])
    framer, events = _feed(kind, chunks)
    frames = [e for e in events if not isinstance(e, FrameError)]
    errors = [e for e in events if isinstance(e, FrameError)]
    assert frames == [e for e in whole_events if not isinstance(e, FrameError)], \
        f"{kind}: chunking changed the decoded frames"
    assert framer.frames == len(frames) == whole.frames
    assert framer.errors == len(errors)

    pos = 0
    for f in frames:
        wire = f.encode()
        assert len(wire) == flen
        at = stream.find(wire, pos)
        assert at >= 0, f"{kind}: frame {wire!r} is not in the input after offset {pos}"
        pos = at + flen

    crlf = stream.count(b"\r") + stream.count(b"\n")
    n = len(stream)
    accounted = framer.frames * flen + framer.discarded_bytes + framer.buffered
    assert framer.discarded_bytes <= n, (kind, framer.discarded_bytes, n)
    assert n - crlf <= accounted <= n, (kind, accounted, n, crlf)
    for e in errors:
        assert 0 < len(e.raw) <= 64 and e.size >= len(e.raw), e
        assert e.raw in stream, e
    assert sum(e.size for e in errors) + framer.frames * flen + framer.buffered <= n

    tail = framer.flush()
    assert framer.buffered == 0
    assert all(isinstance(e, FrameError) for e in tail)
    assert n - crlf <= framer.frames * flen + framer.discarded_bytes <= n
    assert framer.flush() == []


def test_one_input(data: bytes) -> None:
    fdp = atheris.FuzzedDataProvider(data)
    n_sizes = fdp.ConsumeIntInRange(0, MAX_CHUNKS)
    sizes = [fdp.ConsumeIntInRange(1, 64) for _ in range(n_sizes)]
    stream = fdp.ConsumeBytes(fdp.remaining_bytes())
    chunks = split(stream, sizes)
    check_kind("reply", stream, chunks)
    check_kind("command", stream, chunks)


if __name__ == "__main__":
    fuzz_main("framer", test_one_input)
