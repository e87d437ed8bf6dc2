"""armbench.metrics: ISO 9283 figures and the paper's path errors.

Three kinds of check: values worked out by hand (in the comments), a second, plain computation
(loops, ``statistics``, ``math.dist``) over random data, and geometric invariances. Positions are
given to the metrics in metres; hand values are in millimetres, hence the ``MM`` factor.
"""

from __future__ import annotations

import math
import statistics

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armbench.metrics import (
    CUBE_PLANES,
    POSE_CORNERS,
    MetricsInputError,
    cube_corners,
    distance_characteristics,
    error_summary,
    iso_cube_poses,
    multidirectional_variation,
    path_characteristics,
    path_errors,
    point_segment_distances,
    pose_accuracy,
    pose_repeatability,
    project_to_polyline,
    resample_arc_length,
    resample_normal_planes,
    sample_polyline,
    square_yz,
    tracking_errors,
)

MM = 1e-3  # metres per millimetre: hand values are written in mm

Point = tuple[float, float, float]

coord = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False, allow_infinity=False)
point = st.tuples(coord, coord, coord)
# Scattered attained positions: a commanded point plus offsets up to 5 mm.
offset = st.floats(min_value=-5e-3, max_value=5e-3, allow_nan=False, allow_infinity=False)
offsets = st.lists(st.tuples(offset, offset, offset), min_size=2, max_size=30)


def mm(points: list[Point]) -> np.ndarray:
    """Millimetre coordinates as a metre array."""
    return np.array(points, dtype=float) * MM


# ---------------------------------------------------------------------------------------------
# Plain re-implementations (the "second computation"): lists, loops, statistics
# ---------------------------------------------------------------------------------------------


def plain_barycentre(pts: list[Point]) -> Point:
    return (
        statistics.fmean(p[0] for p in pts),
        statistics.fmean(p[1] for p in pts),
        statistics.fmean(p[2] for p in pts),
    )


def plain_ap(pts_mm: list[Point], cmd_mm: Point) -> tuple[float, float, float, float]:
    b = plain_barycentre(pts_mm)
    ax, ay, az = b[0] - cmd_mm[0], b[1] - cmd_mm[1], b[2] - cmd_mm[2]
    return ax, ay, az, math.sqrt(ax * ax + ay * ay + az * az)


def plain_rp(pts_mm: list[Point]) -> float:
    b = plain_barycentre(pts_mm)
    ls = [math.dist(p, b) for p in pts_mm]
    return statistics.fmean(ls) + 3 * statistics.stdev(ls)


def to_mm(pts_m: list[Point]) -> list[Point]:
    return [(p[0] * 1000, p[1] * 1000, p[2] * 1000) for p in pts_m]


# ---------------------------------------------------------------------------------------------
# Pose accuracy and repeatability (ISO 9283 §7.2)
# ---------------------------------------------------------------------------------------------


def test_pose_accuracy_and_repeatability_by_hand() -> None:
    # Attained (mm): (1,0,0) (-1,0,0) (0,3,0) (0,-3,0); commanded (0.5, 0, -1).
    # Barycentre (0,0,0), so AP = (0-0.5, 0-0, 0-(-1)) = (-0.5, 0, 1), APp = sqrt(1.25) = 1.1180.
    # l_j = 1, 1, 3, 3: l_mean = 2; deviations -1,-1,1,1: sum of squares 4, / (n-1) = 4/3,
    # S_l = 2/sqrt(3) = 1.1547; RP = 2 + 3 * 2/sqrt(3) = 2 + 2 sqrt(3) = 5.4641.
    pts = mm([(1, 0, 0), (-1, 0, 0), (0, 3, 0), (0, -3, 0)])
    ap = pose_accuracy(pts, mm([(0.5, 0, -1)])[0])
    assert (ap.ap_x_mm, ap.ap_y_mm, ap.ap_z_mm) == pytest.approx((-0.5, 0.0, 1.0), abs=1e-12)
    assert ap.ap_p_mm == pytest.approx(math.sqrt(1.25))
    assert ap.barycentre_m == pytest.approx((0.0, 0.0, 0.0), abs=1e-15)
    assert ap.n == 4
    rp = pose_repeatability(pts)
    assert rp.l_mean_mm == pytest.approx(2.0)
    assert rp.s_l_mm == pytest.approx(2 / math.sqrt(3))
    assert rp.rp_mm == pytest.approx(2 + 2 * math.sqrt(3))
    assert rp.n == 4


