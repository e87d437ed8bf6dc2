"""Geometry from what a lab has: tool positions measured at known joint angles, with their
uncertainty, from a caliper, a CMM or a camera (``--reference poses.csv``) or from known points
of a plate the operator touched with the tool (``--touch-off plate.toml``,
``bench/calibrate/touch_off.py``).

Each reference pose: the arm's joint angles (its reported ones, as commanded or recorded), how
each joint came there (the direction of its last move, or its whole path since a long move),
the tool position measured there (base frame) and that measurement's standard error. The fit:
nonlinear least squares (``scipy.optimize.least_squares``, bounded: a play is never negative)
of the measured positions against the forward kinematics of the link angles, each link the
reported angle plus the Hall error (the prior's), the joint's offset error, its deflection
under gravity (the prior's masses and stiffness) and where the play leaves it: on the flank
gravity pushes it to where the prior's gravity torque exceeds its hold torque, else trailing
the motor by half the play on the side it last moved from (its path replayed through the play
operator where the pose carries one). Unknowns: the DH length errors d1, d2, a2, a3, the offset
errors and the plays of joints 1 to 3 (joint 4 turns the tool about its own axis: the tool
position does not show it); their standard errors from the Jacobian, scaled by the residuals
where those are larger than the stated uncertainties.
"""

from __future__ import annotations

import csv
import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from armbench.bench.calibrate.model import CalibrationError, Fitted, ReferencePose
from armbench.drivers.model.kinematics import tcp_position
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.model.twin_parameters import GEOMETRY_ERRORS, TWIN
from armbench.fakes.twin.physics import ArmPhysics, Mechanism

__all__ = ["FITTED_KEYS", "REFERENCE_COLUMNS", "Plate", "PlatePoint", "ReferenceError",
           "fit_reference", "read_plate", "read_reference", "write_reference"]

FloatArray = npt.NDArray[np.float64]

#: The columns of a reference file (``approach`` optional: ``++++`` when absent).
REFERENCE_COLUMNS: Final = ("q1_deg", "q2_deg", "q3_deg", "q4_deg", "approach", "x_mm", "y_mm",
                            "z_mm", "sigma_mm")
#: The most reference poses a file may hold.
MAX_POSES: Final = 10_000
_LENGTHS: Final = tuple(p for p in GEOMETRY_ERRORS if p.fitted)
_OFFSET, _PLAY, _HALL = TWIN["offset_error_rad"], TWIN["backlash_rad"], TWIN["hall_error_rad"]
#: The unknowns' settings keys, in the order of the fit's vector.
FITTED_KEYS: Final = (*(p.path() for p in _LENGTHS), *(_OFFSET.path(j) for j in range(3)),
                      *(_PLAY.path(j) for j in range(3)))


class ReferenceError(CalibrationError, ValueError):
    """A reference file or a plate that cannot be used; names the file, the place and why."""

    def __init__(self, path: str, where: str, problem: str) -> None:
        super().__init__(f"{path}: {where}: {problem}")
        self.path = path
        self.where = where
        self.problem = problem


