"""``fake://`` — the firmware emulator in this process, on the running event loop.

It lives with the emulator and is registered as the entry point of its scheme (``fake``, see
:mod:`armbench.drivers.transports`): the driver reaches it through that entry point and never
imports it. Its target declares every capability (:mod:`armbench.drivers.transports.target`):
the virtual clock, a fresh emulator per trial, worker processes, ground truth, its own power
switch, faults and the I²C bus.

``fake://?seed=3&faults=faults.toml&settings=robot.toml&profile=ideal&payload=1.5``: the emulator
is built from the robot settings file (defaults without one), its ``[emulator]`` table
(``profile`` and the payload in kg override it), the fault list and the seed. The query is one
source of settings among others, under the one precedence rule of
:func:`~armbench.drivers.transports.target.resolve` (a flag over the query over the settings file
over the default): without a ``faults`` parameter the settings file's ``[[faults]]`` are used,
without a ``seed`` its ``[emulator] seed``. On a virtual-time loop (``armbench.fakes.clock.vclock``)
minutes of robot time pass in seconds; on a real loop it runs in real time. The emulator is
exposed as ``transport.emulator`` for its side channels: ground truth and power control (what a
laser tracker and a relay give on a real bench).
"""

from __future__ import annotations

from collections.abc import Mapping
from urllib.parse import parse_qs

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings, SerialSettings, load_settings
from armbench.drivers.transports.capabilities import ArmInputs, Capabilities, FreshArm, Given
from armbench.drivers.transports.target import given_by, resolve
from armbench.drivers.transports.url_parts import split_port
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.firmware.emulator_settings import emulator_settings, with_emulator_overrides
from armbench.fakes.firmware.faults import Fault, faults_from_settings, load_faults
from armbench.fakes.links.in_process import InProcessTransport

__all__ = ["FAKE_CAPABILITIES", "FakeTransport", "parse_fake_url"]

#: The query parameters of a ``fake://`` port → the setting each gives.
_KNOWN = {"seed": "seed", "faults": "faults", "settings": "settings", "profile": "profile",
          "payload": "payload_kg"}

#: What the emulator's target can do: everything.
FAKE_CAPABILITIES = Capabilities(clock="virtual", fresh_per_trial=True, parallel=True, truth=True,
                                 power=True, faults=True, i2c_bus=True)


def parse_fake_url(port: str) -> tuple[RobotSettings, int | None, list[Fault]]:
    """Robot settings, seed and faults a ``fake://`` port names on its own (its query over the
    settings file it names over the defaults)."""
    inputs = FakeTransport.arm_inputs(port, resolve(FakeTransport.query(port)))
    return inputs.robot, inputs.seed, list(inputs.faults)


class FakeTransport(InProcessTransport[ArmEmulator]):
    """A transport whose other end is an :class:`~armbench.fakes.firmware.arm_emulator.ArmEmulator`
    on the
    same loop (:class:`~armbench.fakes.links.in_process.InProcessTransport`: reads, receiver,
    close)."""

    scheme = "fake"
    declared = FAKE_CAPABILITIES

    @classmethod
    def query(cls, port: str) -> Given:
        """The query's ``seed``, ``faults``, ``settings``, ``profile`` and ``payload``; an unknown
        parameter, a seed that is not an integer, or anything but a query after ``fake://`` is
        refused naming it."""
        parts = split_port(port, "fake://[?QUERY]", address=False, query=True)
        if parts.scheme.lower() != "fake":
            raise ArmbenchError(f"{port}: not a fake:// port")
        query = parse_qs(parts.query, keep_blank_values=True, strict_parsing=False)
        values: dict[str, str | None] = {}
        for key, items in query.items():
            if key not in _KNOWN:
                raise ArmbenchError(f"{port}: unknown query parameter {key!r} "
                                    f"(known: {', '.join(sorted(_KNOWN))})")
            values[_KNOWN[key]] = items[-1]
        seed_text = values.pop("seed", None)
        seed = None
        if seed_text is not None:
            try:
                seed = int(seed_text)
            except ValueError:
                raise ArmbenchError(f"{port}: seed {seed_text!r} is not an integer") from None
        labels = {name: f"{port}: {key}" for key, name in _KNOWN.items()}
        return given_by(labels, seed=seed, **values)

    @classmethod
    def arm_inputs(cls, port: str, given: Given) -> ArmInputs:
        """The robot settings file (or the defaults) with the ``profile`` and ``payload`` given
        applied to its ``[emulator]`` table; the seed given, else the file's ``[emulator]
        seed``; the fault file given, else the file's ``[[faults]]``."""
        robot = load_settings(given.settings)
        robot = with_emulator_overrides(robot, profile=given.profile,
                                        payload_kg=given.payload_kg)
        seed = given.seed
        if seed is None:
            table = robot.sections.get("emulator", {})
            if isinstance(table, Mapping) and "seed" in table:
                seed = emulator_settings(robot).seed
        faults = (load_faults(given.faults) if given.faults is not None
                  else faults_from_settings(robot))
        return ArmInputs(robot, seed, tuple(faults))

    @classmethod
    def check_settings(cls, port: str, robot: RobotSettings) -> None:
        """The ``[emulator]`` table, its seed too."""
        emulator_settings(robot)

    @classmethod
    def fresh(cls, port: str, serial: SerialSettings, arm: FreshArm) -> FakeTransport:
        """A transport to a new emulator (built by ``arm.factory`` when given) playing
        ``arm.robot`` with seed ``arm.seed``; the emulator is the caller's to close."""
        settings = emulator_settings(arm.robot, seed=arm.seed)
        emulator = (arm.factory(arm.robot, settings, list(arm.faults)) if arm.factory is not None
                    else ArmEmulator(arm.robot, settings, list(arm.faults)))
        return cls(port, serial, emulator)

    @classmethod
    def arm_name(cls, port: str) -> str:
        scheme, sep, rest = port.partition("://")
        return f"{scheme}-{rest}" if sep else port

    def __init__(self, port: str, serial: SerialSettings,
                 emulator: ArmEmulator | None = None) -> None:
        super().__init__(port, serial, emulator)

    @property
    def emulator(self) -> ArmEmulator | None:
        """The emulator (:class:`~armbench.drivers.transports.base.Emulator`): the one given,
        else the one :meth:`open` made (None before)."""
        return self._peer

    async def open(self) -> None:
        if self._open:
            return
        emulator = self._peer
        if emulator is None:  # the port on its own: its query over the settings file
            cls = type(self)
            inputs = cls.arm_inputs(self.port, resolve(cls.query(self.port)))
            overrides = {"seed": inputs.seed} if inputs.seed is not None else {}
            emulator = self._peer = ArmEmulator(
                inputs.robot, emulator_settings(inputs.robot, **overrides), list(inputs.faults))
        self._attach(emulator)
        await emulator.start()
