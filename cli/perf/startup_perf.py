"""Start-up cost: how long a fresh interpreter takes to run a light command, and what it imports.

``startup.help_ms`` (``armbench --help``), ``startup.fk_ms`` (``armbench fk 0 0 0 0``) and
``startup.import_connect_ms`` (``import armbench; armbench.connect``) are wall times of fresh
processes, best of the repeats (interference only ever slows a start). ``startup.heavy_imports``
counts the heavy libraries (:data:`HEAVY`) that ``armbench --help`` and ``fk`` import: 0, since
each command imports what it uses when it runs.
"""

from __future__ import annotations

import subprocess
import sys
import time

from armbench.cli.perf import Figure, PerfOptions

__all__ = ["HEAVY", "heavy_imports", "run"]

#: Libraries a light command must not import at start.
HEAVY = ("scipy", "matplotlib", "jinja2", "mcap", "foxglove", "dask", "labgrid", "zstandard")

_HELP = ("-m", "armbench", "--help")
_FK = ("-m", "armbench", "fk", "0", "0", "0", "0")
_CONNECT = ("-c", "import armbench; armbench.connect")


def _wall_s(args: tuple[str, ...]) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, *args], capture_output=True, check=True, timeout=120)
    return time.perf_counter() - start


def heavy_imports(args: tuple[str, ...]) -> list[str]:
    """The :data:`HEAVY` libraries a fresh ``python ARGS`` imports (``-X importtime``)."""
    done = subprocess.run([sys.executable, "-X", "importtime", *args], capture_output=True,
                          text=True, check=True, timeout=120)
    names = {line.rsplit("|", 1)[-1].strip() for line in done.stderr.splitlines()
             if line.startswith("import time:")}
    return sorted(h for h in HEAVY if h in names)


def run(options: PerfOptions) -> list[Figure]:
    """Measure the start-up figures."""
    repeats = 2 if options.quick else max(3, options.repeats)
    figures = [Figure(name, 1e3 * min(_wall_s(args) for _ in range(repeats)), "ms")
               for name, args in (("startup.help_ms", _HELP), ("startup.fk_ms", _FK),
                                  ("startup.import_connect_ms", _CONNECT))]
    heavy = sorted(set(heavy_imports(_HELP)) | set(heavy_imports(_FK)))
    figures.append(Figure("startup.heavy_imports", float(len(heavy)), "modules",
                          note=", ".join(heavy) or "none"))
    return figures
