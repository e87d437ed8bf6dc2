"""Every calibrated parameter of the twin (the emulator's physical arm), declared once: its name,
unit, settings key, plausible range, default, source and prior standard error.

Pure data, importable from every layer: the twin builds its physics from it
(``fakes/twin/physics.py``), the settings loader checks values against it, ``armbench calibrate``
names and bounds its fits and writes its settings with it, the sensitivity table varies the
assumptions it marks, a campaign gives each drawn value its unit, the calibration page lists what
is never fitted, and ``docs/robot-model.md``'s table is generated from it
(``scripts/twin_parameter_table.py``). Adding a parameter is one entry here and the physics that
uses it (a field of ``JointPhysics``, ``ArmPhysics`` or ``GeometryError`` of the same name).

Values are in the settings file's unit (``unit``: degrees for angles); the twin's attribute
carries its own unit in its ``name`` (``backlash_rad``), and :meth:`TwinParameter.to_twin` converts.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final, Literal

__all__ = [
    "ARM_PARAMETERS",
    "GEOMETRY_ERRORS",
    "JOINT_PARAMETERS",
    "PHYSICS_TABLE",
    "TWIN",
    "TWIN_PARAMETERS",
    "Scope",
    "TwinParameter",
    "Value",
    "by_path",
    "unit_of",
]

#: Where a parameter sits in ``[emulator.physics]``: one per joint (``[….jN]``), one for the arm,
#: or one per DH length (``[….geometry_error]``).
Scope = Literal["joint", "arm", "geometry"]
#: A parameter's value: a number, or the name of a choice (a step-loss law).
Value = float | str
#: The settings table every twin parameter lives under.
PHYSICS_TABLE: Final = "emulator.physics"


@dataclass(frozen=True, slots=True)
class TwinParameter:
    """One parameter of the twin.

    ``name``: the twin's attribute (``JointPhysics.backlash_rad``); ``key``: the settings key in
    its table (``backlash_deg``), ``unit`` that key's unit ("" for a pure number), ``summary`` what
    it is in a line. ``low``..``high``: the plausible range (settings unit), where hidden arms are
    drawn from and what a fit may return; a settings file may go :attr:`band` times beyond it.
    ``default``: the default arm's value, one per joint for a joint's parameter. ``source``: the
    citation or the reasoning behind the default, ``assumption`` when no public source gives it.
    ``ideal``: its value in a joint without the effect (no play, infinite stiffness), where that
    differs from the default; ``sigma``: the prior standard error (settings unit), by default a
    sixth of the range (which then spans ±3 σ). ``fitted``: whether ``armbench calibrate``
    identifies it when its data allow; ``torque``: an assumption the fits that divide by a torque
    rest on (the sensitivity table varies it). ``choices``: the values of a categorical one.
    """

    name: str
    scope: Scope
    key: str
    unit: str
    summary: str
    low: float
    high: float
    default: tuple[Value, ...]
    source: str
    assumption: bool
    ideal: Value | None = None
    sigma: float | None = None
    fitted: bool = False
    torque: bool = False
    choices: tuple[str, ...] = ()

    def path(self, joint: int = 0) -> str:
        """The dotted settings key: ``emulator.physics.j2.backlash_deg`` (``joint`` 0-based, for
        a joint's parameter), ``emulator.physics.payload_kg``,
        ``emulator.physics.geometry_error.d1_m``."""
        table = {"joint": f"j{joint + 1}.", "arm": "", "geometry": "geometry_error."}[self.scope]
        return f"{PHYSICS_TABLE}.{table}{self.key}"

    def default_at(self, joint: int = 0) -> Value:
        """The default arm's value (settings unit) at ``joint`` (0-based; one value for the
        arm's and the geometry's parameters)."""
        return self.default[joint if self.scope == "joint" else 0]

    def ideal_value(self) -> Value:
        """The value in a joint without this effect (settings unit)."""
        return self.default_at(0) if self.ideal is None else self.ideal

    @property
    def prior_sigma(self) -> float:
        """The prior standard error (settings unit); NaN for a choice."""
        if self.choices:
            return math.nan
        return (self.high - self.low) / 6.0 if self.sigma is None else self.sigma

    @property
    def band(self) -> float:
        """How many times beyond its plausible range a settings file may set it: ten, five for
        angles and lengths (a tenth of a degree or a millimetre off is already far), one for the
        arm's own values (the paper's payload, the encoder noise, gravity)."""
        if self.scope == "arm":
            return 1.0
        return 5.0 if self.unit in ("deg", "m") else 10.0

    def accepted(self) -> tuple[float, float]:
        """The values a settings file may give (settings unit): the plausible range widened
        :attr:`band` times on each side (towards zero, for an end on the far side of it)."""
        b = self.band
        return (self.low * b if self.low < 0 else self.low / b,
                self.high * b if self.high > 0 else self.high / b)

    def to_twin(self, value: float) -> float:
        """A settings value in the twin's unit (degrees to radians)."""
        return math.radians(value) if self.unit == "deg" else value

    def from_twin(self, value: float) -> float:
        """A twin value in the settings unit (radians to degrees)."""
        return math.degrees(value) if self.unit == "deg" else value


