"""The report's section of each suite, found by registration: every module of this package that
names the suite it shows (``SUITE``) and builds its section (``build(record, suite, view,
figs)``) is that suite's section, so adding a suite's section is adding its module here (and its
template under ``templates/sections/``); no list elsewhere names it. ``generic`` (any other suite)
and ``traffic`` (the capture) name no suite.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from armbench.record import RunRecord, SuiteRecord
    from armbench.reports.views import Figures, SectionView, SuiteView

__all__ = ["SectionBuilder", "registered_sections"]

SectionBuilder = Callable[["RunRecord", "SuiteRecord", "SuiteView", "Figures"], "SectionView"]


def registered_sections() -> dict[str, SectionBuilder]:
    """Each section module's ``build`` by its ``SUITE``, the modules in name order; two modules
    naming one suite are a bug."""
    found: dict[str, SectionBuilder] = {}
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
        module: Any = importlib.import_module(f"{__name__}.{info.name}")
        suite = getattr(module, "SUITE", None)
        if not isinstance(suite, str):
            continue
        if suite in found:
            raise ImportError(f"two report sections of suite {suite!r}")
        found[suite] = module.build
    return found
