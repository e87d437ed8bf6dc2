"""How many threads OpenBLAS (numpy's and scipy's linear algebra) runs in armbench's own processes.

The bench's matrices are small (a pose's 4×4 chain, a calibration's Jacobian), and a second BLAS
thread was measured to gain nothing on them, a calibration included; but OpenBLAS starts its
threads as it loads, and a thread woken by a call spins for a while before it sleeps, taking a
core from the emulator, the workers and the tests beside it.

armbench's own processes (the ``armbench`` program and its trial workers) ask for one thread,
unless the environment already says how many (``OPENBLAS_NUM_THREADS``, ``GOTO_NUM_THREADS`` or
``OMP_NUM_THREADS``: the user's answer wins). OpenBLAS reads the setting when it loads, with
numpy or scipy, so it is set before either is imported; the processes started later (workers,
``armbench emulate``) inherit it. A process that merely imports armbench keeps its own setting:
its threads are its owner's to set (``docs/performance.md``). So does a worker of such a
process whose main module loaded numpy: a spawned worker imports that module before its
initializer runs.
"""

from __future__ import annotations

import os
from typing import Final

__all__ = ["BLAS_THREAD_VARIABLES", "one_blas_thread"]

BLAS_THREAD_VARIABLES: Final = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")
"""The variables OpenBLAS reads for its thread count, in its order of precedence."""


def one_blas_thread() -> None:
    """Ask OpenBLAS for one thread in this process and the processes it starts, unless the
    environment already sets a thread count (see the module doc)."""
    if not any(os.environ.get(name) for name in BLAS_THREAD_VARIABLES):
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
