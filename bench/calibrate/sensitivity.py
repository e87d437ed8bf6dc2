"""How much each headline figure of a calibration moves across the plausible range of each
assumption it rests on.

The fits of the stiffness and of the step loss divide by torques computed from defaults no
traffic shows (masses, payload, worm efficiency, friction, the pull-out curve's corner, inertia
and spin-up: ``docs/robot-model.md`` marks them as assumptions). Each is set to both ends of its
documented range (``JOINT_RANGES``, ``ARM_RANGES``) in the base, every joint at once, and the fit
is repeated on the same observations: the table gives each identified figure at the two ends.
When there is nothing to show (no such figure was identified, or none moves) the table has no
rows and its ``note`` says why.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Final

from armbench.bench.calibrate.model import Fitted, Observations, Sensitivity, SensitivityRow
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.twin.physics import ARM_RANGES, JOINT_RANGES

__all__ = ["ASSUMPTIONS", "NOTHING_TO_VARY", "Sensitivity", "SensitivityRow", "sensitivity"]

#: The assumed per-joint defaults varied (``docs/robot-model.md``: none has a public source).
ASSUMPTIONS: Final = ("mass_kg", "com_fraction", "efficiency", "friction_nm",
                      "corner_steps_per_s", "inertia_kgm2", "spinup_s")
#: Why a calibration has no sensitivity table when it identified no figure the assumptions enter.
NOTHING_TO_VARY: Final = (
    "no figure that rests on the assumed torques was identified (the stiffness, which needs a "
    "reference instrument; pull-out torques, loss shares and gear ratios, which need speed runs "
    "that show a step loss or a speed scale beyond the noise): there is nothing to vary")


def _with(base: RobotSettings, name: str, value: float) -> RobotSettings:
    data = base.to_mapping()
    physics = data.setdefault("emulator", {}).setdefault("physics", {})
    if name == "payload_kg":
        physics["payload_kg"] = value
    else:
        for j in range(4):
            physics.setdefault(f"j{j + 1}", {})[name] = value
    return RobotSettings.from_mapping(data)


def _headline(fitted: Sequence[Fitted]) -> dict[str, float]:
    return {f.key.removeprefix("emulator.physics."): f.value for f in fitted
            if f.identified and f.choice is None and not f.key.startswith("timing.")
            and math.isfinite(f.value) and not f.key.endswith(("_deg", "_m"))}


def sensitivity(obs: Observations, base: RobotSettings, fitted: Sequence[Fitted],
                fit: Callable[[Observations, RobotSettings], list[Fitted]]) -> Sensitivity:
    """The table for ``fitted`` (the fit of ``obs`` on ``base``), refitting with ``fit``. Only
    the figures that depend on a torque (stiffness, step loss, gear ratio) are listed: the play,
    Hall and kinematic fits use none of the assumptions."""
    nominal = _headline(fitted)
    keys = sorted(nominal)
    rows: list[SensitivityRow] = []
    if not keys:
        return Sensitivity([], [], NOTHING_TO_VARY)
    for name in (*ASSUMPTIONS, "payload_kg"):
        low, high = ARM_RANGES[name] if name == "payload_kg" else JOINT_RANGES[name]
        ends = [_headline(fit(obs, _with(base, name, v))) for v in (low, high)]
        cells = []
        for k in keys:
            lo, hi = (e.get(k, math.nan) for e in ends)
            same = all(math.isclose(v, nominal[k], rel_tol=1e-6) for v in (lo, hi))
            cells.append("" if same else f"{lo:.4g} / {hi:.4g}")
        rows.append(SensitivityRow(name, f"{low:g}..{high:g}", cells))
    if not any(any(r.cells) for r in rows):
        return Sensitivity(keys, [], f"no identified figure that rests on them ({', '.join(keys)})"
                                     " moves when any assumption is set to either end of its "
                                     "range")
    return Sensitivity(keys, rows)
