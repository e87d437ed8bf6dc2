"""Benchmarks behind ``armbench perf``: each module under ``armbench.cli.perf`` yields named
figures.

Figure names are stable across versions so CI can track them; a figure's ``bound`` is a
reference rate measured in the same run (the ratio ``value / bound`` is what targets are set on).
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from typing import Any

__all__ = ["BENCHMARK_MODULES", "Figure", "PerfOptions", "best_rate", "run_benchmarks"]

#: Each module exposes ``run(options) -> list[Figure]``; ``--only`` and the progress name it
#: without its ``_perf`` suffix.
BENCHMARK_MODULES: tuple[str, ...] = (
    "armbench.cli.perf.startup_perf",
    "armbench.cli.perf.codec_perf",
    "armbench.cli.perf.emulator_perf",
    "armbench.cli.perf.transports_perf",
    "armbench.cli.perf.driver_perf",
    "armbench.cli.perf.report_perf",
    "armbench.cli.perf.firmware_perf",
    "armbench.cli.perf.fleet_perf",
    "armbench.cli.perf.run_perf",
)


@dataclass(frozen=True, slots=True)
class Figure:
    """One measured figure: value with unit, and optionally the bound it is compared with."""

    name: str
    value: float
    unit: str
    bound: float | None = None
    ratio: float | None = None
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        """The JSON object of this figure (the ``--json`` schema)."""
        return asdict(self)


@dataclass(frozen=True, slots=True)
class PerfOptions:
    """What the user asked of ``armbench perf``: a port of their own, and how long to measure."""

    port: str | None = None
    repeats: int = 5
    quick: bool = False


def best_rate(fn: Callable[[], int], repeats: int) -> float:
    """Items per second of ``fn`` (which returns how many it processed), best of ``repeats``.

    Best-of-N is the usual defence against a busy machine: interference only ever slows a run.
    """
    best = 0.0
    for _ in range(repeats):
        start = time.perf_counter()
        n = fn()
        elapsed = time.perf_counter() - start
        best = max(best, n / elapsed)
    return best


def run_benchmarks(options: PerfOptions, only: Iterable[str] = (), *,
                   starting: Callable[[str], None] | None = None,
                   measured: Callable[[Figure], None] | None = None) -> list[Figure]:
    """Run every benchmark module (or those whose figure names start with one of ``only``).

    ``starting(module)`` is called before each benchmark module runs and ``measured(figure)``
    for each figure as soon as its module has it, so a caller shows progress on a run that
    takes minutes."""
    prefixes = tuple(only)

    def wanted(f: Figure) -> bool:
        return not prefixes or any(f.name.startswith(p) or f.name.split(".")[0] == p
                                   for p in prefixes)

    figures: list[Figure] = []
    for name in BENCHMARK_MODULES:
        short = name.rsplit(".", 1)[-1].removesuffix("_perf")
        if prefixes and not any(p.split(".")[0] == short or short.startswith(p)
                                for p in prefixes):
            continue
        if starting is not None:
            starting(short)
        for figure in importlib.import_module(name).run(options):
            if wanted(figure):
                figures.append(figure)
                if measured is not None:
                    measured(figure)
    return figures
