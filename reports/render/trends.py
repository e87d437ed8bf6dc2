"""The run index's trends as data: each suite's headline figures across runs, one series per
unit under test, kind of target and view (:func:`trend_series`), each point judged against its
own run's limit.

A series never joins runs of different units (the unit under test's name and serial number;
a run that names none is known by its port) or of different kinds of target (``fake``, ``avr``,
``serial``, ``socket``, ``rfc2217``, ``labgrid``, a plug-in's scheme), nor figures of different
units of measure. The ``true`` view takes only measurements named ``true_*`` from runs that had a
truth source (:attr:`~armbench.record.Environment.declares_truth`); the ``believed`` view the
figure the run recorded under the headline's own name: a reported figure never stands in for a
true one. A point is outside its limit when its run's limit (the one recorded with it) does not
hold its value, so a point beyond the limit line drawn for it is always listed as outside.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

from armbench.record import Measurement, RunRecord
from armbench.record.suite_contract import Headline, contracts
from armbench.reports.render.scorecard import headline_figure, headline_measurement

__all__ = ["TrendPoint", "TrendSeries", "View", "is_true", "trend_series", "unit_of"]

View = Literal["true", "believed"]


@dataclass(frozen=True, slots=True)
class TrendPoint:
    """One run's figure: its run number, value, the bounds of its own run's limit (None: none
    on that side), whether the value is outside them, whether the run found it regressed."""

    run: int
    value: float
    low: float | None
    high: float | None
    outside: bool
    regressed: bool = False
    metric: str = ""


@dataclass(frozen=True, slots=True)
class TrendSeries:
    """One headline figure of one unit under test on one kind of target, in one view, across
    the runs that recorded it, oldest first."""

    suite: str
    headline: str
    view: View
    unit_under_test: str
    kind: str
    unit: str
    points: list[TrendPoint] = field(default_factory=list)

    @property
    def label(self) -> str:
        """The series for people: ``"arm-3 (serial 42) · socket"``."""
        return f"{self.unit_under_test} · {self.kind}"

    @property
    def outside(self) -> list[TrendPoint]:
        """The points outside their limits."""
        return [p for p in self.points if p.outside]


def is_true(m: Measurement) -> bool:
    """Whether ``m`` is a true figure (its name's last part starts with ``true_``)."""
    return m.name.rpartition(".")[2].startswith("true_")


def unit_of(record: RunRecord) -> str:
    """The unit under test a run measured, as the trends tell units apart: its name and serial
    number when the run names it, else its port."""
    dut = record.environment.dut
    if dut.name is not None or dut.serial is not None:
        return dut.label()
    return f"port {record.environment.port or '-'}"


def _point(run: int, m: Measurement, regressed: set[str]) -> TrendPoint:
    low = None if m.limit is None else m.limit.low
    high = None if m.limit is None else m.limit.high
    outside = m.limit is not None and not m.limit.check(m.value)
    return TrendPoint(run, m.value, low, high, outside, m.name in regressed, m.name)


def _figures(record: RunRecord, suite_name: str,
             headline: Headline) -> list[tuple[View, Measurement]]:
    """The figures of one headline in one run, by view (each view at most once)."""
    suite = record.suites.get(suite_name)
    if suite is None:
        return []
    out: list[tuple[View, Measurement]] = []
    believed = headline_measurement(suite, headline)
    if believed is not None and not is_true(believed):
        out.append(("believed", believed))
    shown = headline_figure(suite, headline)
    if (record.environment.declares_truth and shown is not None and shown[1] is not None
            and is_true(shown[0])):
        out.append(("true", shown[0]))
    return out


def trend_series(runs: Sequence[tuple[int, RunRecord]]) -> list[TrendSeries]:
    """Every series of the index's trends from ``runs`` (run number, record) in creation
    order: per headline of each suite (the suite contracts' order, looked up when asked, so a
    contract registered later counts), per view (believed first), per unit under test and kind
    of target, per unit of measure, in the order first seen."""
    headlines = [(c.suite, h) for c in contracts() for h in c.headlines]
    found: dict[tuple[str, str, View, str, str, str], TrendSeries] = {}
    for number, record in runs:
        regressed = (set() if record.baseline is None
                     else {r.name for r in record.baseline.regressions})
        unit_under_test, kind = unit_of(record), record.environment.kind
        for suite_name, h in headlines:
            for view, m in _figures(record, suite_name, h):
                key = (suite_name, h.label, view, unit_under_test, kind, m.unit)
                series = found.setdefault(key, TrendSeries(
                    suite_name, h.label, view, unit_under_test, kind, m.unit))
                series.points.append(_point(number, m, regressed))
    order = {(s, h.label): k for k, (s, h) in enumerate(headlines)}
    return sorted(found.values(), key=lambda s: (order[(s.suite, s.headline)],
                                                 s.view != "believed"))
