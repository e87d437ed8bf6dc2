"""ISO 230-2 (2014) positioning of one axis from bidirectional approaches to a set of targets.

Deviations ``x_ij = attained − target`` of target ``i``, approach ``j``, grouped by approach
direction (↑ moving +, ↓ moving −). Per target: the mean unidirectional deviations ``x̄↑``,
``x̄↓``, their estimators of the standard uncertainty ``s↑``, ``s↓`` and the reversal value
``B_i = x̄↑ − x̄↓``. Of the axis:

* reversal error ``B = max |B_i|`` and mean reversal error ``B̄ = mean B_i``;
* repeatability ``R = max_i max(2 s↑ + 2 s↓ + |B_i|, 4 s↑, 4 s↓)``;
* systematic positioning error ``E = max(x̄↑, x̄↓) − min(x̄↑, x̄↓)`` over all targets;
* accuracy ``A = max(x̄↑ + 2 s↑, x̄↓ + 2 s↓) − min(x̄↑ − 2 s↑, x̄↓ − 2 s↓)``.

Units are those of the input (the joints suite passes radians).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from armbench.metrics._common import MetricsInputError

__all__ = ["AxisPositioning", "axis_positioning"]


@dataclass(frozen=True, slots=True)
class AxisPositioning:
    """ISO 230-2 figures of one axis (unit of the deviations)."""

    accuracy: float
    repeatability: float
    reversal: float
    mean_reversal: float
    systematic: float
    targets: int
    approaches: int


def axis_positioning(targets: Sequence[float], up: Sequence[Sequence[float]],
                     down: Sequence[Sequence[float]]) -> AxisPositioning:
    """The figures from the deviations ``up[i]`` / ``down[i]`` (≥ 2 each) at ``targets[i]``."""
    if not targets or len(up) != len(targets) or len(down) != len(targets):
        raise MetricsInputError("need one list of deviations per target and direction")
    if any(len(u) < 2 for u in up) or any(len(d) < 2 for d in down):
        raise MetricsInputError("need at least 2 approaches per target and direction")
    mu = np.asarray([np.mean(u) for u in up])
    md = np.asarray([np.mean(d) for d in down])
    su = np.asarray([np.std(u, ddof=1) for u in up])
    sd = np.asarray([np.std(d, ddof=1) for d in down])
    b = mu - md
    r = np.maximum(2 * su + 2 * sd + np.abs(b), np.maximum(4 * su, 4 * sd))
    both = np.concatenate([mu, md])
    hi = np.maximum(mu + 2 * su, md + 2 * sd)
    lo = np.minimum(mu - 2 * su, md - 2 * sd)
    return AxisPositioning(
        accuracy=float(hi.max() - lo.min()), repeatability=float(r.max()),
        reversal=float(np.abs(b).max()), mean_reversal=float(b.mean()),
        systematic=float(both.max() - both.min()), targets=len(targets),
        approaches=sum(len(u) for u in up) + sum(len(d) for d in down))
