"""What a campaign draws: arm parameters from a calibration's uncertainties, and the conditions
of a trial (for start-up recovery: the state of each power cut).

``armbench calibrate`` writes a complete robot settings TOML in which every fitted value carries
its standard error in the comment beside it (``backlash_deg = 0.21  # fitted: ± 0.03 deg (1 σ);
...``). :func:`read_uncertainties` reads those back; :func:`draw_arm` draws one arm: each fitted
value from a normal law around it with its sigma, the others as the file has them. A draw outside
the settings' valid range (a negative play) is drawn again, so each parameter follows its normal
law restricted to the values the twin accepts.
"""

from __future__ import annotations

import random
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from armbench.drivers.model.bounds import Bound, check
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings, SettingsError, read_toml_document

__all__ = ["Uncertain", "apply_arm", "draw_arm", "read_uncertainties"]

#: ``key = value  # fitted: ± SIGMA UNIT (1 σ); ...``: the comment ``armbench calibrate`` writes.
_FITTED: Final = re.compile(
    r"^\s*(?P<key>[A-Za-z0-9_-]+|\"[^\"]+\")\s*=\s*[^#]*#\s*fitted:\s*±\s*"
    r"(?P<sigma>[-+0-9.eE]+|inf|nan)\s*(?P<unit>[^(;]*?)\s*\(1\s*σ\)")
_TABLE: Final = re.compile(r"^\s*\[(?P<name>[^\[\]]+)\]\s*(#.*)?$")
#: Draws of one parameter before giving up on a law that is mostly outside its valid range.
MAX_REDRAWS: Final = 100


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


def _unquote(part: str) -> str:
    part = part.strip()
    return part[1:-1] if part.startswith('"') and part.endswith('"') else part


def _lookup(data: Mapping[str, Any], key: str) -> object:
    node: object = data
    for part in key.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return None
        node = node[part]
    return node


def read_uncertainties(path: str | Path) -> list[Uncertain]:
    """The fitted settings of a calibration file with their sigmas (in file order); settings
    without a ``fitted: ± sigma`` comment stay fixed. A sigma that is not a finite number >= 0,
    or a fitted key that is not a number, is a :class:`SettingsError` naming it."""
    p = Path(path)
    text, data = read_toml_document(p, "--settings")
    out: list[Uncertain] = []
    table: list[str] = []
    for line in text.splitlines():
        header = _TABLE.match(line)
        if header is not None:
            table = [_unquote(x) for x in header["name"].split(".")]
            continue
        m = _FITTED.match(line)
        if m is None:
            continue
        key = ".".join([*table, _unquote(m["key"])])
        sigma = float(m["sigma"])
        value = _lookup(data, key)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SettingsError(key, value, f"in {p} has a sigma but is not a number")
        check(key, sigma, Bound(0.0, why=f"its sigma in {p}"))
        out.append(Uncertain(key, float(value), sigma, m["unit"].strip()))
    return out


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