def _joint(name: str, unit: str, summary: str, low: float, high: float,
           default: Value | tuple[Value, ...], source: str, *, key: str = "",
           assumption: bool = True, ideal: Value | None = None, fitted: bool = False,
           torque: bool = False, choices: tuple[str, ...] = ()) -> TwinParameter:
    """A joint's parameter; ``key`` defaults to ``name``, one ``default`` to all four joints."""
    values = default if isinstance(default, tuple) else (default,) * 4
    return TwinParameter(name, "joint", key or name, unit, summary, low, high, values, source,
                         assumption, ideal=ideal, fitted=fitted, torque=torque, choices=choices)


_PLASTIC = "plastic worm gears and plastic-joint tubes"

#: Per joint (``[emulator.physics.jN]``), in the order of ``JointPhysics``'s fields.
JOINT_PARAMETERS: Final = (
    _joint("mass_kg", "kg", "the link this joint carries", 0.0, 8.0, (0.0, 4.5, 3.0, 0.5),
           "the paper (§2) gives about 15 kg for the arm, split here as ~6 kg base and joint-1 "
           "drive, 4.5 kg upper arm with the elbow drive at its end, 3 kg forearm with the wrist "
           "drive, 0.5 kg flange, ~1 kg cables", ideal=0.0, torque=True),
    _joint("com_fraction", "", "its centre of mass along the segment frame k-1 -> frame k",
           0.2, 0.8, (0.5, 0.55, 0.5, 0.5),
           "tubes with the next joint's drive at their distal end", ideal=0.5,
           torque=True),
    _joint("stiffness_nm_per_rad", "N·m/rad", "gear + link torsional stiffness", 300.0, 10000.0,
           (4000.0, 6000.0, 4000.0, 1500.0),
           f"{_PLASTIC}; gives 1–2 mrad of sag at the working poses unloaded, "
           "3–5 mrad with 3 kg (a few mm at the TCP), the order a 15 kg plastic arm shows",
           ideal=math.inf, fitted=True),
    _joint("backlash_rad", "deg", "gear play, full width", 0.0, 1.0, (0.25, 0.25, 0.3, 0.4),
           "typical plastic worm-gear play (a few tenths of a degree); the smaller "
           "the gear, the larger the play", key="backlash_deg", ideal=0.0, fitted=True),
    _joint("hold_nm", "N·m", "gravity torque above which the link rests on one flank of the play",
           0.1, 2.0, 0.5, "static friction of the output bearing"),
    _joint("pullout_nm", "N·m", "stepper pull-out torque at standstill (at the motor)", 0.3, 3.0,
           (1.9, 1.5, 1.2, 0.5),
           "NEMA 23/17 steppers at the 3 A the paper runs them with (§2: \"fully "
           "working with just 3 A\"), below their rated torque", ideal=math.inf, fitted=True),
    _joint("corner_steps_per_s", "microsteps/s",
           "microstep rate where the pull-out torque has halved", 2000.0, 30000.0, 8000.0,
           "a bipolar stepper at 24 V loses about half its torque by ~1000 full "
           "steps/s (8000 microsteps/s at 8 microsteps)", torque=True),
    _joint("efficiency", "", "worm gear forward efficiency (self-locking below 0.5)", 0.2, 0.6,
           0.35, "single-start plastic worm gear, self-locking, as the power-cut "
           "model of `docs/emulator.md` assumes (a joint stays where it was)", torque=True),
    _joint("friction_nm", "N·m", "running friction at the motor", 0.0, 0.2,
           (0.05, 0.05, 0.04, 0.02), "a few percent of the pull-out torque",
           ideal=0.0, torque=True),
    _joint("inertia_kgm2", "kg·m²", "rotor + link inertia reflected to the motor", 0.0, 2e-3,
           (3.0e-4, 4.8e-4, 2.5e-4, 1.0e-4),
           "rotor inertia ~3e-5 kg·m² plus the link's (~1 kg·m² for the upper arm) "
           "over N²", ideal=0.0, torque=True),
    _joint("spinup_s", "s", "time the drive needs to reach the commanded rate", 0.02, 0.5, 0.1,
           "the firmware has no ramp; a stepper reaches its rate within a few "
           "tens of steps", torque=True),
    _joint("stick_rad", "deg", "stick-slip band of a stop at full speed", 0.0, 0.1,
           (0.03, 0.03, 0.03, 0.04),
           "the paper blames the jerky motion on \"the motors' high static friction\" (§7); sized "
           "so that RP is a few tenths of a mm at full speed (igus specifies ±1 mm repeatability "
           "for the robolink family)", key="stick_deg", assumption=False, ideal=0.0,
           fitted=True),
    _joint("stick_floor", "", "its fraction at the lowest speed", 0.0, 1.0, 0.3,
           "a stop at standstill speed still scatters a little (static friction)"),
    _joint("offset_error_rad", "deg", "actual minus nominal DH offset", -0.5, 0.5,
           (0.05, -0.15, 0.2, 0.0),
           "where the links really point at the assembled zero pose",
           key="offset_error_deg", ideal=0.0, fitted=True),
    _joint("hall_error_rad", "deg", "actual minus nominal Hall position", -0.1, 0.1,
           (0.02, -0.03, 0.025, 0.03),
           "Hall switch and magnet mounting; small enough that a recovered joint "
           "stays within the start-up suite's 1 mrad", key="hall_error_deg", ideal=0.0,
           fitted=True),
    _joint("loss_jitter", "", "relative scatter of a run's lost fraction (0: deterministic)",
           0.0, 0.05, 0.0,
           "the torque-speed curve is a property of motor, driver and supply; at "
           "the same load, rate and temperature a slipping stepper loses the same share, so the "
           "default step loss is deterministic. Run-to-run variation on a real arm (supply sag, "
           "winding temperature, mid-band resonance) is either slow drift (recalibrate) or set "
           "per lab; with `loss_jitter = j` a replay's floor grows to about `j` × the lost steps",
           assumption=False),
    _joint("loss_law", "", 'how the drive loses steps: "torque", "stall", "duty" or "none"',
           math.nan, math.nan, "torque",
           "a proportional slip is the simplest law that makes a loaded lift "
           "slower; a real stepper that loses synchronism usually stalls instead. Kept the "
           "default so the default arm's figures stay as measured; a calibration picks the law "
           "the arm shows", fitted=True, choices=("torque", "stall", "duty", "none")),
    _joint("loss_above_duty", "", '"duty": a share is lost at duties above this', 0.0, 99.0, 99.0,
           "only with `loss_law = \"duty\"`; no source: the default loses nothing, a calibration "
           "fits what the arm shows", assumption=False, fitted=True),
    _joint("loss_plus", "", '"duty": share lost moving towards +q', 0.0, 0.9, 0.0,
           "only with `loss_law = \"duty\"`; no source: the default loses nothing, a calibration "
           "fits what the arm shows", assumption=False, fitted=True),
    _joint("loss_minus", "", '"duty": share lost moving towards -q', 0.0, 0.9, 0.0,
           "only with `loss_law = \"duty\"`; no source: the default loses nothing, a calibration "
           "fits what the arm shows", assumption=False, fitted=True),
    _joint("pullout_curve", "", 'its shape: "hyperbolic" (never zero) or "linear" (zero at 2 x '
           'corner)', math.nan, math.nan, "hyperbolic",
           "no datasheet of the arm's steppers and drivers is public. A chopper "
           "drive at a supply well above the winding's rated voltage holds roughly constant "
           "power above its corner (torque ∝ 1/rate: hyperbolic); a low supply voltage or a "
           "large winding inductance gives a torque that falls nearly straight from standstill "
           "to a free-running rate (linear). Kept hyperbolic so the default arm's figures stay "
           "as measured; a calibration that sees stalls picks the shape by held-out prediction",
           fitted=True, choices=("hyperbolic", "linear")),
    _joint("pullin_share", "", '"stall": a stalled rotor restarts below this share of its '
           'keep-up rate', 0.5, 1.0, 1.0,
           "only with `loss_law = \"stall\"`: a rotor out of step falls back in "
           "below its pull-out rate (the pull-in rate is the lower of the two on a stepper's "
           "curves); 1 is no hysteresis, kept so nothing changes where it is not set"),
)

