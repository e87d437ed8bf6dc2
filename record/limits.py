"""Limits and regression tolerances of the bench, loaded from a TOML file (``bench.toml``).

Limits live apart from suite code so a lab can tighten them without touching Python. Each limit
names a metric (``*`` wildcards allowed), its unit and a ``low`` and/or ``high`` bound; a metric
with no matching limit is reported but not judged. The same file holds the regression tolerances
used against a baseline run, the raw ``[bench]`` / ``[suites.<name>]`` parameter tables read by
the suites, and the ``[dut]`` table naming the unit under test (:mod:`armbench.record.dut`). The
format and the matching rules are documented in ``docs/record.md``.

Errors in the file raise :class:`~armbench.drivers.model.settings.SettingsError` naming the dotted
field.
"""

from __future__ import annotations

import copy
import functools
import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

from armbench.drivers.model.bounds import Bound, check
from armbench.drivers.model.settings import SettingsError, read_toml
from armbench.record.dut import Dut, parse_dut

__all__ = [
    "DEFAULT_TOLERANCE_PCT",
    "SPEC_VERSION",
    "Limit",
    "LimitJson",
    "LimitsConfig",
    "Tolerance",
    "best_match",
    "load_limits",
    "matches",
    "parse_limits",
]

#: The version of the limits file format this module reads (the file's ``spec_version``).
SPEC_VERSION = "armbench-limits/1"

#: How much (percent of the baseline value) a metric may get worse before it counts as regressed,
#: when the file does not say otherwise.
DEFAULT_TOLERANCE_PCT = 10.0

_TOP_KEYS = {"spec_version", "required", "optional", "limits", "regression", "bench",
             "suites", "dut"}
_LIMIT_KEYS = {"low", "high", "unit"}
_REGRESSION_KEYS = {"default_tolerance_pct", "metrics"}
_TOLERANCE_KEYS = {"tolerance_pct", "tolerance_abs"}
_NAME_RE = re.compile(r"[A-Za-z0-9_.*%-]+")
#: A limit's ends are any finite numbers (low not above high); a tolerance is not negative.
_FINITE = Bound()
_TOLERANCE_PCT = Bound(0.0, unit="%")
_TOLERANCE_ABS = Bound(0.0)



class LimitJson(TypedDict):
    """The JSON object of a :class:`Limit` (the ``limit`` field of a measurement in
    ``results.json``)."""

    metric: str
    unit: str
    low: float | None
    high: float | None

@dataclass(frozen=True, slots=True)
class Limit:
    """Bounds of a metric, inclusive, in ``unit``: ``low <= value <= high``; either may be None.

    ``metric`` is the name or wildcard pattern as written in the limits file.
    """

    metric: str
    unit: str
    low: float | None = None
    high: float | None = None

    def check(self, value: float) -> bool:
        """True when ``value`` (in ``unit``) lies within the bounds (a NaN never does)."""
        if math.isnan(value):
            return False
        if self.low is not None and value < self.low:
            return False
        return self.high is None or value <= self.high

    def describe(self) -> str:
        """The bounds for people: ``"<= 5 mm"``, ``">= 1 %"`` or ``"0.5 .. 5 mm"``."""
        if self.low is not None and self.high is not None:
            return f"{self.low:g} .. {self.high:g} {self.unit}".rstrip()
        if self.high is not None:
            return f"<= {self.high:g} {self.unit}".rstrip()
        return f">= {self.low:g} {self.unit}".rstrip()

    def to_json(self) -> LimitJson:
        """The JSON object of this limit (the ``limit`` field of a measurement)."""
        return {"metric": self.metric, "unit": self.unit, "low": self.low, "high": self.high}


@dataclass(frozen=True, slots=True)
class Tolerance:
    """How much a metric may get worse than its baseline value: ``tolerance_pct`` percent of
    ``|baseline|`` plus ``tolerance_abs`` in the metric's own unit."""

    tolerance_pct: float
    tolerance_abs: float = 0.0

    def allowance(self, baseline: float) -> float:
        """The allowed worsening (metric unit) relative to a baseline value (metric unit)."""
        return abs(baseline) * self.tolerance_pct / 100.0 + self.tolerance_abs


