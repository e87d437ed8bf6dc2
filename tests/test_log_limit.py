"""Log lines a peer causes once per event come at a bounded rate (``drivers/model/log_limit.py``,
``measurements/reliability.md``, third round): a few per interval, then one line with the count held
back. Before, ``armbench emulate --tcp`` under a 50-client storm logged one WARNING per refused
connection, 125 000 lines (11 MB) in 60 s.
"""

from __future__ import annotations

import asyncio
import logging

import pytest

from armbench.drivers.host.arm import Arm
from armbench.drivers.model.log_limit import DEFAULT_INTERVAL_S, DEFAULT_LINES, LogLimit
from armbench.drivers.model.protocol import Reply
from armbench.drivers.model.server_notes import note_line
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.links.serve import TcpServer, real_time_loop

STORM_CLIENTS = 200


def test_a_few_lines_per_interval_then_their_count(caplog: pytest.LogCaptureFixture) -> None:
    """On virtual time: 100 events in one interval, 3 in the next."""
    logger = logging.getLogger("armbench.test_log_limit")

    async def events() -> LogLimit:
        limit = LogLimit(logger, logging.WARNING, "events")
        for n in range(100):
            limit("event %d", n)
        await asyncio.sleep(DEFAULT_INTERVAL_S)
        for n in range(3):
            limit("late event %d", n)
        limit.flush()
        return limit

    with caplog.at_level(logging.WARNING, logger=logger.name):
        limit = run_virtual(events())
    lines = [r.getMessage() for r in caplog.records]
    suppressed = 100 - DEFAULT_LINES
    assert lines == [*(f"event {n}" for n in range(DEFAULT_LINES)),
                     f"… {suppressed} more events suppressed (at most {DEFAULT_LINES} every "
                     f"{DEFAULT_INTERVAL_S:g} s)",
                     *(f"late event {n}" for n in range(3))]
    assert limit.suppressed_total == suppressed and limit.suppressed == 0


def test_a_tcp_client_storm_logs_a_few_lines(caplog: pytest.LogCaptureFixture) -> None:
    """One client holds the arm; STORM_CLIENTS more connect and are refused, each told why. The
    log has a few refusals and the count of the rest, not one line each (real sockets)."""
    async def storm() -> TcpServer:
        server = TcpServer(ArmEmulator(), idle_timeout_s=60.0)
        host, port = await server.start()
        try:
            _, holder = await asyncio.open_connection(host, port)  # has the arm for 60 s
            await asyncio.sleep(0.1)
            for _ in range(STORM_CLIENTS):
                reader, writer = await asyncio.open_connection(host, port)
                assert b"busy" in await reader.read()
                writer.close()
            holder.close()
        finally:
            await server.close()
        return server

    with caplog.at_level(logging.INFO, logger="armbench.emulator"), \
            asyncio.Runner(loop_factory=real_time_loop) as runner:
        server = runner.run(storm())
    assert server.clients_refused == STORM_CLIENTS
    refusals = [r.getMessage() for r in caplog.records if "refus" in r.getMessage()]
    assert len(refusals) == DEFAULT_LINES + 1, refusals
    assert refusals[-1].startswith(f"… {STORM_CLIENTS - DEFAULT_LINES} more refused clients "
                                   "suppressed")
    assert len(caplog.records) < 3 * DEFAULT_LINES + 3


def test_a_server_that_sends_many_notes_is_logged_a_few_times(
        caplog: pytest.LogCaptureFixture) -> None:
    """A server writes 500 note lines between its replies: the driver logs a few of them and
    their count, and still reads the replies (a real TCP server, in this process)."""
    async def chatty(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        reply = Reply.from_rad([0.0] * 4).encode()
        for n in range(500):
            writer.write(note_line(f"note {n}") + reply)
            await writer.drain()
            await asyncio.sleep(0.001)
        await reader.read()

    async def client() -> None:
        server = await asyncio.start_server(chatty, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        async with Arm.connect(f"socket://127.0.0.1:{port}") as arm:
            await asyncio.sleep(1.0)
            assert arm.server_note is not None
        server.close()

    with caplog.at_level(logging.WARNING, logger="armbench.driver"):
        asyncio.run(client())
    notes = [r.getMessage() for r in caplog.records if "the server says" in r.getMessage()]
    assert len(notes) == DEFAULT_LINES, notes
    assert any(r.getMessage().startswith("… ") and "server notes suppressed" in r.getMessage()
               for r in caplog.records)
