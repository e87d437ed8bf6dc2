"""The generic section: a suite the report has no section of its own for (one from the pytest
plugin, a lab's own suite): its parameters, its trials and its measurements as recorded."""

from __future__ import annotations

from armbench.record import RunRecord, SuiteRecord
from armbench.reports.render.views import Figures, SectionView, SuiteView

__all__ = ["build"]


def build(record: RunRecord, suite: SuiteRecord, view: SuiteView, figs: Figures) -> SectionView:
    """The generic section of ``suite``: no plots, its trials in a table."""
    return SectionView(key=view.key, template="generic", title=f"Suite {suite.name}",
                       suite=view, figures=[])
