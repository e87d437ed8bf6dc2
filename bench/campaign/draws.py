"""What a campaign draws: arm parameters from a calibration's uncertainties, and the conditions
of a trial (for start-up recovery: the state of each power cut).

``armbench calibrate`` writes a complete robot settings TOML whose ``[uncertainty]`` table gives
the standard error of every fitted value (``"emulator.physics.j1.backlash_deg" = 0.03``, in the
unit of its key). :func:`read_uncertainties` reads it; :func:`draw_arm` draws one arm: each value
with a standard error from a normal law around it, the others as the file has them. A draw outside
the settings' valid range (a negative play) is drawn again, so each parameter follows its normal
law restricted to the values the twin accepts.
"""

from __future__ import annotations

import random
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import (
    UNCERTAINTY_TABLE,
    RobotSettings,
    SettingsError,
    read_toml_document,
)
from armbench.drivers.model.twin_parameters import unit_of

__all__ = ["Uncertain", "apply_arm", "draw_arm", "read_uncertainties"]

#: Draws of one parameter before giving up on a law that is mostly outside its valid range.
MAX_REDRAWS: Final = 100
#: What the comment beside a fitted value began with when an older ``armbench calibrate`` kept
#: the standard errors in comments only.
_OLD_COMMENT: Final = "# fitted: ±"


@dataclass(frozen=True, slots=True)
class Uncertain:
    """A fitted setting: its dotted ``key``, fitted ``value`` and one standard error ``sigma``
    (both in ``unit``)."""

    key: str
    value: float
    sigma: float
    unit: str

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready mapping."""
        return {"key": self.key, "value": self.value, "sigma": self.sigma, "unit": self.unit}


def _lookup(data: Mapping[str, Any], key: str) -> float:
    node: Any = data
    for part in key.split("."):
        node = node[part]
    return float(node)


def read_uncertainties(path: str | Path) -> list[Uncertain]:
    """The settings of a calibration file with a standard error in its ``[uncertainty]`` table
    (in the table's order; the settings loader checked each names a number of the file); the
    others stay fixed. A file whose standard errors are comments only (written by an older
    ``armbench calibrate``) is a :class:`SettingsError` that says how to get the table."""
    p = Path(path)
    text, data = read_toml_document(p, "--settings")
    settings = RobotSettings.from_mapping(data)
    if not settings.uncertainty and _OLD_COMMENT in text:
        raise SettingsError(UNCERTAINTY_TABLE, str(p), "is missing: this file gives its standard "
                            "errors in comments, which campaigns no longer read; calibrate "
                            "again, or copy each ± into an [uncertainty] table "
                            "(docs/campaigns.md)")
    return [Uncertain(key, _lookup(data, key), sigma, unit_of(key))
            for key, sigma in settings.uncertainty.items()]


def apply_arm(settings: RobotSettings, arm: Mapping[str, float]) -> RobotSettings:
    """``settings`` with the dotted keys of ``arm`` set to its values."""
    if not arm:
        return settings
    data = settings.to_mapping()
    for key, value in arm.items():
        parts = key.split(".")
        node = data
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    return RobotSettings.from_mapping(data)


def _valid(settings: RobotSettings, arm: Mapping[str, float]) -> bool:
    from armbench.fakes.firmware.emulator_settings import emulator_settings

    try:
        emulator_settings(apply_arm(settings, arm), seed=0)
    except (ArmbenchError, ValueError, TypeError):
        return False
    return True


def draw_arm(settings: RobotSettings, uncertain: Sequence[Uncertain],
             rng: random.Random) -> dict[str, float]:
    """One arm: each uncertain value drawn from N(value, sigma), again while the settings it
    gives are invalid (at most :data:`MAX_REDRAWS` times, then a :class:`SettingsError`)."""
    arm: dict[str, float] = {}
    for u in uncertain:
        for _ in range(MAX_REDRAWS):
            value = rng.gauss(u.value, u.sigma) if u.sigma > 0 else u.value
            if _valid(settings, {**arm, u.key: value}):
                arm[u.key] = value
                break
        else:
            raise SettingsError(u.key, u.value, f"± {u.sigma:g} {u.unit}: {MAX_REDRAWS} draws "
                                                "in a row gave invalid settings")
    return arm
