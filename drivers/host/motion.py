"""Motion planning on the host: speed law (12), coordinated duties, Cartesian paths, run records.

Pure functions and small value types, no I/O and no clocks; :mod:`armbench.drivers.host.arm` uses
them to turn a
move or a path into commands.

Speed law (12) of the paper: a joint moving at PWM duty ``v`` (1..99) makes one motor step every
``101 − v`` control cycles of 80 µs, i.e. ``1e6 / (80 · (101 − v))`` steps per second; duty 0 holds.
Since the step period is a whole number of cycles ``p = 101 − v`` (2..100), a joint can only run at
100 − 2 + 1 = 99 discrete speeds. Coordinated motion therefore works on periods: a joint that has
to make ``N`` steps in ``T`` cycles gets ``p = round(T / N)``, and arrives ``N · p − T`` cycles off,
at most ``N / 2`` cycles (a relative timing error of at most ``1 / (2p)``, i.e. coarse near duty
99 where ``p`` is 2 or 3, fine at low duties).
"""

from __future__ import annotations

import abc
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np
import numpy.typing as npt

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.protocol import CYCLE_S, MAX_DUTY
from armbench.drivers.model.settings import RobotSettings

__all__ = [
    "CYCLE_S",
    "MIN_PERIOD_CYCLES",
    "Arc",
    "Line",
    "Path",
    "PathError",
    "Polyline",
    "arc",
    "coordinated_duties",
    "duty_for_period",
    "duty_for_step_rate",
    "joint_speed_rad_s",
    "joint_times_s",
    "line",
    "period_for_duty",
    "point_to_polyline_m",
    "polyline",
    "segment_duties",
    "square",
    "step_rate",
]

FloatArray = npt.NDArray[np.float64]

#: Shortest step period in cycles (duty 99).
MIN_PERIOD_CYCLES: Final = 101 - MAX_DUTY
#: Longest step period in cycles (duty 1).
MAX_PERIOD_CYCLES: Final = 100


class PathError(ArmbenchError, ValueError):
    """A path cannot be followed: too short, degenerate, or its IK jumps between branches."""


# --------------------------------------------------------------------------------------------
# Speed law (12)


def period_for_duty(duty: int) -> int:
    """Control cycles per step at ``duty`` 1..99: ``101 − duty``."""
    if not 1 <= duty <= MAX_DUTY:
        raise ValueError(f"duty {duty!r} is not 1..{MAX_DUTY}")
    return 101 - duty


def duty_for_period(period_cycles: int) -> int:
    """The duty whose step period is ``period_cycles`` (clamped to 2..100 cycles → duty 99..1)."""
    p = min(MAX_PERIOD_CYCLES, max(MIN_PERIOD_CYCLES, int(period_cycles)))
    return 101 - p


def step_rate(duty: int) -> float:
    """Motor steps per second at ``duty`` (law (12)): ``1e6 / (80 · (101 − duty))``; 0 for 0."""
    if duty == 0:
        return 0.0
    return 1.0 / (period_for_duty(duty) * CYCLE_S)


def duty_for_step_rate(steps_per_s: float) -> int:
    """Inverse of law (12): ``101 − 1e6 / (80 · steps_per_s)``, rounded to the nearest whole
    step period and clamped to duty 1..99 (a rate above 6250 steps/s gives 99)."""
    if not steps_per_s > 0:
        return 1
    return duty_for_period(round(1.0 / (steps_per_s * CYCLE_S)))


def joint_speed_rad_s(duty: int, steps_per_rad: float) -> float:
    """Joint speed in rad/s at ``duty`` for a joint with ``steps_per_rad`` motor steps per rad."""
    return step_rate(duty) / steps_per_rad


def _steps(start: Sequence[float], target: Sequence[float],
           settings: RobotSettings) -> list[float]:
    return [abs(t - s) * j.steps_per_rad
            for s, t, j in zip(start, target, settings.joints, strict=True)]


def joint_times_s(start: Sequence[float], target: Sequence[float], duties: Sequence[int],
                  settings: RobotSettings) -> list[float]:
    """Seconds each joint needs from ``start`` to ``target`` (rad) at its duty (∞ at duty 0 with
    a distance to go, 0 without)."""
    out = []
    for n, d in zip(_steps(start, target, settings), duties, strict=True):
        if n < 0.5:
            out.append(0.0)
        elif d == 0:
            out.append(math.inf)
        else:
            out.append(n * period_for_duty(d) * CYCLE_S)
    return out


def _periods_for(steps: Sequence[float], total_cycles: float, min_period: int) -> list[int]:
    out = []
    for n in steps:
        if n < 0.5:
            out.append(min_period)
            continue
        p = round(total_cycles / n)
        out.append(min(MAX_PERIOD_CYCLES, max(min_period, p)))
    return out


