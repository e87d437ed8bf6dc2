"""The end of a process that may hold worker processes (the ``armbench`` program's): without the
interpreter's teardown, which frees every object the process made (a default run's record,
numpy's and matplotlib's modules) and waits for its workers' own: about half a second at the
end of a default run, with nothing left to do."""

from __future__ import annotations

import atexit
import os
import sys
import threading
from typing import NoReturn

from armbench.bench.workers.worker_process import let_go_workers

__all__ = ["end_process"]


def end_process(status: int) -> NoReturn:
    """End this process with ``status`` (see the module doc). What an exit must do is done
    first: the worker processes let go and waited for, the at-exit handlers run (logging
    flushed, multiprocessing's semaphores released), the standard streams flushed. A thread
    still at work (not a daemon) gets the ordinary exit, which waits for it; so does a stream
    that cannot be flushed, which the ordinary exit reports."""
    let_go_workers(wait=True)
    main_thread = threading.main_thread()
    if any(t is not main_thread and not t.daemon and t.is_alive() for t in threading.enumerate()):
        sys.exit(status)
    atexit._run_exitfuncs()
    try:
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:
                stream.flush()
    except (OSError, ValueError):
        sys.exit(status)
    os._exit(status)
