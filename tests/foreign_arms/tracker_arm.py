"""A foreign arm with play and kinematic errors, and a tracker beside it: a simulator of the seed
paper's arm written apart from armbench (its own protocol code, its own joint and link model,
stdlib only), answering in real time on TCP or a pseudo-terminal.

Joint model: law (12) per joint (``1e6 / (80 (101 - duty))`` microsteps per second, 1600
microsteps per motor revolution, gear ratios 50/50/38/28); the encoder sits on the motor shaft,
so the reported angle is the motor's, in joint units; every joint starts at 0.

Hidden behaviour (all 0 is the plain arm): what the encoders cannot see.

* ``--play-deg`` (per joint, full width): the link follows the motor through a play operator, it
  lags the motor by half the play on the side it was last driven from;
* ``--offset-deg`` (per joint): the link's true zero is off its nominal one;
* ``--a2-error-mm``, ``--a3-error-mm``: the links are longer or shorter than the nominal 0.36 and
  0.27 m (standard DH of the paper's Table 1, protocol zero = upright).

The reported stream is the same with and without them: only a reference instrument sees them.
``--tracker HOST:PORT`` serves one: every client of that port receives, at ``--tracker-rate``
lines a second, ``T t_s x_m y_m z_m q1 q2 q3 q4`` (``t_s`` on the host's CLOCK_MONOTONIC, the
clock asyncio's loop reads; the true TCP position in the base frame; the true link angles in
the protocol convention, rad, offsets included) of the arm of the newest serial connection.

  python3 tracker_arm.py --tcp 127.0.0.1:5555 --tracker 127.0.0.1:5556 [--play-deg 0.5,0.5,0.5,0.5]
      [--offset-deg 0.3,-0.4,0.4,0] [--a2-error-mm 4] [--a3-error-mm -4]
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
D1, D2, A2, A3, D4 = 0.39, 0.009, 0.36, 0.27, 0.0
ALPHA = (math.pi / 2, 0.0, math.pi / 2, 0.0)
DH_OFFSET = (0.0, math.pi / 2, 0.0, 0.0)


def step_rate(duty: int) -> float:
    """The paper's law (12): microsteps per second at a PWM duty (0: hold)."""
    return 0.0 if duty <= 0 else 1e6 / (80.0 * (1 + 100 - duty))


def tcp_m(q: list[float], a2: float, a3: float) -> tuple[float, float, float]:
    """The TCP position (m) of protocol angles ``q`` through standard DH."""
    table = ((0.0, D1), (a2, D2), (a3, 0.0), (0.0, D4))
    m = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    for k in range(4):
        th = q[k] + DH_OFFSET[k]
        a, d = table[k]
        ct, st, ca, sa = math.cos(th), math.sin(th), math.cos(ALPHA[k]), math.sin(ALPHA[k])
        link = [[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]]
        m = [[sum(m[r][i] * link[i][c] for i in range(4)) for c in range(4)] for r in range(4)]
    return m[0][3], m[1][3], m[2][3]


class Arm:
    def __init__(self, args: argparse.Namespace) -> None:
        self.half_play = [math.radians(v) / 2 for v in args.play_deg]
        self.offset = [math.radians(v) for v in args.offset_deg]
        self.a2 = A2 + args.a2_error_mm * 1e-3
        self.a3 = A3 + args.a3_error_mm * 1e-3
        self.motor = [0.0] * 4          # rad of joint, protocol convention, signed
        self.link = [0.0] * 4
        self.target = [0.0] * 4
        self.duty = [0] * 4
        self.t = time.monotonic()

    def advance(self) -> None:
        now = time.monotonic()
        dt, self.t = now - self.t, now
        for j in range(4):
            rate = step_rate(self.duty[j])
            err = self.target[j] - self.motor[j]
            if rate > 0 and err != 0.0:
                step = rate * dt * 2 * math.pi / (MICROSTEPS_PER_REV * GEARS[j])
                self.motor[j] = self.target[j] if abs(err) <= step else (
                    self.motor[j] + math.copysign(step, err))
            # the play operator: the link moves only when the motor pushes it from a flank
            lag = self.motor[j] - self.link[j]
            if lag > self.half_play[j]:
                self.link[j] = self.motor[j] - self.half_play[j]
            elif lag < -self.half_play[j]:
                self.link[j] = self.motor[j] + self.half_play[j]

    def truth(self) -> str:
        self.advance()
        q = [self.link[j] + self.offset[j] for j in range(4)]
        x, y, z = tcp_m(q, self.a2, self.a3)
        return (f"T {time.monotonic():.6f} {x:.7f} {y:.7f} {z:.7f} "
                + " ".join(f"{v:.7f}" for v in q) + "\n")

    def command(self, m: re.Match[bytes]) -> None:
        g = [int(x) for x in m.groups()]
        pos, duty = g[0::2], g[1::2]
        if any(p > TWO_PI_U for p in pos):
            return
        self.advance()
        self.target = [(p / 10000.0 + math.pi) % (2 * math.pi) - math.pi for p in pos]
        self.duty = duty

    def reply(self) -> bytes:
        units = [math.floor((p % (2 * math.pi)) * 10000 + 0.5) for p in self.motor]
        return ("$" + ",".join(f"{u:05d}" for u in units) + "#").encode()


