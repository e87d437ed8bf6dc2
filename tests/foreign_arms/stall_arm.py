"""A foreign arm whose steppers stall: a simulator of the seed paper's arm written apart from
armbench (its own protocol code, its own joint model, stdlib only), answering in real time on TCP
or a pseudo-terminal.

Joint model: law (12) per joint (``1e6 / (80 (101 - duty))`` microsteps per second, 1600
microsteps per motor revolution, gear ratios 50/50/38/28), the reported angle is the joint angle
(an encoder on the joint, no Hall, no EEPROM); every joint starts at 0 (the zero pose).

Hidden behaviour (``--stall``, on by default; ``--no-stall`` is the plain arm): loss of
synchronism. A stepper driven faster than its pull-out rate stops turning: the rotor falls out of
step and hums in place. The pull-out rate here falls with the gravity torque the joint lifts
against (joints 2 and 3 carry the upper arm and the forearm, a worm gear passes a fixed share of
the torque to the motor)::

    pullout_steps_per_s = PULLOUT_FREE * (1 - lifted_torque_nm / STALL_TORQUE)

``lifted_torque_nm`` is the gravity torque about the joint when the move lifts (0 when it lowers,
the self-locking worm gear then holds the load). A joint that stalls stays where it is, whatever
its target, until the commanded rate falls below its pull-in rate (a new command at a lower duty,
or at duty 00); it is not a proportional loss: below the pull-out rate it loses nothing, above it
everything.

  python3 stall_arm.py --tcp 127.0.0.1:5555 [--no-stall] [--pullout-free 7000] [--stall-nm 14]
  python3 stall_arm.py --pty ./stall-tty
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import os
import re
import sys
import time
import tty

TWO_PI_U = 62832
CMD = re.compile(rb"\$(\d{5}),(\d{2}),(\d{5}),(\d{2}),(\d{5}),(\d{2}),(\d{5}),(\d{2})#")
GEARS = (50.0, 50.0, 38.0, 28.0)
MICROSTEPS_PER_REV = 1600.0
G = 9.81
# link masses (kg) and lengths (m) of the upper arm (joint 2) and forearm (joint 3)
M2, M3, A2, A3 = 4.5, 2.5, 0.36, 0.27
#: pull-in rate as a share of the pull-out rate: a stalled rotor restarts only this much slower
PULL_IN_SHARE = 0.8


def step_rate(duty: int) -> float:
    """The paper's law (12): microsteps per second at a PWM duty (0: hold)."""
    return 0.0 if duty <= 0 else 1e6 / (80.0 * (1 + 100 - duty))


def gravity_nm(q: list[float]) -> tuple[float, float]:
    """Gravity torque (N·m) about joints 2 and 3 at joint angles ``q`` (rad, zero = upright; a
    positive torque pulls towards positive angles)."""
    s2, s23 = math.sin(q[1]), math.sin(q[1] + q[2])
    t3 = M3 * G * 0.5 * A3 * s23
    t2 = M2 * G * 0.5 * A2 * s2 + M3 * G * (A2 * s2 + 0.5 * A3 * s23)
    return t2, t3


