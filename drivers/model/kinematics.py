"""Forward and closed-form inverse kinematics of the RoboLink 4-DoF arm (standard DH, Table 1).

Conventions (derivation and the paper's errata in ``docs/kinematics.md``):

* Standard DH, ``A_i = Rz(θ_i)·Tz(d_i)·Tx(a_i)·Rx(α_i)`` and ``T = A1·A2·A3·A4`` with
  ``(a, α, d) = (0, 90°, d1), (a2, 0, d2), (a3, 90°, 0), (0, 0, d4)``. Lengths are metres,
  angles radians.
* *DH angles* ``theta`` are the θ_i of that table; *protocol angles* ``q`` are what the serial
  protocol carries (zero = "all joints looking up, joint 1 to the front"). They are related per
  joint by ``theta = sign * q + offset_rad`` (``armbench.drivers.model.settings.JointSettings``).
* The TCP is the origin of frame 4: ``d4`` along the tool axis ``z4 = z3``, which lies in the arm
  plane perpendicular to the forearm ``a3``. Joint 4 is a pure roll about ``z4``: the TCP position
  does not depend on it, and it is the only free orientation parameter (the tool-axis direction
  follows from the position branch). The IK API therefore takes a target position plus ``roll``.
* IK branches: ``front``/``back`` are the two solutions of θ1 caused by the lateral offset ``d2``
  (the arm reaching towards the target, or turned round and leaning back over the shoulder);
  ``up``/``down`` say whether the elbow lies above or below the straight line from the shoulder
  axis to the TCP in the arm plane. Order of preference: ``BRANCHES``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import Geometry, RobotSettings

__all__ = [
    "BRANCHES",
    "IKSolution",
    "JointLimitError",
    "KinematicsError",
    "LimitViolation",
    "UnreachableError",
    "dh_parameters",
    "dh_to_protocol",
    "fk",
    "fk_dh",
    "ik",
    "ik_best",
    "protocol_to_dh",
    "tcp_point",
    "tcp_position",
    "wrap_protocol",
]

FloatArray = npt.NDArray[np.float64]
Vec4 = tuple[float, float, float, float]
Bound = Literal["lower", "upper"]
UnreachableKind = Literal["not-finite", "offset-cylinder", "beyond-reach", "too-close", "singular"]

#: Every IK branch name, in the order ``ik`` returns them and ``ik_best`` prefers them.
BRANCHES: tuple[str, ...] = ("front-up", "front-down", "back-up", "back-down")

#: Twist angles α_i of Table 1, as exact (cos, sin) pairs so that FK carries no 6e-17 residue.
_ALPHA_COS_SIN: tuple[tuple[float, float], ...] = ((0.0, 1.0), (1.0, 0.0), (0.0, 1.0), (1.0, 0.0))

#: Distances (m) below which a target on a workspace boundary is taken as on it, not beyond it.
_REACH_TOL_M = 1e-12
#: Protocol angles within this much (rad) outside a limit count as on it and are clamped.
_LIMIT_TOL_RAD = 1e-10
#: Two IK candidates whose DH angles all agree to this (rad, modulo 2π) are one solution.
_SAME_SOLUTION_RAD = 1e-9
_TWO_PI = 2.0 * math.pi


class KinematicsError(ArmbenchError, ValueError):
    """Invalid input to a kinematics function (wrong shape, unknown branch, non-finite roll)."""


def _fmt_xyz(xyz: Sequence[float]) -> str:
    return "(" + ", ".join(f"{v:.6g}" for v in xyz) + ") m"


class UnreachableError(KinematicsError):
    """No joint vector puts the TCP at ``target`` (x, y, z in metres, base frame).

    ``kind`` is one of ``not-finite`` (NaN/inf coordinates), ``offset-cylinder`` (closer to the
    base axis than the lateral offset |d2|), ``beyond-reach`` (farther from the shoulder axis than
    a2 + √(a3² + d4²)), ``too-close`` (nearer to it than |a2 − √(a3² + d4²)|) and ``singular``
    (exactly on the shoulder axis when a2 = √(a3² + d4²): joint 2 is undetermined).
    """

    def __init__(self, target: Sequence[float], kind: UnreachableKind, reason: str) -> None:
        super().__init__(f"target {_fmt_xyz(target)} is unreachable: {reason}")
        self.target: tuple[float, ...] = tuple(float(v) for v in target)
        self.kind: UnreachableKind = kind
        self.reason = reason


@dataclass(frozen=True, slots=True)
class LimitViolation:
    """One joint of one IK solution outside its limit (protocol convention, radians)."""

    joint: str
    index: int
    value_rad: float
    limit_rad: float
    bound: Bound

    def __str__(self) -> str:
        side = "below lower" if self.bound == "lower" else "above upper"
        return (f"{self.joint} = {self.value_rad:.6f} rad ({math.degrees(self.value_rad):.2f}°) "
                f"{side} limit {self.limit_rad:.6f} rad ({math.degrees(self.limit_rad):.2f}°)")


class JointLimitError(KinematicsError):
    """The target is reachable, but not by any acceptable branch within the joint limits.

    Names the joint, its value and the limit of the closest candidate (``branch``); every
    candidate's violations are listed in the message.
    """

    def __init__(self, target: Sequence[float], violation: LimitViolation, branch: str,
                 others: str = "") -> None:
        msg = (f"target {_fmt_xyz(target)}: no IK solution within the joint limits; closest is "
               f"branch {branch} with {violation}")
        super().__init__(msg + (f" (other branches: {others})" if others else ""))
        self.target: tuple[float, ...] = tuple(float(v) for v in target)
        self.branch = branch
        self.violation = violation
        self.joint = violation.joint
        self.value_rad = violation.value_rad
        self.limit_rad = violation.limit_rad
        self.bound: Bound = violation.bound


@dataclass(frozen=True, slots=True)
class IKSolution:
    """One inverse-kinematics solution.

    ``q_protocol`` are protocol-convention joint angles (rad), each wrapped into its joint's
    window ``mid ± π`` with ``mid`` the middle of its limits; ``theta_dh`` are the matching DH
    angles (``sign * q + offset``). ``branch`` is one of ``BRANCHES``; ``aliases`` names other
    branches that coincide with this one (arm fully stretched/folded, or target on the
    lateral-offset cylinder) and were therefore not returned separately. ``violations`` holds the
    names of the joints outside their limits, ``limit_violations`` the details.
    """

    q_protocol: Vec4
    theta_dh: Vec4
    branch: str
    within_limits: bool
    violations: tuple[str, ...]
    limit_violations: tuple[LimitViolation, ...] = ()
    aliases: tuple[str, ...] = ()

    def matches(self, branch: str) -> bool:
        """Whether this solution is ``branch`` or coincides with it."""
        return branch == self.branch or branch in self.aliases


# --------------------------------------------------------------------------------------------
# Forward kinematics


def dh_parameters(geometry: Geometry) -> FloatArray:
    """Table 1 as a (4, 3) array of ``(a_m, alpha_rad, d_m)`` rows, joints 1..4."""
    g = geometry
    return np.array([[0.0, math.pi / 2, g.d1_m],
                     [g.a2_m, 0.0, g.d2_m],
                     [g.a3_m, math.pi / 2, 0.0],
                     [0.0, 0.0, g.d4_m]], dtype=np.float64)


def _joint_array(values: npt.ArrayLike, what: str) -> FloatArray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 0 or arr.shape[-1] != 4:
        raise KinematicsError(f"{what} must have shape (4,) or (N, 4), got {arr.shape}")
    return arr


def fk_dh(theta: npt.ArrayLike, geometry: Geometry) -> FloatArray:
    """Pose of frame 4 (the TCP) in the base frame for DH joint angles.

    ``theta`` (rad) has shape ``(4,)`` or ``(N, 4)`` (any leading shape ``(..., 4)`` works);
    the result is ``(4, 4)`` or ``(N, 4, 4)``: homogeneous transforms, translations in metres.
    A trajectory is one vectorised call; there is no Python loop over its rows.
    """
    th = _joint_array(theta, "theta")
    ct, st = np.cos(th), np.sin(th)
    table = dh_parameters(geometry)
    a, d = table[:, 0], table[:, 2]
    ca = np.array([c for c, _ in _ALPHA_COS_SIN])
    sa = np.array([s for _, s in _ALPHA_COS_SIN])
    links = np.zeros((*th.shape, 4, 4), dtype=np.float64)  # (..., joint, row, col)
    links[..., 0, 0] = ct
    links[..., 0, 1] = -st * ca
    links[..., 0, 2] = st * sa
    links[..., 0, 3] = a * ct
    links[..., 1, 0] = st
    links[..., 1, 1] = ct * ca
    links[..., 1, 2] = -ct * sa
    links[..., 1, 3] = a * st
    links[..., 2, 1] = sa
    links[..., 2, 2] = ca
    links[..., 2, 3] = d
    links[..., 3, 3] = 1.0
    pose: FloatArray = (links[..., 0, :, :] @ links[..., 1, :, :]
                        @ links[..., 2, :, :] @ links[..., 3, :, :])
    return pose


def _signs_offsets(settings: RobotSettings) -> tuple[FloatArray, FloatArray]:
    signs = np.array([j.sign for j in settings.joints], dtype=np.float64)
    offsets = np.array([j.offset_rad for j in settings.joints], dtype=np.float64)
    return signs, offsets


def protocol_to_dh(q: npt.ArrayLike, settings: RobotSettings) -> FloatArray:
    """DH angles (rad) of protocol-convention angles ``q`` (rad), shape ``(4,)`` or ``(N, 4)``:
    ``theta = sign * q + offset_rad`` per joint."""
    signs, offsets = _signs_offsets(settings)
    out: FloatArray = signs * _joint_array(q, "q") + offsets
    return out


def dh_to_protocol(theta: npt.ArrayLike, settings: RobotSettings, *,
                   wrap: bool = False) -> FloatArray:
    """Protocol-convention angles (rad) of DH angles ``theta`` (rad), shape ``(4,)`` or ``(N, 4)``:
    ``q = sign * (theta - offset_rad)``. With ``wrap`` each angle is moved by a multiple of 2π
    into its joint's window (see ``wrap_protocol``)."""
    signs, offsets = _signs_offsets(settings)
    q: FloatArray = signs * (_joint_array(theta, "theta") - offsets)
    return wrap_protocol(q, settings) if wrap else q


