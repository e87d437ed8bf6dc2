"""Downsampling of long time series that keeps their extremes: per bucket of consecutive samples
the lowest and the highest point, so a spike survives (plain decimation would skip it). Used where
a series is kept bounded: the plots of the report, the series a record stores."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["envelope_indices"]


def envelope_indices(values: NDArray[np.float64], buckets: int) -> NDArray[np.int64]:
    """The indices (ascending) of a min/max envelope of ``values`` (``(n,)`` or ``(n, k)``: k
    series on one time base): per bucket of consecutive rows, the rows of each series' lowest and
    highest point, plus the first and last row; every row when ``n <= 2 * buckets``. NaNs are
    ignored (a bucket of NaNs only gives nothing)."""
    y = np.asarray(values, dtype=np.float64)
    if y.ndim == 1:
        y = y[:, None]
    n = len(y)
    if n <= 2 * buckets:
        return np.arange(n, dtype=np.int64)
    size = math.ceil(n / buckets)
    pad = np.full((size * buckets - n, y.shape[1]), np.nan)
    yp = np.concatenate([y, pad]).reshape(buckets, size, y.shape[1])
    nan = np.isnan(yp)
    valid = ~np.all(nan, axis=1)  # (buckets, k)
    lo = np.argmin(np.where(nan, np.inf, yp), axis=1)
    hi = np.argmax(np.where(nan, -np.inf, yp), axis=1)
    base = (np.arange(buckets) * size)[:, None]
    idx = np.concatenate([(base + lo)[valid], (base + hi)[valid], [0, n - 1]])
    return np.unique(np.clip(idx, 0, n - 1)).astype(np.int64)
