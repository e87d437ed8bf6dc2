"""Kinematics: FK against an independent library, IK round trips on every branch, errors."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.kinematics import (
    BRANCHES,
    IKSolution,
    JointLimitError,
    KinematicsError,
    UnreachableError,
    dh_to_protocol,
    fk,
    fk_dh,
    ik,
    ik_best,
    protocol_to_dh,
    tcp_point,
    tcp_position,
    wrap_protocol,
)
from armbench.drivers.model.settings import Geometry, RobotSettings

#: Forward kinematics of the paper's DH table computed by independent libraries (its "source"
#: says which), kept in the repository so that every checkout and CI run checks against it.
REFERENCE = Path(__file__).resolve().parent / "fixtures" / "reference" / "fk_vectors.json"
DEFAULT = RobotSettings()
TWO_PI = 2 * math.pi


def _wrapped(a: Any) -> np.ndarray:
    """Angles (or differences) folded into [-π, π)."""
    return np.remainder(np.asarray(a, dtype=float) + math.pi, TWO_PI) - math.pi


def _naive_fk(theta: Any, g: Geometry) -> np.ndarray:
    """Eq. (1) of the paper, matrix by matrix, with np.cos/np.sin of α: an independent oracle."""
    table = [(0.0, math.pi / 2, g.d1_m), (g.a2_m, 0.0, g.d2_m), (g.a3_m, math.pi / 2, 0.0),
             (0.0, 0.0, g.d4_m)]
    t = np.eye(4)
    for th, (a, al, d) in zip(theta, table, strict=True):
        ct, s_t, ca, sa = math.cos(th), math.sin(th), math.cos(al), math.sin(al)
        t = t @ np.array([[ct, -s_t * ca, s_t * sa, a * ct],
                          [s_t, ct * ca, -ct * sa, a * s_t],
                          [0.0, sa, ca, d],
                          [0.0, 0.0, 0.0, 1.0]])
    return t


def _wide_limits(s: RobotSettings) -> RobotSettings:
    joints = tuple(replace(j, lower_rad=math.radians(-179), upper_rad=math.radians(179))
                   for j in s.joints)
    return replace(s, joints=joints)


# ---------------------------------------------------------------------------------- FK


def _reference_cases() -> list[Any]:
    data = json.loads(REFERENCE.read_text())
    return [pytest.param(c, id=f"q={c['q_rad']}-d4={c['d4']}") for c in data["cases"]]


@pytest.mark.parametrize("case", _reference_cases())
def test_fk_matches_independent_library(case: dict[str, Any]) -> None:
    data = json.loads(REFERENCE.read_text())
    dh = data["dh"]
    geometry = Geometry(d1_m=dh["d1"], d2_m=dh["d2"], a2_m=dh["a2"], a3_m=dh["a3"],
                        d4_m=case["d4"])
    got = fk_dh(case["q_rad"], geometry)
    assert got.shape == (4, 4)
    np.testing.assert_allclose(got, np.array(case["T"]), rtol=0, atol=1e-9)


def test_reference_file_covers_two_gripper_offsets() -> None:
    cases = json.loads(REFERENCE.read_text())["cases"]
    assert len(cases) == 10
    assert len({c["d4"] for c in cases}) == 2


def test_fk_matches_naive_product_on_odd_geometry() -> None:
    rng = np.random.default_rng(7)
    g = Geometry(d1_m=0.2, d2_m=-0.05, a2_m=0.3, a3_m=0.45, d4_m=-0.08)
    theta = rng.uniform(-4, 4, (50, 4))
    got = fk_dh(theta, g)
    for row, pose in zip(theta, got, strict=True):
        np.testing.assert_allclose(pose, _naive_fk(row, g), rtol=0, atol=1e-12)


def test_vectorised_fk_equals_per_row() -> None:
    rng = np.random.default_rng(1)
    theta = rng.uniform(-math.pi, math.pi, (200, 4))
    g = Geometry(d4_m=0.1)
    batch = fk_dh(theta, g)
    assert batch.shape == (200, 4, 4)
    for row, pose in zip(theta, batch, strict=True):
        np.testing.assert_array_equal(pose, fk_dh(row, g))
    nested = fk_dh(theta.reshape(10, 20, 4), g)
    assert nested.shape == (10, 20, 4, 4)
    np.testing.assert_array_equal(nested.reshape(200, 4, 4), batch)
    q = dh_to_protocol(theta, DEFAULT)
    np.testing.assert_allclose(tcp_position(q, DEFAULT.with_d4(0.1)), batch[:, :3, 3], atol=1e-15)


@given(st.lists(st.floats(-10, 10), min_size=4, max_size=4), st.booleans(),
       st.floats(-0.2, 0.2))
@settings(max_examples=300, deadline=None)
def test_one_pose_equals_its_row_of_the_vectorised_fk(q: list[float], odd: bool,
                                                      d4: float) -> None:
    """One pose is chained in floats, a trajectory through the matrices: the same TCP within
    rounding, on the default and an odd joint mapping, with any gripper offset."""
    s = (_odd_mapping() if odd else DEFAULT).with_d4(d4)
    batch = tcp_position(np.array([q, q]), s)
    one = tcp_position(q, s)
    assert one.shape == (3,)
    np.testing.assert_allclose(one, batch[0], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(one, tcp_point(q, s))
    np.testing.assert_allclose(one, fk(q, s)[:3, 3], rtol=0, atol=1e-12)


@pytest.mark.parametrize("bad", [[0.0, 0.0, 0.0], 1.0, [[0.0] * 5]])
def test_tcp_position_rejects_wrong_shapes(bad: Any) -> None:
    with pytest.raises(KinematicsError, match="shape"):
        tcp_position(bad, DEFAULT)


def test_tcp_point_rejects_a_pose_of_other_than_four_joints() -> None:
    for q in ([0.0, 0.0, 0.0], [0.0] * 5):
        with pytest.raises(KinematicsError, match=f"4 joint angles, got {len(q)}"):
            tcp_point(q, DEFAULT)


def test_fk_is_rigid_and_position_ignores_joint4() -> None:
    rng = np.random.default_rng(2)
    theta = rng.uniform(-math.pi, math.pi, (100, 4))
    g = Geometry(d4_m=0.07)
    poses = fk_dh(theta, g)
    rot = poses[:, :3, :3]
    np.testing.assert_allclose(rot @ rot.transpose(0, 2, 1), np.broadcast_to(np.eye(3), rot.shape),
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-12)
    np.testing.assert_array_equal(poses[:, 3], np.broadcast_to([0, 0, 0, 1], (100, 4)))
    turned = theta.copy()
    turned[:, 3] += rng.uniform(-3, 3, 100)
    np.testing.assert_allclose(fk_dh(turned, g)[:, :3, 3], poses[:, :3, 3], atol=1e-12)


@pytest.mark.parametrize("bad", [[0.0, 0.0, 0.0], 1.0, [[0.0] * 5]])
def test_fk_rejects_wrong_shapes(bad: Any) -> None:
    with pytest.raises(KinematicsError, match="shape"):
        fk_dh(bad, Geometry())


def test_protocol_zero_is_arm_straight_up_tool_forward() -> None:
    """Default offsets (0, 90°, 0, 0): at protocol zero links a2, a3 point up (z0) and the tool
    axis z4 points to the front (x0), so a gripper offset moves the TCP forwards."""
    s = DEFAULT.with_d4(0.1)
    pose = fk([0, 0, 0, 0], s)
    g = s.geometry
    np.testing.assert_allclose(pose[:3, 3], [g.d4_m, -g.d2_m, g.d1_m + g.a2_m + g.a3_m],
                               atol=1e-15)
    np.testing.assert_allclose(pose[:3, 2], [1, 0, 0], atol=1e-15)


# ---------------------------------------------------------------------- protocol ↔ DH


def _odd_mapping() -> RobotSettings:
    joints = tuple(replace(j, sign=sgn, offset_rad=off) for j, sgn, off in
                   zip(DEFAULT.joints, (-1, 1, -1, 1), (0.3, math.pi / 2, -1.1, 2.0), strict=True))
    return replace(DEFAULT, joints=joints)


@given(st.lists(st.floats(-10, 10), min_size=4, max_size=4), st.booleans())
@settings(max_examples=200, deadline=None)
def test_protocol_dh_round_trip(q: list[float], odd: bool) -> None:
    s = _odd_mapping() if odd else DEFAULT
    theta = protocol_to_dh(q, s)
    expected = [j.to_dh(v) for j, v in zip(s.joints, q, strict=True)]
    np.testing.assert_allclose(theta, expected, atol=1e-12)
    np.testing.assert_allclose(dh_to_protocol(theta, s), q, atol=1e-12)
    wrapped = wrap_protocol(q, s)
    mids = np.array([(j.lower_rad + j.upper_rad) / 2 for j in s.joints])
    assert np.all(wrapped > mids - math.pi - 1e-12)
    assert np.all(wrapped <= mids + math.pi + 1e-12)
    np.testing.assert_allclose(_wrapped(wrapped - np.asarray(q)), 0, atol=1e-9)


def test_default_mapping_and_vectorised_conversion() -> None:
    np.testing.assert_array_equal(protocol_to_dh([0, 0, 0, 0], DEFAULT), [0, math.pi / 2, 0, 0])
    q = np.random.default_rng(3).uniform(-2, 2, (30, 4))
    s = _odd_mapping()
    np.testing.assert_allclose(dh_to_protocol(protocol_to_dh(q, s), s), q, atol=1e-12)
    inside = np.array([[j.lower_rad + 0.01 for j in s.joints], [j.upper_rad for j in s.joints]])
    np.testing.assert_array_equal(wrap_protocol(inside, s), inside)


# ---------------------------------------------------------------------------------- IK

GEOMETRIES = [
    Geometry(),
    Geometry(d4_m=0.12),
    Geometry(d4_m=-0.07),
    Geometry(d1_m=0.25, d2_m=-0.05, a2_m=0.3, a3_m=0.42, d4_m=0.2),
]


def _check_solutions(sols: tuple[IKSolution, ...], target: np.ndarray, s: RobotSettings) -> None:
    assert 1 <= len(sols) <= 4
    names = [x.branch for x in sols]
    assert len(set(names)) == len(names)
    assert [b for b in BRANCHES if b in names] == names  # BRANCHES order
    every = names + [a for x in sols for a in x.aliases]
    assert sorted(every) == sorted(BRANCHES)  # every branch is returned or aliased once
    theta = np.array([x.theta_dh for x in sols])
    np.testing.assert_allclose(fk_dh(theta, s.geometry)[:, :3, 3],
                               np.broadcast_to(target, (len(sols), 3)), rtol=0, atol=1e-9)
    for i in range(len(sols)):
        for k in range(i + 1, len(sols)):
            assert np.max(np.abs(_wrapped(theta[i] - theta[k]))) > 1e-9, (names[i], names[k])
    for x in sols:
        np.testing.assert_allclose(x.theta_dh, protocol_to_dh(x.q_protocol, s), atol=1e-12)
        out = [j.name for j, v in zip(s.joints, x.q_protocol, strict=True)
               if not j.lower_rad <= v <= j.upper_rad]
        assert list(x.violations) == out
        assert x.within_limits == (not out)
        for j, v in zip(s.joints, x.q_protocol, strict=True):  # in the window mid ± π
            mid = (j.lower_rad + j.upper_rad) / 2
            assert mid - math.pi - 1e-12 <= v <= mid + math.pi + 1e-12


def test_ik_round_trip_thousands_of_poses_all_branches() -> None:
    """6000 random joint vectors over four geometries; FK of every returned branch is checked in
    one vectorised call per geometry, the full per-solution checks run on a subsample."""
    rng = np.random.default_rng(12345)
    n = 1500
    checked = found = 0
    for g in GEOMETRIES:
        s = replace(DEFAULT, geometry=g)
        theta = rng.uniform(-math.pi, math.pi, (n, 4))
        targets = fk_dh(theta, g)[:, :3, 3]
        roll = dh_to_protocol(theta, s)[:, 3]
        link = math.hypot(g.a3_m, g.d4_m)
        elbow = theta[:, 2] + math.atan2(-g.d4_m, g.a3_m)           # θ3' of the derivation
        u = g.a2_m * np.cos(theta[:, 1]) + link * np.cos(theta[:, 1] + elbow)
        all_theta: list[tuple[float, ...]] = []
        owner: list[int] = []
        for k in range(n):
            sols = ik(targets[k], s, roll=float(roll[k]))
            if k % 25 == 0:
                _check_solutions(sols, targets[k], s)
            names = [x.branch for x in sols]
            assert len(set(names)) == len(names)
            all_theta.extend(x.theta_dh for x in sols)
            owner.extend([k] * len(sols))
            checked += 1
            if abs(math.sin(elbow[k])) < 1e-4 or abs(u[k]) < 1e-4:
                continue  # near a branch merge the generator is only found to ~1e-8 rad
            assert len(sols) == 4
            found += 1
        th = np.array(all_theta)
        idx = np.array(owner)
        np.testing.assert_allclose(fk_dh(th, g)[:, :3, 3], targets[idx], rtol=0, atol=1e-9)
        # roll: joint 4 of every solution is the generator's joint 4
        assert np.max(np.abs(_wrapped(th[:, 3] - theta[idx, 3]))) < 1e-12
        # the generating joint vector is among the solutions of its target
        dist = np.max(np.abs(_wrapped(th - theta[idx])), axis=1)
        best = np.full(n, np.inf)
        np.minimum.at(best, idx, dist)
        regular = (np.abs(np.sin(elbow)) >= 1e-4) & (np.abs(u) >= 1e-4)
        assert np.all(best[regular] < 1e-8), np.flatnonzero(regular & (best >= 1e-8))
        # solutions of one target are pairwise distinct (they are stored consecutively)
        for off in range(1, 4):
            first = np.flatnonzero(idx[off:] == idx[:-off])
            gap = np.max(np.abs(_wrapped(th[first] - th[first + off])), axis=1)
            assert np.all(gap > 1e-9)
    assert checked == 4 * n
    assert found > 0.98 * checked


@given(
    theta=st.lists(st.floats(-math.pi, math.pi), min_size=4, max_size=4),
    d1=st.floats(0.0, 0.5), d2=st.floats(-0.1, 0.1), a2=st.floats(0.05, 0.6),
    a3=st.floats(0.05, 0.6), d4=st.floats(-0.2, 0.2),
)
@settings(max_examples=300, deadline=None)
def test_ik_round_trip_random_geometry(theta: list[float], d1: float, d2: float, a2: float,
                                       a3: float, d4: float) -> None:
    g = Geometry(d1_m=d1, d2_m=d2, a2_m=a2, a3_m=a3, d4_m=d4)
    s = replace(DEFAULT, geometry=g)
    target = fk_dh(theta, g)[:3, 3]
    try:
        sols = ik(target, s)
    except UnreachableError as exc:  # only the shoulder singularity may refuse a reachable point
        assert exc.kind == "singular"
        return
    _check_solutions(sols, target, s)
    # the generator is recoverable unless it sits at a branch merge or on the shoulder axis
    link = math.hypot(a3, d4)
    elbow = theta[2] + math.atan2(-d4, a3)
    u = a2 * math.cos(theta[1]) + link * math.cos(theta[1] + elbow)
    r = math.hypot(u, a2 * math.sin(theta[1]) + link * math.sin(theta[1] + elbow))
    if min(abs(math.sin(elbow)), abs(u), r) < 1e-6:
        return
    th = np.array(theta)
    th[3] = s.joints[3].to_dh(0.0)
    dist = np.max(np.abs(_wrapped(np.array([x.theta_dh for x in sols]) - th)), axis=1)
    assert dist.min() < 1e-6


def test_ik_with_non_default_protocol_mapping() -> None:
    """Signs and offsets of the settings apply to every joint, roll included."""
    s = _wide_limits(_odd_mapping()).with_d4(0.06)
    rng = np.random.default_rng(11)
    q = rng.uniform(-2.5, 2.5, (200, 4))
    targets = tcp_position(q, s)
    for qk, target in zip(q, targets, strict=True):
        sols = ik(target, s, roll=float(qk[3]))
        _check_solutions(sols, target, s)
        np.testing.assert_allclose(tcp_position([x.q_protocol for x in sols], s),
                                   np.broadcast_to(target, (len(sols), 3)), atol=1e-9)
        assert all(math.isclose(x.q_protocol[3], qk[3], abs_tol=1e-12) for x in sols)
        assert all(math.isclose(x.theta_dh[3], s.joints[3].to_dh(qk[3]), abs_tol=1e-12)
                   for x in sols)
        dist = np.max(np.abs(_wrapped(np.array([x.q_protocol for x in sols]) - qk)), axis=1)
        assert dist.min() < 1e-8


def test_branch_meaning_front_back_and_elbow_up_down() -> None:
    """front: the TCP lies ahead of the shoulder along x1; up: the elbow is above the straight
    line from the shoulder axis to the TCP (world z)."""
    g = Geometry(d4_m=0.05)
    s = replace(DEFAULT, geometry=g)
    rng = np.random.default_rng(5)
    for target in fk_dh(rng.uniform(-math.pi, math.pi, (300, 4)), g)[:, :3, 3]:
        for x in ik(target, s):
            t1, t2 = x.theta_dh[0], x.theta_dh[1]
            x1 = np.array([math.cos(t1), math.sin(t1), 0.0])
            z1 = np.array([math.sin(t1), -math.cos(t1), 0.0])
            shoulder = np.array([0.0, 0.0, g.d1_m]) + g.d2_m * z1
            elbow = shoulder + g.a2_m * (math.cos(t2) * x1 + np.array([0, 0, math.sin(t2)]))
            h_p, h_e = float((target - shoulder) @ x1), float((elbow - shoulder) @ x1)
            if abs(h_p) < 1e-6:
                continue
            side, updown = x.branch.split("-")
            assert (h_p > 0) == (side == "front")
            line_z = shoulder[2] + (target[2] - shoulder[2]) * h_e / h_p
            assert (elbow[2] > line_z) == (updown == "up"), x.branch


def test_zero_pose_is_one_solution_with_all_branches_aliased() -> None:
    target = tcp_position([0, 0, 0, 0], DEFAULT)
    sols = ik(target, DEFAULT)
    assert len(sols) == 1
    assert sols[0].branch == "front-up"
    assert set(sols[0].aliases) == {"front-down", "back-up", "back-down"}
    np.testing.assert_allclose(sols[0].q_protocol, 0, atol=1e-12)
    assert sols[0].within_limits


def test_stretched_arm_merges_elbow_branches() -> None:
    target = tcp_position([0.4, -0.3, 0.0, 0.0], DEFAULT)
    sols = ik(target, DEFAULT)
    assert [x.branch for x in sols] == ["front-up", "back-up"]
    assert [x.aliases for x in sols] == [("front-down",), ("back-down",)]
    np.testing.assert_allclose(sols[0].q_protocol, [0.4, -0.3, 0, 0], atol=1e-7)


def test_target_on_base_axis_without_lateral_offset() -> None:
    s = replace(DEFAULT, geometry=Geometry(d2_m=0.0))
    sols = ik([0.0, 0.0, 0.7], s)
    _check_solutions(sols, np.array([0.0, 0.0, 0.7]), s)


def test_roll_is_joint4_and_wrapped_into_its_window() -> None:
    target = [0.35, 0.2, 0.6]
    for x in ik(target, DEFAULT, roll=TWO_PI + 0.1):
        assert math.isclose(x.q_protocol[3], 0.1, abs_tol=1e-12)
        assert math.isclose(x.theta_dh[3], 0.1, abs_tol=1e-12)
    with pytest.raises(KinematicsError, match="roll"):
        ik(target, DEFAULT, roll=math.nan)


def test_joint_exactly_at_limit_counts_as_inside() -> None:
    j2 = DEFAULT.joints[1]
    q = [0.2, j2.upper_rad, -0.4, 0.0]
    best = ik_best(tcp_position(q, DEFAULT), DEFAULT, near=q)
    assert best.within_limits
    assert best.q_protocol[1] <= j2.upper_rad
    np.testing.assert_allclose(best.q_protocol, q, atol=1e-9)


# ------------------------------------------------------------------------------ errors


@pytest.mark.parametrize(("target", "kind", "geometry"), [
    ([2.0, 0.0, 0.0], "beyond-reach", Geometry()),
    ([0.0, 0.0, 2.0], "offset-cylinder", Geometry()),
    ([0.003, 0.004, 0.8], "offset-cylinder", Geometry()),
    ([0.0, -0.009, 0.39], "too-close", Geometry()),
    ([0.02, -0.009, 0.42], "too-close", Geometry()),
    ([0.0, -0.009, 0.39], "singular", Geometry(d4_m=math.sqrt(0.36**2 - 0.27**2))),
    ([math.nan, 0.1, 0.1], "not-finite", Geometry()),
    ([0.1, math.inf, 0.1], "not-finite", Geometry()),
])
def test_unreachable_targets_raise(target: list[float], kind: str, geometry: Geometry) -> None:
    s = replace(DEFAULT, geometry=geometry)
    with pytest.raises(UnreachableError) as info:
        ik(target, s)
    err = info.value
    assert isinstance(err, ArmbenchError)
    assert isinstance(err, ValueError)
    assert err.kind == kind
    assert f"{target[0]:.6g}" in str(err) and f"{target[2]:.6g}" in str(err)
    with pytest.raises(UnreachableError):
        ik_best(target, s)


def test_just_outside_and_just_inside_reach() -> None:
    g = DEFAULT.geometry
    reach = g.a2_m + g.a3_m
    horizontal = math.sqrt(reach**2 + g.d2_m**2)
    assert ik([horizontal * (1 - 1e-9), 0.0, g.d1_m], DEFAULT)
    with pytest.raises(UnreachableError, match="beyond the reach"):
        ik([horizontal * (1 + 1e-9), 0.0, g.d1_m], DEFAULT)


def test_malformed_target() -> None:
    with pytest.raises(KinematicsError, match="shape"):
        ik([0.1, 0.2], DEFAULT)


# ----------------------------------------------------------------------------- ik_best


def test_ik_best_default_named_and_near() -> None:
    s = _wide_limits(DEFAULT)
    target = [0.4, -0.1, 0.6]
    sols = ik(target, s)
    assert len(sols) == 4 and all(x.within_limits for x in sols)
    assert ik_best(target, s).branch == "front-up"
    for x in sols:
        assert ik_best(target, s, branch=x.branch) == x
        near = np.asarray(x.q_protocol) + 0.05
        assert ik_best(target, s, near=near) == x
    # under the default limits only front-up is inside for this target
    assert ik_best(target, DEFAULT, near=sols[3].q_protocol).branch == "front-up"


def test_ik_best_named_branch_out_of_limits() -> None:
    with pytest.raises(JointLimitError) as info:
        ik_best([0.4, -0.1, 0.6], DEFAULT, branch="back-down")
    err = info.value
    assert err.branch == "back-down"
    assert err.joint in ("j1", "j2")
    assert str(err).count("back-down") >= 1


def test_ik_best_names_joint_value_and_limit() -> None:
    target = [0.5, 0.1, 0.4]  # reachable, but every branch violates a limit of the default model
    assert not any(x.within_limits for x in ik(target, DEFAULT))
    with pytest.raises(JointLimitError) as info:
        ik_best(target, DEFAULT)
    err = info.value
    assert isinstance(err, ArmbenchError) and isinstance(err, ValueError)
    assert (err.branch, err.joint, err.bound) == ("front-up", "j2", "lower")
    assert math.isclose(err.limit_rad, math.radians(-45))
    assert err.value_rad < err.limit_rad
    assert "j2" in str(err) and "-45.00°" in str(err) and "(0.5, 0.1, 0.4)" in str(err)


def test_ik_best_bad_arguments() -> None:
    with pytest.raises(KinematicsError, match="branch"):
        ik_best([0.4, -0.1, 0.6], DEFAULT, branch="left-up")
    with pytest.raises(KinematicsError, match="near"):
        ik_best([0.4, -0.1, 0.6], DEFAULT, near=[0.0, math.nan, 0.0, 0.0])


def test_ik_best_with_aliased_branch() -> None:
    target = tcp_position([0.0, 0.0, 0.0, 0.0], DEFAULT)
    assert ik_best(target, DEFAULT, branch="back-down").branch == "front-up"
