"""``armbench emulate --firmware``: serve the firmware in the loop like the emulator.

With ``--pty`` the harness's own pty is the served device. With ``--tcp`` one client at a time is
bridged to it: bytes from the client go to joint 1's UART, its replies to the client.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
from pathlib import Path

from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.avr.harness import Harness
from armbench.fakes.links.pty_link import claim_link, release_link
from armbench.fakes.links.signals import stop_on_signals

__all__ = ["bridge_tcp", "serve_firmware"]


async def _pump(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    while data := await reader.read(65536):
        writer.write(data)
        await writer.drain()


async def bridge_tcp(harness: Harness, host: str, port: int,
                     stop: asyncio.Event) -> tuple[str, int, asyncio.Server]:
    """Serve ``harness``'s UART on TCP ``host:port`` (one client at a time; a second one is
    closed at once). Returns the bound address and the server."""
    import serial_asyncio_fast  # pyserial imports fcntl and termios on POSIX: only when used

    dev_reader, dev_writer = await serial_asyncio_fast.open_serial_connection(
        url=harness.pty, baudrate=115200)
    busy = asyncio.Lock()

    async def client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if busy.locked():
            writer.close()
            return
        async with busy:
            tasks = [asyncio.create_task(_pump(reader, dev_writer)),
                     asyncio.create_task(_pump(dev_reader, writer))]
            stopped = asyncio.create_task(stop.wait())
            await asyncio.wait([*tasks, stopped], return_when=asyncio.FIRST_COMPLETED)
            for task in (*tasks, stopped):
                task.cancel()
            with contextlib.suppress(ConnectionError):
                writer.close()

    server = await asyncio.start_server(client, host, port)
    bound = server.sockets[0].getsockname()
    return str(bound[0]), int(bound[1]), server


async def serve_firmware(robot: RobotSettings, firmware: str, args: argparse.Namespace,
                         host_port: tuple[str, int] | None) -> None:
    """Start the harness and serve it on its pty (``--link`` too) or on TCP until Ctrl-C,
    SIGTERM or ``--duration``; print the harness's figures at the end."""
    stop = asyncio.Event()
    with stop_on_signals(stop):
        harness = await Harness.start(robot, firmware)
        server: asyncio.Server | None = None
        try:
            if host_port is None:
                where = harness.pty
                if args.link:  # only an earlier emulator's link is replaced, as for --pty
                    claim_link(Path(args.link), harness.pty)
                    where += f" (link {args.link})"
            else:
                host, port, server = await bridge_tcp(harness, *host_port, stop)
                where = f"socket://{host}:{port}"
            print(f"armbench emulate: serving the firmware in the loop on {where}", flush=True)
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(args.duration):
                    await stop.wait()
            stats = await harness.stats()
            print(f"armbench emulate: stopped after {stats['uart']['replies']} replies; "
                  f"figures {json.dumps(stats)}", flush=True)
        finally:
            stop.set()
            if server is not None:
                server.close()
            if host_port is None and args.link:
                release_link(Path(args.link), harness.pty)
            await harness.stop()
