"""The operator of ``armbench calibrate --touch-off`` at a terminal: for each point of the plate it
says where the point is and reads the jogs, one per line, until the tool is on it
(``bench/calibrate/touch_off.py``).

    x +0.5     move the tool 0.5 mm along the base's x (y, z alike)
    j2 -0.1    move joint 2 by -0.1 degree
    ok         the tool is on the point: record the joints
    skip       leave this point out
"""

from __future__ import annotations

import asyncio
import math
import sys
from collections.abc import Callable
from typing import Final, TextIO

from armbench.bench.calibrate.reference import PlatePoint
from armbench.bench.calibrate.touch_off import LIFT_M, Jog

__all__ = ["HELP", "TerminalOperator", "parse_jog"]

HELP: Final = ("jog the tool onto the point: 'x|y|z ±MM' moves the tool (base frame), "
               "'jN ±DEG' joint N; 'ok' when it is on the point, 'skip' to leave it out")
#: The largest jog a line may ask for (mm, degrees): a typing slip must not throw the arm.
MAX_JOG: Final = 20.0


def parse_jog(line: str) -> tuple[str, int, float] | str:
    """A line as ``("tool", axis, metres)``, ``("joint", index, radians)``, ``"ok"``,
    ``"skip"``, or the reason it is none of them (a string starting with ``?``)."""
    words = line.split()
    if words in (["ok"], ["skip"]):
        return words[0]
    if len(words) != 2:
        return f"? {line.strip()!r}: {HELP}"
    what, amount = words
    try:
        value = float(amount)
    except ValueError:
        return f"? {amount!r} is not a number"
    if not math.isfinite(value) or abs(value) > MAX_JOG:
        return f"? {amount!r}: a jog is a finite number within ±{MAX_JOG:g}"
    if what in ("x", "y", "z"):
        return "tool", "xyz".index(what), value * 1e-3
    if what in ("j1", "j2", "j3", "j4"):
        return "joint", int(what[1]) - 1, math.radians(value)
    return f"? {what!r}: {HELP}"


class TerminalOperator:
    """Reads the jogs from ``stdin`` (a line at a time, in a worker thread: the loop goes on)
    and says what it does on ``out``."""

    def __init__(self, stdin: TextIO | None = None, out: TextIO | None = None) -> None:
        self._in = stdin or sys.stdin
        self._out = out or sys.stderr

    def _say(self, text: str) -> None:
        print(text, file=self._out, flush=True)

    async def touch(self, point: PlatePoint, jog: Jog) -> bool:
        """Read jogs for ``point`` until ``ok`` (True) or ``skip`` or the end of the input
        (False)."""
        where = ", ".join(f"{v * 1e3:.2f}" for v in point.xyz_m)
        self._say(f"point {point.name} ({where}) mm: the tool is {LIFT_M * 1e3:g} mm above it; "
                  f"{HELP}")
        read: Callable[[], str] = self._in.readline
        while True:
            line = await asyncio.get_running_loop().run_in_executor(None, read)
            if not line:
                return False
            parsed = parse_jog(line)
            if parsed in ("ok", "skip"):
                return parsed == "ok"
            if isinstance(parsed, str):
                self._say(parsed)
                continue
            kind, index, amount = parsed
            delta = [0.0] * (3 if kind == "tool" else 4)
            delta[index] = amount
            await (jog.tool(delta) if kind == "tool" else jog.joints(delta))
            self._say("joints now " + ", ".join(f"{math.degrees(q):.3f}" for q in jog.q_rad)
                      + " deg")
