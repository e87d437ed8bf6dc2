"""RFC 2217 COM-PORT-OPTION (telnet option 44): its command codes, the serial settings it
carries, the messages a codec queues to set them and the decoding of the ones it receives."""

from __future__ import annotations

import abc
from typing import Final

from armbench.drivers.telnet.events import (
    ComPortReply,
    ComPortRequest,
    Event,
    FlowControl,
    LineState,
    ModemState,
    ProtocolViolation,
    Role,
    Signature,
)

__all__ = [
    "COM_PORT_OPTION",
    "PARITY_CODES",
    "STOPSIZE_CODES",
    "ComPort",
    "ComPortOptions",
    "check_byte",
    "decode_com_port",
]

#: The telnet option number of RFC 2217.
COM_PORT_OPTION: Final = 44


class ComPort:
    """RFC 2217 COM-PORT-OPTION command codes as sent by the client (the server adds 100)."""

    SIGNATURE: Final = 0
    SET_BAUDRATE: Final = 1
    SET_DATASIZE: Final = 2
    SET_PARITY: Final = 3
    SET_STOPSIZE: Final = 4
    SET_CONTROL: Final = 5
    NOTIFY_LINESTATE: Final = 6
    NOTIFY_MODEMSTATE: Final = 7
    FLOWCONTROL_SUSPEND: Final = 8
    FLOWCONTROL_RESUME: Final = 9
    SET_LINESTATE_MASK: Final = 10
    SET_MODEMSTATE_MASK: Final = 11
    PURGE_DATA: Final = 12
    SERVER_OFFSET: Final = 100

    # SET-CONTROL values (a few; see RFC 2217 for the full table)
    CONTROL_QUERY_FLOW: Final = 0
    CONTROL_NO_FLOW: Final = 1
    CONTROL_BREAK_ON: Final = 5
    CONTROL_BREAK_OFF: Final = 6
    CONTROL_DTR_ON: Final = 8
    CONTROL_DTR_OFF: Final = 9
    CONTROL_RTS_ON: Final = 11
    CONTROL_RTS_OFF: Final = 12

    # NOTIFY-MODEMSTATE bits
    MODEM_CD: Final = 0x80
    MODEM_RI: Final = 0x40
    MODEM_DSR: Final = 0x20
    MODEM_CTS: Final = 0x10

    # NOTIFY-LINESTATE bits
    LINE_TIMEOUT: Final = 0x80
    LINE_TSRE: Final = 0x40
    LINE_THRE: Final = 0x20
    LINE_BREAK: Final = 0x10
    LINE_FRAMING_ERROR: Final = 0x08
    LINE_PARITY_ERROR: Final = 0x04
    LINE_OVERRUN_ERROR: Final = 0x02
    LINE_DATA_READY: Final = 0x01


#: SET-PARITY value of each :class:`~armbench.drivers.model.settings.SerialSettings` parity letter.
PARITY_CODES: Final[dict[str, int]] = {"N": 1, "O": 2, "E": 3, "M": 4, "S": 5}
#: SET-STOPSIZE value of each stop-bit count.
STOPSIZE_CODES: Final[dict[float, int]] = {1: 1, 2: 2, 1.5: 3}



