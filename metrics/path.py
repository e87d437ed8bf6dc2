"""Path error metrics of the paper's square experiment (§7): attained positions against a polyline.

The paper drives the arm round a square in the YZ plane and reports the mean Euclidean distance
(12.4 mm) between the position computed by forward kinematics of the reported joints and the
reference trajectory. This module builds that reference, measures each attained point's distance to
it (vectorised point-to-segment distance) and summarises the errors (mean, RMS, max; per axis).
Positions go in as metres; errors come out in millimetres. Pure numpy, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armbench.metrics._common import (
    MM_PER_M,
    FloatArray,
    MetricsInputError,
    as_point,
    as_points,
)

__all__ = [
    "AxisErrorStats",
    "PathErrorSummary",
    "PathErrors",
    "PolylineProjection",
    "error_summary",
    "path_errors",
    "point_segment_distances",
    "project_to_polyline",
    "sample_polyline",
    "square_yz",
    "summarize_errors",
    "tracking_errors",
]

#: Upper bound on the (points x segments) block handled at once by :func:`project_to_polyline`.
_BLOCK = 1_000_000


# --------------------------------------------------------------------------------------------
# Reference geometry
# --------------------------------------------------------------------------------------------


def square_yz(centre_m: ArrayLike, side_m: float) -> FloatArray:
    """Corners (m) of the square of side ``side_m`` (m) centred on ``centre_m`` = (x, y, z) (m) in
    the plane x = const, shape ``(4, 3)``.

    Order: (y-, z-), (y+, z-), (y+, z+), (y-, z+), i.e. counter-clockwise about +x. Pass the
    corners with ``closed=True`` to the functions below to get the closed square.
    """
    c = as_point(centre_m, "centre_m")
    if not side_m > 0:
        raise MetricsInputError(f"side_m: must be positive, got {side_m!r}")
    h = side_m / 2.0
    signs = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    corners = np.tile(c, (4, 1))
    corners[:, 1:] += h * signs
    return corners


def _segments(vertices_m: ArrayLike, closed: bool) -> tuple[FloatArray, FloatArray]:
    v = as_points(vertices_m, "vertices_m", min_count=2)
    if closed:
        return v, np.roll(v, -1, axis=0)
    return v[:-1], v[1:]


def sample_polyline(vertices_m: ArrayLike, spacing_m: float, *, closed: bool = True) -> FloatArray:
    """Points (m) along the polyline through ``vertices_m`` (m), at most ``spacing_m`` (m) apart.

    Every vertex is kept (corners stay exact); each segment is cut into ``ceil(length/spacing)``
    equal pieces. With ``closed`` the closing segment is sampled too and the first vertex is not
    repeated at the end. Shape ``(N, 3)``.
    """
    if not spacing_m > 0:
        raise MetricsInputError(f"spacing_m: must be positive, got {spacing_m!r}")
    starts, ends = _segments(vertices_m, closed)
    out = []
    for a, b in zip(starts, ends, strict=True):
        pieces = max(1, math.ceil(float(np.linalg.norm(b - a)) / spacing_m))
        u = np.arange(pieces)[:, None] / pieces
        out.append(a + u * (b - a))
    if not closed:
        out.append(ends[-1:])
    return np.vstack(out)


# --------------------------------------------------------------------------------------------
# Point-to-polyline distance
# --------------------------------------------------------------------------------------------


def _closest_on_segments(
    points: FloatArray, starts: FloatArray, ends: FloatArray
) -> FloatArray:
    """Closest point of every segment to every point, shape ``(N, S, 3)``."""
    d = ends - starts  # (S, 3)
    len2 = np.sum(d * d, axis=1)  # (S,)
    rel = points[:, None, :] - starts[None, :, :]  # (N, S, 3)
    safe = np.where(len2 > 0.0, len2, 1.0)
    t = np.where(len2 > 0.0, np.sum(rel * d[None, :, :], axis=2) / safe, 0.0)
    t = np.clip(t, 0.0, 1.0)
    out: FloatArray = starts[None, :, :] + t[:, :, None] * d[None, :, :]
    return out


def point_segment_distances(
    points_m: ArrayLike, starts_m: ArrayLike, ends_m: ArrayLike
) -> FloatArray:
    """Euclidean distance (m) from each point ``(N, 3)`` to each segment ``starts[s]-ends[s]``
    (``(S, 3)`` each, m), shape ``(N, S)``. A zero-length segment is its point."""
    p = as_points(points_m, "points_m")
    a = as_points(starts_m, "starts_m")
    b = as_points(ends_m, "ends_m")
    if a.shape != b.shape:
        raise MetricsInputError(f"starts_m and ends_m: shapes {a.shape} and {b.shape} differ")
    closest = _closest_on_segments(p, a, b)
    out: FloatArray = np.linalg.norm(p[:, None, :] - closest, axis=2)
    return out


@dataclass(frozen=True, slots=True, eq=False)
class PolylineProjection:
    """Nearest point of a polyline to each of ``N`` points.

    ``distance_m`` ``(N,)`` and ``closest_m`` ``(N, 3)`` in metres; ``segment`` ``(N,)`` is the
    index of the segment it lies on (segment ``s`` runs from vertex ``s`` to ``s + 1``, the last
    one of a closed polyline back to vertex 0; ties go to the lower index).
    """

    distance_m: FloatArray
    closest_m: FloatArray
    segment: NDArray[np.intp]


def project_to_polyline(
    points_m: ArrayLike, vertices_m: ArrayLike, *, closed: bool = True
) -> PolylineProjection:
    """Distance (m) and nearest point (m) of the polyline through ``vertices_m`` (``(V, 3)``, m;
    joined back to the first vertex if ``closed``) for each point of ``points_m`` (``(N, 3)``, m).

    Exact (segment-wise closed form), vectorised over points and segments in blocks.
    """
    p = as_points(points_m, "points_m")
    starts, ends = _segments(vertices_m, closed)
    n = len(p)
    distance = np.empty(n)
    closest = np.empty((n, 3))
    segment = np.empty(n, dtype=np.intp)
    chunk = max(1, _BLOCK // len(starts))
    for lo in range(0, n, chunk):
        block = p[lo:lo + chunk]
        cand = _closest_on_segments(block, starts, ends)  # (c, S, 3)
        d = np.linalg.norm(block[:, None, :] - cand, axis=2)  # (c, S)
        best = np.argmin(d, axis=1)
        rows = np.arange(len(block))
        distance[lo:lo + chunk] = d[rows, best]
        closest[lo:lo + chunk] = cand[rows, best]
        segment[lo:lo + chunk] = best
    return PolylineProjection(distance_m=distance, closest_m=closest, segment=segment)


# --------------------------------------------------------------------------------------------
# Error series and summaries
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True, eq=False)
class PathErrors:
    """Errors of ``N`` attained points against their reference points, as a series.

    ``error_mm`` ``(N, 3)`` is attained minus reference per axis (x, y, z), signed;
    ``euclidean_mm`` ``(N,)`` its length; ``reference_m`` ``(N, 3)`` the reference point each
    attained point was compared with (m); ``times_s`` ``(N,)`` the sample times (s) if given.
    """

    error_mm: FloatArray
    euclidean_mm: FloatArray
    reference_m: FloatArray
    times_s: FloatArray | None


def _times(times_s: ArrayLike | None, n: int) -> FloatArray | None:
    if times_s is None:
        return None
    t = np.asarray(times_s, dtype=np.float64)
    if t.shape != (n,):
        raise MetricsInputError(f"times_s: expected shape ({n},), got {t.shape}")
    return t


def path_errors(
    attained_m: ArrayLike,
    vertices_m: ArrayLike,
    *,
    closed: bool = True,
    times_s: ArrayLike | None = None,
) -> PathErrors:
    """Errors (mm) of the attained points ``(N, 3)`` (m) against the reference polyline through
    ``vertices_m`` (m): each point is compared with its nearest point on the path (geometric
    error; timing does not count). ``times_s`` (s, ``(N,)``) is carried along for plots."""
    pts = as_points(attained_m, "attained_m")
    proj = project_to_polyline(pts, vertices_m, closed=closed)
    err = (pts - proj.closest_m) * MM_PER_M
    return PathErrors(
        error_mm=err,
        euclidean_mm=proj.distance_m * MM_PER_M,
        reference_m=proj.closest_m,
        times_s=_times(times_s, len(pts)),
    )


def tracking_errors(
    attained_m: ArrayLike, commanded_m: ArrayLike, *, times_s: ArrayLike | None = None
) -> PathErrors:
    """Errors (mm) of attained points ``(N, 3)`` (m) against the commanded points ``(N, 3)`` (m)
    of the same instants (time-indexed error: lag counts, unlike :func:`path_errors`)."""
    pts = as_points(attained_m, "attained_m")
    cmd = as_points(commanded_m, "commanded_m")
    if pts.shape != cmd.shape:
        raise MetricsInputError(
            f"attained_m and commanded_m: shapes {pts.shape} and {cmd.shape} differ"
        )
    err = (pts - cmd) * MM_PER_M
    return PathErrors(
        error_mm=err,
        euclidean_mm=np.linalg.norm(err, axis=1),
        reference_m=cmd,
        times_s=_times(times_s, len(pts)),
    )


@dataclass(frozen=True, slots=True)
class AxisErrorStats:
    """Statistics (mm) of one axis' signed error: mean (bias), mean of |e|, RMS, max of |e|."""

    mean_mm: float
    mean_abs_mm: float
    rms_mm: float
    max_abs_mm: float


