"""The mechanism under the firmware: gravity, compliance, gear play, step loss, kinematic error.

The joint boards (``fakes/twin/joint.py``) run the firmware step-exactly; this module describes the
arm they drive, as a physical object (``docs/robot-model.md`` gives every default and its source):

* link masses and centres of mass plus a payload at the TCP give each joint's gravity torque at the
  current pose (:meth:`Mechanism.gravity_nm`, through the DH chain of
  :mod:`armbench.drivers.model.kinematics`);
* each joint is a torsional spring: the link deflects by torque / stiffness, which the truth sees
  and the motor-side encoder does not (:meth:`Mechanism.true_rad`);
* the gear play sits on the side gravity pushes (``JointModel`` takes it from the torque at each
  event), step loss follows the torque the stepper must give against the pull-out torque it has at
  the commanded rate (:meth:`JointPhysics.loss_fraction`), the link stops within a stick-slip band
  that grows with the approach speed;
* the real arm's DH lengths, joint offsets and Hall positions differ from the nominal ones by small
  amounts: the truth uses the actual ones (:meth:`ArmPhysics.actual_settings`), the firmware and the
  host the nominal ones.

Everything is evaluated per event (a run planned, a stop, a truth sample read), never per control
cycle. ``profile = "ideal"`` switches all of it off (``ArmPhysics`` is then None).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Final, NamedTuple

from armbench.drivers.model.bounds import Bound, check
from armbench.drivers.model.kinematics import dh_parameters
from armbench.drivers.model.settings import Geometry, JointSettings, RobotSettings, SettingsError
from armbench.drivers.model.twin_parameters import (
    ARM_PARAMETERS,
    GEOMETRY_ERRORS,
    JOINT_PARAMETERS,
    PHYSICS_TABLE,
    TWIN,
    TwinParameter,
)

__all__ = [
    "DEFAULT_ARM",
    "DEFAULT_JOINT_PHYSICS",
    "END_STOP_MARGIN_RAD",
    "LOSS_LAWS",
    "PROFILES",
    "PULLOUT_CURVES",
    "TRUTH_HISTORY",
    "ArmPhysics",
    "GeometryError",
    "JointPhysics",
    "Mechanism",
    "TruthSample",
    "arm_physics",
    "end_stop_steps",
    "ideal_geometry",
    "ideal_joint",
]

#: The emulator's profiles: ``physical`` (the default arm of ``docs/robot-model.md``) and
#: ``ideal`` (no physics: the step-exact firmware on a perfect, rigid, play-free mechanism).
PROFILES: Final = ("physical", "ideal")

Vec4 = tuple[float, float, float, float]


#: Truth samples an emulator keeps (one per reply, the newest last). A reply's truth is looked
#: for among the newest 32 (``bench/suites/_common.py:TruthProbe.SEARCH``) and a capture reads
#: the newest; a short history also lets each sample die young, freed by reference counting
#: before the garbage collector's youngest generation has to walk it (``docs/performance.md``).
TRUTH_HISTORY: Final = 256


class TruthSample(NamedTuple):
    """Ground truth beside one reply frame: what a laser tracker would have measured.

    ``t_s`` is when the reply was printed; ``link_rad`` the joint angles after the gear play and
    stick-slip (protocol convention) and ``firmware_rad`` what the firmware believed (its encoder
    counters), each taken when the firmware sampled that joint for the reply; ``motor_rad`` the
    motor shafts' angles then (what a perfect motor-side encoder would read). :attr:`true_rad` adds
    the links' deflection under gravity (computed when read, not per reply).
    """

    t_s: float
    link_rad: Vec4
    firmware_rad: Vec4
    motor_rad: Vec4 | None = None
    mechanism: Mechanism | None = None

    @property
    def true_rad(self) -> Vec4:
        """The real joint angles (rad, protocol convention): play, stick-slip and deflection."""
        if self.mechanism is None:
            return self.link_rad
        return self.mechanism.true_rad(self.link_rad)


@dataclass(frozen=True, slots=True)
class JointPhysics:
    """The physical drive train and link of one joint: one field per joint parameter of
    :mod:`armbench.drivers.model.twin_parameters`, which gives each its unit, range, default and
    source (twin units here: radians where the settings file has degrees). Built by
    :func:`ideal_joint` (no effect but those given) or from the default arm
    (:data:`DEFAULT_JOINT_PHYSICS`).

    ``mass_kg`` / ``com_fraction``: the link this joint carries (from its frame's origin to the
    next, as a fraction of that segment). ``stiffness_nm_per_rad``: torsional stiffness of gear and
    link. ``backlash_rad``: gear play (full width). ``hold_nm``: gravity torque above which the link
    rests on the flank gravity pushes it to (the output bearing's static friction); below it the
    play acts as a plain play operator. ``pullout_nm`` / ``corner_steps_per_s``: the stepper's
    pull-out torque at standstill and the step rate (microsteps/s) where it has fallen to half;
    ``pullout_curve`` its shape between (``PULLOUT_CURVES``): ``"hyperbolic"`` (the default,
    ``pullout_nm / (1 + rate / corner)``: a constant-power drive, never zero) or ``"linear"``
    (``pullout_nm · (1 − rate / (2 corner))``, zero at twice the corner: the straight
    torque-speed line of a voltage-limited drive, so the pull-out rate falls linearly with the
    load and an unloaded joint, lowering through a self-locking gear included, stalls above
    ``2 corner``). ``pullin_share``: a stalled rotor (``loss_law = "stall"``) falls back into
    step only below this share of the rate it could keep (1: at once, no hysteresis).
    ``efficiency``: the worm gear's forward efficiency
    (lifting needs ``τ / (N η)`` at the motor; self-locking below 0.5, lowering needs
    ``τ (1/η − 2) / N``). ``friction_nm``: running friction at the motor. ``inertia_kgm2``:
    rotor plus link inertia reflected to the motor; ``spinup_s``: time the drive takes to reach the
    commanded rate (no ramp in the firmware). ``stick_rad``: stick-slip band of a stop at full
    speed; ``stick_floor``: its fraction at standstill speed (the band grows linearly with the
    approach speed in between). ``offset_error_rad`` / ``hall_error_rad``: the actual DH offset and
    Hall position minus the nominal ones. ``loss_jitter``: relative standard deviation of a run's
    lost fraction about :meth:`loss_fraction` (seeded; 0: the same move under the same load loses
    the same steps).

    ``loss_law`` picks how the drive loses steps (``LOSS_LAWS``): ``"torque"`` (the default) loses
    the share of the torque deficit; ``"stall"`` loses synchronism where the needed torque exceeds
    the pull-out torque at the rate, and the rotor stops (every pulse lost) until the rate falls;
    ``"duty"`` loses a fixed share above a duty, whatever the load: ``loss_plus`` moving towards
    +q and ``loss_minus`` towards −q at duties above ``loss_above_duty``; ``"none"``: no step is
    lost (an arm that showed no loss wherever it was driven).
    """

    mass_kg: float
    com_fraction: float
    stiffness_nm_per_rad: float
    backlash_rad: float
    hold_nm: float
    pullout_nm: float
    corner_steps_per_s: float
    efficiency: float
    friction_nm: float
    inertia_kgm2: float
    spinup_s: float
    stick_rad: float
    stick_floor: float
    offset_error_rad: float
    hall_error_rad: float
    loss_jitter: float
    loss_law: str
    loss_above_duty: float
    loss_plus: float
    loss_minus: float
    pullout_curve: str
    pullin_share: float

    def pullout_at_nm(self, steps_per_s: float) -> float:
        """Pull-out torque (N·m at the motor) at ``steps_per_s`` microsteps/s, on the curve
        ``pullout_curve`` names."""
        if self.pullout_curve == "linear":
            return self.pullout_nm * max(0.0, 1.0 - 0.5 * steps_per_s / self.corner_steps_per_s)
        return self.pullout_nm / (1.0 + steps_per_s / self.corner_steps_per_s)

    def required_nm(self, load_nm: float, direction: int, gear_ratio: float,
                    steps_per_s: float, steps_per_motor_rev: int) -> float:
        """Motor torque (N·m) a run towards ``direction`` at ``steps_per_s`` needs against the
        joint-side gravity torque ``load_nm`` (positive pushes towards +q): lifting or lowering
        through the worm gear, running friction, and accelerating to the rate within
        ``spinup_s``."""
        lift = -direction * load_nm
        if lift > 0.0:
            gravity = lift / (gear_ratio * self.efficiency)
        else:
            gravity = -lift * max(0.0, 1.0 / self.efficiency - 2.0) / gear_ratio
        omega = steps_per_s / steps_per_motor_rev * 2.0 * math.pi
        return gravity + self.friction_nm + self.inertia_kgm2 * omega / self.spinup_s

    def loss_fraction(self, load_nm: float, direction: int, gear_ratio: float,
                      steps_per_s: float, steps_per_motor_rev: int, duty: int = 0) -> float:
        """Fraction of the pulses lost by a run at ``duty`` (``steps_per_s``), at most 0.9.

        ``"torque"``: when the needed torque exceeds the pull-out torque at the rate the motor
        slips until the mean rate is what its torque allows (0 otherwise). ``"duty"``:
        ``loss_plus`` or ``loss_minus`` by the direction above ``loss_above_duty``. ``"stall"``:
        0 (a stalled run loses every pulse: :meth:`stalls`); ``"none"``: 0."""
        law = self.loss_law
        if law == "torque":
            need = self.required_nm(load_nm, direction, gear_ratio, steps_per_s,
                                    steps_per_motor_rev)
            have = self.pullout_at_nm(steps_per_s)
            if need <= have:
                return 0.0
            return min(0.9, 1.0 - have / need)
        if law == "duty" and duty > self.loss_above_duty:
            return min(0.9, self.loss_plus if direction > 0 else self.loss_minus)
        return 0.0

    def stalls(self, load_nm: float, direction: int, gear_ratio: float, steps_per_s: float,
               steps_per_motor_rev: int, humming: bool = False) -> bool:
        """Whether a run loses synchronism and stops (``loss_law = "stall"``): the needed torque
        exceeds the pull-out torque at the rate. A ``humming`` rotor (out of step already)
        pulls in only below ``pullin_share`` of the rate it could keep: it is judged at the rate
        over that share."""
        if self.loss_law != "stall":
            return False
        if humming:
            steps_per_s /= self.pullin_share
        return (self.required_nm(load_nm, direction, gear_ratio, steps_per_s,
                                 steps_per_motor_rev) > self.pullout_at_nm(steps_per_s))

    def jittered(self, fraction: float, normal: float) -> float:
        """A run's lost ``fraction`` scattered by ``loss_jitter`` times the standard normal draw
        ``normal`` (within 0..0.9, as :meth:`loss_fraction`)."""
        return min(0.9, max(0.0, fraction * (1.0 + self.loss_jitter * normal)))

    def stick_band_rad(self, speed_fraction: float) -> float:
        """Width (rad) of the stick-slip band after an approach at ``speed_fraction`` of the
        rated step rate (0..1)."""
        f = min(1.0, max(0.0, speed_fraction))
        return self.stick_rad * (self.stick_floor + (1.0 - self.stick_floor) * f)


@dataclass(frozen=True, slots=True)
class GeometryError:
    """Actual minus nominal DH lengths (m): one field per parameter of
    :data:`~armbench.drivers.model.twin_parameters.GEOMETRY_ERRORS`."""

    d1_m: float
    d2_m: float
    a2_m: float
    a3_m: float
    d4_m: float


def _twin_values(params: Sequence[TwinParameter], joint: int, *,
                 ideal: bool) -> dict[str, Any]:
    """The twin's field values (twin units) of ``params``: the default arm's at ``joint``
    (0-based), or (``ideal``) those without any effect."""
    out: dict[str, Any] = {}
    for p in params:
        value = p.ideal_value() if ideal else p.default_at(joint)
        out[p.name] = value if isinstance(value, str) else p.to_twin(value)
    return out


def ideal_joint(**changes: Any) -> JointPhysics:
    """A joint without any effect (no mass, play, friction or stick-slip; infinite stiffness and
    pull-out torque: the declaration's ideal values) but ``changes`` (twin units)."""
    return JointPhysics(**{**_twin_values(JOINT_PARAMETERS, 0, ideal=True), **changes})


def ideal_geometry() -> GeometryError:
    """An arm built exactly to its nominal DH lengths."""
    return GeometryError(**_twin_values(GEOMETRY_ERRORS, 0, ideal=True))


#: The default arm's joints (``docs/robot-model.md``: sources and assumptions).
DEFAULT_JOINT_PHYSICS: Final = tuple(
    JointPhysics(**_twin_values(JOINT_PARAMETERS, j, ideal=False)) for j in range(4))

_HALL: Final = TWIN["hall_error_rad"]
#: How far beyond each of its configured limits a joint's end stop lies (rad): 1°, twice the
#: largest Hall sensor error a settings file may give (``hall_error_deg``, ±0.5°). The firmware
#: counts angles from where its Hall sensor really is; an end stop on the limit itself lies that
#: error inside the limit as the firmware counts, so the limit on that side cannot be reached
#: (joint 1, Hall error 0.02°: a move to +2.4434 rad stopped at 2.4431 and timed out). A real
#: arm's end stops, too, lie beyond its working range.
END_STOP_MARGIN_RAD: Final = 2.0 * _HALL.to_twin(_HALL.accepted()[1])


def end_stop_steps(joint: JointSettings) -> tuple[int, int]:
    """The motor positions (microsteps) of the joint's two end stops: its limits widened by
    :data:`END_STOP_MARGIN_RAD`."""
    return (round((joint.lower_rad - END_STOP_MARGIN_RAD) * joint.steps_per_rad),
            round((joint.upper_rad + END_STOP_MARGIN_RAD) * joint.steps_per_rad))


#: The step-loss laws of ``JointPhysics.loss_law`` (``docs/robot-model.md``, Step loss).
LOSS_LAWS: Final = TWIN["loss_law"].choices
#: The shapes of the pull-out curve (``JointPhysics.pullout_curve``, ``docs/robot-model.md``).
PULLOUT_CURVES: Final = TWIN["pullout_curve"].choices


@dataclass(frozen=True, slots=True)
class ArmPhysics:
    """The whole physical arm: joints 1..4, the payload at the TCP, encoder noise, DH errors
    (one field per parameter of ``ARM_PARAMETERS`` besides the joints and the DH errors).

    ``payload_kg``: mass at the TCP (0..3 kg, the paper's maximum). ``noise_per_count``: chance
    that an encoder count comes with a spurious ±1 count (electrical noise on the quadrature lines
    while the motor steps). ``gravity_m_s2``: standard gravity.
    """

    joints: tuple[JointPhysics, ...]
    payload_kg: float
    noise_per_count: float
    gravity_m_s2: float
    geometry_error: GeometryError

    def actual_settings(self, nominal: RobotSettings) -> RobotSettings:
        """The real arm's robot model: nominal DH lengths and joint offsets plus their errors."""
        g, e = nominal.geometry, self.geometry_error
        geometry = Geometry(d1_m=g.d1_m + e.d1_m, d2_m=g.d2_m + e.d2_m, a2_m=g.a2_m + e.a2_m,
                            a3_m=g.a3_m + e.a3_m, d4_m=g.d4_m + e.d4_m)
        joints = tuple(replace(j, offset_rad=j.offset_rad + p.offset_error_rad)
                       for j, p in zip(nominal.joints, self.joints, strict=True))
        return replace(nominal, geometry=geometry, joints=joints)


#: The default arm (``docs/robot-model.md``).
DEFAULT_ARM: Final = ArmPhysics(
    DEFAULT_JOINT_PHYSICS, geometry_error=GeometryError(**_twin_values(GEOMETRY_ERRORS, 0,
                                                                       ideal=False)),
    **_twin_values(ARM_PARAMETERS, 0, ideal=False))


def arm_physics(table: Mapping[str, Any] | None, where: str = PHYSICS_TABLE) -> ArmPhysics:
    """Validated physics from an ``[emulator.physics]`` table: arm-wide keys, ``[…geometry_error]``
    and per-joint tables ``[….j1]`` … ``[….j4]`` (the keys of
    :mod:`~armbench.drivers.model.twin_parameters`, angles in degrees); missing keys keep the
    default arm's values."""
    table = dict(table or {})
    joints = []
    for k, base in enumerate(DEFAULT_JOINT_PHYSICS):
        name = f"j{k + 1}"
        jt = table.pop(name, {})
        if not isinstance(jt, Mapping):
            raise SettingsError(f"{where}.{name}", jt, "is not a table")
        joints.append(replace(base, **_read(JOINT_PARAMETERS, jt, f"{where}.{name}")))
    ge = table.pop("geometry_error", {})
    if not isinstance(ge, Mapping):
        raise SettingsError(f"{where}.geometry_error", ge, "is not a table")
    geometry_error = replace(DEFAULT_ARM.geometry_error,
                             **_read(GEOMETRY_ERRORS, ge, f"{where}.geometry_error"))
    arm = _read(ARM_PARAMETERS, table, where, ("j1..j4", "geometry_error"))
    return replace(DEFAULT_ARM, joints=tuple(joints), geometry_error=geometry_error, **arm)


def _read(params: Sequence[TwinParameter], table: Mapping[str, Any], where: str,
          tables: Sequence[str] = ()) -> dict[str, Any]:
    """The twin's values (by field name, twin units) of a settings ``table`` of ``params``: each
    key known, each number within the band :meth:`TwinParameter.accepted` gives, each choice one
    of its parameter's; ``tables``: the sub-tables the message lists as known too."""
    by_key = {p.key: p for p in params}
    out: dict[str, Any] = {}
    for k, v in table.items():
        p = by_key.get(k)
        if p is None:
            known = ", ".join([*tables, *sorted(by_key)])
            raise SettingsError(f"{where}.{k}", v, f"is not a known setting (known: {known})")
        if p.choices:
            if v not in p.choices:
                raise SettingsError(f"{where}.{k}", v, f"is not one of {', '.join(p.choices)}")
            out[p.name] = str(v)
        else:
            out[p.name] = p.to_twin(check(f"{where}.{k}", v, Bound(*p.accepted())))
    return out


class Mechanism:
    """The arm's physics at run time: gravity torques and deflections at a pose.

    ``angles`` returns the joints' link angles now (protocol convention, rad): the emulator reads
    them off its boards when a joint plans a run or stops.
    """

    def __init__(self, physics: ArmPhysics, nominal: RobotSettings,
                 angles: Callable[[], Sequence[float]]) -> None:
        self.physics = physics
        self.actual = physics.actual_settings(nominal)
        self.angles = angles
        table = dh_parameters(self.actual.geometry)
        self._a = [float(x) for x in table[:, 0]]
        self._ca = [round(math.cos(x), 15) for x in table[:, 1]]
        self._sa = [round(math.sin(x), 15) for x in table[:, 1]]
        self._d = [float(x) for x in table[:, 2]]
        self._signs = [j.sign for j in self.actual.joints]
        self._offsets = [j.offset_rad for j in self.actual.joints]
        g = physics.gravity_m_s2
        self._weights = [p.mass_kg * g for p in physics.joints]
        self._payload_n = physics.payload_kg * g
        self._com = [p.com_fraction for p in physics.joints]
        self._k = [p.stiffness_nm_per_rad for p in physics.joints]

    def __eq__(self, other: object) -> bool:
        """Equal when it models the same arm (truth samples compare by value)."""
        if not isinstance(other, Mechanism):
            return NotImplemented
        return self.physics == other.physics and self.actual == other.actual

    def __hash__(self) -> int:
        return hash(self.physics)

    def gravity_nm(self, q_rad: Sequence[float]) -> list[float]:
        """Gravity torque (N·m) on each joint at protocol angles ``q_rad``, positive pushing
        towards +q: link k's weight at ``com_fraction`` of the segment from frame k−1 to frame k
        (standard DH ``A = Rz(θ)·Tz(d)·Tx(a)·Rx(α)``, the actual lengths), the payload at the
        TCP. Only the horizontal components matter: τ_k = z_{k−1} · Σ (p − o_{k−1}) × (0, 0, −w).
        """
        # rotation columns x, y, z and origin o of frame k in the base frame, as plain floats
        xx, xy, xz, yx, yy, yz, zx, zy, zz = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
        ox = oy = oz = 0.0
        frames = [(0.0, 0.0, 0.0, 0.0)]  # o_x, o_y and the horizontal part of z, frames 0..4
        for k in range(4):
            th = self._signs[k] * q_rad[k] + self._offsets[k]
            ct, st = math.cos(th), math.sin(th)
            ca, sa, a, d = self._ca[k], self._sa[k], self._a[k], self._d[k]
            nxx, nxy, nxz = ct * xx + st * yx, ct * xy + st * yy, ct * xz + st * yz
            y0x, y0y, y0z = ct * yx - st * xx, ct * yy - st * xy, ct * yz - st * xz
            ox, oy, oz = ox + d * zx + a * nxx, oy + d * zy + a * nxy, oz + d * zz + a * nxz
            yx, yy, yz, zx, zy, zz = (ca * y0x + sa * zx, ca * y0y + sa * zy, ca * y0z + sa * zz,
                                      ca * zx - sa * y0x, ca * zy - sa * y0y, ca * zz - sa * y0z)
            xx, xy, xz = nxx, nxy, nxz
            frames.append((ox, oy, zx, zy))
        # moment about the base's vertical of each link's weight, accumulated from the tip:
        # w_sum (N) and its horizontal first moments mx, my (N·m) of links k..3 and the payload
        w_sum = self._payload_n
        mx, my = w_sum * frames[4][0], w_sum * frames[4][1]
        out = [0.0, 0.0, 0.0, 0.0]
        for k in range(3, -1, -1):
            w = self._weights[k]
            if w:
                f = self._com[k]
                a0, a1 = frames[k], frames[k + 1]
                w_sum += w
                mx += w * (a0[0] + f * (a1[0] - a0[0]))
                my += w * (a0[1] + f * (a1[1] - a0[1]))
            o_x, o_y, z_x, z_y = frames[k]
            # −Σ w ((p_y − o_y) z_x − (p_x − o_x) z_y)
            out[k] = self._signs[k] * -((my - w_sum * o_y) * z_x - (mx - w_sum * o_x) * z_y)
        return out

    def true_rad(self, link_rad: Sequence[float]) -> Vec4:
        """The links' true angles: ``link_rad`` plus each joint's deflection, torque / stiffness
        (the torque taken at the undeflected pose: the deflection changes it by well under 1 %)."""
        tau = self.gravity_nm(link_rad)
        return (link_rad[0] + tau[0] / self._k[0], link_rad[1] + tau[1] / self._k[1],
                link_rad[2] + tau[2] / self._k[2], link_rad[3] + tau[3] / self._k[3])

    def load_of(self, joint: int) -> Callable[[float], float]:
        """The gravity torque on joint ``joint`` (0-based) as a function of its own link angle,
        the others where they stand now: what ``JointModel`` reads at each event."""

        def load(own_rad: float) -> float:
            q = list(self.angles())
            q[joint] = own_rad
            return self.gravity_nm(q)[joint]

        return load