def wrap_protocol(q: npt.ArrayLike, settings: RobotSettings) -> FloatArray:
    """Protocol angles (rad) moved by multiples of 2π into ``(mid - π, mid + π]`` per joint,
    ``mid`` being the middle of the joint's limits (the window ``armbench.drivers.model.protocol``
    decodes into);
    an angle within the limits stays unchanged."""
    arr = _joint_array(q, "q")
    mid = np.array([(j.lower_rad + j.upper_rad) / 2 for j in settings.joints], dtype=np.float64)
    out: FloatArray = arr - _TWO_PI * np.ceil((arr - mid - math.pi) / _TWO_PI)
    return out


def fk(q_protocol: npt.ArrayLike, settings: RobotSettings) -> FloatArray:
    """TCP pose(s) in the base frame for protocol-convention angles (rad).

    Shape ``(4,)`` or ``(N, 4)`` → ``(4, 4)`` or ``(N, 4, 4)``, translations in metres; uses
    ``settings.geometry`` including the gripper offset ``d4_m``."""
    return fk_dh(protocol_to_dh(q_protocol, settings), settings.geometry)


def tcp_position(q_protocol: npt.ArrayLike, settings: RobotSettings) -> FloatArray:
    """TCP position(s) in metres, ``(3,)`` or ``(N, 3)``, for protocol-convention angles (rad).

    One pose is chained in floats (:func:`tcp_point`), as the suites and the emulator ask for it
    once per sample; a trajectory is one vectorised :func:`fk`."""
    q = _joint_array(q_protocol, "q")
    if q.ndim == 1:
        return np.array(tcp_point(q.tolist(), settings), dtype=np.float64)
    out: FloatArray = fk(q, settings)[..., :3, 3]
    return out