@dataclass(frozen=True, slots=True)
class PathErrorSummary:
    """Summary (mm) of a :class:`PathErrors` series.

    ``mean_mm`` is the paper's figure (mean Euclidean error); ``rms_mm`` the root mean square and
    ``max_mm`` the largest Euclidean error, at sample ``max_index``; ``x``/``y``/``z`` per axis.
    """

    mean_mm: float
    rms_mm: float
    max_mm: float
    max_index: int
    n: int
    x: AxisErrorStats
    y: AxisErrorStats
    z: AxisErrorStats


def _axis_stats(e: FloatArray) -> AxisErrorStats:
    a = np.abs(e)
    return AxisErrorStats(
        mean_mm=float(e.mean()),
        mean_abs_mm=float(a.mean()),
        rms_mm=float(np.sqrt(np.mean(e * e))),
        max_abs_mm=float(a.max()),
    )


def error_summary(errors: PathErrors) -> PathErrorSummary:
    """Mean, RMS and max Euclidean error and per-axis statistics (mm) of ``errors`` (N >= 1)."""
    return summarize_errors(errors.error_mm, errors.euclidean_mm)


def summarize_errors(error_mm: FloatArray, euclidean_mm: FloatArray) -> PathErrorSummary:
    """:func:`error_summary` of the error series alone: ``error_mm`` ``(N, 3)`` and its lengths
    ``euclidean_mm`` ``(N,)`` (a long run's errors pooled without their reference points)."""
    e = euclidean_mm
    if len(e) == 0:
        raise MetricsInputError("errors: empty series")
    i = int(np.argmax(e))
    return PathErrorSummary(
        mean_mm=float(e.mean()),
        rms_mm=float(np.sqrt(np.mean(e * e))),
        max_mm=float(e[i]),
        max_index=i,
        n=len(e),
        x=_axis_stats(error_mm[:, 0]),
        y=_axis_stats(error_mm[:, 1]),
        z=_axis_stats(error_mm[:, 2]),
    )