class ComPortOptions(abc.ABC):
    """The COM-PORT messages of a telnet codec in ``role``: each queued as a subnegotiation of
    :data:`COM_PORT_OPTION` (the codec provides :meth:`send_subnegotiation`)."""

    role: Role

    @abc.abstractmethod
    def send_subnegotiation(self, option: int, payload: bytes) -> None:
        """Queue ``IAC SB option payload IAC SE``."""

    def send_com_port(self, command: int, value: bytes = b"") -> None:
        """Queue a COM-PORT-OPTION message; ``command`` is the client code, 100 is added in the
        server role."""
        if not 0 <= command <= ComPort.PURGE_DATA:
            raise ValueError(f"COM-PORT command: {command} is not 0..12")
        code = command + (ComPort.SERVER_OFFSET if self.role == "server" else 0)
        self.send_subnegotiation(COM_PORT_OPTION, bytes((code,)) + bytes(value))

    def set_baudrate(self, baud: int) -> None:
        """Queue SET-BAUDRATE (bit/s; 0 queries). In the server role: the reply."""
        if not 0 <= baud <= 0xFFFF_FFFF:
            raise ValueError(f"baud rate: {baud} does not fit in 32 bits")
        self.send_com_port(ComPort.SET_BAUDRATE, baud.to_bytes(4, "big"))

    def set_datasize(self, bits: int) -> None:
        """Queue SET-DATASIZE (5..8 data bits; 0 queries)."""
        if bits not in (0, 5, 6, 7, 8):
            raise ValueError(f"data size: {bits} is not 5..8 (or 0 to query)")
        self.send_com_port(ComPort.SET_DATASIZE, bytes((bits,)))

    def set_parity(self, parity: str | int) -> None:
        """Queue SET-PARITY from a letter N/O/E/M/S or an RFC 2217 code (0 queries)."""
        code = PARITY_CODES.get(parity) if isinstance(parity, str) else parity
        if code is None or not 0 <= code <= 5:
            raise ValueError(f"parity: {parity!r} is not one of N, O, E, M, S")
        self.send_com_port(ComPort.SET_PARITY, bytes((code,)))

    def set_stopsize(self, stopbits: float) -> None:
        """Queue SET-STOPSIZE for 1, 1.5 or 2 stop bits (0 queries)."""
        code = 0 if stopbits == 0 else STOPSIZE_CODES.get(stopbits)
        if code is None:
            raise ValueError(f"stop bits: {stopbits!r} is not 1, 1.5 or 2")
        self.send_com_port(ComPort.SET_STOPSIZE, bytes((code,)))

    def set_control(self, value: int) -> None:
        """Queue SET-CONTROL (flow control, BREAK, DTR, RTS; ``ComPort.CONTROL_*``)."""
        check_byte("control value", value)
        self.send_com_port(ComPort.SET_CONTROL, bytes((value,)))

    def flowcontrol(self, suspend: bool) -> None:
        """Queue FLOWCONTROL-SUSPEND (True) or FLOWCONTROL-RESUME (False)."""
        self.send_com_port(ComPort.FLOWCONTROL_SUSPEND if suspend else ComPort.FLOWCONTROL_RESUME)


def decode_com_port(payload: bytes, role: Role) -> list[Event]:
    """The events of a received COM-PORT subnegotiation ``payload`` (code and value) for a codec
    in ``role``; malformed payloads give :class:`ProtocolViolation` events (to be counted)."""
    if not payload:
        return [ProtocolViolation("empty COM-PORT-OPTION subnegotiation")]
    code, value = payload[0], payload[1:]
    offset = ComPort.SERVER_OFFSET if role == "client" else 0
    command = code - offset
    if not 0 <= command <= ComPort.PURGE_DATA:
        return [ProtocolViolation(f"COM-PORT-OPTION command {code} is not expected by a {role}")]
    if command == ComPort.SIGNATURE:
        return [Signature(value)]
    if command in (ComPort.FLOWCONTROL_SUSPEND, ComPort.FLOWCONTROL_RESUME):
        events: list[Event] = []
        if value:
            events.append(ProtocolViolation(f"COM-PORT-OPTION command {code} has {len(value)} "
                                            "unexpected value bytes"))
        events.append(FlowControl(command == ComPort.FLOWCONTROL_SUSPEND))
        return events
    size = 4 if command == ComPort.SET_BAUDRATE else 1
    if len(value) != size:
        return [ProtocolViolation(f"COM-PORT-OPTION command {code} has {len(value)} value "
                                  f"bytes, expected {size}")]
    number = int.from_bytes(value, "big")
    if command == ComPort.NOTIFY_LINESTATE:
        return [LineState(number)]
    if command == ComPort.NOTIFY_MODEMSTATE:
        return [ModemState(number)]
    if role == "client":
        return [ComPortReply(command, number)]
    return [ComPortRequest(command, number)]


def check_byte(what: str, value: int) -> None:
    """Raise :class:`ValueError` unless ``value`` is a byte (0..255)."""
    if not 0 <= value <= 255:
        raise ValueError(f"{what}: {value} is not a byte (0..255)")
