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
                                 emulator, in-process; it lives with the emulator, found by its
                                 entry point)
===============================  ==============================================================

Transports are registered by scheme, as python-can registers its interfaces: each scheme is an
entry point of the group :data:`ENTRY_POINT_GROUP` (``armbench.transports``), armbench's own as
any other distribution's (:mod:`armbench.drivers.model.entry_points`), e.g. in a
``pyproject.toml``::

    [project.entry-points."armbench.transports"]
    can = "mypkg.transport:CanTransport"

A scheme is looked up when a port of it is opened, and only then is its module imported (so
pyserial is not imported for a TCP port, and the driver never imports the emulator unless a
``fake://`` port is opened). A device name has no scheme: it is the serial transport
(:data:`SERIAL_TRANSPORT`), which is no entry point.

The registered class also declares what the target behind its scheme can do (its clock, fresh
arms, workers, ground truth, power): :func:`armbench.drivers.transports.target.target_of` reads
it, and the bench asks that target, never the scheme.
"""

from __future__ import annotations

import importlib
import re
from typing import Final, TypeGuard

from armbench.drivers.model import entry_points
from armbench.drivers.model.errors import TransportError
from armbench.drivers.model.settings import SerialSettings
from armbench.drivers.transports.base import READ_CHUNK, Transport

__all__ = [
    "ENTRY_POINT_GROUP",
    "READ_CHUNK",
    "SERIAL_TRANSPORT",
    "Transport",
    "known_transports",
    "open_transport",
    "scheme_of",
    "transport_class",
]

#: Transport of port strings without a ``scheme://`` prefix (device names).
SERIAL_TRANSPORT = "armbench.drivers.transports.serial_port:SerialTransport"

#: Entry-point group under which distributions register transports by scheme.
ENTRY_POINT_GROUP: Final = "armbench.transports"

_SCHEME_RE = re.compile(r"([A-Za-z][A-Za-z0-9+.-]*)://")


def scheme_of(port: str) -> str | None:
    """The lower-case URL scheme of ``port`` (``"socket"`` for ``socket://h:1``), None for a
    device name such as ``/dev/ttyUSB0`` or ``COM3``."""
    m = _SCHEME_RE.match(port)
    return m.group(1).lower() if m else None


def known_transports() -> dict[str, str]:
    """Every registered scheme → ``"module:Class"`` (nothing imported)."""
    return {scheme: f"{ep.module}:{ep.attr}" for scheme, ep
            in entry_points.registered(ENTRY_POINT_GROUP, fold_case=True).items()}


def _is_transport_class(found: object) -> TypeGuard[type[Transport]]:
    return isinstance(found, type) and issubclass(found, Transport)


def transport_class(port: str) -> type[Transport]:
    """The transport class serving ``port``; imports its module.

    Raises :class:`TransportError` naming the port for an unknown scheme, or for a transport
    whose entry point cannot be loaded (naming the entry point).
    """
    scheme = scheme_of(port)
    if scheme is None:
        module_name, _, class_name = SERIAL_TRANSPORT.partition(":")
        try:
            serial: type[Transport] = getattr(importlib.import_module(module_name), class_name)
        except ImportError as exc:
            raise TransportError(port, f"transport {SERIAL_TRANSPORT} is not available: "
                                       f"{exc}") from exc
        return serial
    known_schemes = known_transports()
    if scheme not in known_schemes:
        known = ", ".join(f"{s}://" for s in sorted(known_schemes))
        raise TransportError(port, f"unknown transport scheme {scheme}:// (known: {known}; "
                                   "no scheme means a serial device)")
    try:
        return entry_points.load(ENTRY_POINT_GROUP, scheme, _is_transport_class,
                                 "a Transport class", fold_case=True)
    except entry_points.EntryPointError as exc:
        raise TransportError(port, f"transport {scheme}:// is not available: {exc}") from exc


def open_transport(port: str, serial: SerialSettings | None = None) -> Transport:
    """The transport for ``port`` with line settings ``serial`` (8N1 115200 by default), not yet
    opened: ``await t.open()`` or ``async with open_transport(...) as t``."""
    return transport_class(port)(port, serial if serial is not None else SerialSettings())
