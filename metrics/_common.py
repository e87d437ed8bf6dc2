"""Shared input checks and small geometry helpers of ``armbench.metrics`` (private).

Every public metric takes positions in metres (the project's length unit) and reports millimetres;
the conversion happens in one place, :data:`MM_PER_M`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armbench.drivers.model.errors import ArmbenchError

__all__ = [
    "MM_PER_M",
    "FloatArray",
    "MetricsInputError",
    "as_point",
    "as_points",
    "cumulative_length",
    "dedupe_consecutive",
]

#: Millimetres per metre: inputs are in metres, results in millimetres.
MM_PER_M = 1000.0

FloatArray = NDArray[np.float64]


class MetricsInputError(ArmbenchError, ValueError):
    """Input to a metric has the wrong shape, too few samples, or non-finite values."""


def as_point(value: ArrayLike, name: str) -> FloatArray:
    """``value`` as a finite float array of shape ``(3,)``; raises :class:`MetricsInputError`."""
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3,):
        raise MetricsInputError(f"{name}: expected shape (3,), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise MetricsInputError(f"{name}: non-finite coordinate")
    return a


def as_points(value: ArrayLike, name: str, min_count: int = 1) -> FloatArray:
    """``value`` as a finite float array of shape ``(n, 3)`` with ``n >= min_count``."""
    a = np.asarray(value, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise MetricsInputError(f"{name}: expected shape (n, 3), got {a.shape}")
    if a.shape[0] < min_count:
        raise MetricsInputError(f"{name}: needs at least {min_count} points, got {a.shape[0]}")
    if not np.all(np.isfinite(a)):
        raise MetricsInputError(f"{name}: non-finite coordinate")
    return a


def dedupe_consecutive(points: FloatArray) -> FloatArray:
    """``points`` without the repeats of a point equal to the one before (a robot at rest)."""
    if len(points) < 2:
        return points
    keep = np.ones(len(points), dtype=bool)
    keep[1:] = np.any(points[1:] != points[:-1], axis=1)
    return points[keep]


def cumulative_length(points: FloatArray) -> FloatArray:
    """Arc length (same unit as ``points``) from the first point to each point, shape ``(n,)``."""
    steps = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return np.concatenate(([0.0], np.cumsum(steps)))
