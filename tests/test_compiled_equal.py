"""The compiled build answers every call as the plain-Python build does: same result, or same error.

mypyc enforces the declared types at run time, where Python only carries the value on: a compiled
hot module may raise on an input its source takes (a string where an ``int`` variable was reused,
a ``numpy.bool`` where a ``bool`` is declared, a ``numpy.int64`` where an ``int`` is), or keep a
different type of value (an ``int`` stored as ``float``). Random calls of each hot module's public
API (its ``__all__``) run in both installed builds (``tests/equal_harness.py``, one long-lived
process per build) with the inputs callers give them: settings tables as a user's TOML holds them,
valid and not (ints where floats are expected and back, strings, booleans, nested tables), numpy
scalars where a caller's numbers come from numpy, and the codec's angles, ticks, duties and byte
streams. Each answer names every value's type, so ``1`` and ``1.0`` differ.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from equal_harness import encode
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_compiled import _env

from armbench.drivers.model.protocol import MAX_TICKS, Command, Reply
from armbench.drivers.model.twin_parameters import (
    ARM_PARAMETERS,
    GEOMETRY_ERRORS,
    JOINT_PARAMETERS,
    TwinParameter,
)

pytestmark = pytest.mark.slow  # two wheels are built (the tests of test_compiled.py share them)

HERE = Path(__file__).resolve().parent
#: A modest number per property: the file runs in well under a minute once the wheels exist.
EXAMPLES = settings(max_examples=150, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

Call = Callable[..., None]


class Harness:
    """``tests/equal_harness.py`` running on one installed tree."""

    def __init__(self, tree: Path) -> None:
        self.process = subprocess.Popen([sys.executable, str(HERE / "equal_harness.py")],
                                        env=_env(tree), cwd=tree, stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True)
        self.build = self._read()["build"]

    def _read(self) -> dict[str, Any]:
        assert self.process.stdout is not None
        line = self.process.stdout.readline()
        if not line:  # it died: a crash in compiled code is a divergence too
            assert self.process.stderr is not None
            pytest.fail(f"the harness ended: {self.process.wait()} {self.process.stderr.read()}")
        answer: dict[str, Any] = json.loads(line)
        return answer

    def call(self, request: str) -> dict[str, Any]:
        assert self.process.stdin is not None
        self.process.stdin.write(request + "\n")
        self.process.stdin.flush()
        return self._read()

    def close(self) -> None:
        assert self.process.stdin is not None
        self.process.stdin.close()
        self.process.wait(timeout=60)


def same(compiled: dict[str, Any], source: dict[str, Any]) -> bool:
    """Whether two answers agree: equal results, or errors of one type with one message (a
    ``TypeError``'s wording is the interpreter's, not the project's: its type must agree)."""
    if "ok" in compiled or "ok" in source:
        return compiled == source
    (type_c, message_c), (type_s, message_s) = compiled["err"], source["err"]
    return bool(type_c == type_s and (type_c == "TypeError" or message_c == message_s))


@pytest.fixture(scope="module")
def call(compiled_tree: Path, pure_tree: Path) -> Iterator[Call]:
    """``call(module, op, *args)``: the call in both builds; fails unless they agree."""
    compiled, source = Harness(compiled_tree), Harness(pure_tree)
    assert (compiled.build, source.build) == ("compiled (mypyc)", "source")

    def both(module: str, op: str, *args: object) -> None:
        request = json.dumps({"module": module, "op": op, "args": encode(list(args))})
        answer_c, answer_s = compiled.call(request), source.call(request)
        assert same(answer_c, answer_s), (
            f"{module}.{op}{args!r}\ncompiled: {answer_c}\nsource:   {answer_s}")

    yield both
    compiled.close()
    source.close()


# --- inputs -------------------------------------------------------------------------------------

#: What else a TOML value or a caller's argument may be.
ODD: st.SearchStrategy[object] = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.integers(-(2**70), 2**70),
    st.booleans(), st.booleans().map(np.bool_), st.text(max_size=4), st.none(),
    st.just([1.0]), st.just({"x": 1}), st.floats(-1e3, 1e3).map(np.float32))


