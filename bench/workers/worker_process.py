"""Worker processes for trials measured in parallel (``armbench.bench.runner.parallel``).

A worker measures one job at a time on a fresh virtual-time loop (:func:`run_job`); what a job
is (one attempt of one trial) is the runner's business: a worker only needs something with an
async ``measure()``, so it imports nothing of the runner. :func:`worker_init` makes a worker a
good child: Ctrl-C is the parent's, and it dies with its parent; it collects its garbage at
armbench's pace and runs one BLAS thread, as the program does, and imports the modules a job
will need as it starts.

A spawned worker takes about a second to start (an interpreter, numpy, the emulator) before it
can measure anything. :func:`prestart` starts the pool of a run at once, so the workers start
while the run's process is still planning; :func:`take_pool` hands it to the runner when it has
the number of workers asked for, and :func:`discard_prestarted` lets an unused one go (stopped
at once: a pool no run took holds nothing a job made). A run done with its pool parks it
(:func:`park`): the next run of the same process (a test session, a notebook, a campaign of
runs) takes it instead of starting workers again, as long as nothing the workers took from the
process at their start (the import path, the working folder, the environment) has changed; the
workers end with the process, or when :func:`discard_parked` lets them go. A worker let go
ends without its interpreter's teardown (:func:`_end_at_once`), and :func:`let_go_workers`
lets a process that is about to end wait for its workers to be gone.
"""

from __future__ import annotations

import atexit
import concurrent.futures
import contextlib
import ctypes
import importlib
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
import weakref
from collections.abc import Coroutine, Sequence
from typing import Any, Protocol, TypeVar

from armbench.bench.workers.blas_threads import one_blas_thread
from armbench.bench.workers.collector_pace import pace_collector

__all__ = ["Job", "discard_parked", "discard_prestarted", "let_go_workers", "new_pool", "park",
           "park_prestarted", "prestart", "run_job", "take_pool", "worker_init"]

_PR_SET_PDEATHSIG = 1  # linux/prctl.h

T_co = TypeVar("T_co", covariant=True)


class Job(Protocol[T_co]):
    """A piece of work sent to a worker (pickled): measured by awaiting ``measure()``."""

    def measure(self) -> Coroutine[Any, Any, T_co]:
        """The coroutine that does the work on the worker's loop."""


def worker_init(parent: int, preload: Sequence[str] = ()) -> None:
    """Worker initializer. Ctrl-C is the parent's to handle (it stops submitting and keeps the
    record): a worker finishes the trial at hand. A worker whose parent dies (``kill -9``) exits
    at once instead of living on as an orphan holding the parent's output pipes: the kernel's
    parent-death signal on Linux, and a watch on ``parent`` (the run's pid) everywhere. The
    modules ``preload`` names are imported last (what a job will need); the worker's end is
    :func:`_end_at_once`, registered first so that every at-exit handler of those modules and
    of the jobs runs before it. It collects its garbage at armbench's pace
    (:mod:`~armbench.bench.workers.collector_pace`) and runs one BLAS thread
    (:mod:`~armbench.bench.workers.blas_threads`)."""
    pace_collector()
    one_blas_thread()
    atexit.register(_end_at_once)
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
    for name in preload:
        importlib.import_module(name)


def _end_at_once() -> None:
    """A worker's last at-exit handler: its loop ended (the pool let it go), so it ends now with
    status 0 instead of tearing its interpreter down (freeing the emulator's and numpy's
    modules: a fifth of a second its parent would wait for). A loop that failed has printed
    why and ends with 0 too: the pool tells a worker's end by its process, not its status. The
    handlers registered since the worker started have run; of those registered before, only
    the standard streams and logging hold anything, flushed here."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError, AttributeError):
            stream.flush()
    os._exit(0)


def _started() -> None:
    """A job that does nothing: submitting one per worker makes the pool start them all."""


#: Variables of the environment that change from call to call within one process and that no
#: job reads: pytest's name of the test running.
_UNREAD_ENVIRONMENT = frozenset({"PYTEST_CURRENT_TEST"})

_untaken: weakref.WeakSet[concurrent.futures.ProcessPoolExecutor] = weakref.WeakSet()
"""The pools :func:`prestart` started that no run has taken (:func:`take_pool`): their workers
have measured nothing."""

_inherited_by: weakref.WeakKeyDictionary[concurrent.futures.ProcessPoolExecutor,
                                         tuple[object, ...]] = weakref.WeakKeyDictionary()
"""What each pool's workers took from this process as they were spawned (:func:`_inherited`)."""


def _inherited() -> tuple[object, ...]:
    """What a spawned worker takes from this process as it starts and a job may depend on: the
    import path, the working folder and the environment."""
    environment = tuple(sorted((k, v) for k, v in os.environ.items()
                               if k not in _UNREAD_ENVIRONMENT))
    return tuple(sys.path), os.getcwd(), environment


