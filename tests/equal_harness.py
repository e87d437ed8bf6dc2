"""Calls into the hot modules (``cli/perf/hot_modules.py``) on request: what
``tests/test_compiled_equal.py`` runs in the compiled build and in the plain-Python one, the same
calls in both, to compare.

Run as a script with ``PYTHONPATH`` on one build's installed tree, it reads one call a line on
stdin, ``{"op": name, "args": [...]}`` (values tagged by :func:`encode` where JSON has no type
for them: tuples, bytes, numpy scalars, dictionaries), and answers one line, ``{"ok": text}``
with the result's canonical text (:func:`canon`: every value with its type, so ``1`` and
``1.0`` differ) or ``{"err": [type, message]}`` with the exception the call raised.
"""

from __future__ import annotations

import asyncio
import dataclasses
import enum
import json
import math
import sys
from collections.abc import Callable, Mapping
from fractions import Fraction
from typing import Any

import numpy as np

#: numpy scalar types a call may carry, by the name :func:`encode` tags them with.
NUMPY_TYPES: dict[str, type[np.generic]] = {"float64": np.float64, "int64": np.int64,
                                             "bool_": np.bool_, "float32": np.float32}


def encode(value: object) -> object:
    """``value`` as JSON: tuples, bytes, numpy scalars and dictionaries tagged, so :func:`decode`
    gives back the same types (JSON would make lists, strings and Python numbers of them)."""
    if isinstance(value, np.generic):
        name = next(k for k, t in NUMPY_TYPES.items() if type(value) is t)
        return {"$np": name, "v": value.item()}
    if isinstance(value, bytes):
        return {"$b": value.hex()}
    if isinstance(value, tuple):
        return {"$t": [encode(v) for v in value]}
    if isinstance(value, list):
        return [encode(v) for v in value]
    if isinstance(value, dict):
        return {"$d": [[k, encode(v)] for k, v in value.items()]}
    return value


def decode(value: Any) -> Any:
    """The value :func:`encode` encoded."""
    if isinstance(value, list):
        return [decode(v) for v in value]
    if isinstance(value, dict):
        if "$np" in value:
            return NUMPY_TYPES[value["$np"]](value["v"])
        if "$b" in value:
            return bytes.fromhex(value["$b"])
        if "$t" in value:
            return tuple(decode(v) for v in value["$t"])
        return {k: decode(v) for k, v in value["$d"]}
    return value


def canon(value: object) -> str:
    """``value`` as text naming every part's type: what must be equal in both builds.

    A float subclass (``numpy.float64``) reads as the float it is: mypyc stores it in a
    ``float`` variable as its value, which behaves alike; an int where a float was, or a
    ``numpy.bool`` where a bool was, differs."""
    if value is None or isinstance(value, (bool, str, bytes, Fraction)):
        return repr(value)
    if isinstance(value, float):  # numpy.float64 is a float: same value, same behaviour
        return f"float:{float(value)!r}"
    if isinstance(value, (int, np.generic)):
        return f"{type(value).__name__}:{value!r}"
    if isinstance(value, enum.Enum):
        return f"{type(value).__name__}.{value.name}"
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        parts = (f"{f.name}={canon(getattr(value, f.name))}" for f in dataclasses.fields(value))
        return f"{type(value).__name__}({', '.join(parts)})"
    if isinstance(value, tuple):
        return f"{type(value).__name__}({', '.join(canon(v) for v in value)})"
    if isinstance(value, list):
        return f"[{', '.join(canon(v) for v in value)}]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k!r}: {canon(v)}" for k, v in value.items()) + "}"
    if type(value).__name__ == "Mechanism":
        return f"Mechanism({canon(value.physics)}, {canon(value.actual)})"  # type: ignore[attr-defined]
    raise TypeError(f"no canonical form for {type(value).__name__}: {value!r}")


# --- the calls ----------------------------------------------------------------------------------
# Each takes decoded JSON values and returns what is compared; imports are inside, so the test
# process can import this module for encode() without loading a build.