class Bench:
    """The arm of the newest serial connection, which the tracker watches."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.arm = Arm(args)

    async def serve_stream(self, reader: asyncio.StreamReader,
                           writer: asyncio.StreamWriter) -> None:
        arm = self.arm = Arm(self.args)
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
                await asyncio.sleep(1.0 / self.args.rate)
        except (ConnectionError, OSError):
            pass
        finally:
            rx_task.cancel()
            writer.close()

    async def serve_tracker(self, reader: asyncio.StreamReader,
                            writer: asyncio.StreamWriter) -> None:
        try:
            while True:
                writer.write(self.arm.truth().encode())
                await writer.drain()
                await asyncio.sleep(1.0 / self.args.tracker_rate)
        except (ConnectionError, OSError):
            pass
        finally:
            writer.close()


def _loopback(address: str) -> tuple[str, int]:
    host, port = address.rsplit(":", 1)
    if host not in ("127.0.0.1", "localhost", "::1"):
        sys.exit(f"tracker_arm: {host} is not a loopback address")
    return host, int(port)


def _four(text: str) -> list[float]:
    values = [float(v) for v in text.split(",")]
    if len(values) != 4:
        raise argparse.ArgumentTypeError(f"{text!r}: give four comma-separated numbers")
    return values


async def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tcp", help="HOST:PORT of the serial link (loopback)")
    ap.add_argument("--pty", help="path of a symlink to a new pseudo-terminal")
    ap.add_argument("--tracker", help="HOST:PORT of the tracker's line stream (loopback)")
    ap.add_argument("--rate", type=float, default=200.0, help="replies per second")
    ap.add_argument("--tracker-rate", type=float, default=100.0, help="tracker lines a second")
    ap.add_argument("--play-deg", type=_four, default=[0.0] * 4, help="play per joint (deg)")
    ap.add_argument("--offset-deg", type=_four, default=[0.0] * 4,
                    help="true minus nominal zero per joint (deg)")
    ap.add_argument("--a2-error-mm", type=float, default=0.0, help="true minus nominal a2")
    ap.add_argument("--a3-error-mm", type=float, default=0.0, help="true minus nominal a3")
    args = ap.parse_args()
    bench = Bench(args)
    servers = []
    if args.tracker:
        host, port = _loopback(args.tracker)
        servers.append(await asyncio.start_server(bench.serve_tracker, host, port))
    if args.tcp:
        host, port = _loopback(args.tcp)
        servers.append(await asyncio.start_server(bench.serve_stream, host, port))
        print(f"tracker arm on {args.tcp}", flush=True)
        await asyncio.gather(*(s.serve_forever() for s in servers))
    elif args.pty:
        master, slave = os.openpty()
        tty.setraw(slave)
        name = os.ttyname(slave)
        if os.path.lexists(args.pty):
            if not (os.path.islink(args.pty) and os.readlink(args.pty).startswith("/dev/pts/")):
                sys.exit(f"tracker_arm: {args.pty} exists and is not an earlier pty link")
            os.unlink(args.pty)
        os.symlink(name, args.pty)
        print(f"tracker arm on {name} -> {args.pty}", flush=True)
        loop = asyncio.get_running_loop()
        reader = asyncio.StreamReader()
        await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader),
                                     os.fdopen(master, "rb", 0))
        wt, wp = await loop.connect_write_pipe(asyncio.streams.FlowControlMixin,
                                               os.fdopen(os.dup(master), "wb", 0))
        await bench.serve_stream(reader, asyncio.StreamWriter(wt, wp, reader, loop))
    else:
        sys.exit("tracker_arm: give --tcp HOST:PORT or --pty PATH")


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(main())