#: The arm's own (``[emulator.physics]``), in the order of ``ArmPhysics``'s fields.
ARM_PARAMETERS: Final = (
    TwinParameter("payload_kg", "arm", "payload_kg", "kg", "at the TCP, 0..3 kg", 0.0, 3.0,
                  (0.0,), "paper: maximum payload 3 kg; no gripper by default (d4 = 0)",
                  assumption=False, torque=True),
    TwinParameter("noise_per_count", "arm", "noise_per_count", "",
                  "chance of a spurious ±1 count per encoder count", 0.0, 1e-3, (1e-6,),
                  "a quadrature decoder with Schmitt-trigger inputs rejects nearly "
                  "all edges from the stepper drivers' switching; one spurious count per million "
                  "(one per 500 motor revolutions) for a well-wired arm. The earlier 5e-5 (a count "
                  "every 10 revolutions) had no source either and made most of the random part of "
                  "a replay (see Scatter)", assumption=True),
    TwinParameter("gravity_m_s2", "arm", "gravity_m_s2", "m/s²", "gravitational acceleration",
                  0.0, 20.0, (9.80665,),
                  "standard gravity (ISO 80000-3); the range admits a weightless arm (0) for tests "
                  "of the rest; σ from the 9.78–9.83 m/s² gravity spans over the Earth's surface",
                  assumption=False, sigma=0.02),
)