def _protocol(name: str, *args: Any) -> object:
    from armbench.drivers.model import protocol as p
    if name == "rad_to_ticks":
        return p.rad_to_ticks(*args)
    if name == "ticks_to_rad":
        return p.ticks_to_rad(*args)
    if name == "encode_reply":
        return p.encode_reply(*args)
    if name == "reply_from_ticks":
        reply = p.Reply.from_ticks(args[0])
        return reply, reply.encode(), reply.angles_rad(args[1], args[2])
    if name == "reply_from_rad":
        reply = p.Reply.from_rad(args[0])
        return reply, reply.encode()
    if name == "angle_decoder":
        decoder = p.AngleDecoder(args[0], args[1])
        return [decoder(p.Reply.from_ticks(t)) for t in args[2]]
    if name == "command":
        command = p.Command(args[0], args[1])
        return command, command.encode(), command.angles_rad(args[2], args[3])
    if name == "command_from_rad":
        command = p.Command.from_rad(args[0], args[1])
        return command, command.encode()
    if name == "framer":
        framer = p.Framer(args[0])
        events: list[object] = []
        for chunk in args[1]:
            one = framer.one_reply(chunk)
            events.append(("one", one) if one is not None else ("feed", framer.feed(chunk)))
            events.append(framer.buffered)
        events.append(framer.flush())
        return events, framer.frames, framer.errors, framer.discarded_bytes
    raise ValueError(f"no protocol call {name!r}")


def _robot(emulator: object = None) -> Any:
    from armbench.drivers.model.settings import RobotSettings

    return RobotSettings(sections={} if emulator is None else {"emulator": emulator})


def _physics(name: str, *args: Any) -> object:
    from armbench.fakes.twin import physics as ph
    if name == "arm_physics":
        return ph.arm_physics(*args)
    if name == "emulator_settings":
        from armbench.fakes.firmware.emulator_settings import actual_robot, emulator_settings

        robot = _robot(args[0])
        return emulator_settings(robot), actual_robot(robot)
    if name == "joint_physics":
        joint = ph.ideal_joint(**args[0])
        load_nm, direction, gear_ratio, steps_per_s, steps_per_rev, fraction, normal, speed = (
            args[1])
        return (joint, joint.pullout_at_nm(steps_per_s),
                joint.required_nm(load_nm, direction, gear_ratio, steps_per_s, steps_per_rev),
                joint.loss_fraction(load_nm, direction, gear_ratio, steps_per_s, steps_per_rev),
                joint.jittered(fraction, normal), joint.stick_band_rad(speed))
    if name == "geometry_error":
        error = dataclasses.replace(ph.ideal_geometry(), **args[0])
        return error, dataclasses.replace(ph.DEFAULT_ARM, geometry_error=error).actual_settings(
            _robot())
    if name == "mechanism":
        physics = ph.arm_physics(args[0])
        q = args[1]
        mechanism = ph.Mechanism(physics, _robot(), lambda: q)
        sample = ph.TruthSample(0.5, q, q, q, mechanism)
        return (mechanism.gravity_nm(q), mechanism.true_rad(q), sample.true_rad,
                [mechanism.load_of(j)(args[2]) for j in range(4)], mechanism == mechanism)
    raise ValueError(f"no physics call {name!r}")


def _stepper(name: str, *args: Any) -> object:
    from armbench.fakes.twin import joint as jo
    from armbench.fakes.twin import stepper as st
    if name == "step_period_ticks":
        return st.step_period_ticks(args[0]), jo.step_period_ticks(args[0])
    if name == "physical_effects":
        return st.PhysicalEffects(**args[0])
    if name == "run":
        run = st.Run(*args[0])
        return run, [(run.steps_after(n), run.offset_after(n)) for n in args[1]]
    if name == "transition":
        return st.Transition(*args)
    raise ValueError(f"no stepper call {name!r}")


