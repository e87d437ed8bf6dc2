"""A foreign arm whose drives lose steps above a duty threshold: a simulator of the seed paper's arm
written apart from armbench (its own protocol code, its own joint model, stdlib only), answering
in real time on TCP.

Joint model: law (12) per joint (``1e6 / (80 (101 - duty))`` microsteps per second, 1600
microsteps per motor revolution, gear ratios 50/50/38/28), the reported angle is the joint angle
(an encoder on the joint, no Hall, no EEPROM); every joint starts at 0 (the zero pose).

Hidden behaviour (``--loss 0,0,0,0`` is the plain arm):

* ``--loss`` (per joint, default ``0,0.25,0.15,0``) and ``--from-duty`` (default 97): at a duty of
  ``--from-duty`` or more a joint loses that share of its pulses, whichever way it moves and
  whatever its load (a supply that sags when its drives run flat out); below it none;
* ``--drift-per-min`` (default 0): the shares grow by that fraction of themselves per minute
  since the connection (the drives warm up: their winding resistance rises, their torque at
  speed falls), so the arm at the end of a session is not the arm at its start.

  python3 threshold_arm.py --tcp 127.0.0.1:5555 [--loss 0,0.25,0.15,0] [--from-duty 97]
      [--drift-per-min 0.5]

Its serving code follows the other arms of this folder on purpose: each is a program of its own,
stdlib only, that shares nothing with armbench or with the others.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import re
import sys
import time

TWO_PI_U = 62832
CMD = re.compile(rb"\$(\d{5}),(\d{2}),(\d{5}),(\d{2}),(\d{5}),(\d{2}),(\d{5}),(\d{2})#")
GEARS = (50.0, 50.0, 38.0, 28.0)
MICROSTEPS_PER_REV = 1600.0


def step_rate(duty: int) -> float:
    """The paper's law (12): microsteps per second at a PWM duty (0: hold)."""
    return 0.0 if duty <= 0 else 1e6 / (80.0 * (1 + 100 - duty))


class Arm:
    def __init__(self, args: argparse.Namespace) -> None:
        self.loss: list[float] = list(args.loss)
        self.from_duty = int(args.from_duty)
        self.drift_per_s = float(args.drift_per_min) / 60.0
        self.pos = [0.0] * 4            # rad, protocol convention, signed
        self.target = [0.0] * 4
        self.duty = [0] * 4
        self.t0 = self.t = time.monotonic()

    def share(self, j: int, duty: int) -> float:
        """The share of joint ``j``'s pulses lost at ``duty`` now."""
        if duty < self.from_duty:
            return 0.0
        grown = self.loss[j] * (1.0 + self.drift_per_s * (self.t - self.t0))
        return min(0.95, grown)

    def advance(self) -> None:
        now = time.monotonic()
        dt, self.t = now - self.t, now
        for j in range(4):
            rate = step_rate(self.duty[j]) * (1.0 - self.share(j, self.duty[j]))
            err = self.target[j] - self.pos[j]
            if rate <= 0 or err == 0.0:
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
    arm = Arm(args)
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


def _four(text: str) -> list[float]:
    values = [float(v) for v in text.split(",")]
    if len(values) != 4 or not all(0.0 <= v < 1.0 for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: give four shares in [0, 1), comma-separated")
    return values


async def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tcp", required=True, help="HOST:PORT to listen on (loopback)")
    ap.add_argument("--rate", type=float, default=200.0, help="replies per second")
    ap.add_argument("--loss", type=_four, default=[0.0, 0.25, 0.15, 0.0],
                    help="share of pulses lost per joint at or above --from-duty")
    ap.add_argument("--from-duty", type=int, default=97, help="lowest duty that loses steps")
    ap.add_argument("--drift-per-min", type=float, default=0.0,
                    help="growth of the shares, as a fraction of themselves per minute")
    args = ap.parse_args()
    host, port = args.tcp.rsplit(":", 1)
    if host not in ("127.0.0.1", "localhost", "::1"):
        sys.exit(f"threshold_arm: {host} is not a loopback address")
    server = await asyncio.start_server(lambda r, w: serve_stream(r, w, args), host, int(port))
    print(f"threshold arm on {args.tcp}", flush=True)
    async with server:
        await server.serve_forever()


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(main())
