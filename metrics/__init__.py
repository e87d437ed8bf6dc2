"""Pure metric code of the bench suites: ISO 9283 pose/path figures and the paper's path errors.

No I/O and no asyncio: every function takes arrays of positions in metres (robot base frame) and
returns typed, frozen results in millimetres. See ``docs/metrics.md`` for the definitions.
"""

from __future__ import annotations

if __name__ != "armbench.metrics":  # the checkout's folder imported by its bare name: a second copy
    raise ImportError(f"{__name__!r} installs as armbench.metrics: import it by that name")

from armbench.metrics._common import MM_PER_M, MetricsInputError
from armbench.metrics.iso9283 import (
    CUBE_PLANES,
    POSE_CORNERS,
    DistanceCharacteristics,
    MultidirectionalVariation,
    PathCharacteristics,
    PathMethod,
    PoseAccuracy,
    PoseRepeatability,
    cube_corners,
    distance_characteristics,
    iso_cube_poses,
    multidirectional_variation,
    path_characteristics,
    pose_accuracy,
    pose_repeatability,
    resample_arc_length,
    resample_normal_planes,
)
from armbench.metrics.path import (
    AxisErrorStats,
    PathErrors,
    PathErrorSummary,
    PolylineProjection,
    error_summary,
    path_errors,
    point_segment_distances,
    project_to_polyline,
    sample_polyline,
    square_yz,
    summarize_errors,
    tracking_errors,
)

__all__ = [
    "CUBE_PLANES",
    "MM_PER_M",
    "POSE_CORNERS",
    "AxisErrorStats",
    "DistanceCharacteristics",
    "MetricsInputError",
    "MultidirectionalVariation",
    "PathCharacteristics",
    "PathErrorSummary",
    "PathErrors",
    "PathMethod",
    "PolylineProjection",
    "PoseAccuracy",
    "PoseRepeatability",
    "cube_corners",
    "distance_characteristics",
    "error_summary",
    "iso_cube_poses",
    "multidirectional_variation",
    "path_characteristics",
    "path_errors",
    "point_segment_distances",
    "pose_accuracy",
    "pose_repeatability",
    "project_to_polyline",
    "resample_arc_length",
    "resample_normal_planes",
    "sample_polyline",
    "square_yz",
    "summarize_errors",
    "tracking_errors",
]