def tcp_point(q_protocol: Sequence[float], settings: RobotSettings) -> tuple[float, float, float]:
    """TCP position (m) of one pose of protocol-convention angles (rad): the DH chain of
    :func:`fk` applied to the TCP's origin, last link first, without building the matrices
    (the same product, summed in another order: equal to it within rounding)."""
    if len(q_protocol) != 4:
        raise KinematicsError(f"q must have 4 joint angles, got {len(q_protocol)}")
    g = settings.geometry
    a_m = (0.0, g.a2_m, g.a3_m, 0.0)
    d_m = (g.d1_m, g.d2_m, 0.0, g.d4_m)
    x = y = z = 0.0
    for i in (3, 2, 1, 0):
        joint = settings.joints[i]
        theta = joint.sign * q_protocol[i] + joint.offset_rad
        ct, st = math.cos(theta), math.sin(theta)
        ca, sa = _ALPHA_COS_SIN[i]
        x, y, z = (ct * x - st * ca * y + st * sa * z + a_m[i] * ct,
                   st * x + ct * ca * y - ct * sa * z + a_m[i] * st,
                   sa * y + ca * z + d_m[i])
    return x, y, z


# --------------------------------------------------------------------------------------------
# Inverse kinematics


def _target(xyz: npt.ArrayLike) -> tuple[float, float, float]:
    arr = np.asarray(xyz, dtype=np.float64)
    if arr.shape != (3,):
        raise KinematicsError(f"target must be (x, y, z) in metres, got shape {arr.shape}")
    x, y, z = (float(v) for v in arr)
    if not all(math.isfinite(v) for v in (x, y, z)):
        raise UnreachableError((x, y, z), "not-finite", "coordinates must be finite (NaN/inf)")
    return x, y, z


