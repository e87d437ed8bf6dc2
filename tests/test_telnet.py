"""The sans-I/O telnet / RFC 2217 codec: escaping, negotiation, subnegotiation, robustness."""

from __future__ import annotations

import itertools
from collections.abc import Iterable

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armbench.drivers.telnet import (
    BINARY,
    COM_PORT_OPTION,
    DO,
    DONT,
    ECHO,
    IAC,
    MAX_SUBNEGOTIATION,
    NOP,
    SB,
    SE,
    SGA,
    WILL,
    WONT,
    Command,
    ComPort,
    ComPortReply,
    ComPortRequest,
    Data,
    Event,
    FlowControl,
    LineState,
    ModemState,
    OptionDeclined,
    OptionDisabled,
    OptionEnabled,
    OptionRefused,
    ProtocolViolation,
    Side,
    Signature,
    Subnegotiation,
    TelnetCodec,
    coalesce,
    escape,
    unescape,
)

# What ser2net 4.3 (accepter telnet(rfc2217)) sends first, recorded from a real session.
SER2NET_GREETING = bytes([IAC, WILL, SGA, IAC, DO, SGA, IAC, WILL, ECHO, IAC, DONT, ECHO,
                          IAC, DO, BINARY, IAC, WILL, BINARY, IAC, DO, COM_PORT_OPTION])


SIDES: tuple[Side, ...] = ("local", "remote")


def data_of(events: Iterable[Event]) -> bytes:
    return b"".join(e.data for e in events if isinstance(e, Data))


def binary_pair() -> tuple[TelnetCodec, TelnetCodec]:
    """A client and a server codec that have agreed on BINARY both ways."""
    client, server = TelnetCodec(), TelnetCodec(role="server")
    client.enable_local(BINARY)
    client.enable_remote(BINARY)
    pump(client, server)
    assert client.local_enabled(BINARY) and client.remote_enabled(BINARY)
    assert server.local_enabled(BINARY) and server.remote_enabled(BINARY)
    return client, server


def pump(a: TelnetCodec, b: TelnetCodec, limit: int = 100) -> tuple[list[Event], list[Event]]:
    """Carry bytes between two codecs until both are quiet; fail if they never stop."""
    ea: list[Event] = []
    eb: list[Event] = []
    for _ in range(limit):
        out_a, out_b = a.data_to_send(), b.data_to_send()
        if not out_a and not out_b:
            return ea, eb
        eb += b.receive_data(out_a)
        ea += a.receive_data(out_b)
    raise AssertionError("negotiation did not settle: the codecs loop")


# --- escaping -----------------------------------------------------------------------------------
def test_escape_doubles_iac() -> None:
    assert escape(b"a\xffb\xff\xff") == b"a\xff\xffb\xff\xff\xff\xff"
    assert unescape(b"a\xff\xffb") == b"a\xffb"


@given(st.binary())
def test_escape_round_trip(data: bytes) -> None:
    assert unescape(escape(data)) == data
    assert escape(data).count(b"\xff") == 2 * data.count(b"\xff")


@given(st.binary(max_size=300), st.booleans())
def test_data_round_trip_through_two_codecs(data: bytes, binary: bool) -> None:
    """Data is exact with BINARY (0xFF doubled) and without (CR sent as CR NUL)."""
    if binary:
        client, server = binary_pair()
    else:
        client, server = TelnetCodec(), TelnetCodec(role="server")
    client.send_data(data)
    wire = client.data_to_send()
    assert data_of(server.receive_data(wire)) == data
    server.send_data(data)
    assert data_of(client.receive_data(server.data_to_send())) == data


def test_cr_nul_only_without_binary() -> None:
    client = TelnetCodec()
    client.send_data(b"a\rb\r\n")
    assert client.data_to_send() == b"a\r\x00b\r\x00\n"
    assert data_of(client.receive_data(b"x\r\x00y\r")) == b"x\ry\r"
    assert data_of(client.receive_data(b"\x00z")) == b"z"  # CR NUL split across reads
    client, _ = binary_pair()
    client.send_data(b"a\rb")
    assert client.data_to_send() == b"a\rb"
    assert data_of(client.receive_data(b"x\r\x00y")) == b"x\r\x00y"


