"""``fake://`` — the firmware emulator in this process, on the running event loop.

It lives with the emulator and is registered by name (the scheme ``fake``, see
:mod:`armbench.drivers.transports`): the driver reaches it through the registry and never imports
it. Its target declares every capability (:mod:`armbench.drivers.transports.target`): the virtual
clock, a fresh emulator per trial, worker processes, ground truth, its own power switch, faults
and the I²C bus.

``fake://?seed=3&faults=faults.toml&settings=robot.toml&profile=ideal&payload=1.5``: the emulator
is built from the robot settings file (defaults without one), its ``[emulator]`` table
(``profile`` and the payload in kg override it), the fault list and the seed. The query is one
source of settings among others, under the one precedence rule of
:func:`~armbench.drivers.transports.target.resolve` (a flag over the query over the settings file
over the default): without a ``faults`` parameter the settings file's ``[[faults]]`` are used,
without a ``seed`` its ``[emulator] seed``. On a virtual-time loop (``armbench.fakes.vclock``)
minutes of robot time pass in seconds; on a real loop it runs in real time. The emulator is
exposed as ``transport.emulator`` for its side channels: ground truth and power control (what a
laser tracker and a relay give on a real bench).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Mapping
from urllib.parse import parse_qs, urlsplit

from armbench.drivers.errors import ArmbenchError
from armbench.drivers.settings import RobotSettings, SerialSettings, load_settings
from armbench.drivers.transports.base import Transport
from armbench.drivers.transports.capabilities import ArmInputs, Capabilities, FreshArm, Given
from armbench.drivers.transports.target import given_by, resolve
from armbench.fakes.arm_emulator import ArmEmulator
from armbench.fakes.emulator_settings import emulator_settings, with_emulator_overrides
from armbench.fakes.faults import Fault, faults_from_settings, load_faults

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


class FakeTransport(Transport):
    """A transport whose other end is an :class:`~armbench.fakes.arm_emulator.ArmEmulator` on the
    same loop."""

    scheme = "fake"

    @classmethod
    def capabilities(cls, port: str) -> Capabilities:
        return FAKE_CAPABILITIES

    @classmethod
    def query(cls, port: str) -> Given:
        """The query's ``seed``, ``faults``, ``settings``, ``profile`` and ``payload``; an unknown
        parameter or a seed that is not an integer is refused naming it."""
        parts = urlsplit(port)
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
        super().__init__(port, serial)
        self._given = emulator
        self.emulator: ArmEmulator | None = emulator
        self._chunks: list[bytes] = []
        self._receiver: Callable[[bytes], None] | None = None
        self._waiter: asyncio.Future[None] | None = None
        self._open = False

    @property
    def is_open(self) -> bool:
        return self._open

    async def open(self) -> None:
        if self._open:
            return
        if self.emulator is None:  # the port on its own: its query over the settings file
            cls = type(self)
            inputs = cls.arm_inputs(self.port, resolve(cls.query(self.port)))
            overrides = {"seed": inputs.seed} if inputs.seed is not None else {}
            self.emulator = ArmEmulator(inputs.robot, emulator_settings(inputs.robot, **overrides),
                                        list(inputs.faults))
        self.emulator.attach_host(self._receive)
        self._open = True
        await self.emulator.start()

    def set_receiver(self, receiver: Callable[[bytes], None] | None) -> None:
        """Hand each chunk to ``receiver`` the moment it arrives (in the emulator's callback, at
        its loop time) instead of keeping it for :meth:`read`: no future and no task switch per
        reply. Chunks already kept are read first; :meth:`read` then waits for more kept chunks
        or the end of the connection. None: back to plain reads."""
        self._receiver = receiver

    def _receive(self, data: bytes) -> None:
        receiver = self._receiver
        if receiver is not None and not self._chunks:
            self.bytes_in += len(data)
            receiver(data)
            return
        self._chunks.append(data)
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    async def read(self) -> bytes:
        while not self._chunks:
            if not self._open:
                raise self._not_open()
            self._waiter = asyncio.get_running_loop().create_future()
            try:
                await self._waiter
            finally:
                self._waiter = None
        data = b"".join(self._chunks)  # no copy for the usual single chunk
        self._chunks.clear()
        self.bytes_in += len(data)
        return data

    async def write(self, data: bytes) -> None:
        if not self._open or self.emulator is None:
            raise self._not_open()
        self.emulator.host_write(data)
        self.bytes_out += len(data)

    async def close(self) -> None:
        if not self._open:
            return
        self._open = False
        self._receiver = None
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_exception(self._lost("transport closed"))
        if self.emulator is not None:
            self.emulator.detach_host()
            if self._given is None:
                await self.emulator.close()