def _position_candidates(x: float, y: float, z: float,
                         g: Geometry) -> list[tuple[str, float, float, float]]:
    """(branch, θ1, θ2, θ3) in DH radians for every branch, in ``BRANCHES`` order.

    With ``u`` the signed distance of the TCP along ``x1`` and ``v = z - d1`` its height above the
    shoulder, FK gives ``x = u c1 + d2 s1``, ``y = u s1 - d2 c1`` and, in the arm plane,
    ``(u, v) = a2·e(θ2) + L·e(θ2 + θ3 + φ)`` with ``L = √(a3² + d4²)``, ``φ = atan2(-d4, a3)``
    and ``e(α) = (cos α, sin α)``.
    """
    target = (x, y, z)
    d1, d2, a2, a3, d4 = g.d1_m, g.d2_m, g.a2_m, g.a3_m, g.d4_m
    rho = math.hypot(x, y)
    if rho < abs(d2) - _REACH_TOL_M:
        raise UnreachableError(target, "offset-cylinder",
                               f"{rho:.6g} m from the base axis, inside the cylinder of radius "
                               f"|d2| = {abs(d2):.6g} m that the offset arm plane cannot enter")
    u_abs = math.sqrt(max(0.0, (rho - abs(d2)) * (rho + abs(d2))))
    v = z - d1
    link = math.hypot(a3, d4)           # shoulder-side view: elbow → TCP distance
    phi = math.atan2(-d4, a3)           # angle of elbow → TCP relative to link a3
    r = math.hypot(u_abs, v)            # shoulder axis → TCP distance in the arm plane
    r_max, r_min = a2 + link, abs(a2 - link)
    if r > r_max + _REACH_TOL_M:
        raise UnreachableError(target, "beyond-reach",
                               f"{r:.6g} m from the shoulder axis in the arm plane, beyond the "
                               f"reach a2 + √(a3² + d4²) = {r_max:.6g} m")
    if r < r_min - _REACH_TOL_M:
        raise UnreachableError(target, "too-close",
                               f"{r:.6g} m from the shoulder axis in the arm plane, nearer than "
                               f"|a2 − √(a3² + d4²)| = {r_min:.6g} m")
    if r <= _REACH_TOL_M:
        raise UnreachableError(target, "singular",
                               "on the shoulder axis with a2 = √(a3² + d4²): joint 2 is "
                               "undetermined")
    # Law of cosines at the shoulder: the angle γ between the shoulder→TCP line and link a2.
    # Solving for θ2 first and taking the forearm direction from the elbow→TCP vector keeps the
    # TCP residual at rounding level even for targets next to the shoulder axis.
    cos_g = max(-1.0, min(1.0, ((a2 - link) * (a2 + link) + r * r) / (2.0 * a2 * r)))
    gamma = math.acos(cos_g)
    heading = math.atan2(y, x)
    out: list[tuple[str, float, float, float]] = []
    for side, su in (("front", 1.0), ("back", -1.0)):
        u = su * u_abs
        theta1 = heading - math.atan2(-d2, u)
        beta = math.atan2(v, u)
        for elbow, turn in (("up", su * gamma), ("down", -su * gamma)):
            # turning link a2 from the shoulder→TCP line towards +v (world z) when the TCP lies
            # ahead (u > 0), towards -v behind, puts the elbow above that line: elbow "up"
            theta2 = beta + turn
            forearm = math.atan2(v - a2 * math.sin(theta2), u - a2 * math.cos(theta2))
            theta3 = forearm - theta2 - phi
            out.append((f"{side}-{elbow}", theta1, theta2, theta3))
    return out