def coordinated_duties(start: Sequence[float], target: Sequence[float], duty: int,
                       settings: RobotSettings) -> tuple[int, int, int, int]:
    """Per-joint duties so that all joints arrive together: the joint needing the most steps runs
    at ``duty``, each other one at the step period (rounded) that spreads its steps over the same
    time. A joint that would need to go slower than duty 1 runs at duty 1 and arrives early."""
    p_req = period_for_duty(duty)
    steps = _steps(start, target, settings)
    total = max(steps) * p_req
    periods = _periods_for(steps, total, p_req)
    d = [duty_for_period(p) for p in periods]
    return (d[0], d[1], d[2], d[3])


def segment_duties(start: Sequence[float], target: Sequence[float], duration_s: float,
                   settings: RobotSettings, max_duty: int = MAX_DUTY) -> tuple[
                       tuple[int, int, int, int], float]:
    """Per-joint duties to go from ``start`` to ``target`` (rad) in ``duration_s``, all joints
    together, none faster than ``max_duty``. When the fastest joint cannot make it in time the
    segment is stretched to what ``max_duty`` allows. Returns the duties and the planned duration
    (seconds, before duty quantisation)."""
    p_min = period_for_duty(max_duty)
    steps = _steps(start, target, settings)
    longest = max(steps)
    total = max(duration_s / CYCLE_S, longest * p_min)
    periods = _periods_for(steps, total, p_min)
    d = [duty_for_period(p) for p in periods]
    return (d[0], d[1], d[2], d[3]), total * CYCLE_S


# --------------------------------------------------------------------------------------------
# Cartesian paths


def _vec3(p: npt.ArrayLike, what: str) -> FloatArray:
    arr = np.asarray(p, dtype=np.float64)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise PathError(f"{what} must be 3 finite coordinates (x, y, z) in metres, got {p!r}")
    return arr


class Path(abc.ABC):
    """A curve in the base frame (metres) parametrised by arc length."""

    @property
    @abc.abstractmethod
    def length_m(self) -> float:
        """Arc length in metres."""

    @abc.abstractmethod
    def point_at(self, s_m: float) -> FloatArray:
        """The point at arc length ``s_m`` (clamped to 0..length)."""

    def waypoints(self, spacing_m: float) -> FloatArray:
        """Points along the path at most ``spacing_m`` apart, both ends included, (N, 3)."""
        if not spacing_m > 0:
            raise PathError(f"spacing {spacing_m!r} m must be > 0")
        n = max(1, math.ceil(self.length_m / spacing_m - 1e-9))
        return np.array([self.point_at(self.length_m * k / n) for k in range(n + 1)])


