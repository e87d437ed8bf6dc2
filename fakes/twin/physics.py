"""The mechanism under the firmware: gravity, compliance, gear play, step loss, kinematic error.

The joint boards (``fakes/twin/joint.py``) run the firmware step-exactly; this module describes the
arm
they drive, as a physical object (``docs/robot-model.md`` gives every default and its source):

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
from dataclasses import dataclass, field, fields, replace
from typing import Any, Final, NamedTuple

from armbench.drivers.model.bounds import Bound, check
from armbench.drivers.model.kinematics import dh_parameters
from armbench.drivers.model.settings import Geometry, JointSettings, RobotSettings, SettingsError

__all__ = [
    "DEFAULT_JOINT_PHYSICS",
    "END_STOP_MARGIN_RAD",
    "LOSS_LAWS",
    "PROFILES",
    "PULLOUT_CURVES",
    "ArmPhysics",
    "GeometryError",
    "JointPhysics",
    "Mechanism",
    "TruthSample",
    "arm_physics",
    "end_stop_steps",
]

#: The emulator's profiles: ``physical`` (the default arm of ``docs/robot-model.md``) and
#: ``ideal`` (no physics: the step-exact firmware on a perfect, rigid, play-free mechanism).
PROFILES: Final = ("physical", "ideal")

Vec4 = tuple[float, float, float, float]


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
    """The physical drive train and link of one joint (units in the names; ranges in
    ``RANGES``; sources in ``docs/robot-model.md``).

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

    mass_kg: float = 0.0
    com_fraction: float = 0.5
    stiffness_nm_per_rad: float = math.inf
    backlash_rad: float = 0.0
    hold_nm: float = 0.5
    pullout_nm: float = math.inf
    corner_steps_per_s: float = 8000.0
    efficiency: float = 0.35
    friction_nm: float = 0.0
    inertia_kgm2: float = 0.0
    spinup_s: float = 0.1
    stick_rad: float = 0.0
    stick_floor: float = 0.3
    offset_error_rad: float = 0.0
    hall_error_rad: float = 0.0
    loss_jitter: float = 0.0
    loss_law: str = "torque"
    loss_above_duty: float = 99.0
    loss_plus: float = 0.0
    loss_minus: float = 0.0
    pullout_curve: str = "hyperbolic"
    pullin_share: float = 1.0

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
    """Actual minus nominal DH lengths (m)."""

    d1_m: float = 0.0
    d2_m: float = 0.0
    a2_m: float = 0.0
    a3_m: float = 0.0
    d4_m: float = 0.0


def _deg(x: float) -> float:
    return math.radians(x)


#: The default arm's joints (``docs/robot-model.md``: sources and assumptions).
DEFAULT_JOINT_PHYSICS: Final = (
    JointPhysics(mass_kg=0.0, stiffness_nm_per_rad=4000.0, backlash_rad=_deg(0.25),
                 pullout_nm=1.9, friction_nm=0.05, inertia_kgm2=3.0e-4, stick_rad=_deg(0.03),
                 offset_error_rad=_deg(0.05), hall_error_rad=_deg(0.02)),
    JointPhysics(mass_kg=4.5, com_fraction=0.55, stiffness_nm_per_rad=6000.0,
                 backlash_rad=_deg(0.25), pullout_nm=1.5, friction_nm=0.05, inertia_kgm2=4.8e-4,
                 stick_rad=_deg(0.03), offset_error_rad=_deg(-0.15), hall_error_rad=_deg(-0.03)),
    JointPhysics(mass_kg=3.0, com_fraction=0.5, stiffness_nm_per_rad=4000.0,
                 backlash_rad=_deg(0.3), pullout_nm=1.2, friction_nm=0.04, inertia_kgm2=2.5e-4,
                 stick_rad=_deg(0.03), offset_error_rad=_deg(0.2), hall_error_rad=_deg(0.025)),
    JointPhysics(mass_kg=0.5, com_fraction=0.5, stiffness_nm_per_rad=1500.0,
                 backlash_rad=_deg(0.4), pullout_nm=0.5, friction_nm=0.02, inertia_kgm2=1.0e-4,
                 stick_rad=_deg(0.04), offset_error_rad=0.0, hall_error_rad=_deg(0.03)),
)

