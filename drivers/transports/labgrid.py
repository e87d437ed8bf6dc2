"""``labgrid://PLACE`` — an arm in a labgrid lab, reached through the place's serial port.

``labgrid://PLACE?coordinator=HOST:PORT`` (or the coordinator from ``LG_COORDINATOR``, as
labgrid's own client reads it; port 20408 when none is given): :meth:`LabgridTransport.open`
acquires the place from the coordinator, finds its ``NetworkSerialPort`` (the serial port an
exporter serves through ser2net, RFC 2217 or raw TCP), and connects to it with the transport
armbench already has for that protocol. :meth:`~LabgridTransport.close` releases the place, also
when the run ends on Ctrl-C or an error. Needs the optional extra ``armbench[labgrid]``.

labgrid's client is itself asyncio (gRPC) and expects a loop of its own, so it runs on a thread
of its own with its own loop (one per coordinator, shared by every place of the run); the run's
event loop only awaits the answers.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import os
import sys
import threading
import time
from typing import Any, ClassVar
from urllib.parse import parse_qs

from armbench.drivers.model.errors import (
    CoordinatorUnreachableError,
    LabgridError,
    NoSerialResourceError,
    PlaceLockedError,
    PlaceUnknownError,
    TransportError,
    shown_port,
)
from armbench.drivers.model.peer_text import peer_str
from armbench.drivers.model.settings import SerialSettings
from armbench.drivers.transports.base import Transport
from armbench.drivers.transports.capabilities import Capabilities
from armbench.drivers.transports.url_parts import PART_CHARS, split_port

__all__ = ["COORDINATOR_ENV", "DEFAULT_COORDINATOR_PORT", "POWER_RESOURCES", "LabgridClient",
           "LabgridPlace", "LabgridTransport", "parse_labgrid_url"]

#: Where labgrid's tools read the coordinator's address from.
COORDINATOR_ENV = "LG_COORDINATOR"
#: The coordinator's port when the address names none (labgrid's default).
DEFAULT_COORDINATOR_PORT = 20408
#: Longest wait for the coordinator to answer a session start, an acquire or a release.
COORDINATOR_TIMEOUT_S = 10.0
#: Pause (s) between two attempts to reach a coordinator that did not take the session.
COORDINATOR_RETRY_S = 0.5
#: What a labgrid port holds.
LABGRID_FORM = "labgrid://PLACE[?coordinator=HOST:PORT]"
#: The resource class of a serial port an exporter serves over the network.
SERIAL_RESOURCE = "NetworkSerialPort"
#: The resource classes that switch a place's power, as ``labgrid-client power`` drives them:
#: a network PDU or relay (``NetworkPowerPort``: simplerest, Tasmota's HTTP and many more
#: models), PDUDaemon, a USB hub port (uhubctl), SiS-PM, Tasmota over MQTT, YKUSH.
POWER_RESOURCES = ("NetworkPowerPort", "PDUDaemonPort", "NetworkUSBPowerPort",
                   "NetworkSiSPMPowerPort", "TasmotaPowerPort", "NetworkYKUSHPowerPort")


def parse_labgrid_url(port: str) -> tuple[str, str]:
    """``(place, coordinator HOST:PORT)`` of a ``labgrid://PLACE[?coordinator=HOST:PORT]`` port;
    anything else in it (a path after the place, a fragment) is refused naming it."""
    parts = split_port(port, LABGRID_FORM, address=True, query=True, path=True)
    place = parts.netloc or parts.path.strip("/")
    if parts.scheme.lower() != "labgrid" or not place:
        raise TransportError(port, "not a labgrid://PLACE port")
    if parts.netloc and parts.path.strip("/"):
        shown = shown_port(parts.path, PART_CHARS)
        raise TransportError(port, f"the path {shown!r} after the place is not understood "
                                   f"({LABGRID_FORM} takes none)")
    query = parse_qs(parts.query, keep_blank_values=True)
    unknown = sorted(set(query) - {"coordinator"})
    if unknown:
        raise TransportError(port, f"unknown query parameter {unknown[0]!r} (known: coordinator)")
    coordinator = (query["coordinator"][-1] if "coordinator" in query
                   else os.environ.get(COORDINATOR_ENV, "127.0.0.1"))
    if not coordinator:
        raise TransportError(port, "coordinator address is empty")
    if ":" not in coordinator.rsplit("]", 1)[-1]:
        coordinator = f"{coordinator}:{DEFAULT_COORDINATOR_PORT}"
    return place, coordinator


class LabgridClient:
    """The labgrid client session of this process for one coordinator, on a thread of its own.

    Shared by every place of that coordinator: gRPC shares one connection between channels to
    the same address, and the coordinator takes one session per connection. Counted: the last
    :meth:`drop` ends the session and its thread.
    """

    _shared: ClassVar[dict[str, LabgridClient]] = {}
    _shared_lock: ClassVar[threading.Lock] = threading.Lock()

    def __init__(self, coordinator: str) -> None:
        self.coordinator = coordinator
        self.users = 0
        self.thread = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="labgrid")
        self._loop: asyncio.AbstractEventLoop | None = None
        self.session: Any = None

    @classmethod
    def get(cls, coordinator: str) -> LabgridClient:
        """The shared client of ``coordinator``, counted once more."""
        with cls._shared_lock:
            client = cls._shared.get(coordinator)
            if client is None:
                client = cls._shared[coordinator] = cls(coordinator)
            client.users += 1
            return client

    def drop(self) -> None:
        """Count one user less; the last one ends the session (on its thread) and the thread."""
        with self._shared_lock:
            self.users -= 1
            if self.users > 0:
                return
            del self._shared[self.coordinator]
        self.thread.submit(self._end)
        self.thread.shutdown(wait=False)

    def run(self, coro: Any) -> Any:
        """Run a coroutine of the session on its loop (on the client's thread) with a deadline."""
        assert self._loop is not None
        return self._loop.run_until_complete(asyncio.wait_for(coro, COORDINATOR_TIMEOUT_S))

    def started(self, port: str) -> Any:
        """The session, started on first use (on the client's thread)."""
        if self.session is not None:
            return self.session
        from labgrid.remote.client import ClientSession

        deadline = time.monotonic() + COORDINATOR_TIMEOUT_S
        while True:
            self._loop = asyncio.new_event_loop()
            asyncio.set_event_loop(self._loop)  # gRPC's asyncio client looks it up
            session = ClientSession(self.coordinator, self._loop)
            try:
                self.run(session.start())
            except Exception as exc:  # labgrid's ServerError, gRPC errors, a timeout
                self._end(session)
                # a coordinator starting or restarting (or too busy to take the stream at once)
                # is asked again until the deadline
                if time.monotonic() + COORDINATOR_RETRY_S < deadline:
                    time.sleep(COORDINATOR_RETRY_S)
                    continue
                raise CoordinatorUnreachableError(
                    port, f"labgrid coordinator {self.coordinator} did not answer within "
                          f"{COORDINATOR_TIMEOUT_S:g} s ({type(exc).__name__}: "
                          f"{peer_str(str(exc))})") from exc
            self.session = session
            return session

    def _end(self, session: Any = None) -> None:
        session = session if session is not None else self.session
        self.session = None
        loop, self._loop = self._loop, None
        if loop is None or session is None:
            return
        try:
            loop.run_until_complete(asyncio.wait_for(session.stop(), COORDINATOR_TIMEOUT_S))
            loop.run_until_complete(session.close())
        except Exception:  # the session is gone either way
            pass
        finally:
            loop.close()


class LabgridPlace:
    """One place of a labgrid lab, acquired and released through the shared client session.

    :meth:`acquire` and :meth:`release` block: call them on ``client.thread``, as
    :class:`LabgridTransport` does.
    """

    def __init__(self, port: str, place: str, client: LabgridClient) -> None:
        self.port = port
        self.place = place
        self.client = client
        self.acquired = False
        self.power: str | None = None
        """The name of the place's power resource (the first of :data:`POWER_RESOURCES`
        available), once acquired; None when it has none."""

    def acquire(self) -> tuple[str, str, int]:
        """Acquire the place; ``(protocol, host, tcp_port)`` of its serial port. On any error
        nothing stays acquired."""
        from labgrid.remote.generated import labgrid_coordinator_pb2 as pb

        session = self.client.started(self.port)
        where = f"at coordinator {self.client.coordinator}"
        try:
            place = session.places.get(self.place)
            if place is None:
                known = peer_str(", ".join(sorted(session.places))) or "none"
                raise PlaceUnknownError(self.port, f"no place {self.place!r} {where} "
                                                   f"(places: {known})")
            if place.acquired:
                raise PlaceLockedError(self.port, f"place {self.place!r} is acquired by "
                                                  f"{peer_str(place.acquired)}", place.acquired)
            try:
                self.client.run(session.stub.AcquirePlace(
                    pb.AcquirePlaceRequest(placename=self.place)))
                self.client.run(session.sync_with_coordinator())
            except Exception as exc:
                detail = peer_str(exc.details() if hasattr(exc, "details") else str(exc))
                owner = session.places[self.place].acquired
                if owner:  # someone was faster
                    raise PlaceLockedError(self.port, f"place {self.place!r} is acquired by "
                                                      f"{peer_str(owner)}", owner) from exc
                raise LabgridError(self.port, f"the coordinator did not give place "
                                              f"{self.place!r}: {detail} (its exporter could not "
                                              f"serve the resources?)") from exc
            self.acquired = True
            return self._serial_port(session, session.places[self.place])
        except BaseException:
            self.release()
            raise

    def _serial_port(self, session: Any, place: Any) -> tuple[str, str, int]:
        resources = session.get_target_resources(place)
        self.power = next((name for (name, cls), r in sorted(resources.items())
                           if cls in POWER_RESOURCES and r.avail), None)
        serial = [r for (_, cls), r in sorted(resources.items()) if cls == SERIAL_RESOURCE]
        available = [r for r in serial if r.avail]
        if not available:
            have = peer_str(", ".join(sorted(f"{name} ({cls})" for name, cls in resources)))
            have = have or "nothing"
            why = "none is available (exporter gone?)" if serial else f"it has {have}"
            raise NoSerialResourceError(self.port, f"place {self.place!r} has no "
                                                   f"{SERIAL_RESOURCE}: {why}")
        args = available[0].args
        return str(args.get("protocol", "rfc2217")), str(args["host"]), int(args["port"])

    def release(self) -> None:
        """Release the place if this object acquired it. Idempotent."""
        if not self.acquired or self.client.session is None:
            return
        from labgrid.remote.generated import labgrid_coordinator_pb2 as pb

        self.acquired = False
        session = self.client.session
        self.client.run(session.stub.ReleasePlace(pb.ReleasePlaceRequest(placename=self.place)))
        self.client.run(session.sync_with_coordinator())


class LabgridTransport(Transport):
    """The serial port of a labgrid place, held for as long as the transport is open."""

    scheme = "labgrid"

    @classmethod
    def arm_name(cls, port: str) -> str:
        """The place's name."""
        place, _ = parse_labgrid_url(port)
        return place

    @classmethod
    def capabilities(cls, port: str) -> Capabilities:
        """Hardware's, with a power switch of its own where the place has a power resource
        (:meth:`power_commands`; the bench finds none on a place without one)."""
        return Capabilities(power=True)

    def __init__(self, port: str, serial: SerialSettings) -> None:
        super().__init__(port, serial)
        self.place_name, self.coordinator = parse_labgrid_url(port)
        self.inner: Transport | None = None
        """The transport to the place's serial port, once open."""
        self._place: LabgridPlace | None = None
        self._power: str | None = None

    @property
    def is_open(self) -> bool:
        return self.inner is not None and self.inner.is_open

    async def _call(self, place: LabgridPlace, fn: Any) -> Any:
        future = asyncio.get_running_loop().run_in_executor(place.client.thread, fn)
        return await asyncio.shield(future)  # a cancelled run still finishes what labgrid does

    def preflight(self) -> None:
        """labgrid must be installed."""
        try:
            import labgrid  # noqa: F401
        except ImportError as exc:
            raise TransportError(self.port, "labgrid is not installed (pip install "
                                            "'armbench[labgrid]')") from exc

    async def open(self) -> None:
        self.preflight()
        if self._place is not None:
            raise TransportError(self.port, "transport is already open")
        place = self._place = LabgridPlace(self.port, self.place_name,
                                           LabgridClient.get(self.coordinator))
        try:
            protocol, host, tcp_port = await self._call(place, place.acquire)
        except BaseException:
            self._place = None
            place.client.drop()
            raise
        from armbench.drivers.transports import transport_class

        self._power = place.power
        scheme = "rfc2217" if protocol == "rfc2217" else "socket"
        inner = transport_class(f"{scheme}://{host}:{tcp_port}")(
            f"{scheme}://{host}:{tcp_port}", self.serial)
        self.inner = inner
        try:
            await inner.open()
        except BaseException:
            await self.close()
            raise

    def power_commands(self) -> tuple[list[str], list[str]] | None:
        """The commands that cut and restore the arm's power through the place's own power
        resource, as labgrid's client does it (``labgrid-client -p PLACE power off|on -n
        NAME``, run by this Python: the place is acquired by this user on this host, which the
        client checks); None when the place, as last acquired, has no power resource."""
        if self._power is None:
            return None
        base = [sys.executable, "-m", "labgrid.remote.client", "-x", self.coordinator,
                "-p", self.place_name, "power"]
        return [*base, "off", "-n", self._power], [*base, "on", "-n", self._power]

    def _open_inner(self) -> Transport:
        if self.inner is None:
            raise TransportError(self.port, "transport is not open")
        return self.inner

    async def read(self) -> bytes:
        data = await self._open_inner().read()
        self.bytes_in += len(data)
        return data

    async def write(self, data: bytes) -> None:
        await self._open_inner().write(data)
        self.bytes_out += len(data)

    async def close(self) -> None:
        inner, self.inner = self.inner, None
        place, self._place = self._place, None
        try:
            if inner is not None:
                await inner.close()
        finally:
            if place is not None:
                try:
                    await self._call(place, place.release)
                finally:
                    place.client.drop()