def test_pose_repeatability_of_points_on_a_sphere_is_its_radius() -> None:
    # Attained (mm): (3,1,0) (1,1,0) (2,2,0) (2,0,0): barycentre (2,1,0), every l_j = 1, S_l = 0,
    # so RP = 1. Commanded (0,0,0): AP = (2,1,0), APp = sqrt(5).
    pts = mm([(3, 1, 0), (1, 1, 0), (2, 2, 0), (2, 0, 0)])
    assert pose_repeatability(pts).rp_mm == pytest.approx(1.0)
    assert pose_accuracy(pts, (0, 0, 0)).ap_p_mm == pytest.approx(math.sqrt(5))


@settings(max_examples=60, deadline=None)
@given(cmd=point, offs=offsets)
def test_pose_figures_match_a_plain_computation(cmd: Point, offs: list[Point]) -> None:
    pts_m = [(cmd[0] + o[0], cmd[1] + o[1], cmd[2] + o[2]) for o in offs]
    ax, ay, az, ap = plain_ap(to_mm(pts_m), to_mm([cmd])[0])
    got = pose_accuracy(pts_m, cmd)
    assert (got.ap_x_mm, got.ap_y_mm, got.ap_z_mm) == pytest.approx((ax, ay, az), abs=1e-8)
    assert got.ap_p_mm == pytest.approx(ap, abs=1e-8)
    assert pose_repeatability(pts_m).rp_mm == pytest.approx(plain_rp(to_mm(pts_m)), abs=1e-8)


@settings(max_examples=40, deadline=None)
@given(cmd=point, offs=offsets, shift=point)
def test_translation_moves_ap_and_leaves_rp(cmd: Point, offs: list[Point], shift: Point) -> None:
    pts = np.array(cmd) + np.array(offs)
    t = np.array(shift)
    before = pose_accuracy(pts, cmd)
    # Attained and commanded moved together: nothing changes.
    both = pose_accuracy(pts + t, np.array(cmd) + t)
    assert (both.ap_x_mm, both.ap_y_mm, both.ap_z_mm) == pytest.approx(
        (before.ap_x_mm, before.ap_y_mm, before.ap_z_mm), abs=1e-8)
    # Only the attained positions moved: AP shifts by the translation (in mm), RP stays.
    moved = pose_accuracy(pts + t, cmd)
    assert (moved.ap_x_mm, moved.ap_y_mm, moved.ap_z_mm) == pytest.approx(
        (before.ap_x_mm + t[0] * 1000, before.ap_y_mm + t[1] * 1000,
         before.ap_z_mm + t[2] * 1000), abs=1e-7)
    assert pose_repeatability(pts + t).rp_mm == pytest.approx(
        pose_repeatability(pts).rp_mm, abs=1e-8)


@settings(max_examples=60, deadline=None)
@given(pos=point, n=st.integers(min_value=2, max_value=60))
def test_one_position_attained_every_time_has_rp_exactly_zero(pos: Point, n: int) -> None:
    """An arm that rests on the same encoder counts reports the same position each cycle: RP and
    vAP are 0, not the rounding of a mean (2.2e-13 mm before)."""
    pts = np.tile(np.array(pos), (n, 1))
    assert pose_repeatability(pts).rp_mm == 0.0
    assert multidirectional_variation([pts, pts[:2]]).vap_p_mm == 0.0
    assert pose_accuracy(pts, pos).ap_p_mm == 0.0


@settings(max_examples=30, deadline=None)
@given(offs=offsets, angle=st.floats(min_value=-math.pi, max_value=math.pi))
def test_rotation_leaves_app_and_rp(offs: list[Point], angle: float) -> None:
    c, s = math.cos(angle), math.sin(angle)
    r = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    pts = np.array(offs) + 0.3
    cmd = np.array([0.3, 0.3, 0.3])
    assert pose_accuracy(pts @ r.T, r @ cmd).ap_p_mm == pytest.approx(
        pose_accuracy(pts, cmd).ap_p_mm, abs=1e-8)
    assert pose_repeatability(pts @ r.T).rp_mm == pytest.approx(
        pose_repeatability(pts).rp_mm, abs=1e-8)


