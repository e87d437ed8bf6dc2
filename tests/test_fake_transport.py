"""The in-process transport base (``fakes/links/in_process.py``) through ``fake://``: the real
emulator on virtual time, read as the driver reads it. Reads, the receiver, the bounded buffer and
close are the base's, so they hold for ``avr://`` on virtual time and any third in-process target
(``tests/test_avr_virtual_time.py`` covers the boards' side)."""

from __future__ import annotations

import asyncio
from typing import Any, ClassVar

import pytest

from armbench.drivers.model.errors import PortLostError, TransportError
from armbench.drivers.model.protocol import Framer, Reply
from armbench.drivers.model.settings import RobotSettings, SerialSettings
from armbench.drivers.transports.base import READ_CHUNK
from armbench.drivers.transports.target import target_of
from armbench.fakes.avr.avr_transport import AvrTransport
from armbench.fakes.avr.harness import LOCKSTEP_CAPABILITIES
from armbench.fakes.avr.lockstep import AvrVirtualTransport
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.fakes.links.fake_transport import FAKE_CAPABILITIES, FakeTransport
from armbench.fakes.links.handover import CountedSink
from armbench.fakes.links.in_process import MAX_UNREAD_BYTES, InProcessTransport

PORT = "fake://?profile=ideal"


def replies(stream: bytes) -> list[Reply]:
    """Every frame of ``stream``, all of them replies (a byte lost or doubled would show as a
    frame error or a frame too many)."""
    frames = list(Framer("reply").feed(stream))
    assert all(isinstance(f, Reply) for f in frames), frames
    return [f for f in frames if isinstance(f, Reply)]


def test_kept_chunks_are_read_before_the_receiver_gets_any() -> None:
    async def main() -> tuple[bytes, bytes, bytes, int]:
        transport = FakeTransport(PORT, SerialSettings())
        await transport.open()
        first = await transport.read()  # waits for the first reply
        await asyncio.sleep(0.05)  # kept meanwhile
        pushed: list[bytes] = []
        transport.set_receiver(pushed.append)
        await asyncio.sleep(0.05)  # still kept: older bytes wait in the buffer
        assert not pushed
        kept = await transport.read()
        await asyncio.sleep(0.05)  # now straight to the receiver
        transport.set_receiver(None)
        await transport.close()
        return first, kept, b"".join(pushed), transport.bytes_in

    first, kept, pushed, bytes_in = run_virtual(main)
    assert len(replies(first)) >= 1
    assert len(replies(kept)) >= 30  # 0.1 s of replies, one a loop
    assert len(replies(pushed)) >= 15
    assert len(replies(first + kept + pushed)) == sum(map(len, map(replies, (first, kept, pushed))))
    assert bytes_in == len(first) + len(kept) + len(pushed)


def test_a_counted_sink_hands_over_and_counts() -> None:
    got: list[bytes] = []
    sink = CountedSink(got.append)
    sink(b"$00001,00002,00003,00004#")
    sink(b"ab")
    assert got == [b"$00001,00002,00003,00004#", b"ab"]
    assert sink.bytes == 27


def test_the_receiver_is_the_peers_sink_while_nothing_is_kept() -> None:
    """With a receiver and nothing kept the emulator calls it through a counted sink (no
    interpreted frame a chunk); without one it calls the transport's own, which keeps chunks for
    reads. Every byte is counted either way, the sink's too once it is let go."""
    async def main() -> tuple[list[int], int, int]:
        transport = FakeTransport(PORT, SerialSettings())
        await transport.open()
        emulator = transport.peer
        assert emulator is not None
        first = await transport.read()  # waits for the first reply
        pushed: list[bytes] = []
        transport.set_receiver(pushed.append)
        assert isinstance(emulator.uart.host_sink, CountedSink)
        await asyncio.sleep(0.05)
        counts = [transport.bytes_in - len(first), sum(map(len, pushed))]
        transport.set_receiver(None)
        assert not isinstance(emulator.uart.host_sink, CountedSink)
        kept = await transport.read()
        counts.append(transport.bytes_in - len(first))
        await transport.close()
        return counts, len(kept), transport.bytes_in - len(first)

    (direct, pushed, after_read), kept, closed = run_virtual(main)
    assert direct == pushed > 0
    assert after_read == pushed + kept
    assert closed == after_read