#: Plausible range (low, high) of every per-joint setting, in the units of its name: where hidden
#: arms are drawn from and what a fit may return (``docs/robot-model.md``).
JOINT_RANGES: Final[Mapping[str, tuple[float, float]]] = {
    "mass_kg": (0.0, 8.0),
    "com_fraction": (0.2, 0.8),
    "stiffness_nm_per_rad": (300.0, 10000.0),
    "backlash_rad": (0.0, _deg(1.0)),
    "hold_nm": (0.1, 2.0),
    "pullout_nm": (0.3, 3.0),
    "corner_steps_per_s": (2000.0, 30000.0),
    "efficiency": (0.2, 0.6),
    "friction_nm": (0.0, 0.2),
    "inertia_kgm2": (0.0, 2e-3),
    "spinup_s": (0.02, 0.5),
    "stick_rad": (0.0, _deg(0.1)),
    "stick_floor": (0.0, 1.0),
    "offset_error_rad": (_deg(-0.5), _deg(0.5)),
    "hall_error_rad": (_deg(-0.1), _deg(0.1)),
    "loss_jitter": (0.0, 0.05),
    "loss_above_duty": (0.0, 99.0),
    "loss_plus": (0.0, 0.9),
    "loss_minus": (0.0, 0.9),
    "pullin_share": (0.5, 1.0),
}
#: How far beyond each of its configured limits a joint's end stop lies (rad): 1°, twice the
#: largest Hall sensor error a settings file may give (``hall_error_deg``, ±0.5°). The firmware
#: counts angles from where its Hall sensor really is; an end stop on the limit itself lies that
#: error inside the limit as the firmware counts, so the limit on that side cannot be reached
#: (joint 1, Hall error 0.02°: a move to +2.4434 rad stopped at 2.4431 and timed out). A real
#: arm's end stops, too, lie beyond its working range.
END_STOP_MARGIN_RAD: Final = math.radians(1.0)


def end_stop_steps(joint: JointSettings) -> tuple[int, int]:
    """The motor positions (microsteps) of the joint's two end stops: its limits widened by
    :data:`END_STOP_MARGIN_RAD`."""
    return (round((joint.lower_rad - END_STOP_MARGIN_RAD) * joint.steps_per_rad),
            round((joint.upper_rad + END_STOP_MARGIN_RAD) * joint.steps_per_rad))


#: The step-loss laws of ``JointPhysics.loss_law`` (``docs/robot-model.md``, Step loss).
LOSS_LAWS: Final = ("torque", "stall", "duty", "none")
#: The shapes of the pull-out curve (``JointPhysics.pullout_curve``, ``docs/robot-model.md``).
PULLOUT_CURVES: Final = ("hyperbolic", "linear")
#: Ranges of the arm-wide settings.
ARM_RANGES: Final[Mapping[str, tuple[float, float]]] = {
    "payload_kg": (0.0, 3.0),
    "noise_per_count": (0.0, 1e-3),
    "geometry_error_m": (-0.002, 0.002),
}


@dataclass(frozen=True, slots=True)
class ArmPhysics:
    """The whole physical arm: joints 1..4, the payload at the TCP, encoder noise, DH errors.

    ``payload_kg``: mass at the TCP (0..3 kg, the paper's maximum). ``noise_per_count``: chance
    that an encoder count comes with a spurious ±1 count (electrical noise on the quadrature lines
    while the motor steps). ``gravity_m_s2``: standard gravity.
    """

    joints: tuple[JointPhysics, ...] = DEFAULT_JOINT_PHYSICS
    payload_kg: float = 0.0
    noise_per_count: float = 1e-6
    gravity_m_s2: float = 9.80665
    geometry_error: GeometryError = field(default_factory=lambda: GeometryError(
        d1_m=0.0006, d2_m=-0.0003, a2_m=0.0008, a3_m=-0.0005))

    def actual_settings(self, nominal: RobotSettings) -> RobotSettings:
        """The real arm's robot model: nominal DH lengths and joint offsets plus their errors."""
        g, e = nominal.geometry, self.geometry_error
        geometry = Geometry(d1_m=g.d1_m + e.d1_m, d2_m=g.d2_m + e.d2_m, a2_m=g.a2_m + e.a2_m,
                            a3_m=g.a3_m + e.a3_m, d4_m=g.d4_m + e.d4_m)
        joints = tuple(replace(j, offset_rad=j.offset_rad + p.offset_error_rad)
                       for j, p in zip(nominal.joints, self.joints, strict=True))
        return replace(nominal, geometry=geometry, joints=joints)