@dataclass(frozen=True)
class LimitsConfig:
    """A parsed limits file. The empty default judges nothing and uses the default tolerance.

    ``limits`` and ``tolerances`` are keyed by metric pattern; ``bench`` and ``suites`` are the
    raw parameter tables; ``dut`` the unit under test its ``[dut]`` table names; ``path`` is the
    file it came from (None when built in code).
    """

    spec_version: str = SPEC_VERSION
    limits: Mapping[str, Limit] = field(default_factory=dict)
    default_tolerance_pct: float = DEFAULT_TOLERANCE_PCT
    tolerances: Mapping[str, Tolerance] = field(default_factory=dict)
    bench: Mapping[str, Any] = field(default_factory=dict)
    suites: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    path: str | None = None
    required: tuple[str, ...] = ()
    """What a run must measure to pass besides the suites it runs: suite names, metric names or
    ``*`` patterns (``"accuracy.*.true_mean_mm"``: a lab that has a tracker)."""
    optional: tuple[str, ...] = ()
    """Suites a run may leave untested without failing its verdict (default: none)."""
    dut: Dut = field(default_factory=Dut)

    def limit_for(self, metric: str) -> Limit | None:
        """The limit of ``metric``: the most specific matching pattern's, or None."""
        pattern = best_match(self.limits, metric)
        return None if pattern is None else self.limits[pattern]

    def tolerance_for(self, metric: str) -> Tolerance:
        """The regression tolerance of ``metric``: the most specific matching
        ``[regression.metrics]`` entry, else ``default_tolerance_pct`` with no absolute slack."""
        pattern = best_match(self.tolerances, metric)
        if pattern is None:
            return Tolerance(self.default_tolerance_pct)
        return self.tolerances[pattern]

    def to_mapping(self) -> dict[str, Any]:
        """The config as a TOML-shaped mapping that :func:`parse_limits` reads back to an equal
        config (defaults written out: what ``armbench config show`` prints)."""
        limits = {name: {k: v for k, v in (("low", lim.low), ("high", lim.high),
                                            ("unit", lim.unit)) if v is not None}
                  for name, lim in self.limits.items()}
        tolerances = {name: {"tolerance_pct": t.tolerance_pct, "tolerance_abs": t.tolerance_abs}
                      for name, t in self.tolerances.items()}
        return {
            "spec_version": self.spec_version,
            "required": list(self.required),
            "optional": list(self.optional),
            "bench": self.bench_params(),
            "limits": limits,
            "regression": {"default_tolerance_pct": self.default_tolerance_pct,
                           "metrics": tolerances},
            "suites": {name: self.suite_params(name) for name in self.suites},
            **({"dut": {**{k: v for k, v in self.dut.items() if not k.startswith("meta.")},
                        "meta": dict(self.dut.meta)}} if self.dut else {}),
        }

    def bench_params(self) -> dict[str, Any]:
        """A copy of the raw ``[bench]`` table (empty if the file has none)."""
        return copy.deepcopy(dict(self.bench))

    def suite_params(self, name: str) -> dict[str, Any]:
        """A copy of the raw ``[suites.<name>]`` table (empty if the file has none)."""
        return copy.deepcopy(dict(self.suites.get(name, {})))


# --------------------------------------------------------------------------------------------
# Wildcard matching
# --------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=1024)
def _compile(pattern: str) -> re.Pattern[str]:
    return re.compile(".*".join(re.escape(part) for part in pattern.split("*")))


def _specificity(pattern: str) -> tuple[bool, int, int, int]:
    """Larger is more specific: exact name, more literal characters, later first wildcard,
    fewer wildcards."""
    stars = pattern.count("*")
    first = pattern.find("*")
    return (stars == 0, len(pattern) - stars, len(pattern) if first < 0 else first, -stars)


def best_match(patterns: Iterable[str], metric: str) -> str | None:
    """The most specific of ``patterns`` matching ``metric``, or None.

    ``*`` matches any run of characters, dots included (``"repeatability.*.rp_mm"`` matches
    ``"repeatability.v50.p1.rp_mm"``). Precedence: an exact name; then the pattern with the most
    literal characters; then the one whose first ``*`` comes later; then the fewest ``*``; a
    remaining tie goes to the pattern that sorts first.
    """
    matching = [p for p in patterns if matches(p, metric)]
    if not matching:
        return None
    return min(matching, key=lambda p: (tuple(-k for k in _specificity(p)), p))


def matches(pattern: str, metric: str) -> bool:
    """Whether the limits file's ``pattern`` (``*`` wildcards, see :func:`best_match`) matches
    the metric name ``metric``."""
    return _compile(pattern).fullmatch(metric) is not None


# --------------------------------------------------------------------------------------------
# Parsing
# --------------------------------------------------------------------------------------------


def load_limits(path: str | Path) -> LimitsConfig:
    """Load and validate a limits file (TOML); errors raise ``SettingsError`` naming the field."""
    p = Path(path)
    data = read_toml(p, "limits file")
    return parse_limits(data, path=str(p))


