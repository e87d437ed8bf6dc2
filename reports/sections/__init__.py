"""The report's section of each suite, found by registration: the entry points of the group
:data:`ENTRY_POINT_GROUP` (``<suite name> = "package.module:build"``), armbench's own suites' as
another distribution's (:mod:`armbench.drivers.model.entry_points`). A section's ``build(record,
suite, view, figs)`` returns its :class:`~armbench.reports.render.views.SectionView` (its
template under ``templates/sections/``). ``generic`` (any other suite) and ``traffic`` (the
capture) are no suite's and are not registered.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import TYPE_CHECKING, TypeGuard

from armbench.drivers.model import entry_points

if TYPE_CHECKING:
    from armbench.record import RunRecord, SuiteRecord
    from armbench.reports.render.views import Figures, SectionView, SuiteView

__all__ = ["ENTRY_POINT_GROUP", "SectionBuilder", "registered_sections"]

SectionBuilder = Callable[["RunRecord", "SuiteRecord", "SuiteView", "Figures"], "SectionView"]

#: Entry-point group of every suite's report section, by the suite's name.
ENTRY_POINT_GROUP = "armbench.report_sections"


def _is_builder(found: object) -> TypeGuard[SectionBuilder]:
    return callable(found)


def registered_sections() -> dict[str, SectionBuilder]:
    """Each registered section's ``build`` by its suite's name (loaded when asked: a section
    registered later counts). A section that cannot be loaded is left out with a warning naming
    its entry point (its suite then gets the generic section), so one broken plug-in does not
    stop a report."""
    found: dict[str, SectionBuilder] = {}
    for name in entry_points.registered(ENTRY_POINT_GROUP):
        try:
            found[name] = entry_points.load(ENTRY_POINT_GROUP, name, _is_builder,
                                            "a section builder (callable)")
        except entry_points.EntryPointError as exc:
            warnings.warn(str(exc), RuntimeWarning, stacklevel=2)
    return found