def numbers(low: float, high: float, *, odd: bool = True) -> st.SearchStrategy[object]:
    """A number in [low, high] as a TOML file (int or float) or numpy gives it, mostly; now and
    then (``odd``) anything else a file or a caller may hold."""
    inside: list[st.SearchStrategy[object]] = [st.floats(low, high),
                                               st.floats(low, high).map(np.float64)]
    if math.ceil(low) <= math.floor(high):
        ints = st.integers(math.ceil(low), min(math.floor(high), 2**62))
        inside += [ints, ints.map(np.int64)]
    return st.one_of(*inside, *inside, *inside, ODD) if odd else st.one_of(*inside)


def wholes(low: int, high: int, *, odd: bool = True) -> st.SearchStrategy[object]:
    """A whole number in [low, high] as Python, numpy or a whole float gives it, or (``odd``)
    anything."""
    ints = st.integers(low, high)
    inside = [ints, ints, ints, ints.map(np.int64), ints.map(float)]
    return st.one_of(*inside, ODD) if odd else st.one_of(*inside)


def reals(low: float, high: float, *, ints: bool = True) -> st.SearchStrategy[object]:
    """A number for an internal ``float`` parameter: a float (Python's or numpy's) or (``ints``)
    an int, mostly in [low, high], sometimes outside. A dataclass's ``float`` field takes no int:
    mypyc stores it as a float where Python keeps the int (the tables convert theirs)."""
    wider = st.floats(low - (high - low) - 1.0, high + (high - low) + 1.0)
    inside = st.floats(low, high)
    out: list[st.SearchStrategy[object]] = [inside, inside, inside.map(np.float64), wider]
    if ints and math.ceil(low) <= math.floor(high):
        out.append(st.integers(math.ceil(low), math.floor(high)))
    return st.one_of(*out)


def counts(low: int, high: int) -> st.SearchStrategy[int]:
    """A whole number for an internal ``int`` parameter: mostly in [low, high], now and then
    just outside. Never a boolean: mypyc's ``int`` keeps its value, not its type."""
    return st.one_of(st.integers(low, high), st.integers(low, high),
                     st.integers(low - 3, high + 3))


def table(fields: dict[str, st.SearchStrategy[object]], *, odd: bool = True
          ) -> st.SearchStrategy[object]:
    """A TOML table of some of ``fields``; now and then (``odd``) one with an unknown key, or
    not a table."""
    some = st.fixed_dictionaries({}, optional=fields)
    if not odd:
        return some
    return st.one_of(some, some, some, some,
                     st.fixed_dictionaries({"bogus": st.integers()}, optional=fields), ODD)


#: The numbers of each table of ``[emulator.physics]``.
_NUMBERS: dict[str, tuple[TwinParameter, ...]] = {
    scope: tuple(p for p in params if not p.choices) for scope, params in (
        ("joint", JOINT_PARAMETERS), ("arm", ARM_PARAMETERS), ("geometry", GEOMETRY_ERRORS))}


