"""The master board's UART as the host sees it: bytes take the time the baud rate implies.

Host → master: each byte completes one byte time after the previous one on the line; the master's
loop reads what has completed into the Arduino core's receive buffer, and bytes that arrive while
that buffer is full are dropped (counted in ``rx_overflow_bytes``), as on a real ATmega328P.

Master → host: ``write`` queues bytes behind what is still on the line and returns when the rest
fits the transmit buffer (a longer print blocks the loop, as ``Serial.print`` does); the bytes reach
the host when their last bit has left, as one chunk, through a ``call_at`` on the running loop.
All computed from timestamps, never per byte in a loop of the event loop.
"""

from __future__ import annotations

import asyncio
import contextvars
import math
from collections import deque
from collections.abc import Callable
from typing import Any

__all__ = ["Uart"]

Deliver = Callable[[bytes], None]
# (data, t_s) -> [(extra delay s, chunk)]: how a chunk to the host is cut, delayed or altered.
TxFilter = Callable[[bytes, float], list[tuple[float, bytes]]]
# (data, t_s) -> data: what a host write turns into on the way to the board.
RxFilter = Callable[[bytes, float], bytes]


class Uart:
    """One serial line between the host and the master board."""

    def __init__(self, byte_s: float, rx_buffer_bytes: int = 64, tx_buffer_bytes: int = 64) -> None:
        self.byte_s = byte_s
        self.rx_buffer_bytes = rx_buffer_bytes
        self.tx_buffer_bytes = tx_buffer_bytes
        self._rx: deque[tuple[float, bytes]] = deque()  # (start of first byte, bytes)
        self._rx_line_free = -math.inf
        self._tx_line_free = -math.inf
        self.host_sink: Deliver | None = None
        self.on_delivered: Callable[[Any], None] | None = None  # gets the tag of a write
        self.tx_filter: TxFilter | None = None
        self.rx_filter: RxFilter | None = None
        self.rx_tap: Callable[[float, bytes], None] | None = None
        """Called with the time and the bytes of each read of the master that finds bytes on the
        line (those it took, maybe none): an observer of what the firmware takes."""
        self.rx_event = asyncio.Event()
        self.rx_bytes = 0
        self.rx_overflow_bytes = 0
        self.rx_lost_bytes = 0
        """Bytes that arrived while the master's receiver was off (unpowered, booting)."""
        self._rx_enabled_s = math.inf
        self.tx_bytes = 0
        self.tx_dropped_bytes = 0
        """Bytes the master printed that no host received (none connected, or power cut)."""
        self.before_deliver: Callable[[float], None] | None = None
        """Called with the loop's time before a chunk reaches the host (deferred main loops)."""
        self.pending_delivery_s = -math.inf
        """When the last unfiltered write reaches the host; -inf after a filtered one."""
        self._generation = 0
        self._loop: asyncio.AbstractEventLoop | None = None  # the master's, from Serial.begin()
        self._context: contextvars.Context | None = None

    # host side ---------------------------------------------------------------------------------
    def host_write(self, data: bytes, t_s: float) -> None:
        """The host sends ``data`` at ``t_s``: the bytes queue behind what is on the line."""
        if self.rx_filter is not None:
            data = self.rx_filter(data, t_s)
        if not data:
            return
        start = max(t_s, self._rx_line_free)
        self._rx.append((start, bytes(data)))
        self._rx_line_free = start + len(data) * self.byte_s
        self.rx_event.set()

    def discard_unsent(self, t_s: float) -> int:
        """Forget the host's bytes that have not begun on the line by ``t_s`` (their sender has
        gone, as a serial port's buffer is flushed when it is closed); returns how many."""
        rx = self._rx
        dropped = 0
        while rx and rx[-1][0] >= t_s:
            dropped += len(rx.pop()[1])
        if rx:
            start, data = rx[-1]
            begun = min(len(data), math.ceil((t_s - start) / self.byte_s - 1e-9))
            dropped += len(data) - begun
            rx[-1] = (start, data[:begun])
            self._rx_line_free = start + begun * self.byte_s
        else:
            self._rx_line_free = min(self._rx_line_free, t_s)
            self.rx_event.clear()
        return dropped

    # master side -------------------------------------------------------------------------------
    def read_available(self, t_s: float, continuous_since: float | None = None) -> bytes:
        """Bytes received by ``t_s`` since the last read, after receive-buffer overflow.

        Bytes completing after ``continuous_since`` were read as they came (a blocking read),
        so they cannot overflow the buffer.
        """
        rx = self._rx
        if not rx:
            return b""
        out = bytearray()
        room = self.rx_buffer_bytes
        byte_s = self.byte_s
        while rx:
            start, data = rx[0]
            done = int((t_s - start) / byte_s + 1e-9)
            if done <= 0:
                break
            done = min(done, len(data))
            if start < self._rx_enabled_s:  # bytes complete before Serial.begin() are lost
                lost = min(done, max(0, int((self._rx_enabled_s - start) / byte_s + 1e-9)))
                self.rx_lost_bytes += lost
                chunk = data[lost:done]
            else:
                chunk = data[:done]
            if continuous_since is None:
                keep = chunk[:room]
            else:
                # bytes completed before the blocking read began are subject to overflow
                early = max(0, min(done, int((continuous_since - start) / byte_s + 1e-9)))
                keep = chunk[:min(early, room)] + chunk[early:]
            room = max(0, room - len(keep))
            self.rx_overflow_bytes += len(chunk) - len(keep)
            out += keep
            if done == len(data):
                rx.popleft()
            else:
                rx[0] = (start + done * byte_s, data[done:])
                break
        if not rx:
            self.rx_event.clear()
        self.rx_bytes += len(out)
        if self.rx_tap is not None:
            self.rx_tap(t_s, bytes(out))
        return bytes(out)

    def time_of_next(self, byte: int) -> float | None:
        """When the next pending (unread) occurrence of ``byte`` will have completed."""
        for start, data in self._rx:
            i = data.find(byte)
            if i >= 0:
                return start + (i + 1) * self.byte_s
        return None

    def write(self, data: bytes, t_s: float, tag: object = None) -> float:
        """The master prints ``data`` at ``t_s``; returns when the print call returns.

        ``tag`` (if not None) is handed to ``on_delivered`` when the last byte reaches the host.
        """
        byte_s = self.byte_s
        free = self._tx_line_free
        queued = (free - t_s) / byte_s if free > t_s else 0.0
        start = free if free > t_s else t_s
        done = start + len(data) * byte_s
        self._tx_line_free = done
        self.tx_bytes += len(data)
        loop = self._loop
        assert loop is not None, "Uart.begin() first"
        if self.tx_filter is None:
            loop.call_at(done, self._deliver, self._generation, data, tag, context=self._context)
            self.pending_delivery_s = done
        else:
            self.pending_delivery_s = -math.inf
            pieces = self.tx_filter(data, done)
            for k, (delay_s, chunk) in enumerate(pieces):
                loop.call_at(done + delay_s, self._deliver, self._generation, chunk,
                             tag if k == len(pieces) - 1 else None, context=self._context)
        overflow = queued + len(data) - self.tx_buffer_bytes
        return t_s + overflow * byte_s if overflow > 0 else t_s

    def _deliver(self, generation: int, data: bytes, tag: object) -> None:
        if generation != self._generation:
            self.tx_dropped_bytes += len(data)
            return
        if self.before_deliver is not None:
            assert self._loop is not None
            self.before_deliver(self._loop.time())
        sink = self.host_sink
        if sink is None:
            self.tx_dropped_bytes += len(data)
            return
        if tag is not None and self.on_delivered is not None:
            self.on_delivered(tag)  # first: the host may judge the reply as it takes it in
        sink(data)

    def cut(self) -> None:
        """The board lost power: bytes still on the line never arrive, the line is idle, and the
        receiver is off until the next :meth:`begin`."""
        self._generation += 1
        self._tx_line_free = -math.inf
        self.pending_delivery_s = -math.inf
        self._rx_enabled_s = math.inf

    def begin(self, t_s: float) -> None:
        """``Serial.begin()`` at ``t_s`` on the running loop: bytes completing from now on are
        received; what the master prints is delivered on that loop."""
        self._rx_enabled_s = t_s
        self._loop = asyncio.get_running_loop()
        self._context = contextvars.copy_context()  # one for every delivery: no copy per call_at

    @property
    def rx_line_free_s(self) -> float:
        """When the host's last byte will have arrived."""
        return self._rx_line_free
