"""Emulated trials on a Dask cluster (``--scheduler tcp://HOST:PORT``, ``[bench] scheduler``).

The parent connects a ``dask.distributed`` client to the scheduler and hands each trial attempt
to :meth:`DaskCluster.executor`, a ``concurrent.futures`` executor like the local process pool
(``armbench.bench.runner.parallel``). Workers may run on other machines: a job writes its capture
part in a temporary folder of its own and sends it back as bytes with the trial
(:class:`~armbench.bench.runner.parallel.JobResult`); the parent writes the record and the
capture. A worker lost mid-trial is Dask's to handle: the scheduler runs the task again on another
worker, and after ``distributed.scheduler.allowed-failures`` losses the future raises
``KilledWorker``, which the runner records as a trial in error. Each future gives one result, so a
trial is never recorded twice.
"""

from __future__ import annotations

import concurrent.futures
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

from armbench.drivers.model.settings import SettingsError

if TYPE_CHECKING:
    from distributed import Client

__all__ = ["DaskCluster", "check_scheduler"]

#: Schemes of a Dask scheduler address the runner accepts.
SCHEMES = ("tcp", "tls", "inproc", "ucx")
#: Seconds to wait for the scheduler to answer when connecting.
CONNECT_TIMEOUT_S = 10.0


def check_scheduler(where: str, address: object, parallel: bool) -> str:
    """``address`` checked (a ``tcp://HOST:PORT`` URL, on a run whose target allows trials in
    worker processes, ``parallel``, with Dask installed); a :class:`SettingsError` naming
    ``where`` otherwise."""
    if not isinstance(address, str):
        raise SettingsError(where, address, "is not a scheduler address (tcp://HOST:PORT)")
    try:  # urlsplit refuses an unclosed IPv6 bracket, .port a port out of range
        url = urlsplit(address)
        port = url.port
    except ValueError:
        raise SettingsError(where, address, "is not a scheduler address (tcp://HOST:PORT)") \
            from None
    if url.scheme not in SCHEMES or not url.hostname or (url.scheme != "inproc" and not port):
        raise SettingsError(where, address, "is not a scheduler address (tcp://HOST:PORT)")
    if not parallel:
        raise SettingsError(where, address, "a Dask scheduler measures trials on simulated "
                                            "arms started fresh in workers; the port's target "
                                            "is not one (fake:// is)")
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise SettingsError(where, address, "needs Dask: pip install 'armbench[dask]'") from None
    return address


class DaskCluster:
    """A client of the Dask scheduler at ``address`` and the executor trials are sent to."""

    def __init__(self, address: str) -> None:
        from distributed import Client

        self.address = address
        # distributed has no type hints for these: the ignores below say so
        self.client: Client = Client(address, timeout=CONNECT_TIMEOUT_S,  # type: ignore[no-untyped-call]
                                     set_as_default=False)
        self.executor: concurrent.futures.Executor = self.client.get_executor(  # type: ignore[no-untyped-call]
            pure=False)

    def threads(self) -> int:
        """Worker threads the cluster has now (at least 1: a cluster still starting)."""
        threads: dict[str, int] = self.client.nthreads()  # type: ignore[no-untyped-call]
        return max(1, sum(threads.values()))

    def close(self) -> None:
        """Cancel what is queued and disconnect (the cluster itself stays up)."""
        self.executor.shutdown(wait=False)  # cancels the futures not finished
        self.client.close()  # type: ignore[no-untyped-call]
