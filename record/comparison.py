"""A run's suite-level figures against a baseline run's: the data (:class:`Comparison` of
:class:`ComparisonRow` s); ``armbench.record.baseline`` computes it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import get_args

from armbench.record.fields import (
    Better,
    RowStatus,
    _bool,
    _choice,
    _get,
    _list,
    _num,
    _obj,
    _opt_num,
    _str,
)
from armbench.record.shapes import ComparisonJson, ComparisonRowJson

__all__ = ["Comparison", "ComparisonRow"]


@dataclass(frozen=True, slots=True)
class ComparisonRow:
    """One metric compared with the baseline (values in ``unit``).

    ``status``: ``"compared"``, ``"new"`` (no baseline value) or ``"missing"`` (no value in this
    run). ``change_abs`` = value - baseline (unit), ``change_pct`` its percentage of ``|baseline|``
    (None for a zero baseline); ``tolerance`` the allowed worsening (unit) =
    ``|baseline| * tolerance_pct / 100 + tolerance_abs``; ``regressed`` when the metric got worse
    in its ``better`` direction by more than that.
    """

    name: str
    unit: str
    status: RowStatus
    baseline: float | None
    value: float | None
    change_abs: float | None
    change_pct: float | None
    tolerance: float | None
    tolerance_pct: float
    tolerance_abs: float
    better: Better | None
    regressed: bool

    @property
    def result(self) -> str:
        """The row's word, as ``armbench compare`` and the report show it: ``REGRESSED``,
        ``improved`` (better by more than the tolerance), ``ok``, ``new`` or ``missing``."""
        if self.status != "compared":
            return self.status
        if self.regressed:
            return "REGRESSED"
        if self.better is None or self.change_abs is None or self.tolerance is None:
            return "ok"
        gain = -self.change_abs if self.better == "lower" else self.change_abs
        return "improved" if gain > self.tolerance else "ok"

    def to_json(self) -> ComparisonRowJson:
        """The JSON object of this row."""
        return {
            "name": self.name, "unit": self.unit, "status": self.status,
            "baseline": self.baseline, "value": self.value,
            "change_abs": self.change_abs, "change_pct": self.change_pct,
            "tolerance": self.tolerance, "tolerance_pct": self.tolerance_pct,
            "tolerance_abs": self.tolerance_abs, "better": self.better,
            "regressed": self.regressed,
        }

    @classmethod
    def from_json(cls, data: object, where: str) -> ComparisonRow:
        """Parse a comparison row; ``where`` is its dotted path, for errors."""
        d = _obj(data, where)

        def num(key: str) -> float | None:
            return _opt_num(_get(d, key, where), f"{where}.{key}")

        return cls(
            name=_str(_get(d, "name", where), f"{where}.name"),
            unit=_str(_get(d, "unit", where), f"{where}.unit"),
            status=_choice(_get(d, "status", where), f"{where}.status", get_args(RowStatus)),
            baseline=num("baseline"), value=num("value"),
            change_abs=num("change_abs"), change_pct=num("change_pct"),
            tolerance=num("tolerance"),
            tolerance_pct=_num(_get(d, "tolerance_pct", where), f"{where}.tolerance_pct"),
            tolerance_abs=_num(_get(d, "tolerance_abs", where), f"{where}.tolerance_abs"),
            better=_choice(_get(d, "better", where), f"{where}.better", (*get_args(Better), None)),
            regressed=_bool(_get(d, "regressed", where), f"{where}.regressed"),
        )


@dataclass(frozen=True, slots=True)
class Comparison:
    """A run's suite-level measurements against those of a baseline run.

    ``baseline_*`` identify the baseline record; ``rows`` go in the run's measurement order, then
    the baseline's missing metrics; ``regressed`` is true when any row regressed.
    """

    baseline_run_id: str
    baseline_created: str
    baseline_git_revision: str
    rows: tuple[ComparisonRow, ...]

    @property
    def regressed(self) -> bool:
        """True when at least one metric regressed."""
        return any(r.regressed for r in self.rows)

    @property
    def regressions(self) -> list[ComparisonRow]:
        """The rows that regressed."""
        return [r for r in self.rows if r.regressed]

    def to_json(self) -> ComparisonJson:
        """The JSON object of this comparison (``record.baseline``)."""
        return {
            "baseline_run_id": self.baseline_run_id,
            "baseline_created": self.baseline_created,
            "baseline_git_revision": self.baseline_git_revision,
            "regressed": self.regressed,
            "rows": [r.to_json() for r in self.rows],
        }

    @classmethod
    def from_json(cls, data: object, where: str) -> Comparison:
        """Parse a comparison object; ``where`` is its dotted path, for errors."""
        d = _obj(data, where)
        rows = _list(_get(d, "rows", where), f"{where}.rows")
        return cls(
            baseline_run_id=_str(_get(d, "baseline_run_id", where), f"{where}.baseline_run_id"),
            baseline_created=_str(_get(d, "baseline_created", where),
                                  f"{where}.baseline_created"),
            baseline_git_revision=_str(_get(d, "baseline_git_revision", where),
                                       f"{where}.baseline_git_revision"),
            rows=tuple(ComparisonRow.from_json(r, f"{where}.rows[{i}]")
                       for i, r in enumerate(rows)),
        )

