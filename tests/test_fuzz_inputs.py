"""Bounded property-based counterparts of the atheris harnesses in ``fuzz/`` (fast, every run).

What ``tests/test_protocol.py``, ``tests/test_telnet.py`` and ``tests/test_emulator.py`` already
check with hypothesis is not repeated; these add:

* the settings loader on random TOML-shaped mappings (known keys with values of every TOML type,
  out-of-range and huge numbers, unknown keys): only ``SettingsError`` naming a field escapes,
  and accepted settings load back from their own ``to_mapping()``;
* the emulator settings table and fault lists the same way;
* the telnet codec in both roles, with non-default accept sets and with our own requests pending
  (WANTYES/WANTNO states) against random wire bytes: bounded output, same result in any chunking;
* both framer kinds on noise that contains ``$``, ``#``, CR/LF and frame fragments, in random
  chunks: same frames however chunked, frames found in the input, byte accounting closes.

The crashes these found are regression tests in ``tests/test_fuzz_regressions.py``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from armbench.drivers.model.protocol import (
    COMMAND_LEN,
    REPLY_LEN,
    Command,
    FrameError,
    FrameKind,
    Framer,
    Reply,
)
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.drivers.telnet import (
    BINARY,
    COM_PORT_OPTION,
    DO,
    DONT,
    ECHO,
    IAC,
    MAX_SUBNEGOTIATION,
    SB,
    SE,
    SGA,
    WILL,
    WONT,
    Data,
    Event,
    ProtocolViolation,
    Side,
    TelnetCodec,
    coalesce,
)
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.fakes.firmware.faults import FAULT_KINDS, Fault, parse_faults

FAST = settings(max_examples=100, deadline=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


# --- TOML-shaped values ---------------------------------------------------------------------------
_EDGE_NUMBERS = (0, 0.0, -0.0, 1, -1, 2, 1.5, 0.5, 1e-320, 5e-324, -5e-324, 1e12, 1e306, 1e308,
                 -1e308, 360, 0x77, 0x08, 2**32, 2**31 - 1, 2**63 - 1, -(2**63), 10**30,
                 10**309, -(10**400), math.inf, -math.inf, math.nan)
_NUMBERS = st.one_of(
    st.sampled_from(_EDGE_NUMBERS),
    st.sampled_from(_EDGE_NUMBERS),
    st.integers(-300, 300),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-(2**63), 2**63 - 1),  # TOML's range; tomllib accepts more (see _EDGE_NUMBERS)
)
_SCALARS = st.one_of(_NUMBERS, _NUMBERS, st.booleans(), st.text(max_size=6),
                     st.sampled_from(["N", "E", "polling", "blocking", "\r\n", "to_robot"]))
_VALUES = st.recursive(
    _SCALARS,
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner,
                                                                max_size=3),
    max_leaves=3)


def _table(keys: Iterable[str], values: st.SearchStrategy[Any] = _VALUES,
           base: Mapping[str, Any] | None = None) -> st.SearchStrategy[dict[str, Any]]:
    """A TOML table: ``base`` with up to 3 of ``keys`` set to random values (sometimes also an
    unknown key). A valid base with a field or two changed reaches the deep checks."""
    known = st.dictionaries(st.sampled_from(sorted(keys)), values, max_size=3)
    junk = st.dictionaries(st.text(max_size=5), values, max_size=1)
    changes = st.one_of(known, known, known, st.builds(lambda a, b: {**a, **b}, known, junk))
    return changes.map(lambda c: {**(base or {}), **c})


_GEOMETRY = ("d1_m", "d2_m", "a2_m", "a3_m", "d4_m")
_SERIAL = ("baudrate", "bytesize", "parity", "stopbits")
_JOINT = ("gear_ratio", "lower_deg", "upper_deg", "offset_deg", "sign", "hall_deg",
          "step_angle_deg", "microsteps", "encoder_counts_per_motor_rev", "i2c_address")
_EMULATOR = ("uart_receive", "i2c_hz", "rx_buffer_bytes", "tx_buffer_bytes", "loop_overhead_s",
             "reply_line_end", "deadband_counts", "recovery_duty", "eeprom_write_s_per_byte",
             "eeprom_cells", "seed")
_EFFECTS = ("miss_probability", "miss_above_duty")
_FAULT = ("kind", "at_s", "after_frames", "duration_s", "joint", "probability", "count",
          "delay_s", "direction")

_EMULATOR_TABLE = st.one_of(
    _table(_EMULATOR),
    st.builds(lambda t, fx: {**t, "effects": fx}, _table(_EMULATOR), _table(_EFFECTS)),
    _VALUES,  # not a table at all
)
_FAULT_VALUES = st.one_of(_VALUES, st.sampled_from(FAULT_KINDS))
_FAULT_BASES = st.one_of(
    st.builds(lambda k: {"kind": k, "at_s": 0.0}, st.sampled_from(FAULT_KINDS)),
    st.builds(lambda k: {"kind": k, "after_frames": 1}, st.sampled_from(FAULT_KINDS)),
    st.builds(lambda k: {"kind": k, "at_s": 1, "joint": 3}, st.sampled_from(FAULT_KINDS)),
    st.just({}),
)
_FAULT_TABLE = _FAULT_BASES.flatmap(lambda base: _table(_FAULT, _FAULT_VALUES, base))
_DOCUMENTS = st.fixed_dictionaries({}, optional={
    "geometry": _table(_GEOMETRY),
    "serial": _table(_SERIAL),
    "joints": st.dictionaries(st.sampled_from(["j1", "j2", "j3", "j4", "j5"]), _table(_JOINT),
                              max_size=3),
    "emulator": _EMULATOR_TABLE,
    "bench": _VALUES,
    "faults": st.lists(_FAULT_TABLE, max_size=3),
}).flatmap(lambda d: st.one_of(st.just(d), st.builds(lambda j: {**d, **j}, _table(["colour"]))))


def _is_error_ok(exc: SettingsError) -> bool:
    return isinstance(exc.field, str) and str(exc).startswith(exc.field)


def _numbers_in(value: Any) -> Iterable[Any]:
    if isinstance(value, Mapping):
        for v in value.values():
            yield from _numbers_in(v)
    elif isinstance(value, list):
        for v in value:
            yield from _numbers_in(v)
    elif isinstance(value, int | float) and not isinstance(value, bool):
        yield value


# --- settings -------------------------------------------------------------------------------------
@FAST
@given(_DOCUMENTS)
def test_settings_from_random_mappings_raise_only_settings_error(doc: dict[str, Any]) -> None:
    try:
        robot = RobotSettings.from_mapping(doc)
    except SettingsError as exc:
        assert _is_error_ok(exc), exc
        return
    again = RobotSettings.from_mapping(robot.to_mapping())
    assert again.geometry == robot.geometry and again.serial == robot.serial
    for a, b in zip(again.joints, robot.joints, strict=True):
        assert math.isclose(a.lower_rad, b.lower_rad, abs_tol=1e-9)
        assert math.isclose(a.upper_rad, b.upper_rad, abs_tol=1e-9)
        assert (a.gear_ratio, a.sign, a.microsteps, a.i2c_address) == (
            b.gear_ratio, b.sign, b.microsteps, b.i2c_address)


@FAST
@given(_EMULATOR_TABLE)
def test_emulator_table_raises_only_settings_error(table: Any) -> None:
    robot = RobotSettings(sections={"emulator": table})
    try:
        emu = emulator_settings(robot)
    except SettingsError as exc:
        assert _is_error_ok(exc), exc
        return
    assert emu.uart_receive in ("polling", "blocking")
    assert emu.reply_line_end in ("", "\n", "\r\n")
    assert 1 <= emu.recovery_duty <= 99


@FAST
@given(st.lists(_FAULT_TABLE, max_size=4))
def test_fault_lists_raise_only_settings_error(items: list[Any]) -> None:
    try:
        faults = parse_faults(items)
    except SettingsError as exc:
        assert _is_error_ok(exc), exc
        assert exc.field.startswith("faults["), exc.field
        return
    assert len(faults) == len(items)
    for f in faults:
        assert isinstance(f, Fault) and f.kind in FAULT_KINDS
        assert (f.at_s is None) != (f.after_frames is None)
        assert f.joint is None or f.joint in (1, 2, 3, 4)
        assert f.direction in ("to_host", "to_robot")


# --- telnet ---------------------------------------------------------------------------------------
_OPTIONS = st.sampled_from([BINARY, ECHO, SGA, COM_PORT_OPTION, 24, 255])
_WIRE_TOKENS = st.one_of(
    st.binary(max_size=8),
    st.sampled_from([b"\xff\xff", b"\r\x00", b"\r\n", b"\r", b"\xff", bytes([IAC, SE])]),
    st.builds(lambda v, o: bytes([IAC, v, o]), st.sampled_from([WILL, WONT, DO, DONT]), _OPTIONS),
    st.builds(lambda o, p, end: bytes([IAC, SB, o]) + p + (bytes([IAC, SE]) if end else b""),
              st.sampled_from([COM_PORT_OPTION, 24]),
              st.one_of(st.binary(max_size=6),
                        st.builds(bytes, st.lists(st.integers(0, 112), min_size=1, max_size=5))),
              st.booleans()),
)
_SIDES: tuple[Side, Side] = ("local", "remote")
_ACCEPT: tuple[tuple[int, ...] | None, ...] = (None, (), tuple(range(256)),
                                               (BINARY, SGA, COM_PORT_OPTION, ECHO))


def _codec(role: str, accept: int, requests: int) -> TelnetCodec:
    sets = _ACCEPT[accept]
    codec = (TelnetCodec(role="server" if role == "server" else "client") if sets is None else
             TelnetCodec(role="server" if role == "server" else "client", accept_local=sets,
                         accept_remote=sets))
    if requests >= 1:
        for option in (COM_PORT_OPTION, BINARY):
            codec.enable_local(option)
            codec.enable_remote(option)
    if requests >= 2:
        for option in (COM_PORT_OPTION, BINARY):
            codec.disable_local(option)
            codec.disable_remote(option)
    codec.data_to_send()
    return codec


@FAST
@given(st.lists(_WIRE_TOKENS, max_size=30).map(b"".join), st.sampled_from(["client", "server"]),
       st.integers(0, 3), st.integers(0, 2), st.lists(st.integers(1, 20), min_size=1, max_size=5))
def test_telnet_any_role_and_state_bounded_and_chunking_invariant(
        wire: bytes, role: str, accept: int, requests: int, sizes: list[int]) -> None:
    whole = _codec(role, accept, requests)
    whole_events = whole.receive_data(wire)
    whole_out = whole.data_to_send()
    assert len(whole_out) <= len(wire)
    assert len(whole_events) <= len(wire)
    assert sum(len(e.data) for e in whole_events if isinstance(e, Data)) <= len(wire)
    assert whole.violations == sum(isinstance(e, ProtocolViolation) for e in whole_events)
    assert len(whole._sb) <= MAX_SUBNEGOTIATION

    cut = _codec(role, accept, requests)
    cut_events: list[Event] = []
    cut_out = b""
    pos = k = 0
    while pos < len(wire):
        size = sizes[k % len(sizes)]
        cut_events += cut.receive_data(wire[pos:pos + size])
        cut_out += cut.data_to_send()
        pos += size
        k += 1
    assert coalesce(cut_events) == coalesce(whole_events)
    assert cut_out == whole_out
    for option in (BINARY, ECHO, SGA, COM_PORT_OPTION, 24, 255):
        for side in _SIDES:
            assert cut.option_state(option, side) == whole.option_state(option, side)


# --- framer ---------------------------------------------------------------------------------------
_REPLIES = st.builds(Reply, *[st.integers(0, 62832)] * 4).map(Reply.encode)
_COMMANDS = st.builds(
    lambda t, d: Command(t, d),
    st.tuples(*[st.integers(0, 62832)] * 4),
    st.tuples(*[st.integers(0, 99)] * 4)).map(Command.encode)
_FRAME_NOISE = st.one_of(
    _REPLIES, _COMMANDS,
    st.builds(lambda f, n: f[:n], st.one_of(_REPLIES, _COMMANDS), st.integers(0, 36)),
    st.builds(lambda f, n: f[n:], st.one_of(_REPLIES, _COMMANDS), st.integers(1, 36)),
    st.sampled_from([b"$", b"#", b"\r\n", b"\r", b"\n", b",", b"62833", b"$$", b"##"]),
    st.binary(max_size=10),
)


@settings(max_examples=200, deadline=None)
@given(st.lists(_FRAME_NOISE, max_size=20).map(b"".join),
       st.lists(st.integers(1, 40), min_size=1, max_size=6),
       st.sampled_from(["reply", "command"]))
def test_framer_chunking_invariants_on_frame_shaped_noise(stream: bytes, sizes: list[int],
                                                           kind: FrameKind) -> None:
    flen = REPLY_LEN if kind == "reply" else COMMAND_LEN
    whole = Framer(kind)
    whole_frames = [e for e in whole.feed(stream) if not isinstance(e, FrameError)]
    framer = Framer(kind)
    events = []
    pos = k = 0
    while pos < len(stream):
        size = sizes[k % len(sizes)]
        events += framer.feed(stream[pos:pos + size])
        assert framer.buffered < flen
        pos += size
        k += 1
    frames = [e for e in events if not isinstance(e, FrameError)]
    errors = [e for e in events if isinstance(e, FrameError)]
    assert frames == whole_frames
    assert all(isinstance(f, Reply if kind == "reply" else Command) for f in frames)
    at = 0
    for f in frames:
        at = stream.index(f.encode(), at) + flen
    crlf = stream.count(b"\r") + stream.count(b"\n")
    total = framer.frames * flen + framer.discarded_bytes + framer.buffered
    assert len(stream) - crlf <= total <= len(stream)
    assert sum(e.size for e in errors) + framer.frames * flen + framer.buffered <= len(stream)
    assert all(e.raw in stream and len(e.raw) <= 64 for e in errors)
    framer.flush()
    assert framer.buffered == 0
    assert framer.discarded_bytes <= len(stream)