_DH = "assembly and tube-cutting tolerances"

#: Actual minus nominal DH lengths (``[emulator.physics.geometry_error]``, metres), in the order
#: of ``GeometryError``'s fields. The tool offset ``d4_m`` is not fitted: it turns the TCP about
#: joint 3 as joint 3's offset does, and only their combination shows.
GEOMETRY_ERRORS: Final = tuple(
    TwinParameter(name, "geometry", name, "m", f"actual minus nominal {name.removesuffix('_m')}",
                  -0.002, 0.002, (value,), _DH, assumption=True, ideal=0.0,
                  fitted=name != "d4_m")
    for name, value in (("d1_m", 0.0006), ("d2_m", -0.0003), ("a2_m", 0.0008),
                        ("a3_m", -0.0005), ("d4_m", 0.0)))

#: Every twin parameter: the joints', the arm's, the geometry's.
TWIN_PARAMETERS: Final = (*JOINT_PARAMETERS, *ARM_PARAMETERS, *GEOMETRY_ERRORS)
#: Every twin parameter by name.
TWIN: Final[Mapping[str, TwinParameter]] = {p.name: p for p in TWIN_PARAMETERS}
_BY_PATH: Final = {p.path(j): p for p in TWIN_PARAMETERS
                   for j in (range(4) if p.scope == "joint" else (0,))}


def by_path(path: str) -> TwinParameter | None:
    """The parameter a dotted settings key names (``emulator.physics.j2.backlash_deg``), if any."""
    return _BY_PATH.get(path)


#: The unit a key of the robot model ends in (``offset_deg``): its keys carry their units.
_SUFFIX_UNITS: Final = (("_deg", "deg"), ("_rad", "rad"), ("_m", "m"), ("_s", "s"),
                        ("_kg", "kg"), ("_hz", "Hz"))


def unit_of(path: str) -> str:
    """The unit of a dotted settings key: its twin parameter's, else the one its name ends in
    (``joints.j2.offset_deg``: deg), "" for a pure number (a gear ratio)."""
    p = by_path(path)
    if p is not None:
        return p.unit
    return next((unit for suffix, unit in _SUFFIX_UNITS if path.endswith(suffix)), "")