def emulator_tables(*, odd: bool) -> tuple[st.SearchStrategy[object], st.SearchStrategy[object]]:
    """``[emulator.physics]`` tables (with ``geometry_error`` and ``jN`` tables) and
    ``[emulator]`` tables (with ``[emulator.effects]`` and ``[emulator.physics]``): only valid
    values of any number type, or (``odd``) any values now and then."""

    def choice(*values: object) -> st.SearchStrategy[object]:
        return st.one_of(st.sampled_from(values), ODD) if odd else st.sampled_from(values)

    def number(low: float, high: float) -> st.SearchStrategy[object]:
        return numbers(low, high, odd=odd)

    def whole(low: int, high: int) -> st.SearchStrategy[object]:
        return wholes(low, high, odd=odd)

    def numbers_of(scope: str) -> dict[str, st.SearchStrategy[object]]:
        return {p.key: number(p.low, p.high) for p in _NUMBERS[scope]}

    joint = table({**numbers_of("joint"), **{p.key: choice(*p.choices)
                                             for p in JOINT_PARAMETERS if p.choices}}, odd=odd)
    geometry = table(numbers_of("geometry"), odd=odd)
    physics = table({**{f"j{k}": joint for k in range(1, 5)}, "geometry_error": geometry,
                     **numbers_of("arm")}, odd=odd)
    effects = table({"miss_probability": number(0.0, 0.99), "miss_above_duty": whole(0, 99)},
                    odd=odd)
    flags = st.one_of(st.booleans(), st.booleans().map(np.bool_), *([ODD] if odd else []))
    return physics, st.one_of(physics.map(lambda p: {"physics": p}), table({
        "profile": choice("physical", "ideal", *(["exact"] if odd else [])),
        "uart_receive": choice("polling", "blocking"),
        "reply_line_end": choice("", "\n", "\r\n", *(["\t"] if odd else [])),
        "fused_bus": flags, "i2c_hz": whole(10_000, 3_400_000), "rx_buffer_bytes": whole(1, 256),
        "tx_buffer_bytes": whole(1, 256), "deadband_counts": whole(0, 10),
        "recovery_duty": whole(1, 99), "seed": whole(0, 2**32 - 1),
        "eeprom_cells": whole(5, 4096), "loop_overhead_s": number(0.0, 1e-3),
        "eeprom_write_s_per_byte": number(0.0, 0.01), "boot_s": number(0.0, 1.0),
        "effects": effects, "physics": physics}, odd=odd))


PHYSICS_TABLE, EMULATOR_TABLE = emulator_tables(odd=True)
VALID_PHYSICS_TABLE, VALID_EMULATOR_TABLE = emulator_tables(odd=False)

ANGLES = st.one_of(st.floats(-10.0, 10.0), st.floats(-10.0, 10.0).map(np.float64),
                   st.integers(-7, 7), st.integers(-7, 7).map(np.int64), ODD)
TICKS = st.one_of(wholes(0, MAX_TICKS), st.integers(-5, MAX_TICKS + 5))
DUTIES = st.one_of(wholes(0, 99), st.integers(-3, 105))
LIMITS = st.one_of(st.floats(-4.0, 4.0), st.floats(-4.0, 4.0).map(np.float64),
                   st.integers(-3, 3), st.integers(-3, 3).map(np.int64))


def four(values: st.SearchStrategy[object]) -> st.SearchStrategy[object]:
    """Four values as a tuple or a list, now and then three or five."""
    return st.one_of(st.tuples(values, values, values, values),
                     st.lists(values, min_size=4, max_size=4),
                     st.lists(values, min_size=3, max_size=5))


def plain_four(values: st.SearchStrategy[Any]) -> st.SearchStrategy[tuple[Any, ...]]:
    return st.tuples(values, values, values, values)


VALID_TICKS = plain_four(st.integers(0, MAX_TICKS))
VALID_DUTIES = plain_four(st.integers(0, 99))


@st.composite
def streams(draw: st.DrawFn) -> list[bytes]:
    """A byte stream of valid replies and commands, torn and damaged ones and noise, cut into
    chunks at random places."""
    pieces = draw(st.lists(st.one_of(
        VALID_TICKS.map(lambda t: Reply(*t).encode()),
        st.tuples(VALID_TICKS, VALID_DUTIES).map(lambda td: Command(*td).encode()),
        st.binary(max_size=40), st.sampled_from([b"\r\n", b"$", b"#", b"\n"]),
        st.text("0123456789,$#\r\n", max_size=45).map(str.encode)), max_size=12))
    stream = b"".join(pieces)
    cuts = sorted(draw(st.lists(st.integers(0, len(stream)), max_size=6)))
    return [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]


# --- the properties -----------------------------------------------------------------------------


