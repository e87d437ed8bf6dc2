"""``armbench monitor``: live joint angles, TCP position, frame rate and error counts.

On a terminal the display is refreshed in place (ANSI cursor moves) ``--rate`` times per second;
otherwise one summary line per refresh; with ``--json`` one JSON object per state received. Against
a target on the virtual clock (``fake://``: the emulator in-process) ``--duration`` counts simulated
seconds and defaults to 10 s.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import sys
from collections import deque
from collections.abc import AsyncIterator, Coroutine
from typing import Any, TextIO, TypeVar

from armbench.cli.commands.bounds import DURATION_S, REPLY_TIMEOUT_S, add_bounded
from armbench.drivers.host.arm import Arm, JointState, ReplyTimeoutError, StateStream
from armbench.drivers.model.bounds import Bound
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.transports import Transport
from armbench.drivers.transports.base import emulated
from armbench.drivers.transports.capabilities import ArmInputs, FreshArm
from armbench.drivers.transports.target import Target, given_by, target_of
from armbench.frontends.foxglove.live import (
    DEFAULT_ENDPOINT,
    LiveView,
    check_live_endpoint,
    live_view,
)

__all__ = ["DEFAULT_FAKE_DURATION_S", "command_inputs", "fresh_transport", "monitor", "register",
           "run_on_port"]

T = TypeVar("T")

#: ``--duration`` on a target on the virtual clock when none is given (virtual time runs as fast
#: as it can).
DEFAULT_FAKE_DURATION_S = 10.0
#: Window of the frame-rate estimate, seconds.
RATE_WINDOW_S = 1.0
#: ``--rate``: refreshes of the display per second, at least one every ten seconds.
REFRESH_HZ = Bound(0.1, 1000.0, "Hz")


def run_on_port(port: str, main: Coroutine[Any, Any, T]) -> T:
    """Run ``main`` on virtual time for a target on the virtual clock (``fake://``: the emulator
    in-process), else in real time."""
    if target_of(port).virtual:
        from armbench.fakes.clock.vclock import (
            run_virtual,  # the CLI may use fakes; the driver may not
        )

        return run_virtual(main)
    return asyncio.run(main)


def command_inputs(port: str, settings_path: str | None) -> tuple[Target, ArmInputs]:
    """The port's target and a command's settings: ``--settings`` over the port's query over the
    settings file over the defaults (``docs/transports.md``)."""
    target = target_of(port)
    return target, target.inputs(given_by({"settings": "--settings"}, settings=settings_path))


def fresh_transport(target: Target, inputs: ArmInputs) -> Transport | None:
    """On a target that starts fresh arms, a transport (not opened) to a new one built from
    ``inputs``, so that the arm and the driver play the same settings; its ``emulator`` is the
    caller's to close. None elsewhere: the driver opens the port."""
    if not target.capabilities.fresh_per_trial:
        return None
    seed = inputs.seed if inputs.seed is not None else 0
    return target.fresh(inputs.robot.serial, FreshArm(inputs.robot, seed, inputs.faults))


async def close_emulator(transport: Transport | None) -> None:
    """Close the emulator of a transport from :func:`fresh_transport`, if it has one."""
    emulator = emulated(transport)
    if emulator is not None:
        await emulator.close()


