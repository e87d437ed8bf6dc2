"""The host's end of a simulated arm that runs in this process, on the running event loop.

A simulator in the same process (the firmware emulator of ``fake://``, the lockstep boards of
``avr://`` on virtual time, a simulator of another distribution) is no byte stream: it hands
the host each chunk from a loop callback at the loop time the chunk arrives, and takes the
host's bytes in a plain call. :class:`InProcessTransport` makes a
:class:`~armbench.drivers.transports.base.Transport` of such a peer (an
:class:`InProcessPeer`) once, for every in-process target:

- chunks are kept for :meth:`~InProcessTransport.read` in a bounded buffer (a host that leaves
  more than :attr:`~InProcessTransport.max_unread_bytes` unread has lost the port, as a UART
  that overruns), or handed to a receiver the moment they arrive
  (:meth:`~InProcessTransport.set_receiver`: no future and no task switch per reply, and,
  while none is kept, no interpreted frame either: the peer calls the receiver through a
  compiled byte count, :class:`~armbench.fakes.links.handover.CountedSink`);
- a read waits on one future, woken by the next chunk, by :meth:`~InProcessTransport.close`
  (a lost port) or by the peer's loss (:meth:`~InProcessTransport._peer_lost`);
- a peer given to the constructor is the caller's to close; one the transport makes itself
  (from its port string, in its own :meth:`~armbench.drivers.transports.base.Transport.open`)
  is closed with it;
- the target's capabilities are a class attribute, :attr:`~InProcessTransport.declared`.

It is not a transport of ``armbench.drivers.transports`` (those carry bytes over an OS
resource): it lives with the simulators, and a subclass only opens its peer.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from typing import ClassVar, Generic, Protocol, TypeVar

from armbench.drivers.model.settings import SerialSettings
from armbench.drivers.transports.base import READ_CHUNK, Transport
from armbench.drivers.transports.capabilities import Capabilities
from armbench.fakes.links.handover import CountedSink

__all__ = ["MAX_UNREAD_BYTES", "InProcessPeer", "InProcessTransport"]

MAX_UNREAD_BYTES = 1 << 20
"""Most bytes kept for :meth:`InProcessTransport.read` before the port counts as lost."""


class InProcessPeer(Protocol):
    """What an in-process simulator offers its host: a sink for the bytes it sends, the bytes
    the host sends, and its life on the running loop."""

    def attach_host(self, sink: Callable[[bytes], None]) -> None:
        """Connect the host: ``sink`` receives every chunk, at the loop time it arrives."""

    def detach_host(self) -> None:
        """Disconnect the host: what the peer sends from now on goes nowhere."""

    def host_write(self, data: bytes) -> None:
        """The host sends ``data`` at the loop's now."""

    async def start(self) -> None:
        """Power up on the running loop."""

    async def close(self) -> None:
        """Stop (idempotent)."""


PeerT = TypeVar("PeerT", bound=InProcessPeer)


