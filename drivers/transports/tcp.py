"""Raw TCP transport: ``socket://HOST:PORT`` (a serial-to-Ethernet bridge in raw mode, the
emulator, ``ser2net`` with a plain ``tcp`` accepter). Bytes pass unchanged; the line settings are
the bridge's business and are ignored here.
"""

from __future__ import annotations

import asyncio

from armbench.drivers.model.errors import TransportError
from armbench.drivers.model.settings import SerialSettings
from armbench.drivers.transports.streams import CLOSE_TIMEOUT_S, StreamTransport, close_writer
from armbench.drivers.transports.url_parts import split_port

__all__ = [
    "CLOSE_TIMEOUT_S",
    "CONNECT_TIMEOUT_S",
    "TcpTransport",
    "close_writer",
    "parse_host_port",
]

CONNECT_TIMEOUT_S = 5.0
"""Seconds :meth:`TcpTransport.open` waits for the TCP connection."""


def parse_host_port(port: str) -> tuple[str, int]:
    """``(host, tcp_port)`` of ``scheme://HOST:PORT`` (IPv6 as ``[::1]``); raises
    :class:`TransportError` naming ``port`` when either is missing, the port is not 1..65535, or
    the URL holds more (a path, a query, a fragment, a user name: nothing reads them)."""
    scheme = port.partition("://")[0] or "scheme"
    url = split_port(port, f"{scheme}://HOST:PORT", address=True, query=False)
    try:
        tcp_port = url.port
    except ValueError as exc:
        raise TransportError(port, f"is not scheme://HOST:PORT ({exc})") from None
    if not url.hostname or tcp_port is None:
        raise TransportError(port, "is not scheme://HOST:PORT (host and TCP port are required)")
    if not 0 < tcp_port < 65536:
        raise TransportError(port, f"TCP port {tcp_port} is not 1..65535")
    return url.hostname, tcp_port


class TcpTransport(StreamTransport):
    """A raw TCP connection carrying the serial byte stream unchanged.

    The peer closing (EOF) or resetting the connection is a :class:`PortLostError`.
    """

    scheme = "socket"
    eof_reason = "connection closed by the peer"

    def __init__(self, port: str, serial: SerialSettings, *,
                 connect_timeout_s: float = CONNECT_TIMEOUT_S) -> None:
        super().__init__(port, serial)
        self.host, self.tcp_port = parse_host_port(port)
        self.connect_timeout_s = connect_timeout_s
        """Seconds :meth:`open` waits for the connection."""

    async def _connect(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        try:
            async with asyncio.timeout(self.connect_timeout_s):
                return await asyncio.open_connection(self.host, self.tcp_port)
        except TimeoutError:
            raise self._error(f"no TCP connection within {self.connect_timeout_s:g} s") from None
        except OSError as exc:
            raise self._error(f"cannot connect: {exc.strerror or exc}") from exc

    def _loss(self, exc: OSError) -> str:
        return f"connection lost: {exc.strerror or exc}"

    def _gone(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> str | None:
        return self.eof_reason if reader.at_eof() or writer.is_closing() else None