def _angle_diff(a: float, b: float) -> float:
    return abs(math.remainder(a - b, _TWO_PI))


def _solution(branch: str, theta: Vec4, aliases: Sequence[str],
              settings: RobotSettings) -> IKSolution:
    q: list[float] = []
    violations: list[LimitViolation] = []
    for i, (joint, th) in enumerate(zip(settings.joints, theta, strict=True)):
        mid = (joint.lower_rad + joint.upper_rad) / 2
        value = joint.from_dh(th)
        value -= _TWO_PI * math.ceil((value - mid - math.pi) / _TWO_PI)
        if joint.lower_rad - _LIMIT_TOL_RAD <= value < joint.lower_rad:
            value = joint.lower_rad
        elif joint.upper_rad < value <= joint.upper_rad + _LIMIT_TOL_RAD:
            value = joint.upper_rad
        if value < joint.lower_rad:
            violations.append(LimitViolation(joint.name, i, value, joint.lower_rad, "lower"))
        elif value > joint.upper_rad:
            violations.append(LimitViolation(joint.name, i, value, joint.upper_rad, "upper"))
        q.append(value)
    q4: Vec4 = (q[0], q[1], q[2], q[3])
    j1, j2, j3, j4 = settings.joints
    th4: Vec4 = (j1.to_dh(q[0]), j2.to_dh(q[1]), j3.to_dh(q[2]), j4.to_dh(q[3]))
    return IKSolution(q_protocol=q4, theta_dh=th4, branch=branch,
                      within_limits=not violations,
                      violations=tuple(v.joint for v in violations),
                      limit_violations=tuple(violations), aliases=tuple(aliases))