def _joint(name: str, *args: Any) -> object:
    from armbench.drivers.model.settings import DEFAULT_JOINTS
    from armbench.fakes.twin.joint import JointModel, PhysicalEffects
    from armbench.fakes.twin.physics import DEFAULT_JOINT_PHYSICS

    if name != "joint_model":
        raise ValueError(f"no joint call {name!r}")
    index, kwargs, effects, actions = args
    if effects is not None:
        kwargs["effects"] = PhysicalEffects(**effects)
    if kwargs.pop("physical", False):
        kwargs["physics"] = DEFAULT_JOINT_PHYSICS[index]
        kwargs["load"] = lambda q: 0.4 * q
    model = JointModel(DEFAULT_JOINTS[index], **kwargs)
    out: list[object] = []
    for action, *call in actions:
        if action == "next_event_tick":
            out.append(model.next_event_tick())
        else:
            out.append(getattr(model, action)(*call))
        out.append((model.tick, model.counter, model.motor_steps, model.state, model.motion,
                    model.target_counts, model.duty, model.homing, model.at_limit,
                    model.stalled, model.true_angle_rad(), model.loaded_angle_rad(),
                    model.load_nm, model.drain_transitions()))
    out.append((model.pulses, model.steps_taken, model.steps_missed, model.steps_blocked,
                model.spurious_counts))
    return out


class _Device:
    """A slave that answers reads with a fixed pattern and keeps what it was written."""

    def __init__(self, answer: bytes) -> None:
        self.answer = answer
        self.received: list[tuple[bytes, float]] = []

    def on_receive(self, data: bytes, t_s: float) -> None:
        self.received.append((bytes(data), t_s))

    def on_request(self, length: int, t_s: float) -> bytes:
        return self.answer


def _i2c(name: str, *args: Any) -> object:
    from armbench.fakes.firmware import i2c
    from armbench.fakes.firmware.i2c_messages import I2CMessage

    def message(spec: list[Any]) -> Any:
        address, read, data = spec
        return I2CMessage.read(address, data) if read else I2CMessage.write(address, data)

    if name == "transaction_bits":
        return i2c.transaction_bits(tuple(message(m) for m in args[0]))
    if name == "bus":
        now, bit_s, devices, transactions = args
        clock = i2c.BusClock(now)
        bus = i2c.I2CBus(clock, bit_s)
        slaves = {address: _Device(answer) for address, answer in devices}
        out: list[object] = []
        for address, slave in slaves.items():
            try:
                bus.attach(address, slave)
            except ValueError as exc:
                out.append(("attach", type(exc).__name__, str(exc)))
        for transaction in transactions:
            msgs = [message(m) for m in transaction]
            try:
                bus.i2c_rdwr(*msgs)
            except OSError as exc:
                out.append(("OSError", exc.errno, str(exc)))
            out.append((clock.now, [bytes(m) for m in msgs]))
        out.append([(a, s.received) for a, s in slaves.items()])
        return out, bus.stats
    raise ValueError(f"no i2c call {name!r}")


def _uart(name: str, *args: Any) -> object:
    from armbench.fakes.firmware.uart import Uart

    if name != "uart":
        raise ValueError(f"no uart call {name!r}")
    byte_s, rx_buffer, tx_buffer, begin_s, actions = args

    async def session() -> object:
        uart = Uart(byte_s, rx_buffer, tx_buffer)
        loop = asyncio.get_running_loop()
        base = loop.time()
        uart.begin(base + begin_s)
        out: list[object] = []
        for action, *call in actions:
            if action == "host_write":
                uart.host_write(call[0], base + call[1])
                out.append(uart.rx_line_free_s - base)
            elif action == "read":
                since = None if call[1] is None else base + call[1]
                out.append(uart.read_available(base + call[0], since))
            elif action == "time_of_next":
                at = uart.time_of_next(call[0])
                out.append(None if at is None else at - base)
            elif action == "write":
                out.append(uart.write(call[0], base + call[1]) - base)
            else:
                uart.cut()
        return out, (uart.rx_bytes, uart.rx_overflow_bytes, uart.rx_lost_bytes, uart.tx_bytes,
                     uart.tx_dropped_bytes)

    return asyncio.run(session())


