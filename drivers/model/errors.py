"""armbench's typed errors, so a front end can tell user errors from bugs: the root, the
transports', the codec's and the driver's.

They live here, in plain Python, rather than beside the code that raises them: the hot modules
that raise them may be compiled (``docs/performance.md``), and an exception class should behave
the same in either build (attributes, subclassing, pickling)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal, Protocol

__all__ = [
    "ArmbenchError",
    "CoordinatorUnreachableError",
    "DriverClosedError",
    "DriverError",
    "FrameValueError",
    "InvalidTargetError",
    "JointRangeError",
    "LabgridError",
    "LastReply",
    "LinkLostError",
    "MoveInterruptedError",
    "MoveTimeoutError",
    "NoSerialResourceError",
    "PlaceLockedError",
    "PlaceUnknownError",
    "PortLostError",
    "ProtocolError",
    "ReplyTimeoutError",
    "SettingsError",
    "TransportError",
    "WaitTimeoutError",
    "format_q_rad",
    "shown_port",
]

#: The most characters of a port string an error message shows: a longer one (a 10 kB device
#: name, a URL with a pasted file in its query) is cut, so the message stays one readable line.
SHOWN_PORT_CHARS = 400


def shown_port(port: str, limit: int = SHOWN_PORT_CHARS) -> str:
    """``port`` (or a part of it) as an error message shows it: whole up to ``limit``
    characters, else its start and how long it is."""
    if len(port) <= limit:
        return port
    return f"{port[:limit]}... ({len(port)} characters)"


class LastReply(Protocol):
    """What an error keeps of the newest reply: its loop time and joint angles. The driver's
    :class:`armbench.drivers.host.state.JointState` is one; named here by shape, so this module, at
    the bottom of the layers, imports nothing of the driver above it (not even for typing)."""

    @property
    def t_s(self) -> float: ...

    @property
    def q_rad(self) -> tuple[float, float, float, float]: ...


class ArmbenchError(Exception):
    """Base of every error armbench raises on purpose (bad input, lost port, timeout, ...)."""


class SettingsError(ArmbenchError, ValueError):
    """A settings value (or an option) is invalid; ``field`` is its dotted path in the TOML file
    (or the option's flag)."""

    def __init__(self, field: str, value: object, reason: str) -> None:
        super().__init__(f"{field}: {value!r} {reason}")
        self.field = field
        self.value = value
        self.reason = reason


class TransportError(ArmbenchError, OSError):
    """A transport could not be opened, configured or used; names the port."""

    def __init__(self, port: str, reason: str) -> None:
        super().__init__(f"{shown_port(port)}: {reason}")
        self.port = port
        self.reason = reason


class PortLostError(TransportError):
    """The port went away while open (USB unplugged, TCP reset, pty closed, emulator killed)."""


class LinkLostError(PortLostError):
    """The link stayed lost longer than the outage timeout: the port went away and reconnecting
    did not bring a reply back in time. Names the port, how long it was silent (``silent_s``, from
    the last valid reply) and why (``cause``); ``attempts`` is the reconnect attempts made."""

    def __init__(self, port: str, cause: str, silent_s: float, attempts: int) -> None:
        super().__init__(port, f"link lost, silent for {silent_s:.1f} s ({cause}; "
                               f"gave up after {attempts} reconnect attempts)")
        self.cause = cause
        self.silent_s = silent_s
        self.attempts = attempts

    def __reduce__(self) -> tuple[object, ...]:
        return (type(self), (self.port, self.cause, self.silent_s, self.attempts))


class LabgridError(TransportError):
    """A ``labgrid://`` place could not be had; subclasses say why."""


class CoordinatorUnreachableError(LabgridError):
    """The labgrid coordinator did not answer."""


class PlaceUnknownError(LabgridError):
    """No place of that name in the lab."""


class PlaceLockedError(LabgridError):
    """The place is acquired by someone else; ``owner`` is labgrid's ``host/user`` of the holder."""

    def __init__(self, port: str, reason: str, owner: str) -> None:
        super().__init__(port, reason)
        self.owner = owner


class NoSerialResourceError(LabgridError):
    """The place has no (available) ``NetworkSerialPort``: no arm to talk to."""


class _RefusedValue(Exception):
    """The message and attributes of a refused value: the ``joint`` (1-based, None when the whole
    value is wrong), the ``field``, the ``value`` and the ``reason``."""

    def __init__(self, joint: int | None, field: str, value: object, reason: str) -> None:
        where = f"joint {joint} {field}" if joint is not None else field
        super().__init__(f"{where}: {value!r} {reason}")
        self.joint = joint
        self.field = field
        self.value = value
        self.reason = reason


class ProtocolError(ArmbenchError, ValueError):
    """Base of the codec's errors."""


class FrameValueError(_RefusedValue, ProtocolError):
    """A value cannot be put on the wire; names the joint (1-based) and the value."""


def format_q_rad(q: Sequence[float]) -> str:
    """Joint angles as the errors print them: ``(+0.1000, ...) rad``."""
    return "(" + ", ".join(f"{v:+.4f}" for v in q) + ") rad"


class DriverError(ArmbenchError):
    """Base of the driver's own errors."""


class DriverClosedError(DriverError):
    """The arm was used after :meth:`Arm.close` (or before it was opened)."""

    def __init__(self, port: str) -> None:
        super().__init__(f"{port}: the arm connection is closed")
        self.port = port


class ReplyTimeoutError(DriverError, TimeoutError):
    """No valid reply arrived within ``timeout_s`` while waiting; ``last_state`` is the newest
    state received before (None if none ever arrived)."""

    def __init__(self, port: str, timeout_s: float, last_state: LastReply | None) -> None:
        last = (f"last reply at t = {last_state.t_s:.3f} s: {format_q_rad(last_state.q_rad)}"
                if last_state is not None else "no reply ever received")
        super().__init__(f"{port}: no valid reply within {timeout_s:g} s ({last})")
        self.port = port
        self.timeout_s = timeout_s
        self.last_state = last_state


class WaitTimeoutError(DriverError, TimeoutError):
    """:meth:`Arm.wait_state` gave up after ``timeout_s``; ``last_state`` is the newest state."""

    def __init__(self, what: str, timeout_s: float, last_state: LastReply | None) -> None:
        last = format_q_rad(last_state.q_rad) if last_state is not None else "no state"
        super().__init__(f"{what} not done within {timeout_s:g} s (last state {last})")
        self.timeout_s = timeout_s
        self.last_state = last_state


class MoveTimeoutError(WaitTimeoutError):
    """A move did not arrive within ``timeout_s``; carries the ``target_rad`` (as put on the
    wire), the ``tolerance_rad`` per joint and the ``last_state``."""

    def __init__(self, target_rad: Sequence[float], tolerance_rad: Sequence[float],
                 timeout_s: float, last_state: LastReply | None) -> None:
        self.target_rad: tuple[float, float, float, float] = (
            float(target_rad[0]), float(target_rad[1]), float(target_rad[2]), float(target_rad[3]))
        self.tolerance_rad = tuple(tolerance_rad)
        what = f"move to {format_q_rad(self.target_rad)}"
        if last_state is not None:
            off = [f"j{i + 1} {q - t:+.4f}" for i, (q, t, tol) in enumerate(
                zip(last_state.q_rad, self.target_rad, self.tolerance_rad, strict=True))
                if abs(q - t) > tol]
            what += " (still off: " + ", ".join(off) + " rad)"
        super().__init__(what, timeout_s, last_state)


class MoveInterruptedError(DriverError):
    """A move was superseded by a newer command (another move, ``stop()``) before arriving."""

    def __init__(self, target_rad: Sequence[float], last_state: LastReply | None) -> None:
        super().__init__(f"move to {format_q_rad(target_rad)} superseded by a newer command")
        self.target_rad = tuple(target_rad)
        self.last_state = last_state


class InvalidTargetError(_RefusedValue, DriverError, ValueError):
    """A target, duty or option refused before anything was sent; ``joint`` is 1-based (None
    when the whole value is wrong), ``field`` names what is wrong."""


class JointRangeError(InvalidTargetError):
    """A joint target outside its limits: names the joint (1-based and by name), the value and
    the violated limit (rad, protocol convention); nothing was sent."""

    def __init__(self, joint: int, joint_name: str, value_rad: float, limit_rad: float,
                 bound: Literal["lower", "upper"]) -> None:
        side = "below the lower" if bound == "lower" else "above the upper"
        super().__init__(joint, "target", value_rad,
                         f"rad ({math.degrees(value_rad):.2f}°) is {side} limit of {joint_name}, "
                         f"{limit_rad:.6f} rad ({math.degrees(limit_rad):.2f}°)")
        self.joint_name = joint_name
        self.value_rad = value_rad
        self.limit_rad = limit_rad
        self.bound = bound
