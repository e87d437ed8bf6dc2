"""The calibration page (``armbench calibrate``'s ``.html`` beside the settings it wrote): what was
measured and fitted, every parameter with its standard error (a kept one with its prior's, and the
twin parameters no calibration fits: :mod:`~armbench.drivers.model.twin_parameters`), the
sensitivity to the assumptions, and figures of the effective speeds and the approaches, in the
report's style. A self-contained HTML document (no script, nothing fetched)."""

from __future__ import annotations

import math

import numpy as np
from markupsafe import Markup
from matplotlib.figure import Figure

from armbench.bench.calibrate.model import CalibrationResult, Fitted, no_truth
from armbench.drivers.model.twin_parameters import TWIN_PARAMETERS, by_path
from armbench.reports.render.format import jinja_environment
from armbench.reports.render.plots import to_svg

__all__ = ["render_page"]


def _figures(result: CalibrationResult) -> list[tuple[str, Markup]]:
    obs = result.observations
    out: list[tuple[str, Markup]] = []
    if obs.speeds:
        fig = Figure(figsize=(7.5, 3.2))
        ax = fig.add_subplot(1, 1, 1)
        for joint in sorted({s.joint for s in obs.speeds}):
            for direction, marker in ((1, "^"), (-1, "v")):
                pts = [(s.duty, s.ratio) for s in obs.speeds
                       if s.joint == joint and s.direction == direction]
                if pts:
                    a = np.asarray(sorted(pts))
                    ax.plot(a[:, 0], a[:, 1], marker=marker, label=f"j{joint} {direction:+d}")
        ax.set_xlabel("duty")
        ax.set_ylabel("effective / law (12) speed")
        ax.legend(fontsize=7, ncol=4)
        fig.subplots_adjust(left=0.1, right=0.98, bottom=0.16, top=0.95)
        out.append(("Effective speed against duty and direction (1 = no step lost)",
                    to_svg(fig, "speed", "effective speed against duty")))
    play = [(ap.joint, ap.direction, ap.link_rad[ap.joint - 1] - ap.motor_rad[ap.joint - 1])
            for ap in obs.approaches if ap.link_rad is not None and ap.motor_rad is not None]
    if play:
        fig = Figure(figsize=(7.5, 3.0))
        ax = fig.add_subplot(1, 1, 1)
        for joint, direction, gap_rad in play:
            ax.plot(joint + 0.1 * direction, math.degrees(gap_rad),
                    "^" if direction > 0 else "v", color="C0" if direction > 0 else "C3")
        ax.set_xticks([1, 2, 3, 4], ["j1", "j2", "j3", "j4"])
        ax.set_ylabel("link − motor (deg)")
        fig.subplots_adjust(left=0.12, right=0.98, bottom=0.12, top=0.95)
        out.append(("Approaches: link against motor, moving + (▲) and − (▼): the gap between "
                    "the groups is the play, their spread the stick-slip band",
                    to_svg(fig, "play", "link against motor per approach")))
    return out


def _prior_sigma(f: Fitted) -> float | None:
    """The prior standard error of a value kept at its prior (None: not a twin parameter)."""
    p = by_path(f.key)
    return None if p is None or p.choices else p.prior_sigma


def render_page(result: CalibrationResult) -> str:
    """The calibration page: a self-contained HTML document (no script, nothing fetched)."""
    template = jinja_environment().get_template("calibration.html.j2")
    return template.render(
        obs=result.observations, error=result.error, NO_TRUTH=no_truth(result.observations),
        held_out=result.held_out,
        sensitivity=result.sensitivity,
        identified=[f for f in result.fitted if f.identified],
        kept=[(f, _prior_sigma(f)) for f in result.fitted if not f.identified],
        never_fitted=sorted({p.key for p in TWIN_PARAMETERS if not p.fitted}),
        figures=_figures(result), kinematic_mm=result.kinematic_mm,
        speeds=sorted(result.observations.speeds, key=lambda s: (s.joint, s.direction, -s.duty)))
