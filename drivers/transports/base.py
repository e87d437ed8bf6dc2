"""The one interface every transport implements: open, read, write, close, two byte counters.

A transport carries raw bytes between the host and the arm's master board (or whatever stands in
for it: a pty, a TCP socket, an RFC 2217 server, the emulator). It knows nothing about frames.
All methods are coroutines to be awaited on one event loop; ``read`` is meant for one reader task
and ``write`` may be called from any task of that loop. Callers put their own deadlines around the
awaits (``asyncio.timeout``): a transport waits as long as the wire makes it wait.

A transport class also declares what the target behind its scheme can do (the class methods
:meth:`Transport.capabilities`, :meth:`Transport.query`, :meth:`Transport.arm_inputs`,
:meth:`Transport.fresh`, :meth:`Transport.check_settings`, :meth:`Transport.arm_name`), read
through :class:`~armbench.drivers.transports.target.Target`. The defaults are real hardware's.

A simulated arm (``fake://``, ``avr://`` on virtual time) has a side channel no wire carries: its
ground truth. Its transport declares it by overriding :attr:`Transport.emulator` with its
simulator's type, which must be an :class:`Emulator` (its :class:`GroundTruth` samples, its true
angles and position, its close); :func:`emulated` reads it from a transport or an arm
(:class:`EmulatedTarget`). The emulator never imports the host driver (``drivers/host``): the
two meet here, below both.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from types import TracebackType
from typing import Protocol, Self, runtime_checkable

from armbench.drivers.model.errors import ArmbenchError, PortLostError, TransportError
from armbench.drivers.model.settings import RobotSettings, SerialSettings, load_settings
from armbench.drivers.transports.capabilities import ArmInputs, Capabilities, FreshArm, Given

__all__ = ["READ_CHUNK", "EmulatedTarget", "Emulator", "GroundTruth", "Transport", "emulated"]

READ_CHUNK = 65536
"""Most bytes one :meth:`Transport.read` returns."""

_Vec4 = tuple[float, float, float, float]


class GroundTruth(Protocol):
    """What a simulated arm knows beside each reply it sends (the emulator's
    ``armbench.fakes.twin.physics.TruthSample``): at ``t_s``, when the reply was printed, the
    real joint angles (``true_rad``), the firmware's belief (``firmware_rad``), the links'
    angles before their deflection under gravity (``link_rad``: ``true_rad`` is a function of
    them for one emulator) and the motor shafts' angles where it models them (``motor_rad``).
    Angles in rad, protocol convention."""

    @property
    def t_s(self) -> float: ...

    @property
    def true_rad(self) -> _Vec4: ...

    @property
    def firmware_rad(self) -> _Vec4: ...

    @property
    def link_rad(self) -> _Vec4: ...

    @property
    def motor_rad(self) -> _Vec4 | None: ...


@runtime_checkable
class Emulator(Protocol):
    """A simulated arm's side channel, as the bench reads it: its ground truth beside each reply
    (``truth``, newest last, bounded; empty before the first reply), its true joint angles
    (rad) and tool position (m, base frame) now, and its end (``close``, idempotent; the
    caller's when it asked for a fresh arm, :meth:`Transport.fresh`)."""

    @property
    def truth(self) -> Sequence[GroundTruth]: ...

    def true_angles_rad(self) -> tuple[float, ...]: ...

    def true_position_m(self) -> tuple[float, float, float]: ...

    async def close(self) -> None: ...


@runtime_checkable
class EmulatedTarget(Protocol):
    """Something with an arm behind it that may be simulated: a :class:`Transport`, or a driver's
    arm (which reads its current transport's). ``emulator`` is None for hardware."""

    @property
    def emulator(self) -> Emulator | None: ...


def emulated(target: EmulatedTarget | None) -> Emulator | None:
    """The emulator behind ``target`` (a transport or an arm), None for hardware or no target."""
    return None if target is None else target.emulator


class Transport(abc.ABC):
    """A byte pipe to the arm, named by its port string.

    Life cycle: construct (no I/O) → :meth:`open` → any number of :meth:`read`/:meth:`write` →
    :meth:`close`. Also an async context manager that opens and closes.

    Errors: :class:`~armbench.drivers.model.errors.TransportError` (naming the port) when the port
    cannot be
    opened or configured or is used while not open;
    :class:`~armbench.drivers.model.errors.PortLostError` when
    the port or its peer goes away while open (EOF, reset, EIO on a pty whose other end closed,
    server killed). After a loss every read/write raises ``PortLostError`` again and
    :meth:`close` still works.
    """

    #: URL scheme this transport serves (``""`` for plain serial device names).
    scheme: str = ""

    # --- what the target behind the scheme can do (read through Target) -----------------------
    @classmethod
    def capabilities(cls, port: str) -> Capabilities:
        """What the target at ``port`` can do (:class:`Capabilities`); real hardware's by
        default: the wall clock, one arm, no ground truth, no power switch of its own."""
        return Capabilities()

    @classmethod
    def query(cls, port: str) -> Given:
        """The settings ``port``'s query carries (seed, settings and fault files, ...), checked:
        a :class:`~armbench.drivers.model.errors.ArmbenchError` names a parameter this target does
        not know. None by default (the query, if any, is the transport's own business)."""
        return Given()

    @classmethod
    def arm_inputs(cls, port: str, given: Given) -> ArmInputs:
        """The run's settings from the winning sources ``given``
        (:func:`~armbench.drivers.transports.target.resolve`), the robot settings file read and
        its own level applied where ``given`` says nothing. By default: the file (or the
        defaults), the seed as given, and no faults (a fault list is refused naming who gave
        it: only a simulated arm takes one)."""
        if given.faults is not None:
            raise ArmbenchError(f"{given.source('faults') or 'faults'}: faults are injected into "
                                f"a simulated arm; the port {port!r} takes none")
        return ArmInputs(load_settings(given.settings), given.seed)

    @classmethod
    def check_settings(cls, port: str, robot: RobotSettings) -> None:
        """Check the parts of ``robot`` this target reads itself (an emulator's ``[emulator]``
        table) before anything runs; nothing by default."""
        return

    @classmethod
    def fresh(cls, port: str, serial: SerialSettings, arm: FreshArm) -> Transport:
        """A transport, not yet opened, to a new arm built from ``arm``; only for targets that
        declare ``fresh_per_trial``. After :meth:`open` its :attr:`emulator` is the arm's side
        channel (ground truth, power), closed by whoever asked for the arm."""
        raise TransportError(port, f"{cls.__name__} cannot start a fresh arm")

    @classmethod
    def arm_name(cls, port: str) -> str:
        """A name for the arm at ``port`` (a fleet run's folder, before sanitising): the address
        after the scheme."""
        _, sep, rest = port.partition("://")
        return rest if sep else port

    def __init__(self, port: str, serial: SerialSettings) -> None:
        self.port = port
        """The port string this transport was made from."""
        self.serial = serial
        """Line settings (baud rate etc.); TCP ignores them, serial and RFC 2217 apply them."""
        self.bytes_in = 0
        """Payload bytes returned by :meth:`read` since construction."""
        self.bytes_out = 0
        """Payload bytes accepted by :meth:`write` since construction."""

    @property
    @abc.abstractmethod
    def is_open(self) -> bool:
        """True between a successful :meth:`open` and :meth:`close` or the loss of the port."""

    @property
    def emulator(self) -> Emulator | None:
        """The simulator behind the port, for its ground truth (:class:`Emulator`); None, the
        default, for hardware. A simulated target's transport overrides it with its
        simulator's type, which mypy then checks against :class:`Emulator`.

        A property of the base rather than an ``isinstance`` check against a
        ``runtime_checkable`` protocol: every transport answers, a transport of another
        distribution included, at the cost of one attribute read (the capture asks at each
        reply; a protocol check costs some microseconds and only sees that the name exists),
        and its type is checked statically where it is declared."""
        return None

    def preflight(self) -> None:
        """Check what can be checked before anything is opened or made (a library the transport
        needs, the firmware it runs): raises :class:`TransportError` naming the port. The bench
        calls it before it makes a run folder; the default checks nothing."""
        return

    def follow(self, previous: Transport) -> None:
        """Called before :meth:`open` when this transport reconnects to the port ``previous``
        lost, so that it can tell its old peer's return from a newcomer under the same name
        (a serial transport refuses a pty that took the lost one's number). The default
        takes nothing: a port's name stands for the same peer each time."""
        return

    @abc.abstractmethod
    async def open(self) -> None:
        """Open and configure the port; raises :class:`TransportError` naming it on failure."""

    @abc.abstractmethod
    async def read(self) -> bytes:
        """Wait for at least one byte and return what is there (at most :data:`READ_CHUNK`).

        Raises :class:`PortLostError` when the port or its peer is gone and nothing is left to
        read, :class:`TransportError` when not open.
        """

    @abc.abstractmethod
    async def write(self, data: bytes) -> None:
        """Write ``data`` and wait until the OS (or the peer's flow control) has taken it.

        Raises :class:`PortLostError` when the port or its peer is gone, :class:`TransportError`
        when not open.
        """

    @abc.abstractmethod
    async def close(self) -> None:
        """Release the port. Idempotent; safe after a loss and before :meth:`open`."""

    async def __aenter__(self) -> Self:
        await self.open()
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        await self.close()

    def __repr__(self) -> str:
        state = "open" if self.is_open else "closed"
        return (f"<{type(self).__name__} {self.port!r} {state} in={self.bytes_in} "
                f"out={self.bytes_out}>")

    # --- helpers for subclasses -----------------------------------------------------------------
    def _error(self, reason: str) -> TransportError:
        """A :class:`TransportError` naming this port."""
        return TransportError(self.port, reason)

    def _lost(self, reason: str) -> PortLostError:
        """A :class:`PortLostError` naming this port."""
        return PortLostError(self.port, reason)

    def _not_open(self) -> TransportError:
        return TransportError(self.port, "transport is not open")