@EXAMPLES
@given(emulator=EMULATOR_TABLE)
def test_settings_tables_build_the_same_emulator(call: Call, emulator: object) -> None:
    """``[emulator]`` of a settings file, as :func:`emulator_settings` reads it (with
    ``[emulator.physics]``, its ``geometry_error`` and ``jN`` tables, ``[emulator.effects]``)."""
    call("physics", "emulator_settings", emulator)


@EXAMPLES
@given(emulator=VALID_EMULATOR_TABLE)
def test_valid_settings_tables_build_the_same_emulator(call: Call, emulator: object) -> None:
    """Valid tables only, each number an int, a float or a numpy scalar: the emulator each
    builds, to the type of every value."""
    call("physics", "emulator_settings", emulator)


@EXAMPLES
@given(physics=st.one_of(VALID_PHYSICS_TABLE, PHYSICS_TABLE))
def test_physics_tables_build_the_same_arm(call: Call, physics: object) -> None:
    call("physics", "arm_physics", physics)


@EXAMPLES
@given(fields=st.fixed_dictionaries({}, optional={
    p.name: st.one_of(st.floats(lo, hi), st.floats(lo, hi).map(np.float64))
    for p in _NUMBERS["joint"] for lo, hi in [(p.to_twin(p.low), p.to_twin(p.high))]}),
       args=st.tuples(reals(-20.0, 20.0), st.sampled_from([1, -1, 0]),
                      st.one_of(st.floats(10.0, 100.0), st.integers(10, 100)),
                      st.one_of(st.floats(0.0, 12_000.0), st.integers(0, 12_000)),
                      st.integers(1, 3200), reals(0.0, 1.0),
                      reals(-3.0, 3.0), reals(-0.5, 1.5)))
def test_joint_physics_gives_the_same_torques(call: Call, fields: dict[str, object],
                                              args: tuple[object, ...]) -> None:
    """:class:`JointPhysics` built as a caller (a calibration fit) may build it, and its
    methods (gear ratio and step rate as the joints give them: a divisor of zero would raise in
    compiled code where numpy's float gives infinity)."""
    call("physics", "joint_physics", fields, args)


@EXAMPLES
@given(fields=st.fixed_dictionaries({}, optional={
    k: reals(-0.01, 0.01, ints=False) for k in ("d1_m", "d2_m", "a2_m", "a3_m", "d4_m")}))
def test_geometry_errors_give_the_same_actual_arm(call: Call, fields: dict[str, object]) -> None:
    call("physics", "geometry_error", fields)


@EXAMPLES
@given(physics=st.one_of(VALID_PHYSICS_TABLE, PHYSICS_TABLE), q=plain_four(reals(-7.0, 7.0)),
       own=reals(-7.0, 7.0))
def test_the_mechanism_gives_the_same_gravity(call: Call, physics: object, q: object,
                                              own: object) -> None:
    """:class:`Mechanism` and :class:`TruthSample` at any pose."""
    call("physics", "mechanism", physics, q, own)


@EXAMPLES
@given(q=ANGLES, joint=st.one_of(st.none(), st.integers(1, 4)), ticks=TICKS, lower=LIMITS,
       upper=LIMITS, valid=VALID_TICKS)
def test_angle_conversions_agree(call: Call, q: object, joint: object, ticks: object,
                                 lower: object, upper: object, valid: tuple[int, ...]) -> None:
    """``rad_to_ticks`` and ``ticks_to_rad`` from any values; ``encode_reply`` (the emulator's
    fast path) from the valid ticks it is documented to take."""
    call("protocol", "rad_to_ticks", q, joint)
    call("protocol", "ticks_to_rad", ticks, lower, upper)
    call("protocol", "encode_reply", *valid)


@EXAMPLES
@given(ticks=st.one_of(VALID_TICKS, four(TICKS)), duties=st.one_of(VALID_DUTIES, four(DUTIES)),
       duty=st.one_of(st.integers(0, 99), DUTIES),
       q=st.one_of(plain_four(st.floats(-7.0, 7.0)), four(ANGLES)), lower=four(LIMITS),
       upper=four(LIMITS), replies=st.lists(VALID_TICKS, max_size=4),
       command=st.tuples(plain_four(st.integers(-5, MAX_TICKS + 5)),
                         plain_four(st.integers(-3, 105))))
