"""An HTTP power relay in front of the emulated arm's power line (``armbench emulate --relay``).

A lab switches its arm's power through a relay on the network; this one switches the emulator's,
so the lab's power commands and its labgrid place (``NetworkPowerPort``, model ``simplerest``)
can be tried without hardware. It answers the two dialects a lab's relay most often speaks:

- labgrid's ``simplerest`` (any "REST relay"): ``GET /relay/INDEX/1`` on, ``GET /relay/INDEX/0``
  off, ``GET /relay/INDEX`` the state (``1`` or ``0``);
- Tasmota's HTTP API: ``GET /cm?cmnd=Power%20On``, ``Power%20Off``, ``Power`` (the state), each
  answered ``{"POWER":"ON"}`` or ``{"POWER":"OFF"}``.

One request per connection, read up to :data:`MAX_REQUEST_BYTES`; anything else is answered 404,
a request that is too long or not HTTP 400. The relay has one channel: every index switches it.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
from collections.abc import Callable
from urllib.parse import parse_qs, urlsplit

__all__ = ["MAX_REQUEST_BYTES", "RelayServer", "relay_answer"]

#: The longest request head the relay reads (bytes): a relay's requests are one short line.
MAX_REQUEST_BYTES = 8192
#: Seconds a client may take to send its request.
_READ_TIMEOUT_S = 10.0
_REST = re.compile(r"/relay/(\d+)(?:/([01]))?/?")


def relay_answer(target: str, powered: Callable[[], bool],
                 switch: Callable[[bool], None]) -> tuple[int, str, str]:
    """The answer to ``GET target``: ``(status, content type, body)``; switches the power through
    ``switch`` when the request says so."""
    url = urlsplit(target)
    rest = _REST.fullmatch(url.path)
    if rest is not None:
        if rest.group(2) is not None:
            switch(rest.group(2) == "1")
        return 200, "text/plain", "1" if powered() else "0"
    if url.path == "/cm":
        command = " ".join(parse_qs(url.query).get("cmnd", [""])[-1].split()).lower()
        if command in ("power on", "power1 on", "power 1", "power1 1"):
            switch(True)
        elif command in ("power off", "power1 off", "power 0", "power1 0"):
            switch(False)
        elif command not in ("power", "power1"):
            return 400, "application/json", json.dumps({"Command": "Unknown"})
        return 200, "application/json", json.dumps({"POWER": "ON" if powered() else "OFF"})
    return 404, "text/plain", "not a relay path: /relay/INDEX[/0|1] or /cm?cmnd=Power%20On|Off"


class RelayServer:
    """Serves :func:`relay_answer` over HTTP on ``host:port`` (0: a free port) on the running
    loop; ``powered()`` reads the power line, ``switch(on)`` sets it."""

    def __init__(self, powered: Callable[[], bool], switch: Callable[[bool], None],
                 host: str, port: int) -> None:
        self.powered = powered
        self.switch = switch
        self.host = host
        self.port = port
        self._server: asyncio.Server | None = None

    async def start(self) -> tuple[str, int]:
        """Listen; the address it listens on."""
        self._server = await asyncio.start_server(self._serve, self.host, self.port,
                                                  limit=MAX_REQUEST_BYTES)
        host, port = self._server.sockets[0].getsockname()[:2]
        return str(host), int(port)

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            async with asyncio.timeout(_READ_TIMEOUT_S):
                head = await reader.readuntil(b"\r\n\r\n")
            method, target, version = head.split(b"\r\n", 1)[0].decode("ascii").split(" ")
            if not version.startswith("HTTP/") or method != "GET":
                raise ValueError(method)
            status, kind, body = relay_answer(target, self.powered, self.switch)
        except (ValueError, UnicodeDecodeError, asyncio.IncompleteReadError,
                asyncio.LimitOverrunError, TimeoutError):
            status, kind, body = 400, "text/plain", "bad request"
        data = body.encode()
        writer.write(f"HTTP/1.1 {status} {'OK' if status == 200 else 'Error'}\r\n"
                     f"Content-Type: {kind}\r\nContent-Length: {len(data)}\r\n"
                     "Connection: close\r\n\r\n".encode() + data)
        with contextlib.suppress(ConnectionError):
            await writer.drain()
        writer.close()
        with contextlib.suppress(ConnectionError):
            await writer.wait_closed()
