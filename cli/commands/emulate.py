"""``armbench emulate``: serve the emulated arm on a pseudo-terminal or a TCP port, in real time."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import sys
from collections.abc import Callable
from typing import Any

from armbench.cli.commands.bounds import DURATION_S, TIMEOUT_S, add_bounded
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.transports.target import given_by, resolve
from armbench.fakes.avr.serve_firmware import serve_firmware
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.fakes.links.fake_transport import FakeTransport
from armbench.fakes.links.pty_link import require_pty
from armbench.fakes.links.relay import RelayServer
from armbench.fakes.links.serve import PtyServer, TcpServer, parse_host_port, real_time_loop
from armbench.fakes.links.signals import stop_on_signals
from armbench.frontends.foxglove.live import (
    DEFAULT_ENDPOINT,
    check_bind,
    check_live_endpoint,
    follow_emulator,
    live_view,
)

__all__ = ["register"]

log = logging.getLogger("armbench.emulator")


def register(sub: Any) -> None:
    """Add the ``emulate`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "emulate",
        description="Run the firmware emulator in real time and serve it as the robot: on a "
                    "pseudo-terminal (any serial program can open it) or on a TCP port.")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--pty", action="store_true", help="serve on a new pseudo-terminal")
    where.add_argument("--tcp", metavar="HOST:PORT",
                       help="serve on TCP (host defaults to 127.0.0.1)")
    p.add_argument("--link", metavar="PATH", help="with --pty: make PATH a symlink to the device")
    p.add_argument("--allow-remote", action="store_true",
                   help="with --tcp or --foxglove: allow binding an address other than loopback "
                        "(no authentication: anyone who reaches it can use it)")
    p.add_argument("--settings", metavar="FILE", help="robot settings TOML ([emulator] table too)")
    p.add_argument("--faults", metavar="FILE", help="fault list TOML ([[faults]] tables)")
    p.add_argument("--seed", type=int, default=None, help="seed of the emulator's randomness")
    p.add_argument("--firmware", metavar="DIR|PATH", default=None,
                   help="serve compiled firmware on four simulated ATmega328P instead (a folder "
                        "of joint1..4.elf/.hex, a path with {n}, or '' for the reference "
                        "firmware; docs/firmware.md)")
    add_bounded(p, "--duration", DURATION_S, default=None, metavar="S",
                help="stop after S seconds (default: until Ctrl-C)")
    add_bounded(p, "--idle-timeout", TIMEOUT_S, default=300.0, metavar="S",
                help="with --tcp: disconnect a client silent for S seconds (default 300)")
    p.add_argument("--relay", metavar="HOST:PORT",
                   help="serve an HTTP power relay switching the emulated arm's power line "
                        "(labgrid simplerest: /relay/0/0 off, /relay/0/1 on; Tasmota: "
                        "/cm?cmnd=Power%%20Off); loopback unless --allow-remote")
    p.add_argument("--foxglove", nargs="?", const=DEFAULT_ENDPOINT, metavar="HOST:PORT",
                   help="serve the joint stream (reported and true) to Foxglove over WebSocket "
                        f"(default {DEFAULT_ENDPOINT}: loopback unless a host is given)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    # flag > settings file > default, as everywhere (docs/transports.md): a --faults list replaces
    # the file's [[faults]]
    inputs = FakeTransport.arm_inputs("fake://", resolve(given_by(
        {"settings": "--settings", "seed": "--seed", "faults": "--faults"},
        settings=args.settings, seed=args.seed, faults=args.faults)))
    robot = inputs.robot
    overrides = {"seed": inputs.seed} if inputs.seed is not None else {}
    settings = emulator_settings(robot, **overrides)
    faults = list(inputs.faults)
    if args.link and not args.pty:
        raise ArmbenchError("--link: only with --pty")
    host_port = parse_host_port(args.tcp) if args.tcp else None
    if host_port is None:  # --pty, the default: before anything is built
        require_pty()
    if args.foxglove is not None:  # refused before anything starts; live_view warns
        check_live_endpoint(args.foxglove, args.allow_remote)
    if host_port is not None:
        warning = check_bind("--tcp", host_port[0], args.allow_remote, "move the arm")
        if warning is not None:
            print(f"armbench emulate: {warning}", file=sys.stderr, flush=True)
    relay = parse_host_port(args.relay) if args.relay else None
    if relay is not None:
        warning = check_bind("--relay", relay[0], args.allow_remote, "switch the arm's power")
        if warning is not None:
            print(f"armbench emulate: {warning}", file=sys.stderr, flush=True)
    if args.firmware is not None:
        if relay is not None:
            raise ArmbenchError("--relay: only with the Python emulator (not --firmware)")
        if args.faults or args.seed is not None:
            raise ArmbenchError("--firmware: --faults and --seed apply to the Python emulator")
        asyncio.run(serve_firmware(robot, args.firmware, args, host_port))
        return 0
    arm = ArmEmulator(robot, settings, faults)
    with asyncio.Runner(loop_factory=real_time_loop) as runner, \
            live_view(args.foxglove, robot, name="emulate", announce=sys.stdout,
                      allow_remote=args.allow_remote) as live:
        follow_emulator(live, arm)
        runner.run(_serve(arm, args, host_port, relay))
    return 0


def _switch(arm: ArmEmulator) -> Callable[[bool], None]:
    def switch(on: bool) -> None:
        if on and not arm.powered:
            arm.power_on()
        elif not on and arm.powered:
            arm.power_off()
        log.info("relay: power %s", "on" if on else "off")

    return switch


async def _serve(arm: ArmEmulator, args: argparse.Namespace,
                 host_port: tuple[str, int] | None, relay: tuple[str, int] | None) -> None:
    stop = asyncio.Event()
    server: PtyServer | TcpServer
    if host_port is None:
        server = PtyServer(arm, args.link)
        path = await server.start()
        link = f" (link {args.link})" if args.link else ""
        print(f"armbench emulate: serving the arm on {path}{link}", flush=True)
    else:
        server = TcpServer(arm, *host_port, idle_timeout_s=args.idle_timeout)
        try:
            host, port = await server.start()
        except OSError as exc:  # the port is taken, the address is not this machine's, ...
            raise ArmbenchError(f"--tcp: cannot serve on {args.tcp}: "
                                f"{exc.strerror or exc}") from None
        print(f"armbench emulate: serving the arm on socket://{host}:{port}", flush=True)
    relay_server = None
    try:
        if relay is not None:  # after the arm's line: scripts read that one first
            relay_server = RelayServer(lambda: arm.powered, _switch(arm), *relay)
            try:
                where = await relay_server.start()
            except OSError as exc:
                raise ArmbenchError(f"--relay: cannot serve on {args.relay}: "
                                    f"{exc.strerror or exc}") from None
            print(f"armbench emulate: power relay on http://{where[0]}:{where[1]}/relay/0 "
                  "(0 off, 1 on)", flush=True)
        with stop_on_signals(stop), contextlib.suppress(TimeoutError):
            async with asyncio.timeout(args.duration):
                await stop.wait()
    finally:
        await server.close()
        if relay_server is not None:
            await relay_server.close()
        stats = arm.stats()
        overrun = (server.receive.overrun_bytes if isinstance(server, PtyServer)
                   else server.overrun_bytes)
        print(f"armbench emulate: stopped after {stats.loops} loops, {stats.commands} commands "
              f"received, {overrun} bytes dropped as overrun (sent faster than the line "
              f"carries them)",
              flush=True)