def test_frames_encode_and_decode_alike(call: Call, ticks: object, duties: object, duty: object,
                                        q: object, lower: object, upper: object,
                                        replies: list[object],
                                        command: tuple[object, object]) -> None:
    """:class:`Reply`, :class:`Command` and :class:`AngleDecoder` from any values (a
    :class:`Command` built directly: from tuples of ints, its declared fields)."""
    call("protocol", "reply_from_ticks", ticks, lower, upper)
    call("protocol", "reply_from_rad", q)
    call("protocol", "command", *command, lower, upper)
    call("protocol", "command_from_rad", q, duty)
    call("protocol", "command_from_rad", q, duties)
    call("protocol", "angle_decoder", lower, upper, replies)


@EXAMPLES
@given(kind=st.sampled_from(["reply", "command", "other"]), chunks=streams())
def test_framers_cut_a_stream_alike(call: Call, kind: str, chunks: list[bytes]) -> None:
    call("protocol", "framer", kind, chunks)


@EXAMPLES
@given(duty=st.one_of(counts(1, 99), ODD, st.integers(1, 99).map(np.int64)),
       effects=st.fixed_dictionaries({}, optional={
           "miss_probability": reals(0.0, 0.99, ints=False), "miss_above_duty": counts(0, 99)}),
       run=st.tuples(st.integers(0, 10_000), st.integers(1, 101), st.sampled_from([1, -1]),
                     st.one_of(st.none(), st.integers(1, 50)), st.integers(0, 50),
                     st.integers(-100, 100), st.integers(-5, 5), st.integers(-5, 5),
                     st.integers(-1, 1), st.booleans()),
       pulses=st.lists(st.integers(0, 60), max_size=4))
def test_stepper_vocabulary_agrees(call: Call, duty: object, effects: object,
                                   run: tuple[object, ...], pulses: list[object]) -> None:
    """``step_period_ticks``, :class:`PhysicalEffects`, :class:`Run`, :class:`Transition`."""
    call("stepper", "step_period_ticks", duty)
    call("stepper", "physical_effects", effects)
    call("stepper", "run", run, pulses)
    call("stepper", "transition", run[0], "cw", run[5])


@st.composite
def joint_actions(draw: st.DrawFn) -> list[list[object]]:
    """A caller's inputs to a joint over time (ticks forward, now and then back)."""
    tick = 0
    actions: list[list[object]] = []
    for _ in range(draw(st.integers(1, 8))):
        tick = max(0, tick + draw(st.integers(-100, 30_000)))
        at = tick
        actions.append(draw(st.one_of(
            st.tuples(st.just("set_reference"), st.just(at), st.integers(-40_000, 40_000),
                      st.one_of(counts(0, 99), counts(0, 99), ODD)),
            st.tuples(st.just("home"), st.just(at), st.sampled_from([1, -1, 0]), counts(1, 99)),
            st.tuples(st.just("stall"), st.just(at), st.booleans()),
            st.tuples(st.just("sample"), st.just(at)),
            st.tuples(st.just("advance"), st.just(at)),
            st.tuples(st.just("next_event_tick"))).map(list)))
    return actions


@EXAMPLES
@given(index=st.integers(0, 3), seed=counts(0, 1000), deadband=counts(0, 5),
       motor_steps=st.integers(-3000, 3000), noise=reals(0.0, 1e-3), physical=st.booleans(),
       effects=st.one_of(st.none(), st.fixed_dictionaries({}, optional={
           "miss_probability": st.floats(0.0, 0.3), "miss_above_duty": st.integers(0, 99)})),
       actions=joint_actions())
def test_joint_models_move_alike(call: Call, index: int, seed: object, deadband: object,
                                 motor_steps: object, noise: object, physical: bool,
                                 effects: object, actions: list[list[object]]) -> None:
    """:class:`JointModel` driven as the boards and their callers drive it."""
    kwargs = {"seed": seed, "deadband_counts": deadband, "motor_steps": motor_steps,
              "noise_per_count": noise, "physical": physical}
    call("joint", "joint_model", index, kwargs, effects, actions)


