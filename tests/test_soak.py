"""Soak (issue 7): an hour of simulated motion over ``fake://`` on virtual time — Cartesian paths
streamed with ``follow_path`` and coordinated joint moves to seeded random targets, every frame
captured to a file — with the memory sampled every simulated minute: Python's allocated blocks
(``sys.getallocatedblocks``) and ``resource.getrusage`` max RSS.

Asserted: after a warm-up, neither grows beyond a fixed bound (≤ warm-up + 50 000 blocks, max
RSS ≤ warm-up + 30 MB) while the capture on disk grows by ~2.3 MB per simulated minute (~140 MB
an hour): the frames go to the file, not to memory. No frame is dropped, no move re-sent.

``test_soak_short`` runs the same loop for two simulated minutes with ``tracemalloc`` tracing from
the end of the warm-up (the bytes allocated since then and still held, ≤ 5 MB; tracing makes the
loop ~6× slower, too dear for the hour, and the warm-up needs none). The hour is marked
``slow`` (``pytest -m "not slow"`` leaves it out) but is part of the default run. Both print the
memory at the start, after the warm-up and at the end, the CPU and wall time, and the capture's
size (``-s``); figures in measurements/reliability.md.
"""

from __future__ import annotations

import asyncio
import contextlib
import random
import resource
import signal
import sys
import time
import tracemalloc
from collections.abc import Awaitable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import pytest

from armbench.drivers.host.arm import Arm
from armbench.drivers.host.motion import square
from armbench.fakes.clock.vclock import run_virtual

T = TypeVar("T")
MB = 1024 * 1024
TRACEMALLOC_GROWTH_MAX = 5 * MB
"""Allowed growth of tracemalloc's current size after the warm-up (bytes)."""
BLOCKS_GROWTH_MAX = 50_000
"""Allowed growth of ``sys.getallocatedblocks()`` after the warm-up: a leak of one object per
reply would add ~1.5 million in the hour."""
MAX_RSS_GROWTH_MAX_KB = 30 * 1024
"""Allowed growth of the max RSS after the warm-up (KiB, as ``ru_maxrss`` on Linux)."""
CENTRE_M = (0.38, 0.0, 0.80)
"""The accuracy suite's square centre: reachable on the front-up branch."""


@dataclass(frozen=True)
class Sample:
    t_s: float
    """Simulated seconds since the soak started."""
    traced: int
    """tracemalloc's current size (bytes)."""
    max_rss_kb: int
    capture_bytes: int
    frames: int


@dataclass(frozen=True)
class SoakReport:
    samples: list[Sample]
    cpu_s: float
    wall_s: float
    frames_received: int
    frames_dropped: int
    commands_sent: int
    resends: int
    moves: int
    capture_lines: int


class Livelock(Exception):
    pass


@contextlib.contextmanager
def cpu_guard(cpu_s: float) -> Iterator[None]:
    """A loop that never yields freezes the virtual clock (no asyncio.timeout fires): stop it
    after ``cpu_s`` seconds of CPU instead of hanging."""

    def on_prof(signum: int, frame: object) -> None:
        raise Livelock(f"more than {cpu_s:g} s of CPU")

    old = signal.signal(signal.SIGPROF, on_prof)
    signal.setitimer(signal.ITIMER_PROF, cpu_s)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0)
        signal.signal(signal.SIGPROF, old)


async def within(aw: Awaitable[T], timeout_s: float) -> T:
    async with asyncio.timeout(timeout_s):
        return await aw


def soak(duration_s: float, sample_s: float, capture: Path, seed: int = 9, *,
         traced: bool = True, trace_from_s: float = 0.0) -> SoakReport:
    """Move for ``duration_s`` simulated seconds, sampling memory every ``sample_s``: Python's
    allocations by ``tracemalloc`` (bytes) when ``traced``, traced from the first sample at or
    after ``trace_from_s`` (earlier samples read 0), else ``sys.getallocatedblocks()`` (blocks;
    no tracing cost)."""
    samples: list[Sample] = []
    def python_memory() -> int:
        return tracemalloc.get_traced_memory()[0] if traced else sys.getallocatedblocks()

    async def main() -> SoakReport:
        loop = asyncio.get_running_loop()
        rng = random.Random(seed)
        async with Arm.connect("fake://", capture=capture) as arm:
            t0 = loop.time()

            def sample() -> None:
                if traced and not tracemalloc.is_tracing() and loop.time() - t0 >= trace_from_s:
                    tracemalloc.start()
                samples.append(Sample(
                    loop.time() - t0, python_memory(),
                    resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
                    capture.stat().st_size if capture.exists() else 0, arm.frames_received))

            async def sampler() -> None:
                while True:
                    sample()
                    await asyncio.sleep(t0 + len(samples) * sample_s - loop.time())

            sampling = asyncio.create_task(sampler())
            moves = 0
            try:
                while loop.time() - t0 < duration_s:
                    if moves % 2 == 0:  # a 10 cm square in the YZ plane at 0.1 m/s (~5 s)
                        run = await within(arm.follow_path(square(CENTRE_M, 0.10, "yz"),
                                                           speed_m_s=0.1), 120.0)
                        assert run.states
                    else:  # a coordinated joint move to a random pose (~1 s)
                        q = (rng.uniform(-0.6, 0.6), rng.uniform(0.1, 0.6),  # inside limits
                             rng.uniform(0.3, 0.95), rng.uniform(-0.4, 0.6))
                        await within(arm.move_joints(q, 99, coordinated=True), 60.0)
                    moves += 1
            finally:
                sampling.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await sampling
            sample()
            counters = (arm.frames_received, arm.frames_dropped, arm.commands_sent,
                        arm.resends)
        with capture.open("rb") as fh:
            lines = sum(1 for _ in fh)
        return SoakReport(samples, 0.0, 0.0, *counters, moves=moves, capture_lines=lines)

    cpu0, wall0 = time.process_time(), time.perf_counter()
    try:
        report = run_virtual(main())
    finally:
        if traced:
            tracemalloc.stop()
    return SoakReport(**{**report.__dict__, "cpu_s": time.process_time() - cpu0,
                         "wall_s": time.perf_counter() - wall0})


