"""The report frees each drawn figure at once, collecting only what the page made."""

from __future__ import annotations

import gc
import subprocess
import sys
import weakref
from pathlib import Path

from matplotlib.figure import Figure

from armbench.reports.render.views import Figures, figures_collected_alone

HERE = str(Path(__file__).parent)


def _draw(figures: Figures) -> tuple[str, weakref.ref[Figure]]:
    made: list[weakref.ref[Figure]] = []

    def plot() -> Figure:  # a closure: drawn each time, never kept (reports.render.svg_cache)
        fig = Figure()
        fig.add_subplot().plot([0.0, 1.0], [1.0, 0.0])
        made.append(weakref.ref(fig))
        return fig

    return str(figures.make(plot, (), "a line", "caption").svg), made[0]


def test_drawn_figures_are_freed_and_the_heap_is_thawed_after_the_page() -> None:
    """In a process of its own: the freeze count is the whole process's, and a test run before
    in the same worker may have left a freeze of its own."""
    done = subprocess.run([sys.executable, "-c", f"import sys; sys.path.insert(0, {HERE!r}); "
                           "import test_report_gc as t; t.freed_and_thawed()"],
                          capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr


def freed_and_thawed() -> None:
    """The body of the test above: a heap thawed before the page is thawed after it (Python 3.12
    starts with objects in the permanent generation: that freeze is the interpreter's, kept as a
    caller's would be, and the figures are freed all the same)."""
    before = gc.get_freeze_count()
    with figures_collected_alone():
        assert gc.get_freeze_count() > 0           # what existed is set aside
        figures = Figures()
        svg, first = _draw(figures)
        _draw(figures)                             # collects the first figure's cycles
        assert first() is None
    assert "<svg" in svg
    assert gc.get_freeze_count() == before


def test_a_freeze_of_the_caller_is_kept() -> None:
    """The block neither thaws the caller's freeze (the count would drop to 0) nor freezes
    more. The count may drop by a few meanwhile: a frozen object that another thread of the
    worker frees (pytest-xdist's channel) leaves the permanent generation."""
    gc.freeze()
    try:
        frozen = gc.get_freeze_count()
        with figures_collected_alone():
            pass
        assert 0 < gc.get_freeze_count() <= frozen
    finally:
        gc.unfreeze()
