"""Hidden arms for the identification tests: physical parameters drawn at random within the ranges
documented in ``docs/robot-model.md`` (``armbench.fakes.twin.physics``), served as
``fake://?settings=hidden.toml``, and the check of a calibration against them.

Only what ``docs/calibration.md`` lists as identifiable is drawn; the rest (link masses, worm
efficiency, friction, inertia, corner rate, hold torque, encoder noise, the tool offset d4) stays
at the default arm's, which the calibration takes as its prior, as a lab would weigh its links.
The payload is drawn too and given to the calibration as known (a lab knows what it mounted).
"""

from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Any

from armbench.bench.calibrate.model import Fitted
from armbench.bench.calibrate.output import toml_text
from armbench.fakes.twin.physics import ARM_RANGES, JOINT_RANGES

__all__ = ["check_recovery", "draw_hidden", "truth_of_key", "write_hidden"]


def _u(rng: random.Random, name: str, scale: float = 1.0) -> float:
    low, high = JOINT_RANGES[name]
    return rng.uniform(low, high) * scale


def draw_hidden(seed: int) -> dict[str, Any]:
    """The ``[emulator]`` table of a hidden arm (seeded)."""
    rng = random.Random(seed)
    joints: dict[str, dict[str, float]] = {}
    for j in range(1, 5):
        t = {
            "backlash_deg": math.degrees(_u(rng, "backlash_rad")),
            "stick_deg": math.degrees(_u(rng, "stick_rad")),
            "hall_error_deg": math.degrees(_u(rng, "hall_error_rad")),
            "offset_error_deg": math.degrees(_u(rng, "offset_error_rad")),
        }
        if j in (2, 3):
            t["stiffness_nm_per_rad"] = _u(rng, "stiffness_nm_per_rad")
            t["pullout_nm"] = _u(rng, "pullout_nm")
        joints[f"j{j}"] = t
    low, high = ARM_RANGES["geometry_error_m"]
    geometry = {k: rng.uniform(low, high) for k in ("d1_m", "d2_m", "a2_m", "a3_m")}
    payload = rng.uniform(*ARM_RANGES["payload_kg"])
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
