"""Hidden arms for the identification tests: physical parameters drawn at random within the ranges
documented in ``docs/robot-model.md`` (``armbench.drivers.model.twin_parameters``), served as
``fake://?settings=hidden.toml``, and the check of a calibration against them.

Only what ``docs/calibration.md`` lists as identifiable is drawn; the rest (link masses, worm
efficiency, friction, inertia, corner rate, hold torque, encoder noise, the tool offset d4) stays
at the default arm's, which the calibration takes as its prior, as a lab would weigh its links.
The payload is drawn too and given to the calibration as known (a lab knows what it mounted).
"""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

from armbench.bench.calibrate.model import Fitted
from armbench.bench.calibrate.output import toml_text
from armbench.drivers.model.twin_parameters import GEOMETRY_ERRORS, TWIN

__all__ = ["check_recovery", "draw_hidden", "truth_of_key", "write_hidden"]


def _u(rng: random.Random, name: str) -> float:
    """A value of twin parameter ``name`` within its plausible range (settings unit)."""
    p = TWIN[name]
    return rng.uniform(p.low, p.high)


def draw_hidden(seed: int) -> dict[str, Any]:
    """The ``[emulator]`` table of a hidden arm (seeded)."""
    rng = random.Random(seed)
    joints: dict[str, dict[str, float]] = {}
    for j in range(1, 5):
        drawn = ["backlash_rad", "stick_rad", "hall_error_rad", "offset_error_rad"]
        if j in (2, 3):
            drawn += ["stiffness_nm_per_rad", "pullout_nm"]
        joints[f"j{j}"] = {TWIN[name].key: _u(rng, name) for name in drawn}
    geometry = {p.key: rng.uniform(p.low, p.high) for p in GEOMETRY_ERRORS if p.fitted}
    payload = _u(rng, "payload_kg")
    return {"seed": seed, "physics": {"payload_kg": payload, "geometry_error": geometry,
                                      **joints}}


def write_hidden(table: dict[str, Any], folder: Path) -> tuple[Path, Path]:
    """``hidden.toml`` (the arm) and ``base.toml`` (what the lab knows: the payload)."""
    hidden = folder / "hidden.toml"
    hidden.write_text(toml_text({"emulator": table}), encoding="utf-8")
    base = folder / "base.toml"
    base.write_text(toml_text({"emulator": {"physics": {
        "payload_kg": table["physics"]["payload_kg"]}}}), encoding="utf-8")
    return hidden, base


def truth_of_key(table: dict[str, Any], key: str) -> float | None:
    """The hidden value of a settings key (``emulator.physics.j2.backlash_deg``), if drawn."""
    node: Any = {"emulator": table}
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return float(node)


def check_recovery(table: dict[str, Any], fitted: list[Fitted]) -> dict[str, bool]:
    """For every identified parameter that was drawn: whether its 95 % interval covers it."""
    out = {}
    for f in fitted:
        if not f.identified:
            continue
        truth = truth_of_key(table, f.key)
        if truth is not None:
            out[f.key] = f.covers(truth)
    return out
