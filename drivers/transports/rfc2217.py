"""RFC 2217 client: ``rfc2217://HOST:PORT`` — a remote serial port behind a telnet
COM-PORT-OPTION server such as ser2net (``accepter: telnet(rfc2217),tcp,PORT``).

Opening connects over TCP, negotiates BINARY and SUPPRESS-GO-AHEAD both ways and our
COM-PORT-OPTION, sets baud rate, data bits, parity and stop bits from
:class:`~armbench.drivers.model.settings.SerialSettings`, and waits for the server to acknowledge
each setting.
It fails with a :class:`~armbench.drivers.model.errors.TransportError` naming the port when the
server refuses
COM-PORT-OPTION (a plain telnet server), does not answer within ``negotiation_timeout_s``, or
acknowledges a different value than asked. Modem control (SET-CONTROL: DTR, RTS, flow control) is
never required: servers on ptys and cheap bridges refuse or ignore it, so it is not sent.

All the protocol work is done by the sans-I/O :class:`~armbench.drivers.telnet.TelnetCodec`; this
module only moves bytes. One background task reads the socket, feeds the codec, answers the server's
negotiation and buffers payload for :meth:`Rfc2217Transport.read` (at most ``max_buffer_bytes``;
beyond that it stops reading and TCP pushes back). FLOWCONTROL-SUSPEND from the server makes
:meth:`~Rfc2217Transport.write` wait for FLOWCONTROL-RESUME.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable

from armbench.drivers.model.errors import PortLostError
from armbench.drivers.model.log_limit import LogLimit
from armbench.drivers.model.settings import SerialSettings
from armbench.drivers.telnet import (
    BINARY,
    COM_PORT_OPTION,
    PARITY_CODES,
    SGA,
    STOPSIZE_CODES,
    ComPort,
    ComPortReply,
    Data,
    Event,
    FlowControl,
    LineState,
    ModemState,
    OptionDisabled,
    OptionEnabled,
    OptionRefused,
    ProtocolViolation,
    Signature,
    TelnetCodec,
)
from armbench.drivers.transports.base import READ_CHUNK, Transport
from armbench.drivers.transports.tcp import CONNECT_TIMEOUT_S, close_writer, parse_host_port

__all__ = ["CLIENT_SIGNATURE", "NEGOTIATION_TIMEOUT_S", "Rfc2217Transport"]

_log = logging.getLogger(__name__)

NEGOTIATION_TIMEOUT_S = 5.0
"""Seconds :meth:`Rfc2217Transport.open` waits for COM-PORT-OPTION and the settings' replies."""
CLIENT_SIGNATURE = b"armbench"
"""What we answer when the server asks for our COM-PORT signature."""

_SETTING_NAMES = {ComPort.SET_BAUDRATE: "baud rate", ComPort.SET_DATASIZE: "data size",
                  ComPort.SET_PARITY: "parity", ComPort.SET_STOPSIZE: "stop size"}