ADDRESSES = st.one_of(st.integers(0x08, 0x77), st.integers(0, 0x7F))
MESSAGES = st.lists(st.one_of(st.tuples(ADDRESSES, st.just(True), st.integers(0, 8)),
                              st.tuples(ADDRESSES, st.just(False), st.binary(max_size=8))).map(
                                  list), min_size=1, max_size=3)


@EXAMPLES
@given(msgs=MESSAGES, now=reals(0.0, 100.0), bit_s=st.sampled_from([1e-5, 2.5e-6]),
       devices=st.lists(st.tuples(ADDRESSES, st.binary(max_size=4)), max_size=3),
       transactions=st.lists(MESSAGES, max_size=5))
def test_i2c_transactions_agree(call: Call, msgs: list[object], now: object, bit_s: float,
                                devices: list[object], transactions: list[object]) -> None:
    """``transaction_bits`` and the bus's timing, statistics and NAKs."""
    call("i2c", "transaction_bits", msgs)
    call("i2c", "bus", now, bit_s, devices, transactions)


TIMES = st.floats(0.0, 0.05)


@EXAMPLES
@given(byte_s=st.one_of(st.sampled_from([86.8e-6, 1e-3]), st.floats(1e-6, 1e-3)),
       buffers=st.tuples(st.integers(1, 64), st.integers(1, 64)), begin_s=TIMES,
       actions=st.lists(st.one_of(
           st.tuples(st.just("host_write"), st.binary(max_size=40), TIMES),
           st.tuples(st.just("read"), TIMES, st.one_of(st.none(), TIMES)),
           st.tuples(st.just("time_of_next"), st.integers(0, 255)),
           st.tuples(st.just("write"), st.binary(max_size=80), TIMES),
           st.tuples(st.just("cut"))).map(list), max_size=10))
def test_uarts_carry_bytes_alike(call: Call, byte_s: object, buffers: tuple[object, object],
                                 begin_s: float, actions: list[object]) -> None:
    call("uart", "uart", byte_s, *buffers, begin_s, actions)


@st.composite
def slave_actions(draw: st.DrawFn) -> list[list[object]]:
    """The master's traffic to a slave and the faults injected into it, over time."""
    t = 0.0
    actions: list[list[object]] = []
    for _ in range(draw(st.integers(1, 8))):
        t += draw(st.floats(0.0, 0.5))
        reference = st.tuples(st.just(1), st.integers(0, 0xFFFF), st.integers(0, 120)).map(
            lambda r: bytes((r[0], r[1] & 0xFF, r[1] >> 8, r[2])))
        actions.append(draw(st.one_of(
            st.tuples(st.just("on_receive"), st.one_of(reference, st.binary(max_size=5)),
                      st.just(t)),
            st.tuples(st.just("on_request"), st.integers(1, 4), st.just(t)),
            st.tuples(st.just("apply_reference"), st.just(t), st.integers(0, MAX_TICKS),
                      counts(0, 99)),
            st.tuples(st.just("sample_position"), st.just(t)),
            st.tuples(st.just("set_stalled"), st.just(t), st.booleans())).map(list)))
    return actions


@EXAMPLES
@given(number=st.integers(2, 4), emulator=st.fixed_dictionaries({}, optional={
    "profile": st.sampled_from(["physical", "ideal"]), "seed": st.integers(0, 100),
    "deadband_counts": st.integers(0, 3)}), motor_steps=st.integers(-2000, 2000),
       actions=slave_actions())
def test_slave_boards_answer_alike(call: Call, number: int, emulator: object, motor_steps: int,
                                   actions: list[object]) -> None:
    """A slave board's Wire handlers and references, as the master and the faults drive it."""
    call("boards", "slave", number, emulator, motor_steps, actions)


