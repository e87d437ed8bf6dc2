"""The stall law's part of the speed model (``bench/calibrate/structure.py``): a drive that loses
synchronism stands wherever the torque a run needs exceeds the pull-out torque at its rate, and
moves at its full speed elsewhere.

The pull-out torque at a rate ``r`` is ``P · g(r)`` with the shape ``g`` of the prior's
``pullout_curve`` or the other one (``fakes/twin/physics.py``): ``1 / (1 + r / corner)``
(hyperbolic) or ``1 − r / (2 corner)`` (linear: zero at twice the corner). A run stalls where
its *factor* ``need / g(r)`` exceeds ``P``, so one number per run and curve carries the rate
and the load; ``P`` lies between the largest factor of a run that moved and the smallest of one
that stalled. The corner itself is the prior's: with the ladder's one pose per joint the runs
bracket one load, and a shape with a fitted corner would explain them as well as any.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
import numpy.typing as npt

from armbench.fakes.twin.physics import PULLOUT_CURVES

__all__ = ["PULLOUT_CURVES", "STALLED_RATIO", "curve_factor", "stall_interval", "stall_pred"]

FloatArray = npt.NDArray[np.float64]

#: A run slower than this ratio stalled (the torque law never loses more than 90 %).
STALLED_RATIO: Final = 0.12


def curve_factor(need_nm: FloatArray, rate: FloatArray, corner: float,
                 curve: str) -> FloatArray:
    """Each run's needed torque over the pull-out curve's shape at its rate (infinite where the
    linear curve has reached zero): the run keeps up where this is at most ``P``."""
    x = rate / corner
    if curve == "linear":
        g = 1.0 - 0.5 * x
        out: FloatArray = np.where(g > 0.0, need_nm / np.where(g > 0.0, g, 1.0), np.inf)
        return out
    if curve != "hyperbolic":
        raise ValueError(f"pull-out curve {curve!r} is not one of {', '.join(PULLOUT_CURVES)}")
    hyp: FloatArray = need_nm * (1.0 + x)
    return hyp


def stall_pred(p_nm: float | FloatArray, factor: FloatArray) -> FloatArray:
    """The ratio the stall law predicts: 1 where the run keeps up, 0 where it stalls."""
    out: FloatArray = (factor <= p_nm).astype(np.float64)
    return out


def stall_interval(ratio: FloatArray, factor: FloatArray,
                   grid: tuple[float, float]) -> tuple[float, float]:
    """The pull-out torque of a stalling drive lies between the largest factor of a run that
    moved and the smallest of one that stalled (``grid``'s ends where a side has no run): its
    geometric middle, and the standard error of a uniform variable over that interval (infinite
    when the runs overlap)."""
    moved = factor[ratio >= STALLED_RATIO]
    stalled = factor[(ratio < STALLED_RATIO) & np.isfinite(factor)]
    lo = float(moved.max()) if len(moved) else grid[0]
    hi = float(stalled.min()) if len(stalled) else grid[1]
    if (ratio < STALLED_RATIO).any() and not len(stalled):
        hi = grid[1]  # only runs past the linear curve's end stalled: no bound from above
    if hi <= lo:
        return math.sqrt(abs(lo * hi)), math.inf
    return math.sqrt(lo * hi), (hi - lo) / (2.0 * math.sqrt(3.0))