def new_pool(workers: int, preload: Sequence[str] = ()) -> concurrent.futures.ProcessPoolExecutor:
    """A pool of ``workers`` spawned worker processes (:func:`worker_init`), each importing
    ``preload`` as it starts; started now, not at the first job."""
    pool = concurrent.futures.ProcessPoolExecutor(
        workers, mp_context=multiprocessing.get_context("spawn"), initializer=worker_init,
        initargs=(os.getpid(), tuple(preload)))
    _inherited_by[pool] = _inherited()
    for _ in range(workers):  # a spawning pool starts a process per job submitted
        pool.submit(_started)
    return pool


_prestarted: tuple[int, tuple[str, ...], concurrent.futures.ProcessPoolExecutor] | None = None
_parked: tuple[int, concurrent.futures.ProcessPoolExecutor] | None = None


def prestart(workers: int, preload: Sequence[str] = ()) -> None:
    """Have a pool of ``workers`` ready for :func:`take_pool`: the parked one if it fits, else
    one started now (one at a time: an unused one started before is let go)."""
    global _prestarted
    discard_prestarted()
    pool = _unpark(workers)
    if pool is None:
        pool = new_pool(workers, preload)
        _untaken.add(pool)
    _prestarted = (workers, tuple(preload), pool)


def take_pool(workers: int, preload: Sequence[str] = ()) -> concurrent.futures.ProcessPoolExecutor:
    """The pool :func:`prestart` readied if it has ``workers`` workers, else the parked one if it
    fits, else a new one importing ``preload`` (and the others let go)."""
    global _prestarted
    if _prestarted is not None and _prestarted[0] == workers:
        pool = _prestarted[2]
        _prestarted = None
    else:
        discard_prestarted()
        pool = _unpark(workers) or new_pool(workers, preload)
    _untaken.discard(pool)
    return pool


def _let_go(pool: concurrent.futures.ProcessPoolExecutor, wait: bool) -> None:
    """Shut ``pool`` down (``wait``: until its workers have ended). The workers of a pool no
    run took hold nothing a job made: they are stopped at once, not waited for while they
    import what a trial needs (a refused run's process would wait a second for them)."""
    if pool in _untaken:
        for process in list((pool._processes or {}).values()):  # None once shut down
            with contextlib.suppress(OSError, ValueError):
                process.terminate()
    pool.shutdown(wait=wait, cancel_futures=True)


def discard_prestarted(*, wait: bool = False) -> None:
    """Let the pool :func:`prestart` readied go, if no run took it (``wait``: until its workers
    have ended)."""
    global _prestarted
    prestarted, _prestarted = _prestarted, None
    if prestarted is not None:
        _let_go(prestarted[2], wait)


def park(pool: concurrent.futures.ProcessPoolExecutor, workers: int) -> None:
    """Keep ``pool``, its ``workers`` all idle and alive, for the next run of this process that
    asks for as many: their start (about a CPU second each) is saved. One pool is kept; one
    parked before is let go."""
    global _parked
    discard_parked()
    _parked = (workers, pool)


def park_prestarted() -> None:
    """At a run's end: the pool :func:`prestart` readied for it, if it took none, parked."""
    global _prestarted
    if _prestarted is not None:
        workers, _, pool = _prestarted
        _prestarted = None
        park(pool, workers)


def _unpark(workers: int) -> concurrent.futures.ProcessPoolExecutor | None:
    """The parked pool if it has ``workers`` workers, none lost, and what they took from this
    process at their start is still the same; else None, the parked one let go."""
    global _parked
    parked, _parked = _parked, None
    if parked is None:
        return None
    count, pool = parked
    if count == workers and _inherited_by.get(pool) == _inherited():
        try:
            pool.submit(_started)  # refused at once by a pool that lost a worker meanwhile
        except (concurrent.futures.BrokenExecutor, RuntimeError):
            pass
        else:
            return pool
    _let_go(pool, False)
    return None


def discard_parked(*, wait: bool = False) -> None:
    """Let the parked pool's workers go (``wait``: until they have ended)."""
    global _parked
    parked, _parked = _parked, None
    if parked is not None:
        _let_go(parked[1], wait)


def let_go_workers(*, wait: bool = False) -> None:
    """Let the prestarted and the parked pool go; ``wait``: until their workers have ended (a
    process about to end without its interpreter's teardown:
    :mod:`~armbench.bench.workers.process_end`). Also run at the process's exit, while the
    modules a pool's clean-up uses are still there."""
    discard_prestarted(wait=wait)
    discard_parked(wait=wait)


atexit.register(let_go_workers)


def run_job(job: Job[T_co]) -> T_co:
    """Measure one job on a fresh virtual-time loop (runs in a worker process)."""
    from armbench.fakes.clock.vclock import run_virtual

    return run_virtual(job.measure())