def test_pose_inputs_are_checked() -> None:
    with pytest.raises(MetricsInputError, match="at least 2"):
        pose_repeatability([(0.0, 0.0, 0.0)])
    with pytest.raises(MetricsInputError, match=r"shape \(n, 3\)"):
        pose_accuracy([(0.0, 0.0)], (0, 0, 0))
    with pytest.raises(MetricsInputError, match="non-finite"):
        pose_accuracy([(0.0, math.nan, 0.0)], (0, 0, 0))
    with pytest.raises(ValueError):  # MetricsInputError is a ValueError too
        pose_accuracy([(0.0, 0.0, 0.0)], (0, 0))


# ---------------------------------------------------------------------------------------------
# Multi-directional variation (§7.3) and distance characteristics (§7.4)
# ---------------------------------------------------------------------------------------------


def test_multidirectional_variation_by_hand() -> None:
    # Barycentres (mm) per direction: (0,0,0), (3,0,0), (0,4,0) (each from two points around it).
    # Distances: 3, 4, 5 -> vAPp = 5; per axis: x 3, y 4, z 0.
    dirs = [
        mm([(-1, 0, 0), (1, 0, 0)]),
        mm([(3, -1, 0), (3, 1, 0)]),
        mm([(0, 4, -2), (0, 4, 2)]),
    ]
    v = multidirectional_variation(dirs)
    assert v.vap_p_mm == pytest.approx(5.0)
    assert (v.vap_x_mm, v.vap_y_mm, v.vap_z_mm) == pytest.approx((3.0, 4.0, 0.0))
    assert v.barycentres_m[1] == pytest.approx((3 * MM, 0.0, 0.0))
    with pytest.raises(MetricsInputError, match="2 approach"):
        multidirectional_variation(dirs[:1])


@settings(max_examples=30, deadline=None)
@given(st.lists(offsets, min_size=2, max_size=4))
def test_multidirectional_variation_matches_a_plain_computation(
        groups: list[list[Point]]) -> None:
    barys = [plain_barycentre(to_mm(g)) for g in groups]
    worst = 0.0
    for h in barys:
        for k in barys:
            worst = max(worst, math.dist(h, k))
    assert multidirectional_variation(groups).vap_p_mm == pytest.approx(worst, abs=1e-9)


def test_distance_characteristics_by_hand() -> None:
    # Pose 1 always at the origin, pose 2 at x = 100, 101, 102 mm; commanded 100.5 mm apart.
    # D_j = 100, 101, 102: D_mean = 101, AD = 101 - 100.5 = 0.5; S_D = 1 (n-1), RD = 3 * 1 = 3.
    # Along y and z both distances are 0, so AD = RD = 0 there; along x same as the total.
    p1 = mm([(0, 0, 0)] * 3)
    p2 = mm([(100, 0, 0), (101, 0, 0), (102, 0, 0)])
    d = distance_characteristics(p1, p2, (0, 0, 0), (100.5 * MM, 0, 0))
    assert d.ad_p_mm == pytest.approx(0.5)
    assert d.rd_p_mm == pytest.approx(3.0)
    assert d.mean_distance_mm == pytest.approx(101.0)
    assert d.commanded_distance_mm == pytest.approx(100.5)
    assert (d.ad_x_mm, d.ad_y_mm, d.ad_z_mm) == pytest.approx((0.5, 0.0, 0.0), abs=1e-9)
    assert (d.rd_x_mm, d.rd_y_mm, d.rd_z_mm) == pytest.approx((3.0, 0.0, 0.0), abs=1e-9)
    assert d.n == 3
    with pytest.raises(MetricsInputError, match="one row per cycle"):
        distance_characteristics(p1, p2[:2], (0, 0, 0), (0.1, 0, 0))


