"""How often the cyclic garbage collector runs in armbench's own processes.

An emulated arm and its driver allocate a few small objects for every reply (a joint state, a
frame's fields, a timer) and free nearly all of them by reference counting at once. CPython's
default pace (the youngest generation collected every 700 allocations) then runs the collector
every couple of replies, to find almost nothing to free. armbench's own processes (the
``armbench`` program and its trial workers) collect the youngest generation every
:data:`YOUNG_ALLOCATIONS` allocations instead; the older generations keep their ratios to it,
so cycles are still collected, in fewer and larger passes. A process that merely imports armbench
(a user's script, a pytest session with the plugin) keeps its own pace: the collector is the
process owner's to set (``docs/performance.md``).
"""

from __future__ import annotations

import gc
from typing import Final

__all__ = ["YOUNG_ALLOCATIONS", "pace_collector"]

YOUNG_ALLOCATIONS: Final = 10_000
"""Allocations (less deallocations) of container objects between two collections of the youngest
generation; CPython's default is 700. Larger values were measured to gain little more
(``measurements/performance.md``)."""


def pace_collector() -> None:
    """Collect the youngest generation every :data:`YOUNG_ALLOCATIONS` allocations; the older
    generations' thresholds are left as they are (see the module doc)."""
    _, middle, oldest = gc.get_threshold()
    gc.set_threshold(YOUNG_ALLOCATIONS, middle, oldest)
