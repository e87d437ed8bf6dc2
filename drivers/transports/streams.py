"""What the serial and raw TCP transports share: a byte pipe over an asyncio stream pair.

Subclasses say how to open the pair (:meth:`StreamTransport._connect`), how to word a loss, and
what tells that the peer is gone before a write; reading, writing, closing and the rule "after a
loss every read and write raises :class:`PortLostError` again" live here once.
"""

from __future__ import annotations

import abc
import asyncio

from armbench.drivers.model.errors import PortLostError
from armbench.drivers.model.settings import SerialSettings
from armbench.drivers.transports.base import READ_CHUNK, Transport

__all__ = ["CLOSE_TIMEOUT_S", "StreamTransport", "close_writer"]

CLOSE_TIMEOUT_S = 1.0
"""Seconds :meth:`StreamTransport.close` waits for the stream to close cleanly."""


async def close_writer(writer: asyncio.StreamWriter, timeout_s: float = CLOSE_TIMEOUT_S) -> None:
    """Close a stream writer and wait (at most ``timeout_s`` seconds) for it; never raises
    ``OSError`` or ``TimeoutError`` (the connection may already be gone)."""
    writer.close()
    try:
        async with asyncio.timeout(timeout_s):
            await writer.wait_closed()
    except (OSError, TimeoutError):
        pass


class StreamTransport(Transport):
    """A transport over an ``asyncio`` (reader, writer) pair."""

    #: Why the port is lost when a read finds the end of the stream.
    eof_reason = "end of file"

    def __init__(self, port: str, serial: SerialSettings) -> None:
        super().__init__(port, serial)
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._lost_reason: str | None = None

    @abc.abstractmethod
    async def _connect(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        """Open the stream pair; raises :class:`TransportError` naming the port on failure."""

    @abc.abstractmethod
    def _loss(self, exc: OSError) -> str:
        """Why the port is lost, worded for an ``OSError`` of a read or write."""

    def _gone(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> str | None:
        """Why the port is known to be lost before a write, or None."""
        return self.eof_reason if writer.is_closing() else None

    def _after_write(self, writer: asyncio.StreamWriter) -> str | None:
        """Why the port turned out lost by a write that raised nothing, or None."""
        return None

    @property
    def is_open(self) -> bool:
        return self._writer is not None and self._lost_reason is None

    async def open(self) -> None:
        if self._writer is not None:
            raise self._error("transport is already open")
        self._reader, self._writer = await self._connect()
        self._lost_reason = None

    async def read(self) -> bytes:
        reader = self._reader
        if reader is None:
            raise self._not_open()
        if self._lost_reason is not None:
            raise self._lost(self._lost_reason)
        try:
            data = await reader.read(READ_CHUNK)
        except OSError as exc:
            raise self._mark_lost(self._loss(exc)) from exc
        if not data:
            if self._reader is None:
                raise self._not_open()
            raise self._mark_lost(self.eof_reason)
        self.bytes_in += len(data)
        return data

    async def write(self, data: bytes) -> None:
        reader, writer = self._reader, self._writer
        if reader is None or writer is None:
            raise self._not_open()
        if self._lost_reason is not None:
            raise self._lost(self._lost_reason)
        gone = self._gone(reader, writer)
        if gone is not None:
            raise self._mark_lost(gone)
        try:
            writer.write(data)
            await writer.drain()
        except OSError as exc:
            raise self._mark_lost(self._loss(exc)) from exc
        gone = self._after_write(writer)
        if gone is not None:
            raise self._mark_lost(gone)
        self.bytes_out += len(data)

    async def close(self) -> None:
        writer = self._writer
        self._reader = self._writer = None
        if writer is not None:
            await close_writer(writer)

    def _mark_lost(self, reason: str) -> PortLostError:
        if self._lost_reason is None:
            self._lost_reason = reason
        return self._lost(self._lost_reason)
