"""What a target can do, and what a simulated one is built from: the declarations a transport
class makes (see :mod:`armbench.drivers.transports.target`).

:class:`Capabilities` is declared by the transport class serving a scheme
(:meth:`~armbench.drivers.transports.base.Transport.capabilities`); the bench reads it and never
the scheme. :class:`Given` is what one source of settings says (the command line's flags, the
port's query): :func:`~armbench.drivers.transports.target.resolve` picks, setting by setting, the
source that wins. :class:`ArmInputs` is the outcome once the robot settings file is read, and
:class:`FreshArm` what the runner hands a simulator for a new arm.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings

__all__ = ["ArmInputs", "Capabilities", "Clock", "FreshArm", "Given"]

Clock = Literal["virtual", "real"]
"""Whose clock the arm runs on: ``"virtual"``, the event loop's own (a simulator that advances
only when the loop lets it: the bench runs it on a virtual-time loop, minutes of robot time in
seconds), or ``"real"``, the wall clock (hardware, or a simulator paced to it)."""


@dataclass(frozen=True, slots=True)
class Capabilities:
    """What a target can do besides carrying bytes. The defaults are those of real hardware.

    ``parallel`` needs ``fresh_per_trial`` and the virtual clock: a worker process measures a
    trial on an arm of its own and the run clock moves by the trial's simulated duration.
    """

    clock: Clock = "real"
    """Whose clock the arm runs on (:data:`Clock`)."""
    fresh_per_trial: bool = False
    """A new arm can be made for every trial (:meth:`Transport.fresh`), built from the robot
    settings, a seed and the fault list; such an arm is never reconnected (a new connection is a
    new arm). The bench's default isolation is then one arm per trial."""
    parallel: bool = False
    """Trials may be measured in worker processes at once, each on a fresh arm."""
    truth: bool = False
    """The opened transport's ``emulator`` gives ground truth: ``true_angles_rad()`` (the joints'
    true angles now, rad) and ``truth`` (the driver-side samples, newest last)."""
    power: bool = False
    """The target switches its own power (an emulator's ``power_off``/``power_on``, a harness's
    ``power``): the bench needs no relay command or operator."""
    faults: bool = False
    """The target takes the fault list (``--faults``, ``?faults=``, ``[[faults]]``)."""
    i2c_bus: bool = False
    """The opened transport's ``emulator.bus`` is the arm's I²C bus (``armbench i2c scan``)."""

    def __post_init__(self) -> None:
        if self.clock not in ("virtual", "real"):
            raise ArmbenchError(f"capabilities: clock {self.clock!r} is not 'virtual' or 'real'")
        if self.parallel and not (self.fresh_per_trial and self.clock == "virtual"):
            raise ArmbenchError("capabilities: parallel workers need fresh_per_trial and the "
                                "virtual clock")

    @property
    def virtual(self) -> bool:
        """Whether the arm runs on the event loop's clock."""
        return self.clock == "virtual"


@dataclass(frozen=True, slots=True)
class Given:
    """What one source (the flags, the port's query) says about the settings of a run; None
    where it says nothing. Paths stay paths: the file level is read once the winner is known."""

    settings: str | None = None
    """Robot settings file (TOML)."""
    seed: int | None = None
    """Seed of the run and of the simulated arm."""
    faults: str | None = None
    """Fault list file (TOML, ``[[faults]]``)."""
    profile: str | None = None
    """The emulator's profile (``[emulator] profile``)."""
    payload_kg: str | None = None
    """The payload in kg (``[emulator.physics] payload_kg``), as given."""
    sources: tuple[tuple[str, str], ...] = field(default=(), compare=False)
    """``(setting, source)`` of every setting given: who said it, for error messages."""

    def source(self, name: str) -> str | None:
        """Who gave setting ``name`` (``"--seed"``, ``"the port's query"``), None if nobody."""
        return dict(self.sources).get(name)


@dataclass(frozen=True, slots=True)
class ArmInputs:
    """The settings of a run once every source is resolved and the robot settings file read."""

    robot: RobotSettings
    """The robot settings (with the query's emulator overrides applied)."""
    seed: int | None
    """The seed given (flag, query or the settings file's ``[emulator] seed``), None if none."""
    faults: tuple[Any, ...] = ()
    """The fault list (``armbench.fakes.firmware.faults.Fault``) for a target that takes faults."""
    given: Given = field(default_factory=Given)
    """The winning sources (the settings and fault files' paths as given)."""


@dataclass(frozen=True, slots=True)
class FreshArm:
    """What a new simulated arm is built from (:meth:`Transport.fresh`)."""

    robot: RobotSettings
    """The arm to play."""
    seed: int
    """Its seed (the runner derives one per trial from the run's)."""
    faults: Sequence[Any] = ()
    """Faults to inject (``armbench.fakes.firmware.faults.Fault``)."""
    factory: Callable[..., Any] | None = None
    """The runner's emulator factory (``fake://``: tests pass one to watch the emulators); a
    simulator of its own may ignore it."""
