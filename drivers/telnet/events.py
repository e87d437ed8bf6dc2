"""Telnet and RFC 2217 events: what :meth:`~armbench.drivers.telnet.codec.TelnetCodec.receive_data`
returns, one immutable value per thing the peer did."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Literal

__all__ = [
    "ComPortReply",
    "ComPortRequest",
    "Command",
    "Data",
    "Event",
    "FlowControl",
    "LineState",
    "ModemState",
    "OptionDeclined",
    "OptionDisabled",
    "OptionEnabled",
    "OptionRefused",
    "ProtocolViolation",
    "Role",
    "Side",
    "Signature",
    "Subnegotiation",
    "coalesce",
]

Side = Literal["local", "remote"]
"""``local``: an option in effect on our side (we send WILL/WONT, the peer DO/DONT);
``remote``: on the peer's side (the peer sends WILL/WONT, we DO/DONT)."""
Role = Literal["client", "server"]



# --- events -------------------------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Data:
    """Payload bytes from the peer, already unescaped."""

    data: bytes


@dataclass(frozen=True, slots=True)
class Command:
    """A telnet command other than negotiation (NOP, BRK, IP, AYT, GA, DM, ...)."""

    code: int


@dataclass(frozen=True, slots=True)
class OptionEnabled:
    """An option is now in effect on ``side``."""

    option: int
    side: Side


@dataclass(frozen=True, slots=True)
class OptionDisabled:
    """An option that was in effect on ``side`` is no longer."""

    option: int
    side: Side


@dataclass(frozen=True, slots=True)
class OptionRefused:
    """The peer refused our request to enable ``option`` on ``side``."""

    option: int
    side: Side


@dataclass(frozen=True, slots=True)
class OptionDeclined:
    """We refused the peer's offer or request for ``option`` on ``side`` (not in our accept set)."""

    option: int
    side: Side


@dataclass(frozen=True, slots=True)
class Subnegotiation:
    """A complete ``IAC SB option ... IAC SE`` for an option this codec does not decode."""

    option: int
    payload: bytes


@dataclass(frozen=True, slots=True)
class ComPortReply:
    """A server's answer to a COM-PORT setting (client role).

    ``command`` is the client command it answers (``ComPort.SET_BAUDRATE`` = 1, ...), ``value``
    the setting now in effect (baud rate in bit/s for SET-BAUDRATE, else the RFC 2217 code).
    """

    command: int
    value: int


@dataclass(frozen=True, slots=True)
class ComPortRequest:
    """A client's COM-PORT setting request (server role); ``value`` 0 asks for the current one."""

    command: int
    value: int


@dataclass(frozen=True, slots=True)
class Signature:
    """COM-PORT SIGNATURE text; empty is a request for the peer's signature."""

    text: bytes


@dataclass(frozen=True, slots=True)
class LineState:
    """NOTIFY-LINESTATE: the line-state bits (``ComPort.LINE_*``)."""

    state: int


@dataclass(frozen=True, slots=True)
class ModemState:
    """NOTIFY-MODEMSTATE: the modem-state bits (``ComPort.MODEM_*`` in the upper nibble)."""

    state: int


@dataclass(frozen=True, slots=True)
class FlowControl:
    """FLOWCONTROL-SUSPEND (``suspended``) or FLOWCONTROL-RESUME from the peer."""

    suspended: bool


@dataclass(frozen=True, slots=True)
class ProtocolViolation:
    """Malformed or out-of-protocol input; reported, counted and otherwise ignored."""

    reason: str


Event = (Data | Command | OptionEnabled | OptionDisabled | OptionRefused | OptionDeclined
         | Subnegotiation | ComPortReply | ComPortRequest | Signature | LineState | ModemState
         | FlowControl | ProtocolViolation)


def coalesce(events: Iterable[Event]) -> list[Event]:
    """``events`` with adjacent :class:`Data` joined and empty ones dropped: where a stream is
    cut into chunks changes only how its payload is split into ``Data`` events, so two feedings
    of the same bytes give equal lists after this."""
    out: list[Event] = []
    for e in events:
        if isinstance(e, Data):
            if not e.data:
                continue
            if out and isinstance(out[-1], Data):
                out[-1] = Data(out[-1].data + e.data)
                continue
        out.append(e)
    return out
