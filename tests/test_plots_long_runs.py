"""The accuracy figures of a long run: every lap drawn, a bounded number of artists and legend
entries, the axes scaled to all laps (not only the ones drawn as lines of their own)."""

from __future__ import annotations

import numpy as np
from matplotlib.collections import LineCollection

from armbench.reports.render import plots
from armbench.reports.render.plots import LEGEND_RUNS
from armbench.reports.render.plotting import COLOURS


def _square_lap(k: int) -> np.ndarray:
    t = np.linspace(0.0, 1.0, 50)
    return np.column_stack([t, t * (1.0 + k), t * (2.0 + k)])


def test_paths_of_200_laps_draw_every_lap_with_bounded_artists() -> None:
    laps = 200
    runs = [plots.AttainedPath(f"lap {k}", _square_lap(k), _square_lap(k) + 0.5)
            for k in range(laps)]
    fig = plots.paths_yz([plots.PathPanel("paper", runs)], None)
    ax = fig.axes[0]
    # LEGEND_RUNS reported and LEGEND_RUNS true lines, plus the "and N more" entry
    assert len(ax.lines) == 2 * LEGEND_RUNS + 1
    drawn = sum(len(c.get_segments()) for c in ax.collections if isinstance(c, LineCollection))
    assert drawn == 2 * (laps - LEGEND_RUNS)
    assert len(ax.collections) <= 2 * 4 * len(COLOURS)
    # one legend for the figure, below its panels
    assert ax.get_legend() is None and len(fig.legends) == 1
    legend = fig.legends[0]
    labels = [t.get_text() for t in legend.get_texts()]
    assert labels[-1] == f"and {laps - LEGEND_RUNS} more"
    assert len(labels) == 2 * LEGEND_RUNS + 1
    # the last lap reaches z = 201.5 mm: the view holds it
    assert ax.get_ylim()[1] >= 2.0 + laps - 1 + 0.5


def test_error_over_time_of_200_laps_scales_to_the_highest_lap() -> None:
    t = np.linspace(0.0, 10.0, 400)
    runs = [plots.ErrorRun(f"lap {k}", t, np.full_like(t, 1.0 + k / 10.0)) for k in range(200)]
    fig = plots.error_over_time([plots.ErrorPanel("paper", runs, 5.0)], 12.4)
    ax = fig.axes[0]
    assert ax.get_ylim()[1] >= 1.0 + 199 / 10.0
    drawn = sum(len(c.get_segments()) for c in ax.collections if isinstance(c, LineCollection))
    assert drawn == 200 - LEGEND_RUNS
