"""Trials on ``fake://`` measured in worker processes, several at once.

With ``isolation = "trial"`` each trial on the emulator is self-contained: a freshly built and
powered emulator seeded from (seed, suite, index, attempt), its own connection and capture part.
Nothing of it depends on the absolute loop time (the emulator's clock is put on a nanosecond
grid from its power-up, ``fakes/boards.py``), so a trial measured on a fresh virtual-time loop in
another process gives the same figures as one measured in turn on the run's loop. The runner
hands such trials to ``[bench] workers`` processes (default: one per CPU, at most two) and
commits them in order: ``started_s`` on the run clock, ``results.json``, and the capture part
merged with its times moved onto the run clock (:func:`armbench.drivers.capture.merge_capture`).

A worker runs :func:`run_job`: the same ``_Run._attempt`` the sequential path runs, on a
``VirtualTimeLoop`` starting at 0, with a stand-in for the record writer (the worker never writes
``results.json``) and the trial's progress messages collected for the parent to print.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Any, cast

from armbench.bench.record import Trial, path_inside

if TYPE_CHECKING:
    from armbench.bench.runner import BenchPlan, PlannedSuite

__all__ = ["JobResult", "TrialJob", "job_part_tag", "run_job", "worker_init"]

_PR_SET_PDEATHSIG = 1  # linux/prctl.h


@dataclass(frozen=True, slots=True)
class TrialJob:
    """One attempt of one trial, sent to a worker (pickled)."""

    plan: BenchPlan
    """The run's plan, without what a worker does not need (records, power, tracker)."""
    suite: PlannedSuite
    index: int
    attempt: int


@dataclass(frozen=True, slots=True)
class JobResult:
    """What a worker sends back: the trial on the worker's clock (``started_s`` from its loop's
    0), its capture parts (times on the same clock) and its progress messages."""

    trial: Trial
    parts: tuple[Path, ...]
    messages: tuple[str, ...]


def job_part_tag(suite: str, index: int, attempt: int) -> str:
    """The name tag of a worker's capture parts: ``.capture.part-job-<suite>-<index>-<attempt>``."""
    return f"-job-{suite}-{index}-{attempt}"


class _JobClock:
    """What ``_Run`` needs of a record writer inside a worker: the run directory for artifacts
    and a clock (the worker's loop time: the parent moves the trial onto the run clock)."""

    def __init__(self, out_dir: Path) -> None:
        self.out_dir = out_dir

    def artifact_path(self, name: str | PurePath) -> Path:
        return path_inside(self.out_dir, name)

    @staticmethod
    def elapsed_s() -> float:
        return asyncio.get_running_loop().time()


class _Messages:
    """Collects the progress lines a trial prints."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def message(self, text: str) -> None:
        self.lines.append(text)


def worker_init(parent: int) -> None:
    """Worker initializer. Ctrl-C is the parent's to handle (it stops submitting and keeps the
    record): a worker finishes the trial at hand. A worker whose parent dies (``kill -9``) exits
    at once instead of living on as an orphan holding the parent's output pipes: the kernel's
    parent-death signal on Linux, and a watch on ``parent`` (the run's pid) everywhere."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:  # died before the signal was armed
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(1.0)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def run_job(job: TrialJob) -> JobResult:
    """Measure one trial attempt on a fresh virtual-time loop (runs in a worker process)."""
    from armbench.fakes.vclock import run_virtual

    return run_virtual(_run_job(job))


async def _run_job(job: TrialJob) -> JobResult:
    from armbench.bench.runner import _default_emulator, _Run

    messages = _Messages()
    run = _Run(job.plan, cast(Any, _JobClock(job.plan.out_dir)), cast(Any, messages),
               _default_emulator, part_tag=job_part_tag(job.suite.name, job.index, job.attempt))
    trial = await run._attempt(job.suite, job.index, job.attempt)
    return JobResult(trial, tuple(run.unmerged), tuple(messages.lines))
