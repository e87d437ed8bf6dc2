"""The hand-over of an in-process simulator's chunks straight to the host's receiver, counted.

Compiled (``cli/perf/hot_modules.py``): ``fake://`` hands its host hundreds of chunks a second
and a campaign millions, and compiled a chunk costs a count and a call, not an interpreted
frame. :class:`~armbench.fakes.links.in_process.InProcessTransport` attaches one to its peer
while a receiver takes the chunks and none is kept for a read.
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["CountedSink"]


class CountedSink:
    """Hands each chunk to ``receiver`` and counts its bytes (:attr:`bytes`)."""

    def __init__(self, receiver: Callable[[bytes], None]) -> None:
        self.receiver = receiver
        self.bytes = 0
        """Bytes handed over so far."""

    def __call__(self, data: bytes) -> None:
        self.bytes += len(data)
        self.receiver(data)
