"""``fake://`` — the firmware emulator in this process, on the running event loop.

It lives with the emulator and is registered by name (the scheme ``fake``, see
:mod:`armbench.drivers.transports`): the driver reaches it through the registry and never imports
it.

``fake://?seed=3&faults=faults.toml&settings=robot.toml&profile=ideal&payload=1.5``: the emulator
is built from the robot settings file (defaults without one), its ``[emulator]`` table
(``profile`` and the payload in kg override it), the fault list and the seed. On a
virtual-time loop (``armbench.fakes.vclock``) minutes of robot time pass in seconds; on a real loop
it runs in real time. The emulator is exposed as ``transport.emulator`` for its side channels:
ground truth and power control (what a laser tracker and a relay give on a real bench).
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from urllib.parse import parse_qs, urlsplit

from armbench.drivers.errors import ArmbenchError
from armbench.drivers.settings import RobotSettings, SerialSettings, load_settings
from armbench.drivers.transports.base import Transport
from armbench.fakes.arm_emulator import ArmEmulator
from armbench.fakes.emulator_settings import emulator_settings, with_emulator_overrides
from armbench.fakes.faults import Fault, faults_from_settings, load_faults

__all__ = ["FakeTransport", "apply_fake_query", "parse_fake_url"]

_KNOWN = {"seed", "faults", "settings", "profile", "payload"}


def parse_fake_url(port: str) -> tuple[RobotSettings, int | None, list[Fault]]:
    """Robot settings, seed and faults named by a ``fake://`` URL's query."""
    parts = urlsplit(port)
    if parts.scheme.lower() != "fake":
        raise ArmbenchError(f"{port}: not a fake:// port")
    query = parse_qs(parts.query, keep_blank_values=True, strict_parsing=False)
    for key in query:
        if key not in _KNOWN:
            raise ArmbenchError(f"{port}: unknown query parameter {key!r} "
                                f"(known: {', '.join(sorted(_KNOWN))})")
    robot = load_settings(query["settings"][-1]) if "settings" in query else RobotSettings()
    robot = apply_fake_query(port, robot)
    seed = None
    if "seed" in query:
        try:
            seed = int(query["seed"][-1])
        except ValueError:
            raise ArmbenchError(f"{port}: seed {query['seed'][-1]!r} is not an integer") from None
    faults = faults_from_settings(robot)
    if "faults" in query:
        faults += load_faults(query["faults"][-1])
    return robot, seed, faults


def apply_fake_query(port: str, robot: RobotSettings) -> RobotSettings:
    """``robot`` with the ``profile`` and ``payload`` (kg) of a ``fake://`` URL's query applied
    to its ``[emulator]`` table."""
    query = parse_qs(urlsplit(port).query, keep_blank_values=True)
    return with_emulator_overrides(robot, profile=query.get("profile", [None])[-1],
                                   payload_kg=query.get("payload", [None])[-1])


class FakeTransport(Transport):
    """A transport whose other end is an :class:`~armbench.fakes.arm_emulator.ArmEmulator` on the
    same loop."""

    scheme = "fake"

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
        if self.emulator is None:
            robot, seed, faults = parse_fake_url(self.port)
            overrides = {"seed": seed} if seed is not None else {}
            self.emulator = ArmEmulator(robot, emulator_settings(robot, **overrides), faults)
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