@dataclass(frozen=True)
class Polyline(Path):
    """Straight segments through ``points`` (N ≥ 2, metres); corners are always waypoints."""

    points: tuple[tuple[float, float, float], ...]
    _cum: tuple[float, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        pts = [tuple(float(c) for c in _vec3(p, f"point {i}")) for i, p in enumerate(self.points)]
        if len(pts) < 2:
            raise PathError(f"a path needs at least 2 points, got {len(pts)}")
        object.__setattr__(self, "points", tuple(pts))
        cum = [0.0]
        for a, b in itertools.pairwise(pts):
            cum.append(cum[-1] + math.dist(a, b))
        if cum[-1] <= 0.0:
            raise PathError("all points of the path coincide")
        object.__setattr__(self, "_cum", tuple(cum))

    @property
    def length_m(self) -> float:
        return self._cum[-1]

    def point_at(self, s_m: float) -> FloatArray:
        s = min(max(s_m, 0.0), self.length_m)
        i = int(np.searchsorted(self._cum, s, side="right")) - 1
        i = min(max(i, 0), len(self.points) - 2)
        seg = self._cum[i + 1] - self._cum[i]
        a, b = np.asarray(self.points[i]), np.asarray(self.points[i + 1])
        f = 0.0 if seg <= 0 else (s - self._cum[i]) / seg
        out: FloatArray = a + (b - a) * f
        return out

    def waypoints(self, spacing_m: float) -> FloatArray:
        if not spacing_m > 0:
            raise PathError(f"spacing {spacing_m!r} m must be > 0")
        out = [np.asarray(self.points[0])]
        for a, b in itertools.pairwise(self.points):
            pa, pb = np.asarray(a), np.asarray(b)
            seg = float(np.linalg.norm(pb - pa))
            if seg <= 0.0:
                continue
            n = max(1, math.ceil(seg / spacing_m - 1e-9))
            out.extend(pa + (pb - pa) * (k / n) for k in range(1, n + 1))
        return np.array(out)


class Line(Polyline):
    """A straight line from ``start`` to ``end`` (metres)."""

    def __init__(self, start: npt.ArrayLike, end: npt.ArrayLike) -> None:
        a = _vec3(start, "start")
        b = _vec3(end, "end")
        super().__init__((tuple(a.tolist()), tuple(b.tolist())))


@dataclass(frozen=True)
class Arc(Path):
    """A circular arc: ``start`` rotated about the axis through ``center`` along ``normal`` by
    ``angle_rad`` (right-hand rule; negative turns the other way)."""

    center: tuple[float, float, float]
    start: tuple[float, float, float]
    angle_rad: float
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def __post_init__(self) -> None:
        c = _vec3(self.center, "center")
        s = _vec3(self.start, "start")
        n = _vec3(self.normal, "normal")
        if np.linalg.norm(n) == 0:
            raise PathError("normal must not be zero")
        n = n / np.linalg.norm(n)
        r = s - c
        r = r - n * float(np.dot(r, n))  # the arc lies in the plane through start ⊥ normal
        if np.linalg.norm(r) <= 0 or not math.isfinite(self.angle_rad) or self.angle_rad == 0:
            raise PathError("an arc needs a start off its axis and a finite non-zero angle")
        object.__setattr__(self, "center", tuple(c.tolist()))
        object.__setattr__(self, "start", tuple(s.tolist()))
        object.__setattr__(self, "normal", tuple(n.tolist()))

    @property
    def radius_m(self) -> float:
        """Radius in metres."""
        c, s, n = (np.asarray(v) for v in (self.center, self.start, self.normal))
        r = s - c
        return float(np.linalg.norm(r - n * float(np.dot(r, n))))

    @property
    def length_m(self) -> float:
        return abs(self.angle_rad) * self.radius_m

    def point_at(self, s_m: float) -> FloatArray:
        s = min(max(s_m, 0.0), self.length_m)
        phi = self.angle_rad * (s / self.length_m)
        c, p, n = (np.asarray(v) for v in (self.center, self.start, self.normal))
        r = p - c
        # Rodrigues' rotation of r about n by phi
        out: FloatArray = c + (r * math.cos(phi) + np.cross(n, r) * math.sin(phi)
                               + n * float(np.dot(n, r)) * (1 - math.cos(phi)))
        return out


def line(start: npt.ArrayLike, end: npt.ArrayLike) -> Line:
    """A straight line from ``start`` to ``end`` (metres)."""
    return Line(start, end)


def polyline(points: Sequence[npt.ArrayLike]) -> Polyline:
    """Straight segments through ``points`` (metres)."""
    return Polyline(tuple(tuple(_vec3(p, "point").tolist()) for p in points))


def arc(center: npt.ArrayLike, start: npt.ArrayLike, angle_rad: float,
        normal: npt.ArrayLike = (0.0, 0.0, 1.0)) -> Arc:
    """An arc about ``center`` (axis ``normal``) from ``start`` through ``angle_rad``."""
    return Arc(tuple(_vec3(center, "center").tolist()),
               tuple(_vec3(start, "start").tolist()),
               float(angle_rad), tuple(_vec3(normal, "normal").tolist()))


def square(center: npt.ArrayLike, side_m: float, plane: str = "yz") -> Polyline:
    """A closed square of side ``side_m`` centred on ``center`` in the plane ``"xy"``, ``"yz"``
    or ``"xz"`` (the paper's test path lies in YZ), starting at its lower-left corner."""
    axes = {"xy": (0, 1), "yz": (1, 2), "xz": (0, 2)}
    if plane not in axes:
        raise PathError(f"plane {plane!r} is not one of xy, yz, xz")
    if not side_m > 0:
        raise PathError(f"side {side_m!r} m must be > 0")
    c = _vec3(center, "center")
    u, v = axes[plane]
    h = side_m / 2
    corners = []
    for du, dv in ((-h, -h), (h, -h), (h, h), (-h, h), (-h, -h)):
        p = c.copy()
        p[u] += du
        p[v] += dv
        corners.append(p)
    return polyline(corners)


def point_to_polyline_m(points: npt.ArrayLike, vertices: npt.ArrayLike) -> FloatArray:
    """Distance (m) of each of ``points`` (N, 3) to the polyline through ``vertices`` (M, 3)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    if len(v) == 1:
        out1: FloatArray = np.linalg.norm(p - v[0], axis=1)
        return out1
    a, b = v[:-1], v[1:]
    ab = b - a
    denom = np.einsum("ij,ij->i", ab, ab)
    denom = np.where(denom > 0, denom, 1.0)
    best = np.full(len(p), np.inf)
    chunk = max(1, 200_000 // max(1, len(a)))
    for i in range(0, len(p), chunk):
        pp = p[i:i + chunk, None, :]
        t = np.clip(np.einsum("nmj,mj->nm", pp - a, ab) / denom, 0.0, 1.0)
        d = np.linalg.norm(pp - (a + t[..., None] * ab), axis=2)
        best[i:i + chunk] = d.min(axis=1)
    return best
