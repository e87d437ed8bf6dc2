"""The front ends, the top layer: the ``armbench`` command line (``main``, one module per
subcommand under ``commands``), the pytest plugin, ``armbench perf``'s benchmarks of every layer,
and the writing of a run's report files once a run is done (``reporting``). Nothing below imports
from here (``docs/architecture.md``).
"""

if __name__ != "armbench.cli":  # the checkout's folder imported by its bare name: a second copy
    raise ImportError(f"{__name__!r} installs as armbench.cli: import it by that name")
