"""The report's section of each suite, found by registration: every module of this package that
names the suite it shows (``SUITE``) and builds its section (``build(record, suite, view,
figs)``) is that suite's section, so adding a suite's section is adding its module here (and its
template under ``templates/sections/``); no list elsewhere names it. ``generic`` (any other suite)
and ``traffic`` (the capture) name no suite. Another distribution registers its suite's section
as an entry point of :data:`ENTRY_POINT_GROUP`: ``<suite name> = "package.module:build"``.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import pkgutil
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from armbench.record import RunRecord, SuiteRecord
    from armbench.reports.render.views import Figures, SectionView, SuiteView

__all__ = ["ENTRY_POINT_GROUP", "SectionBuilder", "registered_sections"]

SectionBuilder = Callable[["RunRecord", "SuiteRecord", "SuiteView", "Figures"], "SectionView"]

#: Entry-point group under which other distributions register a suite's report section, by the
#: suite's name.
ENTRY_POINT_GROUP = "armbench.report_sections"


def registered_sections() -> dict[str, SectionBuilder]:
    """Each section module's ``build`` by its ``SUITE``, the modules in name order, then the
    entry points of :data:`ENTRY_POINT_GROUP` (loaded when asked: a section registered later
    counts); two sections of one suite are a bug."""
    found: dict[str, SectionBuilder] = {}
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda i: i.name):
        module: Any = importlib.import_module(f"{__name__}.{info.name}")
        suite = getattr(module, "SUITE", None)
        if not isinstance(suite, str):
            continue
        if suite in found:
            raise ImportError(f"two report sections of suite {suite!r}")
        found[suite] = module.build
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in found:
            raise ImportError(f"two report sections of suite {ep.name!r}")
        found[ep.name] = ep.load()
    return found
