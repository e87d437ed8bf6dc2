"""Worker processes for trials measured in parallel (``armbench.bench.runner.parallel``).

A worker measures one job at a time on a fresh virtual-time loop (:func:`run_job`); what a job
is (one attempt of one trial) is the runner's business: a worker only needs something with an
async ``measure()``, so it imports nothing of the runner. :func:`worker_init` makes a worker a
good child: Ctrl-C is the parent's, and it dies with its parent.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
import threading
import time
from collections.abc import Coroutine
from typing import Any, Protocol, TypeVar

__all__ = ["Job", "run_job", "worker_init"]

_PR_SET_PDEATHSIG = 1  # linux/prctl.h

T_co = TypeVar("T_co", covariant=True)


class Job(Protocol[T_co]):
    """A piece of work sent to a worker (pickled): measured by awaiting ``measure()``."""

    def measure(self) -> Coroutine[Any, Any, T_co]:
        """The coroutine that does the work on the worker's loop."""


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


def run_job(job: Job[T_co]) -> T_co:
    """Measure one job on a fresh virtual-time loop (runs in a worker process)."""
    from armbench.fakes.clock.vclock import run_virtual

    return run_virtual(job.measure())