def ik(xyz: npt.ArrayLike, settings: RobotSettings, roll: float = 0.0) -> tuple[IKSolution, ...]:
    """Every closed-form IK solution that puts the TCP at ``xyz`` (metres, base frame).

    ``roll`` is joint 4's angle in the protocol convention (rad): the rotation of the tool about
    its own axis ``z4``, the only free orientation parameter of this arm (the TCP position does
    not depend on joint 4; the tool-axis direction follows from the branch). Returns up to four
    solutions in ``BRANCHES`` order; branches that coincide (arm stretched or folded, target on the
    lateral-offset cylinder) are returned once, with the others in ``aliases``. Solutions outside
    the joint limits are included, flagged by ``within_limits``/``violations``.

    Raises ``UnreachableError`` for a target out of reach or not finite, ``KinematicsError`` for a
    malformed target or a non-finite ``roll``.
    """
    x, y, z = _target(xyz)
    roll = float(roll)
    if not math.isfinite(roll):
        raise KinematicsError(f"roll must be finite, got {roll!r}")
    theta4 = settings.joints[3].to_dh(roll)
    kept: list[tuple[str, Vec4, list[str]]] = []
    for branch, t1, t2, t3 in _position_candidates(x, y, z, settings.geometry):
        theta: Vec4 = (t1, t2, t3, theta4)
        for _, other, aliases in kept:
            if all(_angle_diff(a, b) <= _SAME_SOLUTION_RAD for a, b in zip(theta, other,
                                                                          strict=True)):
                aliases.append(branch)
                break
        else:
            kept.append((branch, theta, []))
    return tuple(_solution(branch, theta, aliases, settings) for branch, theta, aliases in kept)


def _excess(sol: IKSolution) -> float:
    return sum(abs(v.value_rad - v.limit_rad) for v in sol.limit_violations)


def ik_best(xyz: npt.ArrayLike, settings: RobotSettings, roll: float = 0.0,
            branch: str | None = None, near: npt.ArrayLike | None = None) -> IKSolution:
    """The one IK solution to use for a move to ``xyz`` (metres) with tool ``roll`` (rad,
    protocol convention of joint 4; see ``ik``), inside the joint limits.

    With ``branch`` (one of ``BRANCHES``) only that branch is acceptable. Otherwise, with
    ``near`` (protocol angles, rad, shape (4,), e.g. the current joint state) the acceptable
    solution closest to it in joint space (Euclidean, protocol radians) wins; without it the
    first in ``BRANCHES`` order.

    Raises ``UnreachableError`` (see ``ik``), ``JointLimitError`` naming the joint, value and limit
    of the closest candidate if no acceptable solution is within the limits, ``KinematicsError``
    for an unknown branch or malformed ``near``.
    """
    if branch is not None and branch not in BRANCHES:
        raise KinematicsError(f"unknown IK branch {branch!r}; expected one of "
                              f"{', '.join(BRANCHES)}")
    near_arr: FloatArray | None = None
    if near is not None:
        near_arr = _joint_array(near, "near")
        if near_arr.shape != (4,) or not np.all(np.isfinite(near_arr)):
            raise KinematicsError(f"near must be 4 finite protocol angles, got {near!r}")
    solutions = ik(xyz, settings, roll)
    candidates = [s for s in solutions if branch is None or s.matches(branch)]
    good = [s for s in candidates if s.within_limits]
    if not good:
        worst = min(candidates, key=_excess)
        violation = max(worst.limit_violations, key=lambda v: abs(v.value_rad - v.limit_rad))
        others = "; ".join(f"{s.branch}: {', '.join(str(v) for v in s.limit_violations)}"
                           for s in candidates if s is not worst)
        raise JointLimitError(_target(xyz), violation, worst.branch, others)
    if near_arr is None:
        return good[0]
    ref = near_arr
    return min(good, key=lambda s: float(np.sum((np.asarray(s.q_protocol) - ref) ** 2)))
