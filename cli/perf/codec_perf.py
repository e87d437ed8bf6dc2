"""Codec throughput: replies decoded through the framer, commands built and encoded.

Bounds: decoding is compared with the bare ``bytes.split`` + ``int`` of the same frames, encoding
with bare ``%``-formatting of the same values; both measured here, in the same run.
"""

from __future__ import annotations

import math
import random

from armbench.cli.perf import Figure, PerfOptions, best_rate
from armbench.drivers.model.protocol import Command, Framer, Reply

__all__ = ["reply_stream", "run"]

CHUNK_BYTES = 64


def reply_stream(count: int, seed: int = 1) -> bytes:
    """A realistic reply stream: four joints moving in small steps, no line ends (as the firmware
    prints), ``count`` frames."""
    rng = random.Random(seed)
    q = [rng.uniform(0, 2 * math.pi) for _ in range(4)]
    out = []
    for _ in range(count):
        q = [(x + rng.uniform(-0.002, 0.002)) % (2 * math.pi) for x in q]
        out.append(Reply.from_rad(q).encode())
    return b"".join(out)


def _chunks(stream: bytes, size: int) -> list[bytes]:
    return [stream[i:i + size] for i in range(0, len(stream), size)]


def run(options: PerfOptions) -> list[Figure]:
    """Measure ``codec.decode_replies`` and ``codec.encode_commands``."""
    n = 20_000 if options.quick else 200_000
    stream = reply_stream(n)
    chunks = _chunks(stream, CHUNK_BYTES)

    def framed() -> int:
        framer = Framer("reply")
        count = 0
        for chunk in chunks:
            count += len(framer.feed(chunk))
        return count

    def bare_decode() -> int:
        count = 0
        for frame in stream.split(b"#")[:-1]:
            a, b, c, d = frame[1:].split(b",")
            int(a), int(b), int(c), int(d)
            count += 1
        return count

    rng = random.Random(2)
    targets = [([rng.uniform(-1.5, 1.5) for _ in range(4)], rng.randrange(1, 100))
               for _ in range(n // 4)]
    fmt = b"$%05d,%02d,%05d,%02d,%05d,%02d,%05d,%02d#"

    def encoded() -> int:
        for q, duty in targets:
            Command.from_rad(q, duty).encode()
        return len(targets)

    def bare_encode() -> int:
        for q, duty in targets:
            fmt % (round(q[0] % 6.283185307179586 * 1e4), duty,
                   round(q[1] % 6.283185307179586 * 1e4), duty,
                   round(q[2] % 6.283185307179586 * 1e4), duty,
                   round(q[3] % 6.283185307179586 * 1e4), duty)
        return len(targets)

    figures = []
    for name, fn, bound_fn, unit in (
        ("codec.decode_replies", framed, bare_decode, "replies/s"),
        ("codec.encode_commands", encoded, bare_encode, "commands/s"),
    ):
        value = bound = 0.0
        for _ in range(options.repeats):  # interleave so both see the same machine load
            value = max(value, best_rate(fn, 1))
            bound = max(bound, best_rate(bound_fn, 1))
        figures.append(Figure(name, value, unit, bound, value / bound))
    return figures
