"""The bench target: what a port string names, parsed once, and what it can do.

``target_of("fake://?seed=3")`` finds the transport class registered for the scheme (an entry
point of ``armbench.transports``, see :mod:`armbench.drivers.transports`) and asks it for its
:class:`Capabilities`. The runner, the pytest plugin, ``monitor``, ``i2c`` and the capture ask
the :class:`Target`, never the scheme:

=====================  ======  =====  ========  =====  =====  ======  =======
target                 clock   fresh  parallel  truth  power  faults  I²C bus
=====================  ======  =====  ========  =====  =====  ======  =======
``fake://``            virtual yes    yes       yes    yes    yes     yes
``avr://``             real    no     no        no     yes    no      no
serial device          real    no     no        no     no     no      no
``socket://``          real    no     no        no     no     no      no
``rfc2217://``         real    no     no        no     no     no      no
``labgrid://``         real    no     no        no     place  no      no
=====================  ======  =====  ========  =====  =====  ======  =======

``place``: the place's power resource, where it has one (``LabgridTransport.power_commands``).

A transport class declares its target's capabilities by overriding the class methods of
:class:`~armbench.drivers.transports.base.Transport`:

- ``capabilities(port) -> Capabilities``: the clock (``"virtual"``: the bench runs it on a
  virtual-time loop), ``fresh_per_trial``, ``parallel``, ``truth``, ``power``, ``faults``,
  ``i2c_bus``;
- ``fresh(port, serial, arm: FreshArm) -> Transport``: a new arm from the robot settings, a seed
  and the faults (for ``fresh_per_trial``); after ``open()`` its ``emulator`` attribute is the
  side channel the bench reads: ground truth (``true_angles_rad()``, ``truth``), the power
  switch (``power_off()``/``power_on()``, or a ``harness``), the I²C ``bus``;
- ``query(port) -> Given`` and ``arm_inputs(port, given) -> ArmInputs``: the settings the
  query carries and how the robot settings file completes them;
- ``check_settings(port, robot)``, ``preflight()``, ``arm_name(port)``.

A simulator of another distribution registered by entry point gets every capability it declares:
virtual time, a fresh arm per trial, worker processes, ground truth, its own power switch.

One source per setting
----------------------
The robot settings file, the seed, the fault list and the emulator's profile and payload may
come from the command line, the port's query and the robot settings file. Each setting is taken
whole from the first source that gives it, in the order **flag > port query > settings file >
default** (:func:`resolve`, then the transport's ``arm_inputs``): a flag is the most specific
and most recent thing the user typed, a port string is reused across commands, a settings file
describes the arm. A fault list is one setting too: ``--faults`` replaces ``?faults=``, which
replaces the settings file's ``[[faults]]``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

from armbench.drivers.model.errors import TransportError
from armbench.drivers.model.settings import RobotSettings, SerialSettings
from armbench.drivers.transports import scheme_of, transport_class
from armbench.drivers.transports.base import Transport
from armbench.drivers.transports.capabilities import (
    ArmInputs,
    Capabilities,
    Clock,
    FreshArm,
    Given,
)

__all__ = ["ArmInputs", "Capabilities", "Clock", "FreshArm", "Given", "Target", "given_by",
           "resolve", "target_of"]

#: The settings :func:`resolve` picks a source for, in :class:`Given`'s order.
SETTINGS: tuple[str, ...] = tuple(f.name for f in fields(Given) if f.name != "sources")


def given_by(origin: str | Mapping[str, str], **values: Any) -> Given:
    """A :class:`Given` of the ``values`` that are not None, each labelled with ``origin`` (one
    label for all, e.g. ``"the port's query"``, or one per setting, e.g. ``{"seed": "--seed"}``)
    for the error messages."""
    present = {k: v for k, v in values.items() if v is not None}
    labels = tuple((k, origin if isinstance(origin, str) else origin.get(k, k))
                   for k in present)
    return Given(**present, sources=labels)


def resolve(*sources: Given) -> Given:
    """Setting by setting, the value of the first source that gives it (flags first, then the
    port's query); the settings file and the defaults come after, in the transport's
    ``arm_inputs``. The one place the precedence is decided."""
    picked: dict[str, Any] = {}
    labels: dict[str, str] = {}
    for source in sources:
        for name in SETTINGS:
            value = getattr(source, name)
            if value is not None and name not in picked:
                picked[name] = value
                labels[name] = source.source(name) or name
    return Given(**picked, sources=tuple(labels.items()))


@dataclass(frozen=True, slots=True)
class Target:
    """What a port string names: its transport class and what the target can do."""

    port: str
    """The port string, as given."""
    transport_class: type[Transport]
    """The class serving its scheme."""
    capabilities: Capabilities
    """What the target declares it can do."""

    @property
    def scheme(self) -> str | None:
        """The URL scheme, None for a serial device name."""
        return scheme_of(self.port)

    @property
    def virtual(self) -> bool:
        """Whether the arm runs on the event loop's clock (the bench runs it on virtual time)."""
        return self.capabilities.virtual

    def connect(self, serial: SerialSettings | None = None) -> Transport:
        """A transport to the arm at the port, not yet opened."""
        return self.transport_class(self.port, serial if serial is not None else SerialSettings())

    def fresh(self, serial: SerialSettings, arm: FreshArm) -> Transport:
        """A transport to a new arm built from ``arm``, not yet opened; a
        :class:`TransportError` for a target that cannot start one."""
        if not self.capabilities.fresh_per_trial:
            raise TransportError(self.port, "this target cannot start a fresh arm")
        return self.transport_class.fresh(self.port, serial, arm)

    def query(self) -> Given:
        """The settings the port's query carries, checked."""
        return self.transport_class.query(self.port)

    def inputs(self, flags: Given | None = None) -> ArmInputs:
        """The run's settings: ``flags`` over the port's query over the robot settings file
        over the defaults."""
        chosen = resolve(flags or Given(), self.query())
        return replace(self.transport_class.arm_inputs(self.port, chosen), given=chosen)

    def check_settings(self, robot: RobotSettings) -> None:
        """Check what this target reads of ``robot`` itself (an emulator's ``[emulator]``)."""
        self.transport_class.check_settings(self.port, robot)

    def preflight(self) -> None:
        """Check what can be checked before anything is opened (the address, a library, the
        firmware): raises :class:`TransportError` naming the port."""
        self.connect().preflight()

    def name(self) -> str:
        """A name for the arm (before sanitising): what the transport class makes of the
        port."""
        return self.transport_class.arm_name(self.port)


def target_of(port: str) -> Target:
    """The :class:`Target` of ``port``: its transport class (imported) and capabilities.

    Raises :class:`TransportError` naming the port for an unknown scheme, a transport that cannot
    be imported, or capabilities that are not a :class:`Capabilities`.
    """
    cls = transport_class(port)
    caps = cls.capabilities(port)
    if not isinstance(caps, Capabilities):
        raise TransportError(port, f"{cls.__name__}.capabilities() returned "
                                   f"{type(caps).__name__}, not Capabilities")
    return Target(port, cls, caps)