def _number(path: str, where: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ReferenceError(path, where, f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise ReferenceError(path, where, f"{text!r} is not a finite number")
    return value


def _approach(path: str, where: str, text: str) -> list[int]:
    if len(text) != 4 or any(c not in "+-" for c in text):
        raise ReferenceError(path, where, f"approach {text!r} is not four of + and -")
    return [1 if c == "+" else -1 for c in text]


def read_reference(path: str | Path) -> list[ReferencePose]:
    """The poses of a reference file (CSV: a header naming :data:`REFERENCE_COLUMNS`, lines
    starting with ``#`` left out; angles in degrees, protocol convention; positions in mm in the
    arm's base frame; ``sigma_mm`` the standard error of each coordinate). Raises
    :class:`ReferenceError` naming the file and the line."""
    name = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ReferenceError(name, "file", f"cannot be read ({exc})") from None
    rows = [(k, line) for k, line in enumerate(text.splitlines(), 1)
            if line.strip() and not line.lstrip().startswith("#")]
    if not rows:
        raise ReferenceError(name, "file", "holds no header and no pose")
    header = [c.strip() for c in next(csv.reader([rows[0][1]]))]
    missing = [c for c in REFERENCE_COLUMNS if c != "approach" and c not in header]
    if missing:
        raise ReferenceError(name, f"line {rows[0][0]}", f"the header lacks {', '.join(missing)}")
    out = []
    for k, line in rows[1:]:
        cells = [c.strip() for c in next(csv.reader([line]))]
        where = f"line {k}"
        if len(cells) != len(header):
            raise ReferenceError(name, where, f"{len(cells)} cells, the header names "
                                              f"{len(header)}")
        row = dict(zip(header, cells, strict=True))
        q = [math.radians(_number(name, where, row[f"q{j}_deg"])) for j in range(1, 5)]
        xyz = [_number(name, where, row[c]) * 1e-3 for c in ("x_mm", "y_mm", "z_mm")]
        sigma = _number(name, where, row["sigma_mm"]) * 1e-3
        if sigma <= 0:
            raise ReferenceError(name, where, f"sigma_mm {row['sigma_mm']} is not > 0")
        out.append(ReferencePose(q, xyz, sigma, _approach(name, where, row.get("approach",
                                                                               "++++")),
                                 source=f"{Path(path).name}:{k}"))
        if len(out) > MAX_POSES:
            raise ReferenceError(name, where, f"more than {MAX_POSES} poses")
    if not out:
        raise ReferenceError(name, "file", "holds a header and no pose")
    return out


def write_reference(poses: Sequence[ReferencePose], path: Path) -> None:
    """Write ``poses`` as a reference file (what :func:`read_reference` reads)."""
    lines = [",".join(REFERENCE_COLUMNS)]
    for p in poses:
        lines.append(",".join([*(f"{math.degrees(v):.6f}" for v in p.q_rad),
                               "".join("+" if d > 0 else "-" for d in p.approach),
                               *(f"{v * 1e3:.4f}" for v in p.xyz_m), f"{p.sigma_m * 1e3:.4f}"]))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


@dataclass(frozen=True, slots=True)
class PlatePoint:
    """A known point of a touch-off plate: its name and position (m, base frame)."""

    name: str
    xyz_m: tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class Plate:
    """A touch-off plate (``plate.toml``): its points, the standard error of each point's
    position in the base frame (machining and placing the plate, m) and of the operator's touch
    (how far from the point the tool is when the operator says it is on it, m)."""

    points: tuple[PlatePoint, ...]
    sigma_m: float
    touch_m: float

    @property
    def point_sigma_m(self) -> float:
        """The standard error of a touched point's position: the plate's and the touch's."""
        return math.hypot(self.sigma_m, self.touch_m)


def read_plate(path: str | Path) -> Plate:
    """A plate file: ``[plate]`` with ``sigma_mm`` and ``touch_mm``, and ``[[plate.points]]``
    each with ``name`` and ``xyz_mm`` (base frame). Raises :class:`ReferenceError`."""
    name = str(path)
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise ReferenceError(name, "file", f"cannot be read as TOML ({exc})") from None
    table = data.get("plate")
    if not isinstance(table, dict):
        raise ReferenceError(name, "[plate]", "is missing")
    values = {}
    for key in ("sigma_mm", "touch_mm"):
        v = table.get(key)
        if isinstance(v, bool) or not isinstance(v, int | float) or not v > 0:
            raise ReferenceError(name, f"plate.{key}", f"{v!r} is not a number > 0")
        values[key] = float(v) * 1e-3
    points = []
    for k, p in enumerate(table.get("points", [])):
        where = f"plate.points[{k}]"
        xyz = p.get("xyz_mm") if isinstance(p, dict) else None
        if (not isinstance(xyz, list) or len(xyz) != 3
                or not all(isinstance(v, int | float) and not isinstance(v, bool)
                           and math.isfinite(v) for v in xyz)):
            raise ReferenceError(name, where, f"xyz_mm {xyz!r} is not three numbers")
        points.append(PlatePoint(str(p.get("name", k + 1)),
                                 (xyz[0] * 1e-3, xyz[1] * 1e-3, xyz[2] * 1e-3)))
    if len(points) < 4:
        raise ReferenceError(name, "plate.points", f"{len(points)} points: at least 4 are needed")
    return Plate(tuple(points), values["sigma_mm"], values["touch_mm"])


def kinematic_model(base: RobotSettings, theta: Sequence[float] | FloatArray) -> RobotSettings:
    """``base`` with the DH length errors ``theta[:4]`` (m) added and the offset errors
    ``theta[4:7]`` (rad) added to joints 1 to 3's DH offsets."""
    g = base.geometry
    geometry = replace(g, **{p.name: getattr(g, p.name) + float(theta[i])
                             for i, p in enumerate(_LENGTHS)})
    joints = tuple(replace(spec, offset_rad=spec.offset_rad + float(theta[4 + i]))
                   if i < 3 else spec for i, spec in enumerate(base.joints))
    return replace(base, geometry=geometry, joints=joints)


def _gap(pose: ReferencePose, j: int, play: float) -> float:
    """The motor's lead over the link (rad) at ``pose``: its path replayed through the play
    operator, or half the play on the side it came from."""
    if not pose.history_rad:
        return pose.approach[j] * play / 2
    half = play / 2
    gap = pose.approach[j] * half
    for a, b in zip(pose.history_rad, pose.history_rad[1:], strict=False):
        gap = min(half, max(-half, gap + b[j] - a[j]))
    return gap


def _sigma_m(pose: ReferencePose, base: RobotSettings) -> float:
    """A pose's positional standard error (per coordinate): the measurement's, and where the
    joints rest within a count of the encoder (uniform), through the kinematics."""
    q = np.asarray(pose.q_rad, dtype=np.float64)
    p0 = tcp_position(q, base)
    var = 0.0
    for j, spec in enumerate(base.joints):
        dq = np.zeros(4)
        dq[j] = 1e-6
        lever = float(np.linalg.norm(tcp_position(q + dq, base) - p0)) / 1e-6
        var += (lever / spec.counts_per_rad) ** 2 / 12.0 / 3.0
    return math.sqrt(pose.sigma_m ** 2 + var)


#: Plays (a share of the documented range's top) a fit starts from and the poses are tested
#: at: a small jog back crosses a small play, not a wide one.
PLAY_STARTS: Final = (0.25, 0.5, 1.0)


def _play_shows(poses: Sequence[ReferencePose], taus: Sequence[Sequence[float]],
                prior: ArmPhysics, j: int) -> bool:
    """Whether the poses tell joint ``j``'s play from its offset: where the link sits moves with
    the play differently at some poses than at others (gravity's flank, the side a path left
    it on, or inside the play after a short jog back), at the prior's play or at one of
    :data:`PLAY_STARTS` of the range's top."""
    p = prior.joints[j]
    top = _PLAY.to_twin(_PLAY.high)
    for play in (max(p.backlash_rad, 1e-4), *(f * top for f in PLAY_STARTS)):
        slopes = []
        for pose, tau in zip(poses, taus, strict=True):
            if abs(tau[j]) > p.hold_nm:
                slopes.append(0.5 if tau[j] > 0 else -0.5)
            else:
                slopes.append((_gap(pose, j, play + 1e-6) - _gap(pose, j, play)) / 1e-6)
        if max(slopes) - min(slopes) > 0.25:
            return True
    return False


def fit_reference(poses: Sequence[ReferencePose], base: RobotSettings, prior: ArmPhysics,
                  what: str = "reference poses",
                  known_play: dict[int, float] | None = None) -> list[Fitted]:
    """The DH length errors, the offset errors and the plays of joints 1 to 3 from ``poses``
    (see the module doc), each a :class:`Fitted` with its standard error, the prior kept with
    the reason where the poses do not determine it. A joint's play is fitted only where the
    poses put its link on both flanks (else it and the offset are one unknown): it is then
    ``known_play`` (rad, per joint 0..2: measured otherwise, e.g. by a reference instrument) or
    the prior's, and the reason says so. ``what`` names the source in the reasons."""
    mech = Mechanism(prior, base, lambda: [0.0] * 4)
    links = []
    for pose in poses:
        tau = mech.gravity_nm(pose.q_rad)
        links.append((np.asarray(pose.q_rad, dtype=np.float64), tau))
    known = dict(known_play or {})
    for j in range(3):
        if j not in known and not _play_shows(poses, [t for _, t in links], prior, j):
            known[j] = prior.joints[j].backlash_rad
    free = [i for i in range(10) if i < 7 or (i - 7) not in known]
    sigmas = np.asarray([_sigma_m(p, base) for p in poses])
    measured = np.asarray([p.xyz_m for p in poses], dtype=np.float64)
    ge = prior.geometry_error
    theta0 = np.asarray([*(getattr(ge, p.name) for p in _LENGTHS),
                         *(prior.joints[j].offset_error_rad for j in range(3)),
                         *(prior.joints[j].backlash_rad for j in range(3))], dtype=np.float64)

    def link_angles(pose: ReferencePose, q: FloatArray, tau: Sequence[float],
                    theta: FloatArray) -> FloatArray:
        out = q.copy()
        for j in range(4):
            p = prior.joints[j]
            play = float(theta[7 + j]) if j < 3 else p.backlash_rad
            held = abs(tau[j]) > p.hold_nm
            gap = -math.copysign(play / 2, tau[j]) if held else _gap(pose, j, play)
            offset = 0.0 if j < 3 else p.offset_error_rad   # joints 1-3: in the model's DH
            out[j] += p.hall_error_rad + offset - gap + tau[j] / p.stiffness_nm_per_rad
        return out

    full = theta0.copy()
    for j, value in known.items():
        full[7 + j] = value

    def residuals(x: FloatArray) -> FloatArray:
        theta = full.copy()
        theta[free] = x
        model = kinematic_model(base, theta)
        pred = np.asarray([tcp_position(link_angles(pose, q, tau, theta), model)
                           for pose, (q, tau) in zip(poses, links, strict=True)])
        r: FloatArray = ((pred - measured) / sigmas[:, None]).reshape(-1)
        return r

    low = np.asarray([-np.inf if i < 7 else 0.0 for i in free])
    result = None
    top = _PLAY.to_twin(_PLAY.high)
    for share in (None, *PLAY_STARTS):  # the plays from the prior's and across the range:
        start = full[free].copy()       # a play the poses cross only when wide is found so
        if share is not None:
            start[[k for k, i in enumerate(free) if i >= 7]] = share * top
        tried = least_squares(residuals, np.maximum(start, low),
                              bounds=(low, np.full(len(free), np.inf)),
                              x_scale=np.full(len(free), 1e-3), method="trf")
        if result is None or tried.cost < result.cost:
            result = tried
    assert result is not None
    dof = max(1, result.fun.size - len(free))
    chi2 = float(result.fun @ result.fun) / dof
    cov_free = np.linalg.pinv(result.jac.T @ result.jac) * max(1.0, chi2)
    params = [*_LENGTHS, *([_OFFSET] * 3), *([_PLAY] * 3)]
    out = []
    for i, (key, p) in enumerate(zip(FITTED_KEYS, params, strict=True)):
        prior_value = p.from_twin(float(theta0[i]))
        if i not in free:
            out.append(Fitted(key, prior_value, None, p.unit, False,
                              f"the {len(poses)} {what} put the link on one flank of its play "
                              "only (the play and the offset are then one unknown): the offset "
                              f"is fitted with the play at {p.from_twin(full[i]):.4g} {p.unit}",
                              prior_value))
            continue
        k = free.index(i)
        sigma = p.from_twin(math.sqrt(max(0.0, float(cov_free[k, k]))))
        value = p.from_twin(float(result.x[k]))
        assumed = 7 + i - 4 if 4 <= i < 7 and (7 + i - 4) not in free else None
        if len(poses) < 4 or not sigma <= 0.5 * (p.high - p.low):
            out.append(Fitted(key, prior_value, None, p.unit, False,
                              f"not resolved by {len(poses)} {what} (σ {sigma:.2g} {p.unit})",
                              prior_value))
            continue
        note = "" if assumed is None else (
            f"; its play not seen: fitted with the play at {_PLAY.from_twin(full[assumed]):.4g} "
            "deg (an error of that play moves this offset by half of it)")
        out.append(Fitted(key, value, sigma, p.unit, True,
                          f"{len(poses)} {what} (χ²/dof {chi2:.3g}){note}", prior_value))
    return out