@settings(max_examples=40, deadline=None)
@given(c1=point, c2=point, o1=offsets, o2=offsets)
def test_distance_characteristics_match_a_plain_computation(
        c1: Point, c2: Point, o1: list[Point], o2: list[Point]) -> None:
    n = min(len(o1), len(o2))
    a = [(c1[0] + o[0], c1[1] + o[1], c1[2] + o[2]) for o in o1[:n]]
    b = [(c2[0] + o[0], c2[1] + o[1], c2[2] + o[2]) for o in o2[:n]]
    dists = [math.dist(p, q) * 1000 for p, q in zip(a, b, strict=True)]
    dx = [abs(p[0] - q[0]) * 1000 for p, q in zip(a, b, strict=True)]
    got = distance_characteristics(a, b, c1, c2)
    assert got.ad_p_mm == pytest.approx(statistics.fmean(dists) - math.dist(c1, c2) * 1000,
                                        abs=1e-8)
    assert got.rd_p_mm == pytest.approx(3 * statistics.stdev(dists), abs=1e-8)
    assert got.ad_x_mm == pytest.approx(statistics.fmean(dx) - abs(c1[0] - c2[0]) * 1000,
                                        abs=1e-8)
    assert got.rd_x_mm == pytest.approx(3 * statistics.stdev(dx), abs=1e-8)


# ---------------------------------------------------------------------------------------------
# Test cube and its poses (§6)
# ---------------------------------------------------------------------------------------------


def test_cube_corners_follow_the_documented_numbering() -> None:
    c = cube_corners((1.0, 2.0, 3.0), 0.2)
    assert c[0] == pytest.approx((0.9, 1.9, 2.9))  # C1: (-, -, -)
    assert c[1] == pytest.approx((1.1, 1.9, 2.9))  # C2: (+, -, -)
    assert c[2] == pytest.approx((1.1, 2.1, 2.9))  # C3: (+, +, -)
    assert c[3] == pytest.approx((0.9, 2.1, 2.9))  # C4: (-, +, -)
    assert c[4:] == pytest.approx(c[:4] + np.array([0.0, 0.0, 0.2]))  # C5..C8 above C1..C4


@pytest.mark.parametrize("plane", sorted(CUBE_PLANES))
@pytest.mark.parametrize("rotated", [False, True])
def test_cube_poses_lie_in_the_diagonal_plane_at_ten_percent(plane: str, rotated: bool) -> None:
    centre, side = np.array([0.4, -0.1, 0.35]), 0.25
    rot = None
    if rotated:  # cube turned 30 degrees about z, then 10 about x
        a, b = math.radians(30), math.radians(10)
        rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
        rx = np.array([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]])
        rot = rx @ rz
    corners = cube_corners(centre, side, rot)
    poses = iso_cube_poses(centre, side, plane, rotation=rot)
    assert poses.shape == (5, 3)
    assert poses[0] == pytest.approx(centre)  # P1 at the centre
    ca, cb, cc, cd = (corners[i - 1] for i in CUBE_PLANES[plane])
    # The plane holds two opposite parallel edges: a-b and c-d are cube edges, parallel, and
    # sqrt(2) * side apart (a face diagonal).
    assert np.linalg.norm(cb - ca) == pytest.approx(side)
    assert np.cross(cb - ca, cd - cc) == pytest.approx(np.zeros(3), abs=1e-12)
    assert np.linalg.norm(cd - ca) == pytest.approx(side * math.sqrt(2))
    normal = np.cross(cb - ca, cd - ca)
    normal /= np.linalg.norm(normal)
    assert (poses - ca) @ normal == pytest.approx(np.zeros(5), abs=1e-12)
    diagonal = side * math.sqrt(3)
    for k, name in enumerate(POSE_CORNERS[plane], start=1):
        corner = corners[int(name[1:]) - 1]
        opposite = 2 * centre - corner
        assert name in plane.split("-")
        assert np.linalg.norm(poses[k] - corner) == pytest.approx(0.1 * diagonal)
        # On the diagonal from the corner to the opposite corner.
        assert np.cross(poses[k] - corner, opposite - corner) == pytest.approx(
            np.zeros(3), abs=1e-12)
    # P2/P4 and P3/P5 are symmetric about the centre (on the same diagonal).
    assert poses[1] + poses[3] == pytest.approx(2 * centre)
    assert poses[2] + poses[4] == pytest.approx(2 * centre)


