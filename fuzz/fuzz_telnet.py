"""atheris harness: ``armbench.drivers.telnet.TelnetCodec`` (client and server role) on arbitrary
wire bytes.

Input layout (``atheris.FuzzedDataProvider``: integers from the end, bytes from the front)::

    <wire bytes> <chunk sizes: n bytes, each 1 + b % 64> <n = b % 16> <setup byte>

setup byte: bit 0 role (0 client, 1 server); bits 1-2 accept sets (default, nothing, every
option, default plus ECHO); bit 3 we ask for COM-PORT-OPTION and BINARY both ways first (so the
peer's answers meet WANTYES states); bit 4 then we also ask to disable them again (WANTNO /
queued states of RFC 1143).

Invariants (any violation is a crash):

* ``receive_data`` never raises; ``violations`` equals the ``ProtocolViolation`` events;
* output is bounded: bytes queued for the peer <= bytes received (each answer is one 3-byte
  reply to one 3-byte negotiation), payload out <= bytes in, events <= bytes in, a pending
  subnegotiation never holds more than ``MAX_SUBNEGOTIATION`` bytes, no event carries more;
* whole and chunked feeding give the same events (adjacent ``Data`` merged), the same bytes to
  send, the same violation count and the same option states (the docstring's promise);
* an option is never in effect on a side whose accept set lacks it (offers are refused);
* interleaved with our own API calls between chunks (enable/disable either side, send data,
  commands and COM-PORT requests; the call is picked by each chunk-size byte), nothing raises,
  the Q-method states stay valid and output stays within what was received plus what we asked
  to send.

Run: ``python fuzz/fuzz_telnet.py -max_total_time=60 -rss_limit_mb=512 fuzz/corpus/telnet``
"""

from __future__ import annotations

from collections.abc import Sequence

import atheris
from _harness import fuzz_main, split

with atheris.instrument_imports(include=["drivers"]):
    from armbench.drivers.telnet import (
        BINARY,
        COM_PORT_OPTION,
        ECHO,
        MAX_SUBNEGOTIATION,
        NOP,
        SGA,
        Data,
        Event,
        ProtocolViolation,
        Role,
        Side,
        Signature,
        Subnegotiation,
        TelnetCodec,
        coalesce,
    )

MAX_CHUNKS = 15
_ACCEPT: tuple[tuple[int, ...] | None, ...] = (
    None,  # the codec's default
    (),
    tuple(range(256)),
    (BINARY, SGA, COM_PORT_OPTION, ECHO),
)
_WATCHED = (BINARY, ECHO, SGA, COM_PORT_OPTION, 24, 255)
_SIDES: tuple[Side, Side] = ("local", "remote")


def make_codec(setup: int) -> tuple[TelnetCodec, bytes]:
    """A codec configured by the setup byte and what it queued before any input."""
    role: Role = "server" if setup & 1 else "client"
    accept = _ACCEPT[(setup >> 1) & 3]
    codec = (TelnetCodec(role=role) if accept is None
             else TelnetCodec(role=role, accept_local=accept, accept_remote=accept))
    if setup & 8:
        for option in (COM_PORT_OPTION, BINARY):
            codec.enable_local(option)
            codec.enable_remote(option)
    if setup & 16:
        for option in (COM_PORT_OPTION, BINARY):
            codec.disable_local(option)
            codec.disable_remote(option)
    return codec, codec.data_to_send()


def feed(setup: int, chunks: Sequence[bytes]) -> tuple[TelnetCodec, list[Event], bytes]:
    """Feed ``chunks``, checking the per-call invariants; events and bytes queued in reply."""
    codec, _ = make_codec(setup)
    events: list[Event] = []
    out = bytearray()
    fed = 0
    for chunk in chunks:
        new = codec.receive_data(chunk)
        fed += len(chunk)
        assert len(codec._sb) <= MAX_SUBNEGOTIATION, len(codec._sb)
        out += codec.data_to_send()
        assert len(out) <= fed, (len(out), fed)
        events += new
        assert len(events) <= fed, (len(events), fed)
    return codec, events, bytes(out)


def _accepted_only(codec: TelnetCodec) -> None:
    for option in _WATCHED:
        assert not codec.local_enabled(option) or option in codec.accept_local, option
        assert not codec.remote_enabled(option) or option in codec.accept_remote, option


def interleaved(setup: int, wire: bytes, sizes: Sequence[int]) -> None:
    """Our API calls between the chunks: each size byte also picks a call and an option."""
    codec, _ = make_codec(setup)
    budget = 0
    out = 0
    for k, chunk in enumerate(split(wire, sizes)):
        code = sizes[k % len(sizes)] - 1
        action, option = code % 9, _WATCHED[(code // 9) % len(_WATCHED)]
        if action == 1:
            codec.enable_local(option)
        elif action == 2:
            codec.disable_local(option)
        elif action == 3:
            codec.enable_remote(option)
        elif action == 4:
            codec.disable_remote(option)
        elif action == 5:
            codec.send_data(chunk)
        elif action == 6:
            codec.send_command(NOP)
        elif action == 7:
            codec.set_baudrate(0xFFFF_FFFF)
        elif action == 8:
            codec.flowcontrol(True)
        budget += 3 + 14 + 2 * len(chunk)  # one negotiation, one COM-PORT message or data
        codec.receive_data(chunk)
        out += len(codec.data_to_send())
        assert out <= budget, (out, budget)
        assert len(codec._sb) <= MAX_SUBNEGOTIATION
        for opt in _WATCHED:
            for side in _SIDES:
                assert codec.option_state(opt, side) in ("no", "yes", "wantno", "wantyes")
        _accepted_only(codec)


def test_one_input(data: bytes) -> None:
    fdp = atheris.FuzzedDataProvider(data)
    setup = fdp.ConsumeIntInRange(0, 31)
    n_sizes = fdp.ConsumeIntInRange(0, MAX_CHUNKS)
    sizes = [fdp.ConsumeIntInRange(1, 64) for _ in range(n_sizes)]
    wire = fdp.ConsumeBytes(fdp.remaining_bytes())

    whole, whole_events, whole_out = feed(setup, [wire])
    assert whole.violations == sum(isinstance(e, ProtocolViolation) for e in whole_events)
    assert whole.wire_bytes_in == len(wire)
    payload = sum(len(e.data) for e in whole_events if isinstance(e, Data))
    assert payload <= len(wire), (payload, len(wire))
    for e in whole_events:
        if isinstance(e, Subnegotiation):
            assert len(e.payload) <= MAX_SUBNEGOTIATION
        elif isinstance(e, Signature):
            assert len(e.text) < MAX_SUBNEGOTIATION

    if not sizes:
        sizes = [1]  # byte by byte: the harshest split
    cut, cut_events, cut_out = feed(setup, split(wire, sizes))
    assert coalesce(cut_events) == coalesce(whole_events), "chunking changed the events"
    assert cut_out == whole_out, "chunking changed the bytes sent"
    assert cut.violations == whole.violations
    for option in _WATCHED:
        for side in _SIDES:
            assert cut.option_state(option, side) == whole.option_state(option, side)
    _accepted_only(whole)
    interleaved(setup, wire, sizes)


if __name__ == "__main__":
    fuzz_main("telnet", test_one_input)