def _boards(name: str, *args: Any) -> object:
    from armbench.drivers.model.settings import DEFAULT_JOINTS
    from armbench.fakes.firmware.boards import SlaveBoard
    from armbench.fakes.firmware.eeprom import Eeprom
    from armbench.fakes.firmware.emulator_settings import emulator_settings
    from armbench.fakes.firmware.i2c import BusClock, I2CBus

    if name == "emulator":
        return _emulator(*args)
    if name != "slave":
        raise ValueError(f"no boards call {name!r}")
    number, emulator, motor_steps, actions = args
    settings = emulator_settings(_robot(emulator))
    bus = I2CBus(BusClock(), settings.i2c_bit_s)
    board = SlaveBoard(number, DEFAULT_JOINTS[number - 1], settings, Eeprom(), bus, motor_steps)
    board._setup(0.0)  # what power_on does after the boot delay, without a running loop
    out: list[object] = []
    for action, *call in actions:
        out.append(getattr(board, action)(*call))
        out.append((board.status_byte(), board.reference, board.bad_writes, board.last_write,
                    board.counter_rad(), board.true_rad(), board.last_firmware_rad))
    return out


def _emulator(emulator: object, q_rad: list[float], duty: int) -> object:
    """The whole emulator built from an ``[emulator]`` table (the boards read their settings
    there), on virtual time: one command, the replies of the next 1.5 s, the statistics."""
    from armbench.drivers.model.protocol import Command
    from armbench.fakes.clock.vclock import run_virtual
    from armbench.fakes.firmware.arm_emulator import ArmEmulator

    async def session() -> object:
        arm = ArmEmulator(_robot(emulator))
        loop = asyncio.get_running_loop()
        replies: list[tuple[float, bytes]] = []
        arm.attach_host(lambda data: replies.append((loop.time(), data)))
        async with arm:
            arm.host_write(Command.from_rad(q_rad, duty).encode())
            await asyncio.sleep(1.5)
        return replies, arm.stats().to_json()

    return run_virtual(session())


def _replies(name: str, *args: Any) -> object:
    """A link's reply stream fed ``chunks`` (each by :meth:`one` first, as the link does, or by
    :meth:`receive`): every state, batch and counter."""
    from armbench.drivers.host.replies import ReplyStream

    if name != "stream":
        raise ValueError(f"no replies call {name!r}")
    lower, upper, seq0, chunks = args
    stream = ReplyStream(lower, upper, seq0)
    out: list[object] = []
    for k, (chunk, every, restart) in enumerate(chunks):
        if restart:
            stream.restart()
        t_s = 0.01 * k
        one = None if every else stream.one(chunk, t_s)
        if one is not None:
            out.append(("one", tuple(one)))
        else:
            batch = stream.receive(chunk, t_s, every=every)
            out.append(("batch", batch.events, [tuple(s) for s in batch.states],
                        None if batch.state is None else tuple(batch.state), batch.single))
        out.append((stream.seq, stream.synced, stream.frames_received, stream.frames_dropped,
                    stream.discarded_bytes))
    return out


def _intake(name: str, *args: Any) -> object:
    """A link's intake (``drivers.host.intake``) pushed ``chunks`` at loop times ``times``,
    with a recorder, a capture and a waiter for joint 1 past ``mark``; chunks that are not one
    reply go through the reply stream's batches, as the link's general path takes them: every
    state, recording, capture call, outage and the waiter's answer."""
    from armbench.drivers.host.intake import ReplyIntake
    from armbench.drivers.host.link_outages import OutageLog
    from armbench.drivers.host.replies import ReplyStream
    from armbench.drivers.host.state import JointState
    from armbench.drivers.host.waiters import Waiters
    from armbench.fakes.clock.vclock import run_virtual

    if name != "push":
        raise ValueError(f"no intake call {name!r}")
    silence_s, mark, times, chunks = args

    async def session() -> object:
        loop = asyncio.get_running_loop()
        stream, waiters = ReplyStream((-3.2,) * 4, (3.2,) * 4), Waiters()
        captured: list[object] = []
        general: list[object] = []

        class Capture:
            def reply(self, t_s: float, data: bytes) -> None:
                captured.append((t_s, data))

        def chunk(data: bytes, t_s: float) -> None:
            batch = stream.receive(data, t_s)
            general.append((t_s, data, len(batch.events)))
            if batch.state is not None:
                intake.took(batch.state, t_s)

        intake = ReplyIntake(stream, waiters, OutageLog(silence_s), silence_s, chunk,
                             lambda exc: general.append(repr(exc)))
        intake.clock, intake.capture = loop.time, Capture()
        recorded: list[JointState] = []
        intake.recorders.append(recorded)
        waiter = waiters.add(lambda state: state.q_rad[0] >= mark, math.inf)
        out: list[object] = []
        for t_s, data in zip(times, chunks, strict=True):
            await asyncio.sleep(t_s)
            intake.push(data)
            state = intake.state
            out.append((None if state is None else tuple(state), intake.last_rx_s,
                        intake.tx_since_rx, intake.outages.count))
        answer = waiter.future.result() if waiter.future.done() else None
        outages = intake.outages.between(-math.inf, math.inf, math.inf)
        return (out, [tuple(s) for s in recorded], captured, general,
                [dataclasses.astuple(o) for o in outages],
                None if answer is None else tuple(answer))

    return run_virtual(session())