def test_default_plane_pose_corners() -> None:
    assert POSE_CORNERS["C1-C2-C7-C8"] == ("C2", "C7", "C8", "C1")
    p = iso_cube_poses((0, 0, 0), 1.0, fraction=0.12)
    # P2 near C2 = (+0.5, -0.5, -0.5): C2 + 0.24 * (centre - C2).
    assert p[1] == pytest.approx((0.5 * 0.76, -0.5 * 0.76, -0.5 * 0.76))
    with pytest.raises(MetricsInputError, match="plane"):
        iso_cube_poses((0, 0, 0), 1.0, "C1-C2-C3-C4")
    with pytest.raises(MetricsInputError, match="fraction"):
        iso_cube_poses((0, 0, 0), 1.0, fraction=0.6)
    with pytest.raises(MetricsInputError, match="orthonormal"):
        cube_corners((0, 0, 0), 1.0, np.eye(3) * 2)


# ---------------------------------------------------------------------------------------------
# Path accuracy and repeatability (§8.2)
# ---------------------------------------------------------------------------------------------


def test_path_accuracy_and_repeatability_by_hand() -> None:
    # Reference: x = 0, 1, 2 mm on the x axis. Path 1 runs 1 mm above it (y = +1), path 2 at y = +3.
    # In every normal plane (x = const) the attained points are y = 1 and y = 3: barycentre y = 2,
    # so AT = 2 mm; l = 1 and 1 around it, S = 0, so RT = 1 mm.
    ref = mm([(0, 0, 0), (1, 0, 0), (2, 0, 0)])
    p1 = mm([(-1, 1, 0), (3, 1, 0)])  # two samples; the planes cut the segment between them
    p2 = mm([(-1, 3, 0), (0.5, 3, 0), (3, 3, 0)])
    r = path_characteristics([p1, p2], ref)
    assert r.method == "normal_planes"
    assert r.at_mm == pytest.approx(2.0)
    assert r.rt_mm == pytest.approx(1.0)
    assert r.accuracy_mm == pytest.approx([2.0, 2.0, 2.0])
    assert r.barycentres_m[:, 0] == pytest.approx(ref[:, 0])
    assert r.barycentres_m[:, 1] == pytest.approx([2 * MM] * 3)
    assert r.n == 2
    up = np.array([0.0, MM, 0.0])
    corr = path_characteristics([ref + up, ref + 3 * up], ref, method="corresponding")
    assert (corr.at_mm, corr.rt_mm) == pytest.approx((2.0, 1.0))
    single = path_characteristics([p1], ref)
    assert single.at_mm == pytest.approx(1.0)
    assert single.rt_mm is None and single.repeatability_mm is None


@settings(max_examples=40, deadline=None)
@given(st.lists(st.lists(st.tuples(offset, offset, offset), min_size=4, max_size=4),
                min_size=2, max_size=6))
def test_path_figures_match_a_plain_computation(offs: list[list[Point]]) -> None:
    ref = [(0.1 * i, 0.05, 0.3) for i in range(4)]
    paths = [[(r[0] + o[0], r[1] + o[1], r[2] + o[2]) for r, o in zip(ref, path, strict=True)]
             for path in offs]
    at, rt = 0.0, 0.0
    for i in range(len(ref)):
        pts = to_mm([path[i] for path in paths])
        b = plain_barycentre(pts)
        at = max(at, math.dist(b, to_mm([ref[i]])[0]))
        rt = max(rt, plain_rp(pts))
    got = path_characteristics(paths, ref, method="corresponding")
    assert got.at_mm == pytest.approx(at, abs=1e-8)
    assert got.rt_mm == pytest.approx(rt, abs=1e-8)


