"""How much each headline figure of a calibration moves across the plausible range of each
assumption it rests on.

The fits of the stiffness and of the step loss divide by torques computed from defaults no
traffic shows (masses, payload, worm efficiency, friction, the pull-out curve's corner, inertia
and spin-up: ``torque`` in :mod:`~armbench.drivers.model.twin_parameters`). Each is set to both
ends of its plausible range in the base, every joint at once, and the fit is repeated on the
same observations: the table gives each identified figure at the two ends. When there is nothing
to show (no such figure was identified, or none moves) the table has no rows and its ``note``
says why.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Final

from armbench.bench.calibrate.model import Fitted, Observations, Sensitivity, SensitivityRow
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.model.twin_parameters import PHYSICS_TABLE, TWIN_PARAMETERS, TwinParameter

__all__ = ["ASSUMPTIONS", "NOTHING_TO_VARY", "Sensitivity", "SensitivityRow", "sensitivity"]

#: The values the torque fits take from the base and never fit, varied (the joints' first).
ASSUMPTIONS: Final = tuple(p for p in TWIN_PARAMETERS if p.torque)
#: Why a calibration has no sensitivity table when it identified no figure the assumptions enter.
NOTHING_TO_VARY: Final = (
    "no figure that rests on the assumed torques was identified (the stiffness, which needs a "
    "reference instrument; pull-out torques, loss shares and gear ratios, which need speed runs "
    "that show a step loss or a speed scale beyond the noise): there is nothing to vary")


def _with(base: RobotSettings, p: TwinParameter, value: float) -> RobotSettings:
    """``base`` with ``p`` at ``value`` (on every joint, for a joint's parameter)."""
    data = base.to_mapping()
    for j in range(4 if p.scope == "joint" else 1):
        table = data
        *path, key = p.path(j).split(".")
        for part in path:
            table = table.setdefault(part, {})
        table[key] = value
    return RobotSettings.from_mapping(data)


def _headline(fitted: Sequence[Fitted]) -> dict[str, float]:
    return {f.key.removeprefix(f"{PHYSICS_TABLE}."): f.value for f in fitted
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
    for p in ASSUMPTIONS:
        low, high = p.low, p.high
        ends = [_headline(fit(obs, _with(base, p, v))) for v in (low, high)]
        cells = []
        for k in keys:
            lo, hi = (e.get(k, math.nan) for e in ends)
            same = all(math.isclose(v, nominal[k], rel_tol=1e-6) for v in (lo, hi))
            cells.append("" if same else f"{lo:.4g} / {hi:.4g}")
        rows.append(SensitivityRow(p.key, f"{low:g}..{high:g}", cells))
    if not any(any(r.cells) for r in rows):
        return Sensitivity(keys, [], f"no identified figure that rests on them ({', '.join(keys)})"
                                     " moves when any assumption is set to either end of its "
                                     "range")
    return Sensitivity(keys, rows)
