"""Sans-I/O telnet (RFC 854/855) codec, RFC 2217 aware (:mod:`.comport`); events in :mod:`.events`.

Bytes in, events out; bytes to send queued for the caller. No sockets, no clocks, no tasks: the
asyncio RFC 2217 client (:mod:`armbench.drivers.transports.rfc2217`) and the tests drive the same
object, in the style of h11::

    codec = TelnetCodec()
    codec.enable_local(COM_PORT_OPTION)       # queue IAC WILL COM-PORT-OPTION
    sock.send(codec.data_to_send())
    for event in codec.receive_data(sock.recv(4096)):
        ...                                   # Data, OptionEnabled, ComPortReply, ...
    sock.send(codec.data_to_send())           # answers to the peer's negotiation, if any

What it does:

* **IAC escaping** both ways: 0xFF in data is sent as ``IAC IAC`` and ``IAC IAC`` received is one
  0xFF data byte. While BINARY is not in effect in a direction, a bare CR is sent as ``CR NUL`` and
  ``CR NUL`` received is one CR (RFC 854), so data stays 8-bit exact either way.
* **Option negotiation** with the Q method of RFC 1143 (states NO/YES/WANTNO/WANTYES and a queue
  bit per option and side), which never loops and never answers an acknowledgement. Options the
  peer offers that are not in the accept sets are refused (DONT/WONT) and reported.
* **Subnegotiation** ``IAC SB <option> ... IAC SE`` with ``IAC IAC`` unescaping; the parser is a
  byte-level state machine, so input split at any byte gives the same events. A payload longer
  than :data:`MAX_SUBNEGOTIATION` bytes is dropped and reported.
* **RFC 2217** (option 44): SIGNATURE, SET-BAUDRATE, SET-DATASIZE, SET-PARITY, SET-STOPSIZE,
  SET-CONTROL, NOTIFY-LINESTATE, NOTIFY-MODEMSTATE, FLOWCONTROL-SUSPEND/RESUME,
  SET-LINESTATE-MASK, SET-MODEMSTATE-MASK and PURGE-DATA, in both roles (a client sends ``code``
  and receives ``code + 100``; a server the other way round).

:meth:`TelnetCodec.receive_data` never raises on wire bytes: malformed input (a stray SE, an
unterminated subnegotiation, a COM-PORT message of the wrong length, a negotiation that breaks
RFC 1143) becomes a :class:`ProtocolViolation` event and is counted in ``violations``. Only
misuse of the API (a baud rate that does not fit in 32 bits, ...) raises :class:`ValueError`.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Final

from armbench.drivers.telnet.comport import (
    COM_PORT_OPTION,
    ComPortOptions,
    check_byte,
    decode_com_port,
)
from armbench.drivers.telnet.events import (
    Command,
    Data,
    Event,
    OptionDeclined,
    OptionDisabled,
    OptionEnabled,
    OptionRefused,
    ProtocolViolation,
    Role,
    Side,
    Subnegotiation,
)

__all__ = [
    "AO",
    "AYT",
    "BINARY",
    "BRK",
    "DM",
    "DO",
    "DONT",
    "EC",
    "ECHO",
    "EL",
    "GA",
    "IAC",
    "IP",
    "MAX_SUBNEGOTIATION",
    "NOP",
    "SB",
    "SE",
    "SGA",
    "WILL",
    "WONT",
    "TelnetCodec",
    "escape",
    "unescape",
]

# --- telnet commands (RFC 854) ------------------------------------------------------------------
SE: Final = 240
NOP: Final = 241
DM: Final = 242
BRK: Final = 243
IP: Final = 244
AO: Final = 245
AYT: Final = 246
EC: Final = 247
EL: Final = 248
GA: Final = 249
SB: Final = 250
WILL: Final = 251
WONT: Final = 252
DO: Final = 253
DONT: Final = 254
IAC: Final = 255

# --- options ------------------------------------------------------------------------------------
BINARY: Final = 0
ECHO: Final = 1
SGA: Final = 3

MAX_SUBNEGOTIATION: Final = 1024
"""Longest subnegotiation payload kept, in bytes; longer ones are dropped and reported."""

_CR: Final = 13
_NUL: Final = 0
_IAC_B: Final = b"\xff"
_NAMES: Final = {SE: "SE", NOP: "NOP", DM: "DM", BRK: "BRK", IP: "IP", AO: "AO", AYT: "AYT",
                 EC: "EC", EL: "EL", GA: "GA", SB: "SB", WILL: "WILL", WONT: "WONT", DO: "DO",
                 DONT: "DONT", IAC: "IAC"}


def escape(data: bytes) -> bytes:
    """``data`` with every 0xFF doubled, as it goes on the wire in BINARY mode."""
    return data.replace(_IAC_B, b"\xff\xff")


def unescape(wire: bytes) -> bytes:
    """The data of ``wire`` bytes holding only data and ``IAC IAC`` (the inverse of
    :func:`escape`); any other telnet sequence is dropped. For streams use :class:`TelnetCodec`."""
    codec = TelnetCodec(accept_local=(), accept_remote=())
    codec._q_remote[BINARY] = (_YES, _EMPTY)  # exact bytes: no CR NUL rule
    return b"".join(e.data for e in codec.receive_data(wire) if isinstance(e, Data))


# --- parser states and Q-method states ----------------------------------------------------------
_S_DATA: Final = 0
_S_IAC: Final = 1
_S_OPT: Final = 2
_S_SB_OPT: Final = 3
_S_SB: Final = 4
_S_SB_IAC: Final = 5

_NO: Final = 0
_YES: Final = 1
_WANTNO: Final = 2
_WANTYES: Final = 3
_EMPTY: Final = 0
_OPPOSITE: Final = 1
_STATE_NAMES: Final = ("no", "yes", "wantno", "wantyes")

_DEFAULT_ACCEPT: Final = (BINARY, SGA, COM_PORT_OPTION)


class TelnetCodec(ComPortOptions):
    """One side of a telnet connection, RFC 2217 aware; no I/O.

    ``role`` decides the direction of COM-PORT codes (a ``client`` sends 1..12 and receives
    101..112). ``accept_local`` are the options we agree to enable on our side when the peer asks
    (DO); ``accept_remote`` those we agree to let the peer enable (WILL). Everything else is
    refused. Options we ask for with :meth:`enable_local`/:meth:`enable_remote` are added to the
    accept sets.
    """

    def __init__(self, *, role: Role = "client", accept_local: Iterable[int] = _DEFAULT_ACCEPT,
                 accept_remote: Iterable[int] = _DEFAULT_ACCEPT) -> None:
        if role not in ("client", "server"):
            raise ValueError(f"role: {role!r} is not 'client' or 'server'")
        self.role: Role = role
        self.accept_local: set[int] = set(accept_local)
        self.accept_remote: set[int] = set(accept_remote)
        self._q_local: dict[int, tuple[int, int]] = {}
        self._q_remote: dict[int, tuple[int, int]] = {}
        self._out = bytearray()
        self._state = _S_DATA
        self._verb = 0
        self._sb_option = 0
        self._sb = bytearray()
        self._sb_overflow = False
        self._cr = False
        self.violations = 0
        """Protocol violations seen on the wire (each also reported as an event)."""
        self.declined = 0
        """Peer offers/requests we refused."""
        self.wire_bytes_in = 0
        """Bytes fed to :meth:`receive_data`."""
        self.wire_bytes_out = 0
        """Bytes handed out by :meth:`data_to_send`."""

    # --- state queries --------------------------------------------------------------------------
    def local_enabled(self, option: int) -> bool:
        """True when ``option`` is in effect on our side."""
        return self._q_local.get(option, (_NO, _EMPTY))[0] == _YES

    def remote_enabled(self, option: int) -> bool:
        """True when ``option`` is in effect on the peer's side."""
        return self._q_remote.get(option, (_NO, _EMPTY))[0] == _YES

    def option_state(self, option: int, side: Side) -> str:
        """RFC 1143 state of ``option`` on ``side``: ``no``, ``yes``, ``wantno`` or ``wantyes``."""
        table = self._q_local if side == "local" else self._q_remote
        return _STATE_NAMES[table.get(option, (_NO, _EMPTY))[0]]

    @property
    def pending_subnegotiation(self) -> bool:
        """True while the parser is inside ``IAC SB ... IAC SE`` (or any unfinished sequence)."""
        return self._state != _S_DATA

    # --- output ---------------------------------------------------------------------------------
    def data_to_send(self) -> bytes:
        """Take the bytes queued for the peer (empty when there are none)."""
        out = bytes(self._out)
        self._out.clear()
        self.wire_bytes_out += len(out)
        return out

    def send_data(self, data: bytes) -> None:
        """Queue payload bytes, escaping 0xFF (and CR as CR NUL while we are not BINARY)."""
        out = bytes(data).replace(_IAC_B, b"\xff\xff")
        if not self.local_enabled(BINARY):
            out = out.replace(b"\r", b"\r\x00")
        self._out += out

    def send_command(self, code: int) -> None:
        """Queue ``IAC code`` for a plain command (NOP, BRK, AYT, GA, ...)."""
        if not NOP <= code <= GA:
            raise ValueError(f"command: {code} is not a plain telnet command (241..249)")
        self._out += bytes((IAC, code))

    def send_subnegotiation(self, option: int, payload: bytes) -> None:
        """Queue ``IAC SB option payload IAC SE`` with 0xFF in ``payload`` doubled."""
        check_byte("option", option)
        self._out += bytes((IAC, SB, option)) + escape(bytes(payload)) + bytes((IAC, SE))

    def enable_local(self, option: int) -> bool:
        """Ask to enable ``option`` on our side (WILL); False when nothing had to be sent."""
        check_byte("option", option)
        self.accept_local.add(option)
        return self._request(self._q_local, option, True, WILL, WONT)

    def disable_local(self, option: int) -> bool:
        """Ask to disable ``option`` on our side (WONT); False when nothing had to be sent."""
        check_byte("option", option)
        return self._request(self._q_local, option, False, WILL, WONT)

    def enable_remote(self, option: int) -> bool:
        """Ask the peer to enable ``option`` (DO); False when nothing had to be sent."""
        check_byte("option", option)
        self.accept_remote.add(option)
        return self._request(self._q_remote, option, True, DO, DONT)

    def disable_remote(self, option: int) -> bool:
        """Ask the peer to disable ``option`` (DONT); False when nothing had to be sent."""
        check_byte("option", option)
        return self._request(self._q_remote, option, False, DO, DONT)

    # --- input ----------------------------------------------------------------------------------
    def receive_data(self, data: bytes) -> list[Event]:
        """Feed bytes from the wire; return the events they complete, in stream order.

        Adjacent payload is merged into one :class:`Data` event per run. Never raises on the
        content of ``data``; answers to the peer's negotiation are queued for
        :meth:`data_to_send`.
        """
        self.wire_bytes_in += len(data)
        events: list[Event] = []
        n = len(data)
        binary_in = self.remote_enabled(BINARY)
        plain = binary_in or (not self._cr and b"\r" not in data)
        if self._state == _S_DATA and plain and _IAC_B not in data:
            if n:
                self._cr = False
                events.append(Data(bytes(data)))
            return events
        pending = bytearray()
        i = 0
        while i < n:
            state = self._state
            if state == _S_DATA:
                j = data.find(_IAC_B, i)
                end = n if j < 0 else j
                if end > i:
                    self._take_data(data[i:end], pending)
                if j < 0:
                    break
                i = j + 1
                self._state = _S_IAC
                continue
            byte = data[i]
            i += 1
            if state == _S_IAC:
                self._after_iac(byte, pending, events)
            elif state == _S_OPT:
                self._state = _S_DATA
                _flush(pending, events)
                self._negotiate(self._verb, byte, events)
            elif state == _S_SB_OPT:
                self._sb_option = byte
                self._sb.clear()
                self._sb_overflow = False
                self._state = _S_SB
            elif state == _S_SB:
                j = data.find(_IAC_B, i - 1)
                end = n if j < 0 else j
                self._sb_add(data[i - 1:end])
                if j < 0:
                    i = n
                else:
                    i = j + 1
                    self._state = _S_SB_IAC
            else:  # _S_SB_IAC
                if byte == IAC:
                    self._sb_add(_IAC_B)
                    self._state = _S_SB
                elif byte == SE:
                    self._state = _S_DATA
                    _flush(pending, events)
                    self._end_subnegotiation(events)
                else:
                    _flush(pending, events)
                    self._violation(events, f"IAC {_name(byte)} inside subnegotiation of option "
                                            f"{self._sb_option}; subnegotiation dropped")
                    self._sb.clear()
                    self._after_iac(byte, pending, events)
        _flush(pending, events)
        return events

    def _take_data(self, chunk: bytes, pending: bytearray) -> None:
        if self.remote_enabled(BINARY):
            self._cr = False
            pending += chunk
            return
        if self._cr and chunk[0] == _NUL:
            chunk = chunk[1:]
        self._cr = bool(chunk) and chunk[-1] == _CR
        pending += chunk.replace(b"\r\x00", b"\r")

    def _after_iac(self, byte: int, pending: bytearray, events: list[Event]) -> None:
        """Handle the byte after an IAC in the data stream."""
        self._state = _S_DATA
        if byte == IAC:
            self._cr = False
            pending.append(IAC)
            return
        _flush(pending, events)
        if WILL <= byte <= DONT:
            self._verb = byte
            self._state = _S_OPT
        elif byte == SB:
            self._state = _S_SB_OPT
        elif byte == SE:
            self._violation(events, "IAC SE outside a subnegotiation")
        elif byte > SE:
            events.append(Command(byte))
        else:
            self._violation(events, f"IAC followed by 0x{byte:02x}, which is not a command")

    def _sb_add(self, chunk: bytes) -> None:
        if self._sb_overflow:
            return
        if len(self._sb) + len(chunk) > MAX_SUBNEGOTIATION:
            self._sb_overflow = True
            self._sb.clear()
            return
        self._sb += chunk

    def _violation(self, events: list[Event], reason: str) -> None:
        self.violations += 1
        events.append(ProtocolViolation(reason))

    # --- negotiation (RFC 1143 Q method) ---------------------------------------------------------
    def _request(self, table: dict[int, tuple[int, int]], option: int, enable: bool, yes: int,
                 no: int) -> bool:
        state, queue = table.get(option, (_NO, _EMPTY))
        if enable:
            if state == _NO:
                table[option] = (_WANTYES, _EMPTY)
                self._out += bytes((IAC, yes, option))
                return True
            if state == _WANTNO and queue == _EMPTY:
                table[option] = (_WANTNO, _OPPOSITE)
                return True
            if state == _WANTYES and queue == _OPPOSITE:
                table[option] = (_WANTYES, _EMPTY)
                return True
            return False
        if state == _YES:
            table[option] = (_WANTNO, _EMPTY)
            self._out += bytes((IAC, no, option))
            return True
        if state == _WANTYES and queue == _EMPTY:
            table[option] = (_WANTYES, _OPPOSITE)
            return True
        if state == _WANTNO and queue == _OPPOSITE:
            table[option] = (_WANTNO, _EMPTY)
            return True
        return False

    def _negotiate(self, verb: int, option: int, events: list[Event]) -> None:
        side: Side
        if verb in (WILL, WONT):
            side, table, accept, yes, no = "remote", self._q_remote, self.accept_remote, DO, DONT
        else:
            side, table, accept, yes, no = "local", self._q_local, self.accept_local, WILL, WONT
        state, queue = table.get(option, (_NO, _EMPTY))
        positive = verb in (WILL, DO)
        if positive:
            if state == _NO:
                if option in accept:
                    table[option] = (_YES, _EMPTY)
                    self._out += bytes((IAC, yes, option))
                    events.append(OptionEnabled(option, side))
                else:
                    self._out += bytes((IAC, no, option))
                    self.declined += 1
                    events.append(OptionDeclined(option, side))
            elif state == _WANTNO:
                self._violation(events, f"{_name(no)} {option} answered by {_name(verb)}")
                if queue == _EMPTY:
                    table[option] = (_NO, _EMPTY)
                else:
                    table[option] = (_YES, _EMPTY)
                    events.append(OptionEnabled(option, side))
            elif state == _WANTYES:
                if queue == _EMPTY:
                    table[option] = (_YES, _EMPTY)
                    events.append(OptionEnabled(option, side))
                else:
                    table[option] = (_WANTNO, _EMPTY)
                    self._out += bytes((IAC, no, option))
            return
        if state == _YES:
            table[option] = (_NO, _EMPTY)
            self._out += bytes((IAC, no, option))
            events.append(OptionDisabled(option, side))
        elif state == _WANTNO:
            if queue == _EMPTY:
                table[option] = (_NO, _EMPTY)
                events.append(OptionDisabled(option, side))
            else:
                table[option] = (_WANTYES, _EMPTY)
                self._out += bytes((IAC, yes, option))
        elif state == _WANTYES:
            table[option] = (_NO, _EMPTY)
            events.append(OptionRefused(option, side))

    # --- subnegotiation ------------------------------------------------------------------------
    def _end_subnegotiation(self, events: list[Event]) -> None:
        option, payload = self._sb_option, bytes(self._sb)
        self._sb.clear()
        if self._sb_overflow:
            self._sb_overflow = False
            self._violation(events, f"subnegotiation of option {option} longer than "
                                    f"{MAX_SUBNEGOTIATION} bytes; dropped")
            return
        if option != COM_PORT_OPTION:
            events.append(Subnegotiation(option, payload))
            return
        for event in decode_com_port(payload, self.role):
            if isinstance(event, ProtocolViolation):
                self._violation(events, event.reason)
            else:
                events.append(event)


def _flush(pending: bytearray, events: list[Event]) -> None:
    if pending:
        events.append(Data(bytes(pending)))
        pending.clear()


def _name(code: int) -> str:
    return _NAMES.get(code, str(code))