# --- negotiation --------------------------------------------------------------------------------
def test_client_against_ser2net_greeting() -> None:
    """The bytes a real ser2net sends: we accept BINARY/SGA/COM-PORT and refuse ECHO."""
    client = TelnetCodec(accept_local=(BINARY, SGA), accept_remote=(BINARY, SGA))
    for opt in (BINARY, SGA):
        client.enable_local(opt)
        client.enable_remote(opt)
    client.enable_local(COM_PORT_OPTION)
    assert client.data_to_send() == bytes([IAC, WILL, BINARY, IAC, DO, BINARY, IAC, WILL, SGA,
                                           IAC, DO, SGA, IAC, WILL, COM_PORT_OPTION])
    events = client.receive_data(SER2NET_GREETING)
    # ECHO offered → DONT ECHO; everything else answers our own requests, so nothing is sent.
    assert client.data_to_send() == bytes([IAC, DONT, ECHO])
    assert OptionDeclined(ECHO, "remote") in events
    assert OptionEnabled(COM_PORT_OPTION, "local") in events
    for opt in (BINARY, SGA):
        assert client.local_enabled(opt) and client.remote_enabled(opt)
    assert client.local_enabled(COM_PORT_OPTION)
    assert client.violations == 0
    # A second greeting (a confused server) is ignored: nothing to answer, nothing changes.
    client.receive_data(SER2NET_GREETING[:-3])
    assert client.data_to_send() == bytes([IAC, DONT, ECHO])


def test_refusing_server() -> None:
    client = TelnetCodec()
    client.enable_local(COM_PORT_OPTION)
    client.data_to_send()
    events = client.receive_data(bytes([IAC, DONT, COM_PORT_OPTION]))
    assert events == [OptionRefused(COM_PORT_OPTION, "local")]
    assert client.data_to_send() == b""  # never answer an answer
    assert client.option_state(COM_PORT_OPTION, "local") == "no"


def test_unknown_options_are_refused() -> None:
    client = TelnetCodec()
    events = client.receive_data(bytes([IAC, WILL, 24, IAC, DO, 31, IAC, DO, ECHO]))
    assert client.data_to_send() == bytes([IAC, DONT, 24, IAC, WONT, 31, IAC, WONT, ECHO])
    assert events == [OptionDeclined(24, "remote"), OptionDeclined(31, "local"),
                      OptionDeclined(ECHO, "local")]
    assert client.declined == 3
    # WONT/DONT for options that are off need no answer.
    assert client.receive_data(bytes([IAC, WONT, 24, IAC, DONT, 31])) == []
    assert client.data_to_send() == b""


def test_disable_and_reenable_queue() -> None:
    client, server = binary_pair()
    assert client.disable_local(BINARY)
    assert client.enable_local(BINARY)  # queued while WANTNO
    assert not client.enable_local(BINARY)  # already queued
    ec, es = pump(client, server)
    # RFC 1143: WONT, DONT back, then WILL from the queue, DO back; no event for the transient.
    assert ec == [OptionEnabled(BINARY, "local")]
    assert es == [OptionDisabled(BINARY, "remote"), OptionEnabled(BINARY, "remote")]
    assert client.local_enabled(BINARY) and server.remote_enabled(BINARY)


def test_peer_turns_option_off() -> None:
    client, server = binary_pair()
    server.disable_remote(BINARY)  # server: DONT BINARY
    ec, es = pump(client, server)
    assert OptionDisabled(BINARY, "local") in ec
    assert OptionDisabled(BINARY, "remote") in es
    assert not client.local_enabled(BINARY)


_OPTS = st.sampled_from([BINARY, ECHO, SGA, COM_PORT_OPTION, 24])
_ACTIONS = st.lists(st.tuples(st.booleans(), st.sampled_from(["local", "remote"]), st.booleans(),
                              _OPTS), max_size=30)


@settings(max_examples=200, deadline=None)
@given(_ACTIONS, st.sets(_OPTS), st.sets(_OPTS), st.sets(_OPTS), st.sets(_OPTS),
       st.lists(st.integers(0, 3), max_size=30))
