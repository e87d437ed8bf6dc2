"""A foreign arm with a mis-stated gear ratio and a ragged link: a simulator of the seed paper's
arm written apart from armbench (its own protocol code, its own joint model, stdlib only),
answering in real time on TCP or a pseudo-terminal.

Joint model: law (12) per joint (``1e6 / (80 (101 - duty))`` microsteps per second, 1600
microsteps per motor revolution), the reported angle is the joint angle; every joint starts at 0.

Hidden behaviour (``--gear-j3 38 --interval-ms 5 5 --drop 0`` is the plain arm):

* ``--gear-j3``: joint 3's worm gear has another ratio than the nominal 38 (a 39.5 gear is
  3.9 % slower at every duty: a speed scale on one joint, nothing else changes);
* ``--interval-ms LO HI``: the replies come every LO..HI ms (uniform, drawn per reply, seeded by
  ``--seed``) instead of at a steady rate, as from a firmware whose loop time varies with its work;
* ``--drop``: the share of replies that are never sent (a reply lost on a busy bus).

  python3 jitter_arm.py --tcp 127.0.0.1:5555 [--gear-j3 39.5] [--interval-ms 5 20] [--drop 0.02]
  python3 jitter_arm.py --pty ./jitter-tty
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import os
import random
import re
import sys
import time
import tty

TWO_PI_U = 62832
CMD = re.compile(rb"\$(\d{5}),(\d{2}),(\d{5}),(\d{2}),(\d{5}),(\d{2}),(\d{5}),(\d{2})#")
MICROSTEPS_PER_REV = 1600.0


def step_rate(duty: int) -> float:
    """The paper's law (12): microsteps per second at a PWM duty (0: hold)."""
    return 0.0 if duty <= 0 else 1e6 / (80.0 * (1 + 100 - duty))


class Arm:
    def __init__(self, gears: tuple[float, float, float, float]) -> None:
        self.gears = gears
        self.pos = [0.0] * 4            # rad, protocol convention, signed
        self.target = [0.0] * 4
        self.duty = [0] * 4
        self.t = time.monotonic()

    def advance(self) -> None:
        now = time.monotonic()
        dt, self.t = now - self.t, now
        for j in range(4):
            rate = step_rate(self.duty[j])
            err = self.target[j] - self.pos[j]
            if rate <= 0 or err == 0.0:
                continue
            step = rate * dt * 2 * math.pi / (MICROSTEPS_PER_REV * self.gears[j])
            self.pos[j] = self.target[j] if abs(err) <= step else self.pos[j] + math.copysign(
                step, err)

    def command(self, m: re.Match[bytes]) -> None:
        g = [int(x) for x in m.groups()]
        pos, duty = g[0::2], g[1::2]
        if any(p > TWO_PI_U for p in pos):
            return
        self.advance()
        self.target = [(p / 10000.0 + math.pi) % (2 * math.pi) - math.pi for p in pos]
        self.duty = duty

    def reply(self) -> bytes:
        units = [math.floor((p % (2 * math.pi)) * 10000 + 0.5) for p in self.pos]
        return ("$" + ",".join(f"{u:05d}" for u in units) + "#").encode()


async def serve_stream(reader: asyncio.StreamReader, writer: asyncio.StreamWriter,
                       args: argparse.Namespace) -> None:
    arm = Arm((50.0, 50.0, args.gear_j3, 28.0))
    rng = random.Random(args.seed)
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
            if rng.random() >= args.drop:
                writer.write(arm.reply())
                await writer.drain()
            lo, hi = args.interval_ms
            await asyncio.sleep(1e-3 * rng.uniform(lo, hi))
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
            sys.exit(f"jitter_arm: {link} exists and is not an earlier pty link; not touching it")
        os.unlink(link)
    os.symlink(name, link)
    print(f"jitter arm on {name} -> {link}", flush=True)
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
    ap.add_argument("--gear-j3", type=float, default=39.5, help="joint 3's true gear ratio")
    ap.add_argument("--interval-ms", type=float, nargs=2, default=[5.0, 20.0],
                    metavar=("LO", "HI"), help="range of the reply interval (ms)")
    ap.add_argument("--drop", type=float, default=0.02, help="share of replies never sent")
    ap.add_argument("--seed", type=int, default=1, help="seed of the intervals and drops")
    args = ap.parse_args()
    if args.tcp:
        host, port = args.tcp.rsplit(":", 1)
        if host not in ("127.0.0.1", "localhost", "::1"):
            sys.exit(f"jitter_arm: {host} is not a loopback address")
        server = await asyncio.start_server(lambda r, w: serve_stream(r, w, args), host,
                                            int(port))
        print(f"jitter arm on {args.tcp}", flush=True)
        async with server:
            await server.serve_forever()
    elif args.pty:
        await serve_pty(args.pty, args)
    else:
        sys.exit("jitter_arm: give --tcp HOST:PORT or --pty PATH")


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(main())