def test_normal_planes_on_a_square_find_the_offset_path() -> None:
    # Reference: square of side 100 mm sampled every 5 mm. Attained: the square grown to 102 mm
    # (every side 1 mm further out), sampled every 0.7 mm from another start. Normal planes on
    # the sides meet it 1 mm out; at a corner the bisector plane meets its corner, sqrt(2) mm out.
    centre = np.array([0.45, 0.0, 0.5])
    corners = square_yz(centre, 0.100)
    ref = sample_polyline(corners, 0.005)
    grown = np.roll(sample_polyline(square_yz(centre, 0.102), 0.0007), 37, axis=0)
    got = resample_normal_planes(grown, ref, closed=True)
    err = np.linalg.norm(got - ref, axis=1) / MM
    is_corner = np.array([any(np.allclose(r, c) for c in corners) for r in ref])
    assert err[~is_corner] == pytest.approx(1.0)
    assert err[is_corner] == pytest.approx(math.sqrt(2))
    r = path_characteristics([grown], ref, closed=True)
    assert r.at_mm == pytest.approx(math.sqrt(2))
    assert is_corner[r.at_index]
    # Arc length: the grown square is the reference scaled about the centre by 1.02, so equal
    # fractions of length land on the scaled reference points (same start needed: no roll).
    grown0 = sample_polyline(square_yz(centre, 0.102), 0.0007)
    arc = resample_arc_length(grown0, ref, closed=True)
    assert arc == pytest.approx(centre + 1.02 * (ref - centre), abs=1e-12)


def test_a_path_that_misses_a_normal_plane_is_reported() -> None:
    ref = mm([(0, 0, 0), (10, 0, 0), (20, 0, 0)])
    short = mm([(-1, 1, 0), (5, 1, 0)])  # never reaches x = 10 or x = 20
    assert np.isnan(resample_normal_planes(short, ref)[1:]).all()
    with pytest.raises(MetricsInputError, match=r"reference points \[1, 2\]"):
        path_characteristics([short], ref)
    with pytest.raises(MetricsInputError, match="coincide"):
        path_characteristics([short], mm([(0, 0, 0), (0, 0, 0)]))
    with pytest.raises(MetricsInputError, match="one row per"):
        path_characteristics([short], ref, method="corresponding")


# ---------------------------------------------------------------------------------------------
# Paper-style path errors (path.py)
# ---------------------------------------------------------------------------------------------


def test_square_yz_corners() -> None:
    sq = square_yz((0.4, 0.1, 0.5), 0.2)
    assert sq == pytest.approx(
        np.array([(0.4, 0.0, 0.4), (0.4, 0.2, 0.4), (0.4, 0.2, 0.6), (0.4, 0.0, 0.6)]))
    dense = sample_polyline(sq, 0.03)
    assert dense[:, 0] == pytest.approx(np.full(len(dense), 0.4))
    assert len(dense) == 4 * 7  # 0.2 / 0.03 -> 7 pieces per side, first vertex not repeated
    assert len(sample_polyline(sq, 0.03, closed=False)) == 3 * 7 + 1


@settings(max_examples=40, deadline=None)
@given(
    verts=st.lists(point, min_size=2, max_size=5),
    pts=st.lists(point, min_size=1, max_size=5),
    closed=st.booleans(),
)
def test_point_to_polyline_against_dense_sampling(
        verts: list[Point], pts: list[Point], closed: bool) -> None:
    v = np.array(verts)
    proj = project_to_polyline(pts, v, closed=closed)
    samples = 4001
    ends = np.roll(v, -1, axis=0) if closed else v[1:]
    starts = v if closed else v[:-1]
    u = np.linspace(0.0, 1.0, samples)[:, None, None]
    dense = (starts + u * (ends - starts)).reshape(-1, 3)
    brute = np.array([np.min(np.linalg.norm(dense - p, axis=1)) for p in np.array(pts)])
    step = float(np.max(np.linalg.norm(ends - starts, axis=1))) / (samples - 1)
    assert np.all(proj.distance_m <= brute + 1e-12)
    assert np.all(brute - proj.distance_m <= step / 2 + 1e-12)
    # The reported closest point is on the reported segment and at the reported distance.
    assert np.linalg.norm(np.array(pts) - proj.closest_m, axis=1) == pytest.approx(
        proj.distance_m, abs=1e-12)
    seg = point_segment_distances(proj.closest_m, starts[proj.segment], ends[proj.segment])
    assert np.diag(seg) == pytest.approx(np.zeros(len(pts)), abs=1e-9)


def test_point_segment_distances_by_hand() -> None:
    # Segment (0,0,0)-(2,0,0). (1,1,0): foot inside, distance 1. (3,0,4): past the end, distance
    # to (2,0,0) = sqrt(1 + 16). (-3,4,0): before the start, 5. Degenerate segment at (0,0,1):
    # plain point distance.
    d = point_segment_distances([(1, 1, 0), (3, 0, 4), (-3, 4, 0)],
                                [(0, 0, 0), (0, 0, 1)], [(2, 0, 0), (0, 0, 1)])
    assert d[:, 0] == pytest.approx([1.0, math.sqrt(17), 5.0])
    assert d[:, 1] == pytest.approx([math.sqrt(3), math.sqrt(9 + 9), math.sqrt(25 + 1)])


