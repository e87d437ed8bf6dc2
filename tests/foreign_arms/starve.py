"""Starve processes as a loaded machine does, at its worst: one of them, picked at random every
0.2–1 s, is paused (SIGSTOP) for 20–300 ms and then let go on (SIGCONT). A paused arm sends no
reply and reads no command meanwhile; a paused host reads the arm's replies late, in a burst.

    with starved([arm.process.pid, host_pid], seed=1) as pauses:
        ...                      # pauses: (pid, start_s, length_s) of each pause, monotonic clock
"""

from __future__ import annotations

import contextlib
import os
import random
import signal
import threading
import time
from collections.abc import Iterator, Sequence
from typing import Final

#: A pause's length (s), drawn uniformly.
PAUSE_S: Final = (0.02, 0.3)
#: The time between two pauses (s), drawn uniformly.
BETWEEN_S: Final = (0.2, 1.0)


@contextlib.contextmanager
def starved(pids: Sequence[int], seed: int) -> Iterator[list[tuple[int, float, float]]]:
    """Pause the processes ``pids`` at random (seeded) until the block ends; every paused one is
    let go on at the end, whatever happened. Yields the pauses made so far (a list that grows)."""
    rng = random.Random(seed)
    stop = threading.Event()
    pauses: list[tuple[int, float, float]] = []

    def run() -> None:
        while not stop.wait(rng.uniform(*BETWEEN_S)):
            pid, length = rng.choice(list(pids)), rng.uniform(*PAUSE_S)
            start = time.monotonic()
            try:
                os.kill(pid, signal.SIGSTOP)
                stop.wait(length)
            except ProcessLookupError:
                continue
            finally:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGCONT)
            pauses.append((pid, start, time.monotonic() - start))

    thread = threading.Thread(target=run, name="starve", daemon=True)
    thread.start()
    try:
        yield pauses
    finally:
        stop.set()
        thread.join()
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGCONT)