def arm_physics(table: Mapping[str, Any] | None, where: str = "emulator.physics") -> ArmPhysics:
    """Validated physics from an ``[emulator.physics]`` table: arm-wide keys, ``[…geometry_error]``
    and per-joint tables ``[….j1]`` … ``[….j4]`` (angles in degrees: ``backlash_deg``,
    ``stick_deg``, ``offset_error_deg``, ``hall_error_deg``); missing keys keep the defaults."""
    table = dict(table or {})
    default = ArmPhysics()
    joints = list(default.joints)
    for k in range(len(joints)):
        name = f"j{k + 1}"
        jt = table.pop(name, {})
        if not isinstance(jt, Mapping):
            raise SettingsError(f"{where}.{name}", jt, "is not a table")
        joints[k] = _joint_physics(joints[k], jt, f"{where}.{name}")
    ge_table = table.pop("geometry_error", {})
    if not isinstance(ge_table, Mapping):
        raise SettingsError(f"{where}.geometry_error", ge_table, "is not a table")
    ge: dict[str, float] = {}
    known_ge = {f.name for f in fields(GeometryError)}
    low, high = ARM_RANGES["geometry_error_m"]
    for ge_key, v in ge_table.items():
        if ge_key not in known_ge:
            raise SettingsError(f"{where}.geometry_error.{ge_key}", v, "is not a known setting")
        ge[str(ge_key)] = check(f"{where}.geometry_error.{ge_key}", v, Bound(low * 5, high * 5))
    geometry_error = replace(default.geometry_error, **ge)
    arm: dict[str, Any] = {}
    for key, v in table.items():
        if key not in ("payload_kg", "noise_per_count", "gravity_m_s2"):
            raise SettingsError(f"{where}.{key}", v, "is not a known setting (known: j1..j4, "
                                "geometry_error, payload_kg, noise_per_count, gravity_m_s2)")
        low, high = ARM_RANGES.get(key, (0.0, 20.0))
        arm[key] = check(f"{where}.{key}", v, Bound(low, high))
    return replace(default, joints=tuple(joints), geometry_error=geometry_error, **arm)


_DEG_KEYS: Final = {"backlash_deg": "backlash_rad", "stick_deg": "stick_rad",
                    "offset_error_deg": "offset_error_rad", "hall_error_deg": "hall_error_rad"}


def _joint_physics(base: JointPhysics, table: Mapping[str, Any], where: str) -> JointPhysics:
    known = {f.name for f in fields(JointPhysics)} - set(_DEG_KEYS.values()) | set(_DEG_KEYS)
    out: dict[str, Any] = {}
    for k, v in table.items():
        if k not in known:
            raise SettingsError(f"{where}.{k}", v, f"is not a known setting (known: "
                                                  f"{', '.join(sorted(known))})")
        if k in ("loss_law", "pullout_curve"):
            choices = LOSS_LAWS if k == "loss_law" else PULLOUT_CURVES
            if v not in choices:
                raise SettingsError(f"{where}.{k}", v, f"is not one of {', '.join(choices)}")
            out[k] = str(v)
            continue
        attr = _DEG_KEYS.get(k, k)
        low, high = JOINT_RANGES[attr]
        if attr in _DEG_KEYS.values():
            bound_deg = Bound(math.degrees(low) * 5, math.degrees(high) * 5, "deg")
            out[attr] = math.radians(check(f"{where}.{k}", v, bound_deg))
        else:
            out[attr] = check(f"{where}.{k}", v, Bound(low / 10, high * 10))
    return replace(base, **out)


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