def _waiters(name: str, *args: Any) -> object:
    """Waiters for the joint-1 angle to pass each of ``marks`` (deadlines at loop times
    ``wakes``), offered ``q1s`` one state each: which resolved, with what, and when."""
    from armbench.drivers.host.state import JointState
    from armbench.drivers.host.waiters import Waiters
    from armbench.drivers.model.protocol import Reply
    from armbench.fakes.clock.vclock import run_virtual

    if name != "offer":
        raise ValueError(f"no waiters call {name!r}")
    marks, wakes, q1s = args

    async def session() -> object:
        def past(mark: float) -> Callable[[JointState], bool]:
            return lambda state: state.q_rad[0] >= mark

        def seq(state: JointState | None) -> int | None:
            return None if state is None else state.seq

        waiters = Waiters()
        added = [waiters.add(past(m), w) for m, w in zip(marks, wakes, strict=True)]
        out: list[object] = []
        for k, q1 in enumerate(q1s):
            await asyncio.sleep(0.01)
            waiters.offer(JointState(0.01 * k, (q1, 0.0, 0.0, 0.0), Reply(0, 0, 0, 0), k))
            out.append([(w.future.done(), w.woken,
                         seq(w.future.result()) if w.future.done() else None) for w in added])
            out.append(bool(waiters))
        waiters.close()
        out.append([(w.woken, w.future.done()) for w in added])
        return out

    return run_virtual(session())


def _arrival(name: str, *args: Any) -> object:
    """An arrival tracker on a link never opened, aimed at a command (``ahead_s`` its
    look-ahead), offered states of ``qs``: arrived or not, and its progress bookkeeping."""
    from armbench.drivers.host.arrival import ArrivalTracker
    from armbench.drivers.host.link import ArmLink
    from armbench.drivers.host.state import JointState
    from armbench.drivers.model.protocol import Command, Reply

    if name != "reached":
        raise ValueError(f"no arrival call {name!r}")
    tol, goal, duties, ahead_s, qs = args
    tracker = ArrivalTracker(ArmLink("fake://"), tol, 100.0, 10.0, 0, 0.0)
    tracker.aim(Command((0, 0, 0, 0), duties), goal, 0.0, ahead_s)
    out: list[object] = []
    for k, q in enumerate(qs):
        out.append(tracker.reached(JointState(0.01 * k, q, Reply(0, 0, 0, 0), k)))
        out.append((tracker._best, tracker._last_progress))
    return out


CALLS: dict[str, Callable[..., object]] = {"protocol": _protocol, "physics": _physics,
                                           "stepper": _stepper, "joint": _joint, "i2c": _i2c,
                                           "uart": _uart, "boards": _boards,
                                           "replies": _replies, "intake": _intake,
                                           "waiters": _waiters,
                                           "arrival": _arrival}


def answer(line: str) -> str:
    """The answer line to one request line."""
    request = json.loads(line)
    try:
        result = canon(CALLS[request["module"]](request["op"], *decode(request["args"])))
    except Exception as exc:  # the error is the answer: it must be the same in both builds
        return json.dumps({"err": [type(exc).__name__, str(exc)]})
    return json.dumps({"ok": result})


def main() -> None:
    """Answer requests until stdin closes; the first line says which build answers."""
    from armbench.cli.perf.hot_modules import build_name

    print(json.dumps({"build": build_name()}), flush=True)
    for line in sys.stdin:
        print(answer(line), flush=True)


if __name__ == "__main__":
    main()