@settings(EXAMPLES, max_examples=25)
@given(emulator=VALID_EMULATOR_TABLE, q=plain_four(st.floats(-0.5, 0.5)), duty=st.integers(1, 99))
def test_emulators_built_from_any_valid_table_reply_alike(call: Call, emulator: object,
                                                          q: object, duty: int) -> None:
    """The whole emulator from a valid ``[emulator]`` table (numbers of any type): the boards read
    their settings in compiled code."""
    call("boards", "emulator", emulator, q, duty)


@EXAMPLES
@given(lower=four(LIMITS), upper=four(LIMITS), seq0=st.integers(0, 10),
       chunks=streams(), every=st.lists(st.booleans(), min_size=7, max_size=7),
       restart=st.integers(0, 8))
def test_reply_streams_give_the_same_states(call: Call, lower: object, upper: object,
                                            seq0: object, chunks: list[bytes],
                                            every: list[bool], restart: int) -> None:
    """The driver's reply stream (``drivers.host.replies``) over any byte stream, by single
    replies and batches (``every``: a state per reply), with a reconnection somewhere. Its
    caller, the link, numbers the states from a count (``seq0``, an ``int``) and gives the
    joints' limits as the settings hold them."""
    fed = [(c, every[k % 7], k == restart) for k, c in enumerate(chunks)]
    call("replies", "stream", lower, upper, seq0, fed)


@EXAMPLES
@given(data=st.data(), silence_s=st.sampled_from([0.05, 0.5]), mark=st.floats(-3.0, 3.0))
def test_intakes_take_replies_alike(call: Call, data: st.DataObject, silence_s: float,
                                    mark: float) -> None:
    """The link's per-reply path (``drivers.host.intake``): chunks drawn from a few replies (so
    that an arm at rest repeats its reply) and damaged or torn ones, pushed with gaps that are
    sometimes a silence: the states, recordings, capture, outages and the waiter's answer."""
    replies = data.draw(st.lists(VALID_TICKS.map(lambda t: Reply(*t).encode()), min_size=1,
                                 max_size=3))
    chunk = st.one_of(st.sampled_from(replies), st.sampled_from(replies).map(lambda r: r[:9]),
                      st.binary(max_size=30), st.sampled_from(replies).map(lambda r: r + r))
    chunks = data.draw(st.lists(chunk, max_size=12))
    times = data.draw(st.lists(st.sampled_from([0.0, 0.002, 0.01, 0.3, 1.0]),
                               min_size=len(chunks), max_size=len(chunks)))
    call("intake", "push", silence_s, mark, times, chunks)


@EXAMPLES
@given(waits=st.lists(st.tuples(st.floats(-2.0, 2.0), st.one_of(
           st.floats(0.0, 0.2), st.just(math.inf))), max_size=4),
       q1s=st.lists(st.one_of(st.floats(-2.0, 2.0), st.integers(-2, 2)), max_size=12))
def test_waiters_resolve_alike(call: Call, waits: list[tuple[float, float]],
                               q1s: list[object]) -> None:
    """The driver's waiters (``drivers.host.waiters``): resolved by a state, by their deadline
    or by closing, in the same order."""
    call("waiters", "offer", [m for m, _ in waits], [w for _, w in waits], q1s)


@EXAMPLES
@given(tol=plain_four(st.one_of(st.floats(0.0, 0.05), st.integers(0, 1))),
       goal=plain_four(st.floats(-3.0, 3.0)), duties=VALID_DUTIES,
       ahead_s=st.one_of(st.just(0.0), st.floats(0.0, 0.5)),
       qs=st.lists(plain_four(st.floats(-3.0, 3.0)), max_size=10))
def test_arrival_is_seen_alike(call: Call, tol: object, goal: object, duties: object,
                               ahead_s: float, qs: list[object]) -> None:
    """The driver's arrival tracker (``drivers.host.arrival``): arrival, the look-ahead of a
    path and the progress bookkeeping that decides a resend."""
    call("arrival", "reached", tol, goal, duties, ahead_s, qs)
