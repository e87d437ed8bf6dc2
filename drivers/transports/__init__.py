"""Transports: one interface, chosen by the port string.

===============================  ==============================================================
port string                      transport
===============================  ==============================================================
``/dev/ttyUSB0``, ``COM3``,      :class:`~armbench.drivers.transports.serial_port.SerialTransport`
``/dev/pts/7`` (no scheme)       (a local serial port, via pyserial-asyncio-fast)
``socket://HOST:PORT``           :class:`~armbench.drivers.transports.tcp.TcpTransport` (raw TCP)
``rfc2217://HOST:PORT``          :class:`~armbench.drivers.transports.rfc2217.Rfc2217Transport`
                                 (telnet COM-PORT-OPTION, e.g. ser2net)
``fake://...``                   ``armbench.fakes.links.fake_transport:FakeTransport`` (the
emulator,
                                 in-process; it lives with the emulator, registered by name)
===============================  ==============================================================

Transports are registered by scheme, as python-can registers its interfaces: :data:`TRANSPORTS`
holds the built-in ones as ``"module:Class"`` strings, and other distributions add schemes as
entry points of the group :data:`ENTRY_POINT_GROUP` (``armbench.transports``), e.g. in their
``pyproject.toml``::

    [project.entry-points."armbench.transports"]
    can = "mypkg.transport:CanTransport"

A scheme is looked up when a port of it is opened, and only then is its module imported (so
pyserial is not imported for a TCP port, and the driver never imports the emulator unless a
``fake://`` port is opened). Built-in schemes win over entry points of the same name.

The registered class also declares what the target behind its scheme can do (its clock, fresh
arms, workers, ground truth, power): :func:`armbench.drivers.transports.target.target_of` reads
it, and the bench asks that target, never the scheme.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import re
from typing import Final

from armbench.drivers.model.errors import TransportError
from armbench.drivers.model.settings import SerialSettings
from armbench.drivers.transports.base import READ_CHUNK, Transport

__all__ = [
    "ENTRY_POINT_GROUP",
    "READ_CHUNK",
    "SERIAL_TRANSPORT",
    "TRANSPORTS",
    "Transport",
    "known_transports",
    "open_transport",
    "scheme_of",
    "transport_class",
]

#: Transport of port strings without a ``scheme://`` prefix (device names).
SERIAL_TRANSPORT = "armbench.drivers.transports.serial_port:SerialTransport"

#: The built-in URL schemes → ``"module:Class"`` of their transports, imported lazily. The same
#: are declared as entry points in ``pyproject.toml``; listed here too so that they work from a
#: source tree whose installed metadata is older.
TRANSPORTS: dict[str, str] = {
    "socket": "armbench.drivers.transports.tcp:TcpTransport",
    "rfc2217": "armbench.drivers.transports.rfc2217:Rfc2217Transport",
    "fake": "armbench.fakes.links.fake_transport:FakeTransport",
    "labgrid": "armbench.drivers.transports.labgrid:LabgridTransport",
    "avr": "armbench.fakes.avr.avr_transport:AvrTransport",
}

#: Entry-point group under which distributions register transports by scheme.
ENTRY_POINT_GROUP: Final = "armbench.transports"

_SCHEME_RE = re.compile(r"([A-Za-z][A-Za-z0-9+.-]*)://")


def scheme_of(port: str) -> str | None:
    """The lower-case URL scheme of ``port`` (``"socket"`` for ``socket://h:1``), None for a
    device name such as ``/dev/ttyUSB0`` or ``COM3``."""
    m = _SCHEME_RE.match(port)
    return m.group(1).lower() if m else None


def _entry_points() -> dict[str, str]:
    """Schemes registered as entry points of :data:`ENTRY_POINT_GROUP` → ``"module:Class"``."""
    return {ep.name.lower(): f"{ep.module}:{ep.attr}"
            for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def known_transports() -> dict[str, str]:
    """Every registered scheme → ``"module:Class"``: the entry points, and the built-ins over
    them."""
    return {**_entry_points(), **TRANSPORTS}


def transport_class(port: str) -> type[Transport]:
    """The transport class serving ``port``; imports its module.

    Raises :class:`TransportError` naming the port for an unknown scheme or a transport module
    that cannot be imported.
    """
    scheme = scheme_of(port)
    if scheme is None:
        target = SERIAL_TRANSPORT
    else:
        found = TRANSPORTS.get(scheme) or _entry_points().get(scheme)
        if found is None:
            known = ", ".join(f"{s}://" for s in sorted(known_transports()))
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