def test_close_wakes_a_waiting_read_and_leaves_a_given_emulator_running() -> None:
    robot = RobotSettings()

    async def main() -> None:
        emulator = ArmEmulator(robot, emulator_settings(robot))
        transport = FakeTransport(PORT, robot.serial, emulator)
        await transport.open()
        await transport.read()
        reading = asyncio.create_task(transport.read())
        await asyncio.sleep(0)  # the read waits for the next reply
        await transport.close()
        with pytest.raises(PortLostError, match="transport closed"):
            await reading
        assert not transport.is_open
        with pytest.raises(TransportError, match="not open"):
            await transport.read()
        with pytest.raises(TransportError, match="not open"):
            await transport.write(b"$x#")
        await transport.close()  # idempotent
        assert emulator.started  # the caller's to close
        received = transport.bytes_in
        await asyncio.sleep(0.05)  # detached: its replies go nowhere
        assert transport.bytes_in == received
        await emulator.close()

        own = FakeTransport(PORT, robot.serial)
        await own.open()
        made = own.emulator
        assert made is not None and made.started
        await own.close()
        assert not made.started  # made by the transport, closed with it

    run_virtual(main)


class SmallBuffer(FakeTransport):
    max_unread_bytes: ClassVar[int] = 500


def test_a_host_that_falls_behind_loses_the_port_instead_of_growing_a_buffer() -> None:
    async def main() -> None:
        transport = SmallBuffer(PORT, SerialSettings())
        await transport.open()
        await asyncio.sleep(1.0)  # about 400 replies, none read
        assert not transport.is_open  # lost, as every transport after a loss
        kept = await transport.read()  # what was kept is still read
        assert 0 < len(kept) <= SmallBuffer.max_unread_bytes
        assert len(replies(kept)) >= 1
        with pytest.raises(PortLostError, match=r"left \d+ bytes unread \(at most 500"):
            await transport.read()
        with pytest.raises(PortLostError, match="unread"):
            await transport.write(b"$00000,00000,00000,00000,099#")
        await transport.close()

    run_virtual(main)


def test_a_read_returns_at_most_read_chunk_bytes_and_keeps_the_rest_in_order() -> None:
    async def main() -> tuple[list[bytes], int]:
        transport = FakeTransport(PORT, SerialSettings())
        await transport.open()
        await asyncio.sleep(8.0)  # more than READ_CHUNK bytes of replies, none read
        chunks = [await transport.read()]
        chunks.append(await transport.read())
        await transport.close()
        return chunks, transport.bytes_in

    chunks, bytes_in = run_virtual(main)
    assert len(chunks[0]) == READ_CHUNK
    assert 0 < len(chunks[1]) < MAX_UNREAD_BYTES
    assert len(replies(b"".join(chunks))) > 3000
    assert bytes_in == sum(map(len, chunks))


@pytest.mark.parametrize(("port", "cls", "declared"), [
    ("fake://", FakeTransport, FAKE_CAPABILITIES),
    ("avr://", AvrVirtualTransport, LOCKSTEP_CAPABILITIES),
])
def test_each_in_process_target_declares_its_capabilities_once(
        port: str, cls: type[InProcessTransport[Any]], declared: object) -> None:
    assert issubclass(cls, InProcessTransport)
    assert cls.capabilities(port) is declared
    assert target_of(port).capabilities == declared
    assert AvrTransport.capabilities("avr://?firmware=x") == LOCKSTEP_CAPABILITIES