def test_negotiation_never_loops_and_agrees(actions: list[tuple[bool, str, bool, int]],
                                            cl: set[int], cr: set[int], sl: set[int],
                                            sr: set[int], deliveries: list[int]) -> None:
    """Random enable/disable requests on both ends, with random partial delivery in between:
    the Q method settles, and both ends agree on every option."""
    client = TelnetCodec(accept_local=cl, accept_remote=cr)
    server = TelnetCodec(role="server", accept_local=sl, accept_remote=sr)
    wire_cs = bytearray()
    wire_sc = bytearray()
    steps = iter(deliveries)
    for on_client, side, enable, opt in actions:
        codec = client if on_client else server
        name = f"{'enable' if enable else 'disable'}_{side}"
        getattr(codec, name)(opt)
        wire_cs.extend(client.data_to_send())
        wire_sc.extend(server.data_to_send())
        cut = next(steps, 3)  # deliver part of what is in flight, keeping stream order
        if cut & 1 and wire_cs:
            server.receive_data(bytes(wire_cs[:3]))
            del wire_cs[:3]
        if cut & 2 and wire_sc:
            client.receive_data(bytes(wire_sc[:3]))
            del wire_sc[:3]
    server.receive_data(bytes(wire_cs))
    client.receive_data(bytes(wire_sc))
    pump(client, server)
    for opt in (BINARY, ECHO, SGA, COM_PORT_OPTION, 24):
        assert client.local_enabled(opt) == server.remote_enabled(opt)
        assert client.remote_enabled(opt) == server.local_enabled(opt)
        for codec in (client, server):
            assert codec.option_state(opt, "local") in ("no", "yes")
            assert codec.option_state(opt, "remote") in ("no", "yes")


# --- RFC 2217 -----------------------------------------------------------------------------------
def _sb(*payload: int) -> bytes:
    return bytes([IAC, SB, COM_PORT_OPTION]) + escape(bytes(payload)) + bytes([IAC, SE])


def test_com_port_requests_on_the_wire() -> None:
    client = TelnetCodec()
    client.set_baudrate(115200)
    client.set_datasize(8)
    client.set_parity("E")
    client.set_stopsize(1.5)
    client.set_control(ComPort.CONTROL_DTR_ON)
    client.flowcontrol(True)
    client.flowcontrol(False)
    assert client.data_to_send() == (_sb(1, 0, 1, 0xC2, 0) + _sb(2, 8) + _sb(3, 3) + _sb(4, 3)
                                     + _sb(5, 8) + _sb(8) + _sb(9))
    client.set_baudrate(0x0001C2FF)  # a 0xFF inside the value is doubled
    assert client.data_to_send() == bytes([IAC, SB, 44, 1, 0, 1, 0xC2, IAC, IAC, IAC, SE])
    with pytest.raises(ValueError, match="parity"):
        client.set_parity("X")
    with pytest.raises(ValueError, match="stop bits"):
        client.set_stopsize(3)


def test_server_replies_decoded() -> None:
    client = TelnetCodec()
    wire = (_sb(100, *b"ser2net") + _sb(101, 0, 1, 0xC2, 0) + _sb(102, 8) + _sb(103, 1)
            + _sb(104, 1) + _sb(106, 0x60) + _sb(107, 0xB0) + _sb(108) + _sb(109) + _sb(100))
    assert client.receive_data(wire) == [
        Signature(b"ser2net"), ComPortReply(ComPort.SET_BAUDRATE, 115200),
        ComPortReply(ComPort.SET_DATASIZE, 8), ComPortReply(ComPort.SET_PARITY, 1),
        ComPortReply(ComPort.SET_STOPSIZE, 1), LineState(0x60), ModemState(0xB0),
        FlowControl(True), FlowControl(False), Signature(b"")]
    assert client.violations == 0


def test_server_role_round_trip() -> None:
    client, server = binary_pair()
    client.set_baudrate(9600)
    client.set_control(ComPort.CONTROL_RTS_ON)
    assert server.receive_data(client.data_to_send()) == [
        ComPortRequest(ComPort.SET_BAUDRATE, 9600),
        ComPortRequest(ComPort.SET_CONTROL, ComPort.CONTROL_RTS_ON)]
    server.set_baudrate(9600)  # the server acknowledges the baud rate and ignores SET-CONTROL
    assert client.receive_data(server.data_to_send()) == [
        ComPortReply(ComPort.SET_BAUDRATE, 9600)]


def test_refused_modem_control_is_harmless() -> None:
    """ser2net on a pty answers SET-CONTROL with nothing or a bogus value: just an event."""
    client = TelnetCodec()
    client.set_control(ComPort.CONTROL_DTR_ON)
    client.data_to_send()
    assert client.receive_data(_sb(105, 0)) == [ComPortReply(ComPort.SET_CONTROL, 0)]
    assert client.receive_data(b"data") == [Data(b"data")]