class InProcessTransport(Transport, Generic[PeerT]):
    """A transport whose other end is an :class:`InProcessPeer` on the same loop (:attr:`peer`);
    a subclass whose peer is an :class:`~armbench.drivers.transports.base.Emulator` declares it
    as its ``emulator`` (ground truth, power).

    A subclass sets :attr:`scheme` and :attr:`declared`, and implements :meth:`open`: make the
    peer when none was given, then start it and :meth:`_attach` it, in the order its peer needs
    (the emulator is attached first, to miss nothing it sends while it starts). Errors of the
    peer's :meth:`~InProcessPeer.host_write` listed in :attr:`peer_errors` are a lost port."""

    declared: ClassVar[Capabilities] = Capabilities(clock="virtual")
    """What the target can do (:meth:`capabilities`): at least the loop's clock, on which the
    peer runs."""
    peer_errors: ClassVar[tuple[type[Exception], ...]] = ()
    """Exceptions of the peer's ``host_write`` that mean it is gone (a lost port)."""
    max_unread_bytes: ClassVar[int] = MAX_UNREAD_BYTES
    """Most bytes kept unread; one more chunk and the port is lost (the chunk is dropped)."""

    @classmethod
    def capabilities(cls, port: str) -> Capabilities:
        return cls.declared

    def __init__(self, port: str, serial: SerialSettings, peer: PeerT | None = None) -> None:
        self._direct: CountedSink | None = None
        """The peer's sink while chunks go straight to the receiver (:meth:`_route`)."""
        self._bytes_in = 0
        super().__init__(port, serial)
        self._given = peer
        self._peer: PeerT | None = peer
        self._chunks: list[bytes] = []
        self._unread = 0
        self._receiver: Callable[[bytes], None] | None = None
        self._waiter: asyncio.Future[None] | None = None
        self._open = False
        self._lost_reason: str | None = None

    @property
    def peer(self) -> PeerT | None:
        """The peer: the one given, else the one :meth:`open` made (None before)."""
        return self._peer

    @property
    def bytes_in(self) -> int:
        """Payload bytes received: returned by :meth:`read` or handed to the receiver."""
        direct = self._direct
        return self._bytes_in if direct is None else self._bytes_in + direct.bytes

    @bytes_in.setter
    def bytes_in(self, value: int) -> None:
        direct = self._direct
        self._bytes_in = value if direct is None else value - direct.bytes

    @property
    def is_open(self) -> bool:
        """Opened, not closed, and the port not lost (:meth:`_peer_lost`)."""
        return self._open and self._lost_reason is None

    def _attach(self, peer: PeerT) -> None:
        """Take what ``peer`` sends from now on; the transport is open."""
        peer.attach_host(self._receive)
        self._open = True
        self._route()

    def set_receiver(self, receiver: Callable[[bytes], None] | None) -> None:
        """Hand each chunk to ``receiver`` the moment it arrives (in the peer's callback, at
        its loop time) instead of keeping it for :meth:`read`: no future and no task switch per
        reply. Chunks already kept are read first; :meth:`read` then waits for more kept chunks
        or the end of the connection. None: back to plain reads."""
        self._receiver = receiver
        self._route()

    def _route(self) -> None:
        """Attach the peer to the receiver itself (through a :class:`CountedSink`) while one is
        set and no chunk is kept, else to :meth:`_receive`; a sink let go leaves its count in
        :attr:`bytes_in`."""
        peer, receiver, direct = self._peer, self._receiver, self._direct
        if peer is None or not self._open:
            return
        if receiver is not None and not self._chunks:
            if direct is None or direct.receiver != receiver:
                self._let_go_direct()
                self._direct = CountedSink(receiver)
                peer.attach_host(self._direct)
            return
        if direct is not None:
            self._let_go_direct()
            peer.attach_host(self._receive)

    def _let_go_direct(self) -> None:
        """Stop using the counted sink, its count kept in :attr:`bytes_in`."""
        direct, self._direct = self._direct, None
        if direct is not None:
            self._bytes_in += direct.bytes

    def _receive(self, data: bytes) -> None:
        """The peer's sink while no receiver takes the chunks, or chunks are still kept
        (:meth:`_route`): a chunk at its loop time, kept for :meth:`read`."""
        if self._lost_reason is not None:
            return
        unread = self._unread + len(data)
        if unread > self.max_unread_bytes:
            self._peer_lost(f"the host left {unread} bytes unread "
                            f"(at most {self.max_unread_bytes} are kept)")
            return
        self._unread = unread
        self._chunks.append(data)
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def _peer_lost(self, reason: object) -> None:
        """The peer is gone (or the host fell too far behind it): what is kept is still read,
        then every read and write raises a lost port naming ``reason``; a waiting read at
        once."""
        self._lost_reason = str(reason)
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_exception(self._lost(self._lost_reason))

    async def read(self) -> bytes:
        while not self._chunks:
            if not self._open:
                raise self._not_open()
            if self._lost_reason is not None:
                raise self._lost(self._lost_reason)
            self._waiter = asyncio.get_running_loop().create_future()
            try:
                await self._waiter
            finally:
                self._waiter = None
        if self._unread > READ_CHUNK:
            return self._read_some()
        data = b"".join(self._chunks)  # no copy for the usual single chunk
        self._chunks.clear()
        self._unread = 0
        self.bytes_in += len(data)
        self._route()  # a receiver now takes the chunks straight
        return data

    def _read_some(self) -> bytes:
        """:data:`READ_CHUNK` bytes of a backlog larger than that, the rest kept."""
        data = b"".join(self._chunks)
        self._chunks[:] = [data[READ_CHUNK:]]
        self._unread = len(data) - READ_CHUNK
        data = data[:READ_CHUNK]
        self.bytes_in += len(data)
        return data

    async def write(self, data: bytes) -> None:
        peer = self._peer
        if not self._open or peer is None:
            raise self._not_open()
        if self._lost_reason is not None:
            raise self._lost(self._lost_reason)
        try:
            peer.host_write(data)
        except self.peer_errors as exc:
            raise self._lost(str(exc)) from exc
        self.bytes_out += len(data)

    async def close(self) -> None:
        if not self._open:
            return
        self._open = False
        self._receiver = None
        self._let_go_direct()
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_exception(self._lost("transport closed"))
        peer = self._peer
        if peer is not None:
            peer.detach_host()
            if self._given is None:
                await peer.close()