def parse_limits(data: Mapping[str, Any], *, path: str | None = None) -> LimitsConfig:
    """Validate a TOML-shaped mapping of the limits format; ``path`` is kept for the record."""
    _unknown("", data, _TOP_KEYS)
    version = data.get("spec_version")
    if version is None:
        raise SettingsError("spec_version", None, f"is missing; expected {SPEC_VERSION!r}")
    if version != SPEC_VERSION:
        raise SettingsError("spec_version", version,
                            f"is not supported (this armbench reads {SPEC_VERSION!r})")

    limits: dict[str, Limit] = {}
    for metric, table in _table("limits", data.get("limits", {})).items():
        limits[metric] = _parse_limit(metric, table)

    regression = _table("regression", data.get("regression", {}))
    _unknown("regression", regression, _REGRESSION_KEYS)
    default_pct = check("regression.default_tolerance_pct",
                        regression.get("default_tolerance_pct", DEFAULT_TOLERANCE_PCT),
                        _TOLERANCE_PCT)
    tolerances: dict[str, Tolerance] = {}
    for metric, table in _table("regression.metrics", regression.get("metrics", {})).items():
        where = f"regression.metrics.{_quote(metric)}"
        _check_name(where, metric)
        t = _table(where, table)
        _unknown(where, t, _TOLERANCE_KEYS)
        if not t:
            raise SettingsError(where, dict(t), "sets neither tolerance_pct nor tolerance_abs")
        pct = check(f"{where}.tolerance_pct", t.get("tolerance_pct", default_pct),
                    _TOLERANCE_PCT)
        slack = check(f"{where}.tolerance_abs", t.get("tolerance_abs", 0.0), _TOLERANCE_ABS)
        tolerances[metric] = Tolerance(pct, slack)

    required = _names("required", data.get("required", []))
    optional = _names("optional", data.get("optional", []))
    bench = _table("bench", data.get("bench", {}))
    suites = _table("suites", data.get("suites", {}))
    for name, table in suites.items():
        _table(f"suites.{_quote(name)}", table)
    return LimitsConfig(
        spec_version=version,
        limits=limits,
        default_tolerance_pct=default_pct,
        tolerances=tolerances,
        bench=copy.deepcopy(dict(bench)),
        suites={name: copy.deepcopy(dict(table)) for name, table in suites.items()},
        path=path,
        required=required,
        optional=optional,
        dut=parse_dut(data.get("dut", {})),
    )


def _names(where: str, value: object) -> tuple[str, ...]:
    """A list of suite or metric names (``*`` wildcards allowed), each checked."""
    if not isinstance(value, list):
        raise SettingsError(where, value, "is not a list of names")
    for i, name in enumerate(value):
        if not isinstance(name, str):
            raise SettingsError(f"{where}[{i}]", name, "is not a string")
        _check_name(f"{where}[{i}]", name)
    return tuple(dict.fromkeys(value))


def _parse_limit(metric: str, table: object) -> Limit:
    where = f"limits.{_quote(metric)}"
    _check_name(where, metric)
    t = _table(where, table)
    _unknown(where, t, _LIMIT_KEYS)
    if "unit" not in t:
        raise SettingsError(f"{where}.unit", None, "is missing (write unit = \"\" if the "
                                                   "metric has none)")
    unit = t["unit"]
    if not isinstance(unit, str):
        raise SettingsError(f"{where}.unit", unit, "is not a string")
    high = None if "high" not in t else check(f"{where}.high", t["high"], _FINITE)
    low = None if "low" not in t else check(
        f"{where}.low", t["low"], _FINITE if high is None else Bound(high=high, why="high"))
    if low is None and high is None:
        raise SettingsError(where, dict(t), "sets neither low nor high")
    return Limit(metric, unit, low, high)


def _quote(metric: str) -> str:
    """A metric name as a TOML key: dotted names need quotes."""
    return f'"{metric}"'


def _check_name(where: str, metric: str) -> None:
    if not _NAME_RE.fullmatch(metric):
        raise SettingsError(where, metric, "is not a metric name (letters, digits, _ . - % and "
                                           "* wildcards)")


def _table(where: str, value: object) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise SettingsError(where, value, "is not a table")
    return value


def _unknown(where: str, table: Mapping[str, Any], known: set[str]) -> None:
    for key in table:
        if key not in known:
            path = f"{where}.{key}" if where else key
            raise SettingsError(path, table[key],
                                f"is not a known key (known: {', '.join(sorted(known))})")
