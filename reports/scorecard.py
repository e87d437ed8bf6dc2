"""The scorecard: per suite its headline figures (from the suite contract), each with its limit,
margin, outcome, change against the baseline and the paper's figure, all as the record holds them.
A headline that names a pattern shows the worst recorded metric that matches it."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from fnmatch import fnmatchcase

from armbench.bench.record import ComparisonRow, Measurement, RunRecord, SuiteRecord
from armbench.bench.suites.contract import (
    ACCURACY,
    JOINTS,
    REPEATABILITY,
    STARTUP,
    TWIN_CHECK,
    Headline,
)
from armbench.reports.format import format_value, margin
from armbench.reports.views import ScoreRow

__all__ = ["GENERIC_HEADLINES", "HEADLINES", "change_text", "headline_measurement", "score_rows"]

#: The headline figures of each suite the contract knows, by suite name.
HEADLINES: Mapping[str, Sequence[Headline]] = {
    ACCURACY.suite: ACCURACY.headlines,
    REPEATABILITY.suite: REPEATABILITY.headlines,
    STARTUP.suite: STARTUP.headlines,
    JOINTS.suite: JOINTS.headlines,
    TWIN_CHECK.suite: TWIN_CHECK.headlines,
}
#: Headlines of a suite the contract does not know (the pytest plugin's): its failed
#: measurements first, then its judged ones, at most this many.
GENERIC_HEADLINES = 4


def headline_measurement(suite: SuiteRecord, headline: Headline) -> Measurement | None:
    """The recorded measurement a headline shows: the metric itself, or the worst of the
    metrics matching its pattern (highest when higher is worse, else lowest)."""
    if not headline.worst_of:
        return next((m for m in suite.measurements if m.name == headline.metric), None)
    matching = [m for m in suite.measurements if fnmatchcase(m.name, headline.metric)]
    if not matching:
        return None
    pick = max if headline.higher_is_worse else min
    return pick(matching, key=lambda m: m.value)


def change_text(cmp: ComparisonRow) -> tuple[str, str]:
    """``("+1.2 mm", "worse")``: the change against the baseline and its direction in a word
    (``worse``, ``better``, ``same`` within tolerance, ``new``, ``missing``)."""
    words = {"REGRESSED": "worse", "improved": "better", "ok": "same"}
    word = words.get(cmp.result, cmp.result)
    if cmp.change_abs is None:
        return "-", word
    return format_value(cmp.change_abs, cmp.unit, signed=True), word


def _row(label: str, m: Measurement, cmp: ComparisonRow | None,
         paper: float | None) -> ScoreRow:
    change, direction = ("", "") if cmp is None else change_text(cmp)
    return ScoreRow(
        label=label, metric=m.name, value=format_value(m.value, m.unit),
        limit="-" if m.limit is None else m.limit.describe(),
        margin=format_value(margin(m), m.unit, signed=True) if m.limit is not None else "-",
        outcome=m.outcome, change=change, direction=direction,
        paper="" if paper is None else format_value(paper, m.unit))


def score_rows(record: RunRecord, suite: SuiteRecord,
               headlines: Sequence[Headline] | None,
               cmp_rows: Mapping[str, ComparisonRow]) -> list[ScoreRow]:
    """The scorecard rows of ``suite``: its contract's ``headlines``, or (None: a suite the
    contract does not know) its failed and judged measurements."""
    rows: list[ScoreRow] = []
    if headlines is None:
        judged = sorted((m for m in suite.measurements if m.limit is not None),
                        key=lambda m: m.outcome != "fail")
        for m in judged[:GENERIC_HEADLINES]:
            rows.append(_row(m.description or m.name, m, cmp_rows.get(m.name), None))
        return rows
    for h in headlines:
        found = headline_measurement(suite, h)
        if found is None:
            continue
        paper = None if h.paper is None else record.reference.get(h.paper)
        rows.append(_row(h.label, found, cmp_rows.get(found.name), paper))
    return rows
