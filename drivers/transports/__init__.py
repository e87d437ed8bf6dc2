"""Transports: one interface, chosen by the port string.

===============================  ==============================================================
port string                      transport
===============================  ==============================================================
``/dev/ttyUSB0``, ``COM3``,      :class:`~armbench.drivers.transports.serial_port.SerialTransport`
``/dev/pts/7`` (no scheme)       (a local serial port, via pyserial-asyncio-fast)
``socket://HOST:PORT``           :class:`~armbench.drivers.transports.tcp.TcpTransport` (raw TCP)
``rfc2217://HOST:PORT``          :class:`~armbench.drivers.transports.rfc2217.Rfc2217Transport`
                                 (telnet COM-PORT-OPTION, e.g. ser2net)
``fake://...``                   ``armbench.drivers.transports.fake:FakeTransport`` (in-process)
===============================  ==============================================================

:data:`TRANSPORTS` maps each URL scheme to ``"module:Class"``; the module is imported only when a
port of that scheme is opened, so adding a transport is adding one module and one entry here.
"""

from __future__ import annotations

import importlib
import re

from armbench.drivers.errors import TransportError
from armbench.drivers.settings import SerialSettings
from armbench.drivers.transports.base import READ_CHUNK, Transport

__all__ = [
    "READ_CHUNK",
    "SERIAL_TRANSPORT",
    "TRANSPORTS",
    "Transport",
    "open_transport",
    "scheme_of",
    "transport_class",
]

#: Transport of port strings without a ``scheme://`` prefix (device names).
SERIAL_TRANSPORT = "armbench.drivers.transports.serial_port:SerialTransport"

#: URL scheme → ``"module:Class"`` of its transport, imported lazily.
TRANSPORTS: dict[str, str] = {
    "socket": "armbench.drivers.transports.tcp:TcpTransport",
    "rfc2217": "armbench.drivers.transports.rfc2217:Rfc2217Transport",
    "fake": "armbench.drivers.transports.fake:FakeTransport",
    "avr": "armbench.drivers.transports.avr:AvrTransport",
}

_SCHEME_RE = re.compile(r"([A-Za-z][A-Za-z0-9+.-]*)://")


def scheme_of(port: str) -> str | None:
    """The lower-case URL scheme of ``port`` (``"socket"`` for ``socket://h:1``), None for a
    device name such as ``/dev/ttyUSB0`` or ``COM3``."""
    m = _SCHEME_RE.match(port)
    return m.group(1).lower() if m else None


def transport_class(port: str) -> type[Transport]:
    """The transport class serving ``port``; imports its module.

    Raises :class:`TransportError` naming the port for an unknown scheme or a transport module
    that cannot be imported.
    """
    scheme = scheme_of(port)
    if scheme is None:
        target = SERIAL_TRANSPORT
    else:
        found = TRANSPORTS.get(scheme)
        if found is None:
            known = ", ".join(f"{s}://" for s in sorted(TRANSPORTS))
            raise TransportError(port, f"unknown transport scheme {scheme}:// (known: {known}; "
                                       "no scheme means a serial device)")
        target = found
    module_name, _, class_name = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise TransportError(port, f"transport {target} is not available: {exc}") from exc
    cls = getattr(module, class_name, None)
    if not (isinstance(cls, type) and issubclass(cls, Transport)):
        raise TransportError(port, f"transport {target} is not a Transport class")
    return cls


def open_transport(port: str, serial: SerialSettings | None = None) -> Transport:
    """The transport for ``port`` with line settings ``serial`` (8N1 115200 by default), not yet
    opened: ``await t.open()`` or ``async with open_transport(...) as t``."""
    return transport_class(port)(port, serial if serial is not None else SerialSettings())
