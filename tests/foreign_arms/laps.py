"""Real-time captures of a foreign arm for twin-check: armbench's driver moves the arm over a
socket (long single-joint moves at several duties, then the accuracy suite's square, corners and
a streamed path) while the capture (JSON Lines) records every frame; the tracker's truth, where
the arm has one, is kept on the capture's clock."""

from __future__ import annotations

import asyncio
import contextlib
import json
from pathlib import Path

from armbench.drivers.capture.jsonl import CaptureWriter
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.errors import MoveTimeoutError
from armbench.drivers.model.settings import RobotSettings
from armbench.metrics import square_yz
from foreign_arms.tracker_client import TrackerStream

#: Longest silence of the arm tolerated (s).
REPLY_TIMEOUT_S = 10.0
CORNERS = square_yz((0.38, 0.0, 0.80), 0.15)
#: Single-joint moves (target, duty) of the short lap, from the zero pose and back.
JOINT_MOVES = [((0.5, 0.0, 0.0, 0.0), 99), ((0.0, 0.0, 0.0, 0.0), 95),
               ((0.0, 0.0, 0.8, 0.0), 99), ((0.0, 0.0, -0.4, 0.0), 97),
               ((0.0, 0.3, 0.0, 0.6), 99), ((0.0, 0.0, 0.0, 0.0), 99)]


async def _moves(arm: Arm, full: bool) -> None:
    for q, duty in JOINT_MOVES:
        # a stalling arm may not get there: the capture holds what it did
        with contextlib.suppress(MoveTimeoutError):
            await arm.move_joints(q, duty, timeout_s=8.0)
        await asyncio.sleep(0.15)
    if not full:
        return
    with contextlib.suppress(MoveTimeoutError):
        await arm.move_to(CORNERS[0], branch="front-up", coordinated=True, timeout_s=10.0)
    await asyncio.sleep(0.2)
    for k in (1, 2, 3, 0):
        with contextlib.suppress(MoveTimeoutError):
            await arm.move_to(CORNERS[k], branch="front-up", timeout_s=8.0)
    with contextlib.suppress(MoveTimeoutError):
        await arm.follow_path([*CORNERS, CORNERS[0]], speed_m_s=0.05, spacing_m=0.005,
                              branch="front-up")
    await asyncio.sleep(0.2)


async def capture_lap(url: str, capture: Path, *, full: bool = True,
                      tracker: tuple[str, int] | None = None) -> list[list[float]]:
    """Drive the arm at ``url`` through the lap into ``capture``; the tracker's samples
    ``[t_s, x_m, y_m, z_m, q1..q4]`` on the capture's clock (empty without a tracker)."""
    loop = asyncio.get_running_loop()
    writer = CaptureWriter(capture, loop.time())
    async with contextlib.AsyncExitStack() as stack:
        stream = None
        if tracker is not None:
            stream = await stack.enter_async_context(TrackerStream(*tracker))
        # a loaded machine may starve the arm's process for a while: not a fault of the link
        arm = await stack.enter_async_context(Arm.connect(url, RobotSettings(), capture=writer,
                                                          reply_timeout_s=REPLY_TIMEOUT_S))
        await _moves(arm, full)
    writer.close()
    if stream is None:
        return []
    return [[s[0] - writer.t0_s, *s[1:]] for s in stream.samples]


def lap_in_process(url: str, capture: Path, full: bool,
                   tracker: tuple[str, int] | None) -> list[list[float]]:
    """:func:`capture_lap` on an event loop of its own, for a process of its own: laps taken at
    once as threads of one process share its interpreter lock, and a lap's host waits for the
    others' Python work between two of its arm's replies (a loaded machine makes that tens of
    milliseconds)."""
    return asyncio.run(capture_lap(url, capture, full=full, tracker=tracker))


def write_truth(samples: list[list[float]], path: Path) -> None:
    """Keep the tracker's samples beside the capture (JSON)."""
    path.write_text(json.dumps(samples))