def check(report: SoakReport, warmup_s: float, duration_s: float, sample_s: float, *,
          traced: bool = True) -> str:
    """The assertions of both soaks; returns the summary printed with ``-s``. Python memory is
    tracemalloc's bytes (``traced``) or allocated blocks."""
    samples = report.samples
    assert samples[-1].t_s >= duration_s
    assert len(samples) >= duration_s / sample_s
    warm = next(s for s in samples if s.t_s >= warmup_s)
    after = [s for s in samples if s.t_s >= warm.t_s]
    end = samples[-1]
    worst = max(s.traced for s in after)
    bound = TRACEMALLOC_GROWTH_MAX if traced else BLOCKS_GROWTH_MAX
    assert worst <= warm.traced + bound, (warm.traced, worst)
    assert end.max_rss_kb <= warm.max_rss_kb + MAX_RSS_GROWTH_MAX_KB, (warm.max_rss_kb,
                                                                       end.max_rss_kb)
    # Frames go to disk: the capture grows with the frames while Python memory does not.
    frames = end.frames - warm.frames
    assert frames >= 300 * (end.t_s - warm.t_s)  # ~420 replies per simulated second
    assert end.capture_bytes - warm.capture_bytes >= 40 * frames  # a JSON line per frame
    assert report.capture_lines >= report.frames_received + report.commands_sent
    assert report.frames_dropped == 0 and report.resends == 0
    first = samples[0]
    scale, unit = (MB, "MB traced") if traced else (1000, "k blocks")
    lines = [f"soak of {end.t_s / 60:.1f} simulated min: {report.moves} moves, "
             f"{report.frames_received} frames in, {report.commands_sent} commands out",
             f"  CPU {report.cpu_s:.1f} s, wall {report.wall_s:.1f} s "
             f"({end.t_s / report.cpu_s:.1f} simulated s per CPU s, "
             f"{'tracemalloc on' if traced else 'no tracing'})",
             f"  t_sim      {unit:>10}   max RSS MB   capture MB"]
    lines += [f"  {s.t_s:7.0f} s  {s.traced / scale:10.2f}   {s.max_rss_kb / 1024:10.1f}   "
              f"{s.capture_bytes / MB:10.1f}" for s in samples]
    lines.append(f"  start {first.traced / scale:.2f} {unit} / {first.max_rss_kb / 1024:.1f} MB "
                 f"max RSS; after warm-up ({warm.t_s:.0f} s) {warm.traced / scale:.2f} / "
                 f"{warm.max_rss_kb / 1024:.1f}; end {end.traced / scale:.2f} / "
                 f"{end.max_rss_kb / 1024:.1f}; worst after warm-up {worst / scale:.2f} {unit}")
    return "\n".join(lines)


@pytest.mark.slow
def test_soak_hour(tmp_path: Path) -> None:
    """An hour of simulated motion, memory sampled every simulated minute (allocated blocks and
    max RSS: tracing would make the hour ~6x dearer), warm-up 5 minutes."""
    with cpu_guard(3600.0):
        report = soak(3600.0, 60.0, tmp_path / "soak.jsonl", traced=False)
    print("\n" + check(report, warmup_s=300.0, duration_s=3600.0, sample_s=60.0, traced=False))


def test_soak_short(tmp_path: Path) -> None:
    """The same loop for two simulated minutes, sampled every 10 s, warm-up 30 s (traced from
    its end)."""
    with cpu_guard(300.0):
        report = soak(120.0, 10.0, tmp_path / "soak.jsonl", trace_from_s=30.0)
    print("\n" + check(report, warmup_s=30.0, duration_s=120.0, sample_s=10.0))