def test_path_errors_of_points_inside_the_square() -> None:
    # Square of side 100 mm; points 1 mm inside each side, away from the corners, and 2 mm in
    # front of the plane (x + 2 mm) on the bottom side: distances 1, 1, 1, 1, sqrt(1 + 4).
    c = np.array([0.4, 0.0, 0.5])
    sq = square_yz(c, 0.1)
    pts = c + mm([(0, 0, -49), (0, 49, 10), (0, -20, 49), (0, -49, -30), (2, 5, -49)])
    e = path_errors(pts, sq, times_s=[0.0, 0.1, 0.2, 0.3, 0.4])
    assert e.euclidean_mm == pytest.approx([1, 1, 1, 1, math.sqrt(5)])
    assert e.error_mm[0] == pytest.approx((0.0, 0.0, 1.0), abs=1e-9)  # above the bottom side
    assert e.error_mm[1] == pytest.approx((0.0, -1.0, 0.0), abs=1e-9)  # left of the right side
    assert e.times_s is not None and e.times_s[-1] == pytest.approx(0.4)
    s = error_summary(e)
    assert s.mean_mm == pytest.approx((4 + math.sqrt(5)) / 5)
    assert s.rms_mm == pytest.approx(math.sqrt((4 + 5) / 5))
    assert s.max_mm == pytest.approx(math.sqrt(5))
    assert (s.max_index, s.n) == (4, 5)
    assert s.x.max_abs_mm == pytest.approx(2.0)
    assert s.x.mean_mm == pytest.approx(0.4, abs=1e-9)
    with pytest.raises(MetricsInputError, match="times_s"):
        path_errors(pts, sq, times_s=[0.0])


def test_tracking_errors_and_summary_by_hand() -> None:
    # Errors (mm) against the commanded points of the same instants: (0,0,0) and (3,4,0).
    # Euclidean 0 and 5: mean 2.5, RMS sqrt(25/2), max 5 at sample 1.
    # x: 0 and 3 -> mean 1.5, RMS sqrt(9/2), max 3; y: 0 and 4; z: 0.
    cmd = mm([(10, 10, 10), (20, 20, 20)])
    att = cmd + mm([(0, 0, 0), (3, 4, 0)])
    s = error_summary(tracking_errors(att, cmd))
    assert (s.mean_mm, s.rms_mm, s.max_mm, s.max_index) == pytest.approx(
        (2.5, math.sqrt(12.5), 5.0, 1))
    assert (s.x.mean_mm, s.x.mean_abs_mm, s.x.rms_mm, s.x.max_abs_mm) == pytest.approx(
        (1.5, 1.5, math.sqrt(4.5), 3.0))
    assert (s.y.mean_mm, s.y.max_abs_mm) == pytest.approx((2.0, 4.0))
    assert s.z.rms_mm == pytest.approx(0.0, abs=1e-9)
    with pytest.raises(MetricsInputError, match="differ"):
        tracking_errors(att, cmd[:1])


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(offset, offset, offset), min_size=1, max_size=40))
def test_error_summary_matches_a_plain_computation(errs: list[Point]) -> None:
    cmd = np.zeros((len(errs), 3))
    s = error_summary(tracking_errors(np.array(errs), cmd))
    eu = [math.hypot(*e) * 1000 for e in errs]
    assert s.mean_mm == pytest.approx(statistics.fmean(eu), abs=1e-9)
    assert s.rms_mm == pytest.approx(math.sqrt(statistics.fmean(x * x for x in eu)), abs=1e-9)
    assert s.max_mm == pytest.approx(max(eu), abs=1e-9)
    zs = [e[2] * 1000 for e in errs]
    assert s.z.mean_mm == pytest.approx(statistics.fmean(zs), abs=1e-9)
    assert s.z.max_abs_mm == pytest.approx(max(abs(z) for z in zs), abs=1e-9)