class Rfc2217Transport(Transport):
    """A serial port reached through an RFC 2217 server.

    After :meth:`open`: ``replies`` holds the server's last acknowledged value per COM-PORT
    command (``replies[ComPort.SET_BAUDRATE]`` is the baud rate in bit/s), ``signature`` the
    server's signature if it sent one, ``line_state``/``modem_state`` the last notifications,
    ``suspended`` whether the server has asked us to stop sending.
    """

    scheme = "rfc2217"

    def __init__(self, port: str, serial: SerialSettings, *,
                 connect_timeout_s: float = CONNECT_TIMEOUT_S,
                 negotiation_timeout_s: float = NEGOTIATION_TIMEOUT_S,
                 max_buffer_bytes: int = 1 << 20) -> None:
        super().__init__(port, serial)
        self.host, self.tcp_port = parse_host_port(port)
        self.connect_timeout_s = connect_timeout_s
        """Seconds :meth:`open` waits for the TCP connection."""
        self.negotiation_timeout_s = negotiation_timeout_s
        """Seconds :meth:`open` waits for the telnet/RFC 2217 negotiation to finish."""
        self.max_buffer_bytes = max_buffer_bytes
        """Received payload bytes held for :meth:`read` before the socket stops being read."""
        self.replies: dict[int, int] = {}
        self.signature: bytes | None = None
        self.line_state: int | None = None
        self.modem_state: int | None = None
        self.suspended = False
        self._codec = TelnetCodec(role="client")
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._task: asyncio.Task[None] | None = None
        self._rx = bytearray()
        self._rx_ready = asyncio.Event()
        self._rx_drained = asyncio.Event()
        self._changed = asyncio.Event()
        self._resumed = asyncio.Event()
        self._lost_reason: str | None = None
        self._opened = False
        self._option_log = LogLimit(_log, logging.WARNING, "COM-PORT-OPTION lines")

    @property
    def is_open(self) -> bool:
        return self._opened and self._lost_reason is None

    @property
    def codec(self) -> TelnetCodec:
        """The telnet codec of the current connection (negotiation state, violation count)."""
        return self._codec

    # --- open -----------------------------------------------------------------------------------
    async def open(self) -> None:
        if self._writer is not None:
            raise self._error("transport is already open")
        wanted = self._wanted()
        try:
            async with asyncio.timeout(self.connect_timeout_s):
                reader, writer = await asyncio.open_connection(self.host, self.tcp_port)
        except TimeoutError:
            raise self._error(f"no TCP connection within {self.connect_timeout_s:g} s") from None
        except OSError as exc:
            raise self._error(f"cannot connect: {exc.strerror or exc}") from exc
        self._reset(reader, writer)
        try:
            await self._negotiate(wanted)
        except BaseException:
            await self._shutdown()
            raise
        self._opened = True

    def _reset(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._reader, self._writer = reader, writer
        self._codec = codec = TelnetCodec(role="client", accept_local=(BINARY, SGA),
                                          accept_remote=(BINARY, SGA))
        self._rx.clear()
        self._lost_reason = None
        self.replies.clear()
        self.signature = self.line_state = self.modem_state = None
        self.suspended = False
        self._resumed.set()
        codec.enable_local(BINARY)
        codec.enable_remote(BINARY)
        codec.enable_local(SGA)
        codec.enable_remote(SGA)
        codec.enable_local(COM_PORT_OPTION)
        writer.write(codec.data_to_send())
        self._task = asyncio.create_task(self._pump(reader, writer, codec),
                                         name=f"rfc2217 reader {self.port}")

    def _wanted(self) -> dict[int, int]:
        """The value each setting command must be acknowledged with."""
        s = self.serial
        parity = PARITY_CODES.get(s.parity)
        stopsize = STOPSIZE_CODES.get(s.stopbits)
        if parity is None or stopsize is None or s.bytesize not in (5, 6, 7, 8) or not (
                0 < s.baudrate <= 0xFFFF_FFFF):
            raise self._error(f"unsupported line settings {s}")
        return {ComPort.SET_BAUDRATE: s.baudrate, ComPort.SET_DATASIZE: s.bytesize,
                ComPort.SET_PARITY: parity, ComPort.SET_STOPSIZE: stopsize}

    async def _negotiate(self, wanted: dict[int, int]) -> None:
        codec = self._codec
        step = "COM-PORT-OPTION"
        try:
            async with asyncio.timeout(self.negotiation_timeout_s):
                await self._wait_for(lambda: codec.option_state(COM_PORT_OPTION, "local")
                                     != "wantyes")
                if not codec.local_enabled(COM_PORT_OPTION):
                    raise self._error(
                        "the server refuses COM-PORT-OPTION, so it is no RFC 2217 port (use "
                        "socket:// for a raw TCP port, or telnet(rfc2217) in ser2net)")
                s = self.serial
                for command in wanted:
                    self.replies.pop(command, None)
                codec.set_baudrate(s.baudrate)
                codec.set_datasize(s.bytesize)
                codec.set_parity(s.parity)
                codec.set_stopsize(s.stopbits)
                self._send_pending()
                step = "the serial settings"
                await self._wait_for(lambda: all(c in self.replies for c in wanted))
        except TimeoutError:
            missing = ", ".join(_SETTING_NAMES[c] for c in _SETTING_NAMES
                                if c not in self.replies)
            what = ("no answer to WILL COM-PORT-OPTION" if step == "COM-PORT-OPTION"
                    else f"the server did not acknowledge {missing}")
            raise self._error(f"{what} within {self.negotiation_timeout_s:g} s") from None
        for command, value in wanted.items():
            got = self.replies[command]
            if got != value:
                raise self._error(f"the server set {_SETTING_NAMES[command]} {got} "
                                  f"instead of {value}")

    async def _wait_for(self, done: Callable[[], bool]) -> None:
        while not done():
            if self._lost_reason is not None:
                raise self._error(f"RFC 2217 negotiation failed: {self._lost_reason}")
            self._changed.clear()
            await self._changed.wait()

    # --- background reader ------------------------------------------------------------------------
    async def _pump(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                    codec: TelnetCodec) -> None:
        try:
            while True:
                while len(self._rx) >= self.max_buffer_bytes:
                    self._rx_drained.clear()
                    await self._rx_drained.wait()
                chunk = await reader.read(READ_CHUNK)
                if not chunk:
                    self._set_lost("connection closed by the server")
                    return
                events = codec.receive_data(chunk)
                for event in events:
                    self._handle(event, codec)
                out = codec.data_to_send()
                if out:
                    writer.write(out)
        except OSError as exc:
            self._set_lost(f"connection lost: {exc.strerror or exc}")
        except Exception as exc:  # a bug must not leave readers waiting forever
            _log.exception("%s: RFC 2217 reader failed", self.port)
            self._set_lost(f"reader failed: {exc!r}")

    def _handle(self, event: Event, codec: TelnetCodec) -> None:
        if isinstance(event, Data):
            self._rx += event.data
            self._rx_ready.set()
            return
        if isinstance(event, ComPortReply):
            self.replies[event.command] = event.value
        elif isinstance(event, Signature):
            if event.text:
                self.signature = event.text
            else:
                codec.send_com_port(ComPort.SIGNATURE, CLIENT_SIGNATURE)
        elif isinstance(event, LineState):
            self.line_state = event.state
        elif isinstance(event, ModemState):
            self.modem_state = event.state
        elif isinstance(event, FlowControl):
            self.suspended = event.suspended
            if event.suspended:
                self._resumed.clear()
            else:
                self._resumed.set()
        elif isinstance(event, ProtocolViolation):
            _log.debug("%s: %s", self.port, event.reason)
        elif (isinstance(event, OptionEnabled | OptionDisabled | OptionRefused)
              and event.option == COM_PORT_OPTION and self._opened
              and not codec.local_enabled(COM_PORT_OPTION)):
            self._option_log("%s: the server turned COM-PORT-OPTION off", self.port)
        self._changed.set()

    def _set_lost(self, reason: str) -> None:
        if self._lost_reason is None:
            self._lost_reason = reason
        self._rx_ready.set()
        self._changed.set()
        self._resumed.set()

    def _send_pending(self) -> None:
        out = self._codec.data_to_send()
        if out and self._writer is not None:
            self._writer.write(out)

    # --- data path ------------------------------------------------------------------------------
    async def read(self) -> bytes:
        while not self._rx:
            if not self._opened:
                raise self._not_open()
            if self._lost_reason is not None:
                raise self._lost(self._lost_reason)
            self._rx_ready.clear()
            await self._rx_ready.wait()
        if not self._opened:
            raise self._not_open()
        data = bytes(self._rx[:READ_CHUNK])
        del self._rx[:len(data)]
        self._rx_drained.set()
        self.bytes_in += len(data)
        return data

    async def write(self, data: bytes) -> None:
        while True:
            writer = self._writer
            if not self._opened or writer is None:
                raise self._not_open()
            if self._lost_reason is not None:
                raise self._lost(self._lost_reason)
            if self._resumed.is_set():
                break
            await self._resumed.wait()
        if writer.is_closing():
            raise self._mark_lost("connection closed")
        self._codec.send_data(data)
        try:
            writer.write(self._codec.data_to_send())
            await writer.drain()
        except OSError as exc:
            raise self._mark_lost(f"connection lost: {exc.strerror or exc}") from exc
        self.bytes_out += len(data)

    def _mark_lost(self, reason: str) -> PortLostError:
        self._set_lost(reason)
        return self._lost(self._lost_reason or reason)

    # --- close ----------------------------------------------------------------------------------
    async def close(self) -> None:
        self._opened = False
        self._option_log.flush()
        await self._shutdown()

    async def _shutdown(self) -> None:
        task, writer = self._task, self._writer
        self._task = None
        self._reader = self._writer = None
        self._rx_ready.set()
        self._resumed.set()
        self._changed.set()
        if task is not None:
            task.cancel()
            await asyncio.wait([task], timeout=1.0)
        if writer is not None:
            await close_writer(writer)