@pytest.mark.parametrize(("wire", "reason"), [
    (_sb(101, 1, 2), "4"),  # short baud value
    (_sb(102), "expected 1"),
    (_sb(1, 8), "not expected by a client"),  # a client command sent to the client
    (_sb(200, 1), "not expected"),
    (bytes([IAC, SB, 44, IAC, SE]), "empty"),
    (bytes([IAC, SE]), "outside a subnegotiation"),
    (bytes([IAC, 7]), "not a command"),
    (bytes([IAC, SB, 44, 101, 0, IAC, WILL, 3]), "inside subnegotiation"),
])
def test_malformed_input_is_reported(wire: bytes, reason: str) -> None:
    client = TelnetCodec()
    events = client.receive_data(wire)
    violations = [e for e in events if isinstance(e, ProtocolViolation)]
    assert len(violations) == 1 and reason in violations[0].reason
    assert client.violations == 1
    assert client.receive_data(b"ok") == [Data(b"ok")]  # back to data afterwards


def test_iac_inside_subnegotiation_is_processed_after_abort() -> None:
    client = TelnetCodec()
    events = client.receive_data(bytes([IAC, SB, 44, 101, 0, IAC, WILL, 3]) + b"x")
    assert isinstance(events[0], ProtocolViolation)
    assert events[1:] == [OptionEnabled(SGA, "remote"), Data(b"x")]


def test_overlong_subnegotiation_is_dropped() -> None:
    client = TelnetCodec()
    wire = bytes([IAC, SB, 24]) + b"a" * (MAX_SUBNEGOTIATION + 1) + bytes([IAC, SE]) + b"z"
    events = client.receive_data(wire)
    assert isinstance(events[0], ProtocolViolation) and events[1:] == [Data(b"z")]
    ok = bytes([IAC, SB, 24]) + b"a\xff\xffb" + bytes([IAC, SE])
    assert client.receive_data(ok) == [Subnegotiation(24, b"a\xffb")]


def test_commands() -> None:
    client = TelnetCodec()
    assert client.receive_data(bytes([65, IAC, NOP, 66, IAC, 246])) == [
        Data(b"A"), Command(NOP), Data(b"B"), Command(246)]
    client.send_command(NOP)
    assert client.data_to_send() == bytes([IAC, NOP])
    with pytest.raises(ValueError):
        client.send_command(SB)


# --- robustness ---------------------------------------------------------------------------------
_TOKENS = st.one_of(
    st.binary(max_size=12),
    st.just(b"\xff\xff"),
    st.just(b"\r\x00"),
    st.just(b"\r\n"),
    st.builds(lambda v, o: bytes([IAC, v, o]), st.sampled_from([WILL, WONT, DO, DONT]), _OPTS),
    st.builds(lambda c: bytes([IAC, c]), st.integers(0, 255)),
    st.builds(lambda p: _sb(*p), st.lists(st.integers(0, 255), max_size=8)),
    st.builds(lambda o, p: bytes([IAC, SB, o]) + p, _OPTS, st.binary(max_size=6)),
)
_STREAMS = st.lists(_TOKENS, max_size=25).map(b"".join)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=400), st.sampled_from(["client", "server"]))
def test_arbitrary_bytes_never_raise(data: bytes, role: str) -> None:
    codec = TelnetCodec(role="server" if role == "server" else "client")
    events = codec.receive_data(data)
    events += codec.receive_data(data)
    codec.data_to_send()
    assert codec.violations == sum(isinstance(e, ProtocolViolation) for e in events)


@settings(max_examples=300, deadline=None)
@given(st.one_of(_STREAMS, st.binary(max_size=200)), st.lists(st.integers(0, 400), max_size=8),
       st.booleans())
def test_split_anywhere_gives_the_same_output(stream: bytes, cuts: list[int],
                                              binary: bool) -> None:
    """Feeding a stream whole or in pieces (including 1-byte pieces) yields the same events,
    the same bytes to send and the same negotiation state."""
    def fresh() -> TelnetCodec:
        if binary:
            codec, _ = binary_pair()
            codec.data_to_send()
            return codec
        return TelnetCodec()

    whole = fresh()
    whole_events = whole.receive_data(stream)
    whole_out = whole.data_to_send()
    points = sorted({min(c, len(stream)) for c in cuts} | {0, len(stream)})
    pieces = [stream[a:b] for a, b in itertools.pairwise(points)]
    for chunks in (pieces, [stream[i:i + 1] for i in range(len(stream))]):
        split = fresh()
        split_events: list[Event] = []
        for chunk in chunks:
            split_events += split.receive_data(chunk)
        assert coalesce(split_events) == coalesce(whole_events)
        assert split.data_to_send() == whole_out
        assert split.violations == whole.violations
        for opt in (BINARY, ECHO, SGA, COM_PORT_OPTION, 24):
            for side in SIDES:
                assert split.option_state(opt, side) == whole.option_state(opt, side)