def register(sub: Any) -> None:
    """Add the ``monitor`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "monitor",
        description="Show the arm's state as it streams in: joint angles (rad and degrees), the "
                    "TCP position by forward kinematics, the reply rate and the error counters.")
    p.add_argument("--port", default="fake://",
                   help="serial device, socket://HOST:PORT, rfc2217://HOST:PORT or fake:// "
                        "(default fake://, the emulator on virtual time)")
    p.add_argument("--json", action="store_true", help="one JSON object per state on stdout")
    add_bounded(p, "--duration", DURATION_S, default=None, metavar="S",
                help="stop after S seconds (default: until Ctrl-C; "
                     f"{DEFAULT_FAKE_DURATION_S:g} simulated s on fake://)")
    p.add_argument("--settings", default=None, metavar="FILE", help="robot settings TOML")
    add_bounded(p, "--rate", REFRESH_HZ, default=10.0, metavar="HZ",
                help="display refreshes per second without --json (default 10)")
    add_bounded(p, "--reply-timeout", REPLY_TIMEOUT_S, default=0.5, metavar="S",
                help="report the arm as silent after S seconds without a reply (default 0.5)")
    p.add_argument("--foxglove", nargs="?", const=DEFAULT_ENDPOINT, metavar="HOST:PORT",
                   help="serve the joint stream to Foxglove over WebSocket (default "
                        f"{DEFAULT_ENDPOINT}: loopback unless a host is given)")
    p.add_argument("--allow-remote", action="store_true",
                   help="with --foxglove: allow binding an address other than loopback (no "
                        "authentication: anyone who reaches it can read the stream)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    target, inputs = command_inputs(args.port, args.settings)
    settings = inputs.robot
    duration = args.duration
    if duration is None and target.virtual:
        duration = DEFAULT_FAKE_DURATION_S
    if args.foxglove is not None:  # refused before connecting; live_view warns
        check_live_endpoint(args.foxglove, args.allow_remote)
    return run_on_port(args.port, monitor(args.port, settings, json_lines=args.json,
                                          duration_s=duration, refresh_hz=args.rate,
                                          reply_timeout_s=args.reply_timeout, out=sys.stdout,
                                          foxglove=args.foxglove,
                                          allow_remote=args.allow_remote,
                                          transport=fresh_transport(target, inputs)))


@contextlib.asynccontextmanager
async def _live(endpoint: str | None, settings: RobotSettings,
                allow_remote: bool) -> AsyncIterator[LiveView | None]:
    with live_view(endpoint, settings, name="monitor", announce=sys.stderr,
                   allow_remote=allow_remote) as view:
        yield view


class _Rate:
    """Replies per second over the last ``RATE_WINDOW_S``."""

    def __init__(self) -> None:
        self._samples: deque[tuple[float, int]] = deque()

    def update(self, t_s: float, count: int) -> float:
        s = self._samples
        s.append((t_s, count))
        while len(s) > 2 and t_s - s[1][0] >= RATE_WINDOW_S:
            s.popleft()
        t0, c0 = s[0]
        return (count - c0) / (t_s - t0) if t_s > t0 else 0.0


def state_json(arm: Arm, state: JointState, rate_hz: float, skipped: int) -> dict[str, Any]:
    """The ``--json`` object of one state."""
    return {
        "t_s": state.t_s, "seq": state.seq,
        "q_rad": list(state.q_rad), "q_deg": [math.degrees(q) for q in state.q_rad],
        "ticks": list(state.ticks), "tcp_m": list(state.tcp_m(arm.settings)),
        "rate_hz": rate_hz, "frames_received": arm.frames_received,
        "frames_dropped": arm.frames_dropped, "discarded_bytes": arm.discarded_bytes,
        "skipped": skipped, "reconnects": arm.reconnects,
    }


def _lines(arm: Arm, state: JointState, rate_hz: float, stream: StateStream,
           note: str) -> list[str]:
    x, y, z = state.tcp_m(arm.settings)
    out = [f"armbench monitor  {arm.port}  t = {state.t_s:9.3f} s  {rate_hz:7.1f} replies/s  "
           f"{note}",
           f"received {arm.frames_received}  dropped {arm.frames_dropped}  discarded "
           f"{arm.discarded_bytes} B  skipped {stream.skipped}  reconnects {arm.reconnects}",
           "joint        rad        deg   ticks"]
    for j, q, t in zip(arm.settings.joints, state.q_rad, state.ticks, strict=True):
        out.append(f"{j.name:<5s} {q:+10.5f} {math.degrees(q):+10.3f}   {t:5d}")
    out.append(f"TCP   x {x:+.4f} m   y {y:+.4f} m   z {z:+.4f} m")
    return out


def _summary(arm: Arm, state: JointState, rate_hz: float, note: str) -> str:
    q = " ".join(f"{v:+.5f}" for v in state.q_rad)
    x, y, z = state.tcp_m(arm.settings)
    line = (f"t={state.t_s:.3f}s q=[{q}] rad tcp=({x:+.4f}, {y:+.4f}, {z:+.4f}) m "
            f"{rate_hz:.1f}/s rx={arm.frames_received} dropped={arm.frames_dropped} "
            f"discarded={arm.discarded_bytes}B")
    return f"{line} {note}" if note else line


async def monitor(port: str, settings: RobotSettings, *, json_lines: bool = False,
                  duration_s: float | None = None, refresh_hz: float = 10.0,
                  reply_timeout_s: float = 0.5, out: TextIO = sys.stdout,
                  foxglove: str | None = None, allow_remote: bool = False,
                  transport: Transport | None = None) -> int:
    """Stream the arm's state to ``out`` until ``duration_s`` (loop seconds) or cancellation;
    with ``foxglove`` (``HOST:PORT``) to Foxglove too (:mod:`armbench.frontends.foxglove.live`; a
    host other than loopback only with ``allow_remote``). ``transport``: one from
    :func:`fresh_transport`
    (its emulator closed at the end), else the driver opens ``port``."""
    try:
        return await _monitor(port, settings, json_lines=json_lines, duration_s=duration_s,
                              refresh_hz=refresh_hz, reply_timeout_s=reply_timeout_s, out=out,
                              foxglove=foxglove, allow_remote=allow_remote, transport=transport)
    finally:
        await close_emulator(transport)


async def _monitor(port: str, settings: RobotSettings, *, json_lines: bool,
                   duration_s: float | None, refresh_hz: float, reply_timeout_s: float,
                   out: TextIO, foxglove: str | None, allow_remote: bool,
                   transport: Transport | None) -> int:
    tty = out.isatty() and not json_lines
    period = 1.0 / refresh_hz if refresh_hz > 0 else 0.0
    rate = _Rate()
    drawn = 0
    async with Arm.connect(port, settings, reply_timeout_s=reply_timeout_s,
                           transport=transport) as arm, \
            _live(foxglove, settings, allow_remote) as live:
        loop = asyncio.get_running_loop()
        end = None if duration_s is None else loop.time() + duration_s
        stream = arm.states()
        last_draw = -math.inf
        note = ""
        while end is None or loop.time() < end:
            try:
                async with asyncio.timeout_at(end) as cm:
                    state = await anext(stream)
            except ReplyTimeoutError as exc:
                note = f"SILENT: {exc}"
                state = arm.state
            except TimeoutError:
                if cm.expired():
                    break
                raise
            except StopAsyncIteration:
                break
            else:
                note = ""
            r = rate.update(state.t_s, arm.frames_received)
            if live is not None and not note:
                live.driver_state(state, arm.ground_truth())
            if json_lines:
                out.write(json.dumps(state_json(arm, state, r, stream.skipped)) + "\n")
                continue
            now = loop.time()
            if now - last_draw < period and not note:
                continue
            last_draw = now
            lines = _lines(arm, state, r, stream, note)
            if tty:
                if drawn:
                    out.write(f"\x1b[{drawn}A")
                out.write("".join(f"\r{line}\x1b[K\n" for line in lines))
                drawn = len(lines)
            else:
                out.write(_summary(arm, state, r, note) + "\n")
            with contextlib.suppress(BrokenPipeError):
                out.flush()
    return 0
