"""Raw TCP transport: ``socket://HOST:PORT`` (a serial-to-Ethernet bridge in raw mode, the
emulator, ``ser2net`` with a plain ``tcp`` accepter). Bytes pass unchanged; the line settings are
the bridge's business and are ignored here.
"""

from __future__ import annotations

import asyncio
import urllib.parse

from drivers.errors import PortLostError, TransportError
from drivers.settings import SerialSettings
from drivers.transports.base import READ_CHUNK, Transport

__all__ = [
    "CLOSE_TIMEOUT_S",
    "CONNECT_TIMEOUT_S",
    "TcpTransport",
    "close_writer",
    "parse_host_port",
]

CONNECT_TIMEOUT_S = 5.0
"""Seconds :meth:`TcpTransport.open` waits for the TCP connection."""
CLOSE_TIMEOUT_S = 1.0
"""Seconds :meth:`TcpTransport.close` waits for the socket to close cleanly."""


def parse_host_port(port: str) -> tuple[str, int]:
    """``(host, tcp_port)`` of ``scheme://HOST:PORT`` (IPv6 as ``[::1]``); raises
    :class:`TransportError` naming ``port`` when either is missing or the port is not 1..65535."""
    try:
        url = urllib.parse.urlsplit(port)
        tcp_port = url.port
    except ValueError as exc:
        raise TransportError(port, f"is not scheme://HOST:PORT ({exc})") from None
    if not url.hostname or tcp_port is None:
        raise TransportError(port, "is not scheme://HOST:PORT (host and TCP port are required)")
    if not 0 < tcp_port < 65536:
        raise TransportError(port, f"TCP port {tcp_port} is not 1..65535")
    return url.hostname, tcp_port


async def close_writer(writer: asyncio.StreamWriter, timeout_s: float = CLOSE_TIMEOUT_S) -> None:
    """Close a stream writer and wait (at most ``timeout_s`` seconds) for it; never raises
    ``OSError`` or ``TimeoutError`` (the connection may already be gone)."""
    writer.close()
    try:
        async with asyncio.timeout(timeout_s):
            await writer.wait_closed()
    except (OSError, TimeoutError):
        pass


class TcpTransport(Transport):
    """A raw TCP connection carrying the serial byte stream unchanged.

    The peer closing (EOF) or resetting the connection is a :class:`PortLostError`.
    """

    scheme = "socket"

    def __init__(self, port: str, serial: SerialSettings, *,
                 connect_timeout_s: float = CONNECT_TIMEOUT_S) -> None:
        super().__init__(port, serial)
        self.host, self.tcp_port = parse_host_port(port)
        self.connect_timeout_s = connect_timeout_s
        """Seconds :meth:`open` waits for the connection."""
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._lost_reason: str | None = None

    @property
    def is_open(self) -> bool:
        return self._writer is not None and self._lost_reason is None

    async def open(self) -> None:
        if self._writer is not None:
            raise self._error("transport is already open")
        try:
            async with asyncio.timeout(self.connect_timeout_s):
                reader, writer = await asyncio.open_connection(self.host, self.tcp_port)
        except TimeoutError:
            raise self._error(f"no TCP connection within {self.connect_timeout_s:g} s") from None
        except OSError as exc:
            raise self._error(f"cannot connect: {exc.strerror or exc}") from exc
        self._reader, self._writer = reader, writer
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
            raise self._mark_lost(f"connection lost: {exc.strerror or exc}") from exc
        if not data:
            if self._reader is None:
                raise self._not_open()
            raise self._mark_lost("connection closed by the peer")
        self.bytes_in += len(data)
        return data

    async def write(self, data: bytes) -> None:
        reader, writer = self._reader, self._writer
        if reader is None or writer is None:
            raise self._not_open()
        if self._lost_reason is not None:
            raise self._lost(self._lost_reason)
        if reader.at_eof() or writer.is_closing():
            raise self._mark_lost("connection closed by the peer")
        try:
            writer.write(data)
            await writer.drain()
        except OSError as exc:
            raise self._mark_lost(f"connection lost: {exc.strerror or exc}") from exc
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
