"""ISO 9283:1998 performance criteria, position part: test cube, pose, distance and path figures.

Pure numpy, no I/O. Positions go in as metres (arrays of shape ``(n, 3)`` in the robot base frame),
every figure comes out in millimetres (``_mm`` fields). Orientation criteria (APa, APb, APc, ...)
are left out: the RoboLink's 4 DoF leave tool orientation under-determined, and the bench measures
positions only. Formulas, clause numbers and the choices made where the standard leaves room are in
``docs/metrics.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from armbench.metrics._common import (
    MM_PER_M,
    FloatArray,
    MetricsInputError,
    as_point,
    as_points,
    cumulative_length,
    dedupe_consecutive,
)

__all__ = [
    "CUBE_PLANES",
    "POSE_CORNERS",
    "DistanceCharacteristics",
    "MultidirectionalVariation",
    "PathCharacteristics",
    "PathMethod",
    "PoseAccuracy",
    "PoseRepeatability",
    "cube_corners",
    "distance_characteristics",
    "iso_cube_poses",
    "multidirectional_variation",
    "path_characteristics",
    "pose_accuracy",
    "pose_repeatability",
    "resample_arc_length",
    "resample_normal_planes",
]

# --------------------------------------------------------------------------------------------
# Test cube (ISO 9283 §6, figures "cube within the working space" and "plane to be used")
# --------------------------------------------------------------------------------------------

#: Signs of the eight cube corners C1..C8 along the cube's own axes (u, v, w), half a side each.
#: C1..C4 go round the bottom face (w = -) counter-clockwise seen from +w, starting at (-, -);
#: C5..C8 sit above C1..C4. With this numbering each of ISO's four diagonal planes below contains
#: two opposite parallel edges (C1-C2 and C7-C8, etc.).
_CORNER_SIGNS: FloatArray = np.array(
    [
        [-1, -1, -1],  # C1
        [+1, -1, -1],  # C2
        [+1, +1, -1],  # C3
        [-1, +1, -1],  # C4
        [-1, -1, +1],  # C5
        [+1, -1, +1],  # C6
        [+1, +1, +1],  # C7
        [-1, +1, +1],  # C8
    ],
    dtype=np.float64,
)

#: The four diagonal planes ISO 9283 allows, each as its corners in order round the rectangle.
CUBE_PLANES: dict[str, tuple[int, int, int, int]] = {
    "C1-C2-C7-C8": (1, 2, 7, 8),
    "C2-C3-C8-C5": (2, 3, 8, 5),
    "C3-C4-C5-C6": (3, 4, 5, 6),
    "C4-C1-C6-C7": (4, 1, 6, 7),
}

#: Corner each of P2..P5 is placed near, per plane: P2 near the second corner named in the plane,
#: then on round the rectangle (P3, P4), P5 near the first. For the default plane: P2-C2, P3-C7,
#: P4-C8, P5-C1, so P2/P4 and P3/P5 lie on the two diagonals and the ISO cycle
#: P1-P5-P4-P3-P2 goes round the rectangle.
POSE_CORNERS: dict[str, tuple[str, str, str, str]] = {
    plane: (f"C{b}", f"C{c}", f"C{d}", f"C{a}") for plane, (a, b, c, d) in CUBE_PLANES.items()
}


def _rotation(rotation: ArrayLike | None) -> FloatArray:
    if rotation is None:
        return np.eye(3)
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3) or not np.allclose(r.T @ r, np.eye(3), atol=1e-9):
        raise MetricsInputError("rotation: expected an orthonormal 3x3 matrix")
    return r


def cube_corners(
    centre_m: ArrayLike, side_m: float, rotation: ArrayLike | None = None
) -> FloatArray:
    """The eight corners C1..C8 (rows 0..7) of the ISO test cube, in metres, shape ``(8, 3)``.

    ``centre_m`` is the cube centre and ``side_m`` its edge length (m). The cube's edges are
    parallel to the base frame unless ``rotation`` (3x3, columns = cube axes u, v, w in base
    coordinates) says otherwise. Numbering: C1..C4 round the bottom face (w = -side/2)
    counter-clockwise seen from +w starting at (-u, -v); C5..C8 above C1..C4.
    """
    centre = as_point(centre_m, "centre_m")
    if not side_m > 0:
        raise MetricsInputError(f"side_m: must be positive, got {side_m!r}")
    r = _rotation(rotation)
    offsets: FloatArray = (_CORNER_SIGNS * (side_m / 2.0)) @ r.T
    return centre + offsets


def iso_cube_poses(
    centre_m: ArrayLike,
    side_m: float,
    plane: str = "C1-C2-C7-C8",
    *,
    fraction: float = 0.10,
    rotation: ArrayLike | None = None,
) -> FloatArray:
    """The five ISO 9283 test positions P1..P5 (rows 0..4), in metres, shape ``(5, 3)``.

    P1 is the cube centre. P2..P5 lie in the diagonal ``plane`` on its diagonals, at
    ``fraction`` x diagonal length from the corners named by ``POSE_CORNERS[plane]``
    (P2 near C2, P3 near C7, P4 near C8, P5 near C1 for the default plane). ISO asks for
    (10 +- 2) % of the diagonal; ``fraction`` must be in (0, 0.5). The plane's diagonals are space
    diagonals of the cube, so their length is ``side_m * sqrt(3)``.
    """
    if plane not in CUBE_PLANES:
        raise MetricsInputError(f"plane: {plane!r} is not one of {sorted(CUBE_PLANES)}")
    if not 0.0 < fraction < 0.5:
        raise MetricsInputError(f"fraction: must be in (0, 0.5), got {fraction!r}")
    corners = cube_corners(centre_m, side_m, rotation)
    centre = corners.mean(axis=0)
    near = np.array([int(name[1:]) - 1 for name in POSE_CORNERS[plane]])
    c = corners[near]
    # From a corner towards the diagonally opposite one (2*centre - c): fraction of the diagonal.
    poses = c + fraction * 2.0 * (centre - c)
    return np.vstack([centre, poses])


# --------------------------------------------------------------------------------------------
# Pose characteristics (ISO 9283 §7.2, §7.3, §7.4)
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class PoseAccuracy:
    """Position accuracy of one pose (ISO 9283 §7.2.1), millimetres.

    ``ap_x_mm`` etc. are barycentre minus commanded per axis (signed); ``ap_p_mm`` is the length of
    that vector. ``barycentre_m`` is the mean attained position (m); ``n`` the number of cycles.
    """

    ap_x_mm: float
    ap_y_mm: float
    ap_z_mm: float
    ap_p_mm: float
    barycentre_m: tuple[float, float, float]
    n: int


@dataclass(frozen=True, slots=True)
class PoseRepeatability:
    """Position repeatability of one pose (ISO 9283 §7.2.2), millimetres.

    ``rp_mm = l_mean_mm + 3 * s_l_mm``, where ``l_j`` is the distance of attained position ``j``
    to the barycentre and ``s_l_mm`` their sample standard deviation (n - 1).
    """

    rp_mm: float
    l_mean_mm: float
    s_l_mm: float
    n: int


@dataclass(frozen=True, slots=True)
class MultidirectionalVariation:
    """Multi-directional pose accuracy variation (ISO 9283 §7.3), millimetres.

    ``vap_p_mm`` is the largest distance between the barycentres reached from the different
    approach directions; ``vap_x_mm`` etc. the largest difference per axis (each maximised on its
    own, so they may come from different pairs).
    """

    vap_p_mm: float
    vap_x_mm: float
    vap_y_mm: float
    vap_z_mm: float
    barycentres_m: tuple[tuple[float, float, float], ...]


@dataclass(frozen=True, slots=True)
class DistanceCharacteristics:
    """Distance accuracy and repeatability between two poses (ISO 9283 §7.4), millimetres.

    ``ad_p_mm`` = mean attained distance - commanded distance (signed). Per axis,
    ``ad_x_mm`` = mean of ``|x1j - x2j|`` - ``|xc1 - xc2|``. ``rd_*_mm`` is the half-width
    ``3 * S`` (sample standard deviation, n - 1) that ISO writes as ``RD = +-3 S``.
    """

    ad_p_mm: float
    ad_x_mm: float
    ad_y_mm: float
    ad_z_mm: float
    rd_p_mm: float
    rd_x_mm: float
    rd_y_mm: float
    rd_z_mm: float
    mean_distance_mm: float
    commanded_distance_mm: float
    n: int


def _xyz(v: FloatArray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def pose_accuracy(attained_m: ArrayLike, commanded_m: ArrayLike) -> PoseAccuracy:
    """ISO 9283 §7.2.1 position accuracy of ``n >= 1`` attained positions ``(n, 3)`` (m) of one
    commanded position ``(3,)`` (m): AP per axis and APp, in mm."""
    pts = as_points(attained_m, "attained_m")
    cmd = as_point(commanded_m, "commanded_m")
    bary = _barycentre(pts)
    ap = (bary - cmd) * MM_PER_M
    return PoseAccuracy(
        ap_x_mm=float(ap[0]),
        ap_y_mm=float(ap[1]),
        ap_z_mm=float(ap[2]),
        ap_p_mm=float(np.linalg.norm(ap)),
        barycentre_m=_xyz(bary),
        n=len(pts),
    )


def _barycentre(pts: FloatArray) -> FloatArray:
    """Mean of ``pts`` along axis 0, taken about the first row: exact when every row is the same
    (an arm resting on the same encoder count gives RP 0, not 2e-13 mm of rounding)."""
    first = pts[0]
    out: FloatArray = first + (pts - first).mean(axis=0)
    return out


def _mean_and_std(v: FloatArray, axis: int = -1) -> tuple[FloatArray, FloatArray]:
    """Mean and sample standard deviation (n - 1) of ``v`` along ``axis``."""
    return v.mean(axis=axis), v.std(axis=axis, ddof=1)


def pose_repeatability(attained_m: ArrayLike) -> PoseRepeatability:
    """ISO 9283 §7.2.2 position repeatability RP (mm) of ``n >= 2`` attained positions ``(n, 3)``
    (m) of one commanded pose."""
    pts = as_points(attained_m, "attained_m", min_count=2)
    dist = np.linalg.norm(pts - _barycentre(pts), axis=1) * MM_PER_M
    mean, s = _mean_and_std(dist)
    return PoseRepeatability(
        rp_mm=float(mean + 3.0 * s), l_mean_mm=float(mean), s_l_mm=float(s), n=len(pts)
    )


def multidirectional_variation(
    attained_by_direction_m: Sequence[ArrayLike],
) -> MultidirectionalVariation:
    """ISO 9283 §7.3 vAP (mm) from the attained positions (m) of one pose approached from each of
    ``>= 2`` directions (ISO uses 3), one ``(n_k, 3)`` array per direction."""
    if len(attained_by_direction_m) < 2:
        raise MetricsInputError("attained_by_direction_m: needs at least 2 approach directions")
    bary = np.array(
        [
            _barycentre(as_points(a, f"attained_by_direction_m[{k}]"))
            for k, a in enumerate(attained_by_direction_m)
        ]
    )
    diff = (bary[:, None, :] - bary[None, :, :]) * MM_PER_M  # (k, k, 3)
    per_axis = np.abs(diff).max(axis=(0, 1))
    return MultidirectionalVariation(
        vap_p_mm=float(np.linalg.norm(diff, axis=2).max()),
        vap_x_mm=float(per_axis[0]),
        vap_y_mm=float(per_axis[1]),
        vap_z_mm=float(per_axis[2]),
        barycentres_m=tuple(_xyz(b) for b in bary),
    )


def distance_characteristics(
    attained_1_m: ArrayLike,
    attained_2_m: ArrayLike,
    commanded_1_m: ArrayLike,
    commanded_2_m: ArrayLike,
) -> DistanceCharacteristics:
    """ISO 9283 §7.4 distance accuracy AD and repeatability RD (mm) between two poses.

    ``attained_1_m[j]`` and ``attained_2_m[j]`` (m) are the positions reached at the two poses in
    cycle ``j``; both ``(n, 3)`` with ``n >= 2``. ``commanded_1_m``/``commanded_2_m`` (m) are the
    commanded positions (ISO uses P2 and P4 of the cube).
    """
    p1 = as_points(attained_1_m, "attained_1_m", min_count=2)
    p2 = as_points(attained_2_m, "attained_2_m", min_count=2)
    if p1.shape != p2.shape:
        raise MetricsInputError(
            f"attained_1_m and attained_2_m: one row per cycle each, got {p1.shape} and {p2.shape}"
        )
    c1 = as_point(commanded_1_m, "commanded_1_m")
    c2 = as_point(commanded_2_m, "commanded_2_m")
    d_axes = np.abs(p1 - p2) * MM_PER_M  # (n, 3): D_xj, D_yj, D_zj
    d_p = np.linalg.norm(p1 - p2, axis=1) * MM_PER_M  # (n,): D_j
    dc_axes = np.abs(c1 - c2) * MM_PER_M
    dc_p = float(np.linalg.norm(c1 - c2)) * MM_PER_M
    mean_axes, s_axes = _mean_and_std(d_axes, axis=0)
    mean_p, s_p = _mean_and_std(d_p)
    ad_axes = mean_axes - dc_axes
    return DistanceCharacteristics(
        ad_p_mm=float(mean_p) - dc_p,
        ad_x_mm=float(ad_axes[0]),
        ad_y_mm=float(ad_axes[1]),
        ad_z_mm=float(ad_axes[2]),
        rd_p_mm=3.0 * float(s_p),
        rd_x_mm=3.0 * float(s_axes[0]),
        rd_y_mm=3.0 * float(s_axes[1]),
        rd_z_mm=3.0 * float(s_axes[2]),
        mean_distance_mm=float(mean_p),
        commanded_distance_mm=dc_p,
        n=len(p1),
    )


# --------------------------------------------------------------------------------------------
# Path characteristics (ISO 9283 §8.2)
# --------------------------------------------------------------------------------------------

#: How attained paths are paired with the reference points: ISO's normal planes, equal fraction of
#: arc length, or "corresponding" when every attained path already has one row per reference point.
PathMethod = Literal["normal_planes", "arc_length", "corresponding"]

#: Upper bound on the (reference chunk x attained segments) block handled at once.
_BLOCK = 1_000_000


@dataclass(frozen=True, slots=True, eq=False)
class PathCharacteristics:
    """Path accuracy AT and path repeatability RT (ISO 9283 §8.2), millimetres.

    ``accuracy_mm[i]`` is the distance from reference point ``i`` to the barycentre of the ``n``
    attained points paired with it; ``at_mm`` its maximum, reached at ``at_index``.
    ``repeatability_mm[i]`` is ``l_mean_i + 3 S_li`` around that barycentre; ``rt_mm`` its
    maximum at ``rt_index`` (``None`` when ``n == 1``: no spread from one path).
    ``barycentres_m`` has shape ``(m, 3)`` (m).
    """

    at_mm: float
    at_index: int
    rt_mm: float | None
    rt_index: int | None
    accuracy_mm: FloatArray
    repeatability_mm: FloatArray | None
    barycentres_m: FloatArray
    n: int
    method: PathMethod


def _unit_rows(v: FloatArray) -> FloatArray:
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    out: FloatArray = v / norm
    return out


def _reference(reference_m: ArrayLike, closed: bool) -> FloatArray:
    ref = as_points(reference_m, "reference_m", min_count=2)
    steps = np.diff(np.vstack([ref, ref[:1]]) if closed else ref, axis=0)
    if np.any(np.all(steps == 0.0, axis=1)):
        raise MetricsInputError("reference_m: two consecutive reference points coincide")
    return ref


def _tangents(ref: FloatArray, closed: bool) -> FloatArray:
    """Unit tangent of the reference polyline at each of its points: the bisector of the unit
    directions of the segments before and after (the one segment at an open end). Where the path
    turns back on itself the incoming direction is used."""
    seg = _unit_rows(np.diff(np.vstack([ref, ref[:1]]) if closed else ref, axis=0))
    if closed:
        incoming, outgoing = np.roll(seg, 1, axis=0), seg
    else:
        incoming = np.vstack([seg[:1], seg])
        outgoing = np.vstack([seg, seg[-1:]])
    t = incoming + outgoing
    norm = np.linalg.norm(t, axis=1)
    back = norm < 1e-12
    t[back] = incoming[back]
    norm[back] = 1.0
    out: FloatArray = t / norm[:, None]
    return out


def resample_normal_planes(
    attained_m: ArrayLike, reference_m: ArrayLike, *, closed: bool = False
) -> FloatArray:
    """The attained path's crossings with the planes normal to the reference path (ISO 9283 §8.2).

    For each reference point ``i`` (m, shape ``(m, 3)``), the plane through it normal to the
    reference tangent (bisector of the adjacent segment directions) is intersected with every
    segment of the attained polyline (m, shape ``(k, 3)``, linearly interpolated between samples);
    the crossing nearest to the reference point is kept. Rows where the attained path never
    crosses the plane are NaN. ``closed`` treats both polylines as loops (last point joined to the
    first). Returns shape ``(m, 3)`` (m).
    """
    ref = _reference(reference_m, closed)
    att = dedupe_consecutive(as_points(attained_m, "attained_m", min_count=2))
    if closed:
        att = np.vstack([att, att[:1]])
    if len(att) < 2:
        raise MetricsInputError("attained_m: the path does not move")
    tan = _tangents(ref, closed)
    a0, a1 = att[:-1], att[1:]
    step = a1 - a0
    out = np.full_like(ref, np.nan)
    chunk = max(1, _BLOCK // len(a0))
    for lo in range(0, len(ref), chunk):
        r = ref[lo:lo + chunk, None, :]  # (c, 1, 3)
        t = tan[lo:lo + chunk, None, :]
        s = np.sum((att[None, :, :] - r) * t, axis=2)  # (c, k) signed distances to the planes
        s0, s1 = s[:, :-1], s[:, 1:]
        crosses = (s0 * s1) <= 0.0
        denom = s0 - s1
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(denom != 0.0, s0 / np.where(denom != 0.0, denom, 1.0), 0.0)
        pts = a0[None, :, :] + np.clip(u, 0.0, 1.0)[:, :, None] * step[None, :, :]
        d2 = np.where(crosses, np.sum((pts - r) ** 2, axis=2), np.inf)
        best = np.argmin(d2, axis=1)
        rows = np.arange(len(best))
        found = np.isfinite(d2[rows, best])
        out[lo:lo + chunk][found] = pts[rows, best][found]
    return out


def resample_arc_length(
    attained_m: ArrayLike, reference_m: ArrayLike, *, closed: bool = False
) -> FloatArray:
    """The attained path at the same fractions of its arc length as the reference points.

    Reference point ``i`` sits at fraction ``s_i / S`` of the reference length; the attained
    polyline (m, ``(k, 3)``, repeated samples dropped) is interpolated linearly at the same
    fraction of its own length. ``closed`` counts the closing segment in both lengths. Always
    defined, unlike :func:`resample_normal_planes`, but it pairs by progress, not by geometry.
    Returns shape ``(m, 3)`` (m).
    """
    ref = _reference(reference_m, closed)
    att = dedupe_consecutive(as_points(attained_m, "attained_m", min_count=2))
    if closed:
        ref = np.vstack([ref, ref[:1]])
        att = np.vstack([att, att[:1]])
    s_ref = cumulative_length(ref)
    s_att = cumulative_length(att)
    if s_att[-1] == 0.0:
        raise MetricsInputError("attained_m: the path does not move")
    f_ref = s_ref / s_ref[-1]
    f_att = s_att / s_att[-1]
    out = np.column_stack([np.interp(f_ref, f_att, att[:, k]) for k in range(3)])
    return out[:-1] if closed else out


def path_characteristics(
    attained_paths_m: Sequence[ArrayLike],
    reference_m: ArrayLike,
    *,
    method: PathMethod = "normal_planes",
    closed: bool = False,
) -> PathCharacteristics:
    """ISO 9283 §8.2 path accuracy AT and path repeatability RT (mm).

    ``attained_paths_m`` holds the ``n`` recorded paths (m), each ``(k_j, 3)``; ``reference_m``
    the commanded path sampled at the ``m`` points where the figures are evaluated (m, ``(m, 3)``).
    Each attained path is paired with the reference points by ``method``: ``"normal_planes"``
    (ISO; see :func:`resample_normal_planes`), ``"arc_length"`` (:func:`resample_arc_length`), or
    ``"corresponding"`` (each path already has shape ``(m, 3)``, row ``i`` belonging to reference
    point ``i``). Raises :class:`MetricsInputError` if a path misses a normal plane.
    """
    if len(attained_paths_m) < 1:
        raise MetricsInputError("attained_paths_m: needs at least one path")
    ref = _reference(reference_m, closed)
    paired = []
    for j, path in enumerate(attained_paths_m):
        if method == "normal_planes":
            p = resample_normal_planes(path, ref, closed=closed)
            missing = np.flatnonzero(np.isnan(p[:, 0]))
            if len(missing):
                raise MetricsInputError(
                    f"attained_paths_m[{j}]: does not cross the normal plane at reference points "
                    f"{missing[:10].tolist()}; use method='arc_length'"
                )
        elif method == "arc_length":
            p = resample_arc_length(path, ref, closed=closed)
        elif method == "corresponding":
            p = as_points(path, f"attained_paths_m[{j}]")
            if p.shape != ref.shape:
                raise MetricsInputError(
                    f"attained_paths_m[{j}]: shape {p.shape}, expected {ref.shape} (one row per "
                    "reference point)"
                )
        else:
            raise MetricsInputError(f"method: unknown {method!r}")
        paired.append(p)
    pts = np.stack(paired)  # (n, m, 3)
    bary = _barycentre(pts)  # (m, 3)
    accuracy = np.linalg.norm(bary - ref, axis=1) * MM_PER_M
    at_index = int(np.argmax(accuracy))
    rt_mm: float | None = None
    rt_index: int | None = None
    repeat: FloatArray | None = None
    if len(pts) >= 2:
        dist = np.linalg.norm(pts - bary[None, :, :], axis=2) * MM_PER_M  # (n, m)
        mean, s = _mean_and_std(dist, axis=0)
        repeat = mean + 3.0 * s
        rt_index = int(np.argmax(repeat))
        rt_mm = float(repeat[rt_index])
    return PathCharacteristics(
        at_mm=float(accuracy[at_index]),
        at_index=at_index,
        rt_mm=rt_mm,
        rt_index=rt_index,
        accuracy_mm=accuracy,
        repeatability_mm=repeat,
        barycentres_m=bary,
        n=len(pts),
        method=method,
    )