class Arm:
    def __init__(self, stall: bool, pullout_free: float, stall_nm: float) -> None:
        self.stall = stall
        self.pullout_free = pullout_free
        self.stall_nm = stall_nm
        self.pos = [0.0] * 4            # rad, protocol convention, signed
        self.target = [0.0] * 4
        self.duty = [0] * 4
        self.stalled = [False] * 4
        self.t = time.monotonic()

    def pullout(self, j: int, direction: float) -> float:
        """Pull-out rate (microsteps/s) of joint ``j`` moving in ``direction`` now."""
        if j not in (1, 2):
            return self.pullout_free
        torque = gravity_nm(self.pos)[j - 1]
        lifted = max(0.0, -torque * direction)  # gravity pulls against the motion: lifting
        return self.pullout_free * max(0.0, 1.0 - lifted / self.stall_nm)

    def advance(self) -> None:
        now = time.monotonic()
        dt, self.t = now - self.t, now
        for j in range(4):
            rate = step_rate(self.duty[j])
            err = self.target[j] - self.pos[j]
            if rate <= 0 or err == 0.0:
                self.stalled[j] = False
                continue
            if self.stall:
                limit = self.pullout(j, math.copysign(1.0, err))
                if self.stalled[j] and rate < PULL_IN_SHARE * limit:
                    self.stalled[j] = False
                elif rate > limit:
                    self.stalled[j] = True
                if self.stalled[j]:
                    continue
            step = rate * dt * 2 * math.pi / (MICROSTEPS_PER_REV * GEARS[j])
            self.pos[j] = self.target[j] if abs(err) <= step else self.pos[j] + math.copysign(
                step, err)

    def command(self, m: re.Match[bytes]) -> None:
        g = [int(x) for x in m.groups()]
        pos, duty = g[0::2], g[1::2]
        if any(p > TWO_PI_U for p in pos):
            return
        self.advance()
        # wire angles are in [0, 2π): the arm's joints turn less than half a turn either way
        self.target = [(p / 10000.0 + math.pi) % (2 * math.pi) - math.pi for p in pos]
        self.duty = duty

    def reply(self) -> bytes:
        units = [math.floor((p % (2 * math.pi)) * 10000 + 0.5) for p in self.pos]
        return ("$" + ",".join(f"{u:05d}" for u in units) + "#").encode()


async def serve_stream(reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                       args: argparse.Namespace) -> None:
    arm = Arm(args.stall, args.pullout_free, args.stall_nm)
    buf = bytearray()

    async def rx() -> None:
        while True:
            data = await reader.read(256)
            if not data:
                return
            buf.extend(data)
            while (m := CMD.search(buf)) is not None:
                arm.command(m)
                del buf[:m.end()]
            if len(buf) > 512:
                del buf[:-64]

    rx_task = asyncio.create_task(rx())
    try:
        while not rx_task.done():
            arm.advance()
            writer.write(arm.reply())
            await writer.drain()
            await asyncio.sleep(1.0 / args.rate)
    except (ConnectionError, OSError):
        pass
    finally:
        rx_task.cancel()
        writer.close()


async def serve_pty(link: str, args: argparse.Namespace) -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    name = os.ttyname(slave)
    if os.path.lexists(link):
        if not (os.path.islink(link) and os.readlink(link).startswith("/dev/pts/")):
            sys.exit(f"stall_arm: {link} exists and is not an earlier pty link; not touching it")
        os.unlink(link)
    os.symlink(name, link)
    print(f"stall arm on {name} -> {link}", flush=True)
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader),
                                 os.fdopen(master, "rb", 0))
    wt, wp = await loop.connect_write_pipe(asyncio.streams.FlowControlMixin,
                                           os.fdopen(os.dup(master), "wb", 0))
    await serve_stream(reader, asyncio.StreamWriter(wt, wp, reader, loop), args)


async def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tcp", help="HOST:PORT to listen on (loopback)")
    ap.add_argument("--pty", help="path of a symlink to a new pseudo-terminal")
    ap.add_argument("--rate", type=float, default=200.0, help="replies per second")
    ap.add_argument("--stall", action=argparse.BooleanOptionalAction, default=True,
                    help="the hidden loss of synchronism (--no-stall: the plain arm)")
    ap.add_argument("--pullout-free", type=float, default=7000.0,
                    help="pull-out rate without load (microsteps/s)")
    ap.add_argument("--stall-nm", type=float, default=14.0,
                    help="lifted gravity torque (N·m) at which the pull-out rate reaches 0")
    args = ap.parse_args()
    if args.tcp:
        host, port = args.tcp.rsplit(":", 1)
        if host not in ("127.0.0.1", "localhost", "::1"):
            sys.exit(f"stall_arm: {host} is not a loopback address")
        server = await asyncio.start_server(lambda r, w: serve_stream(r, w, args), host,
                                            int(port))
        print(f"stall arm on {args.tcp}", flush=True)
        async with server:
            await server.serve_forever()
    elif args.pty:
        await serve_pty(args.pty, args)
    else:
        sys.exit("stall_arm: give --tcp HOST:PORT or --pty PATH")


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(main())
