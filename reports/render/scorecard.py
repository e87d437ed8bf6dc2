"""The scorecard: per suite its headline figures (from the suite contract), each with its limit,
margin, outcome, change against the baseline and the paper's figure, all as the record holds them.
A headline that names a pattern shows the worst recorded metric that matches it.

Honest headlines: where the record holds the true figure beside the one the encoders report (the
``true_`` metric a run with ground truth records: the emulator, a reference instrument), the
headline is the true figure and the reported one is shown as what the firmware believes; without
one, the row says it is the encoders' view. Every metric that regressed against the baseline gets
a row of its own, every figure without a limit says why, and lifetimes print in human units with
a warning below :data:`LIFE_WARN_YEARS`."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from fnmatch import fnmatchcase

from armbench.record import ComparisonRow, Measurement, RunRecord, SuiteRecord
from armbench.record.limits import Limit
from armbench.record.suite_contract import (
    LIFE_WARN_YEARS,
    Headline,
    UnknownContractError,
    contract,
    contracts,
    records_truth,
)
from armbench.reports.render.format import format_duration, format_number, format_value, margin
from armbench.reports.render.views import ScoreRow

__all__ = ["GENERIC_HEADLINES", "HEADLINES", "LIFE_WARN_YEARS", "TRUTH_SUITES", "change_text",
           "headline_figure", "headline_measurement", "score_rows",
           "suite_headlines", "true_name"]

#: The headline figures of each suite the contract knows, by suite name, in the contracts' order
#: (registered where each is defined, :func:`armbench.record.suite_contract.register`).
HEADLINES: Mapping[str, Sequence[Headline]] = {c.suite: c.headlines for c in contracts()}
#: Headlines of a suite the contract does not know (the pytest plugin's): its failed
#: measurements first, then its judged ones, at most this many.
GENERIC_HEADLINES = 4
_YEAR_S = 365.25 * 86400.0
#: Suites that record a ``true_`` figure beside each reported position figure when the run has
#: ground truth: without one, their position figures are the encoders' view.
TRUTH_SUITES = frozenset(c.suite for c in contracts() if c.has_true_figures)


def suite_headlines(name: str) -> Sequence[Headline] | None:
    """The headline figures of the suite ``name`` as its registered contract names them (looked
    up when asked, so a contract registered later counts); None for a suite with no contract."""
    try:
        return contract(name).headlines
    except UnknownContractError:
        return None


_NO_LIMIT = "none set"


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


def true_name(metric: str) -> str:
    """The name of the true figure beside a reported one (``accuracy.paper.mean_mm`` ->
    ``accuracy.paper.true_mean_mm``): ``true_`` before the last part of the name, as the suites
    record it."""
    head, dot, last = metric.rpartition(".")
    return f"{head}{dot}true_{last}"


def _true_of(suite: SuiteRecord, headline: Headline, reported: Measurement) -> Measurement | None:
    """The true figure beside ``reported`` (for a pattern: the worst true figure matching it)."""
    if reported.name.rpartition(".")[2].startswith("true_"):
        return None
    if not headline.worst_of:
        name = true_name(reported.name)
        return next((m for m in suite.measurements if m.name == name), None)
    return headline_measurement(suite, Headline(headline.label, true_name(headline.metric),
                                                True, headline.higher_is_worse))


def headline_figure(suite: SuiteRecord,
                    headline: Headline) -> tuple[Measurement, Measurement | None] | None:
    """What a headline shows: (the true figure, the firmware's beside it) where the record
    holds both, else (the recorded figure, None); None when the suite lacks it."""
    found = headline_measurement(suite, headline)
    if found is None:
        return None
    true = _true_of(suite, headline, found)
    return (found, None) if true is None else (true, found)


def _human_value(m: Measurement) -> str:
    """The value in its unit, a lifetime or duration in units people read (``13.1 h``)."""
    if m.unit == "years" and m.value < 2.0:
        return format_duration(m.value * _YEAR_S)  # the years are in the metric's table
    if m.unit == "h" and m.value >= 48.0:
        return f"{m.value / 24.0:.3g} days"
    if m.unit == "s" and m.value >= 60.0:
        return format_duration(m.value)
    return format_value(m.value, m.unit)


def change_text(cmp: ComparisonRow) -> tuple[str, str]:
    """``("+1.2 mm", "worse")``: the change against the baseline and its direction in a word
    (``worse``, ``better``, ``same`` within tolerance, ``new``, ``missing``)."""
    words = {"REGRESSED": "worse", "improved": "better", "ok": "same"}
    word = words.get(cmp.result, cmp.result)
    if cmp.change_abs is None:
        return "-", word
    return format_value(cmp.change_abs, cmp.unit, signed=True), word


#: The order of a true figure's row's limits and margins: the arm's truth, the firmware's belief.
_PAIR = ("true", "firmware")


#: How the margin column names the figure whose margin it shows.
_SHORT_VIEW = {"true": "true", "firmware": "fw"}


def _pair_limits(limits: Sequence[Limit | None]) -> str:
    """A true figure's limit and the firmware's, ``true · firmware`` on one line: ``≤ 5 · 2 mm``
    where both bound the same side in the same unit, else each written out (``-``: none)."""
    def bound(lim: Limit) -> tuple[str, float | None]:
        return ("≤", lim.high) if lim.low is None else ("≥", lim.low) if lim.high is None \
            else ("", None)

    set_ = [lim for lim in limits if lim is not None]
    kinds = {bound(lim)[0] for lim in set_}
    if len(set_) == 2 and len(kinds) == 1 and "" not in kinds and \
            len({lim.unit for lim in set_}) == 1:
        op = kinds.pop()
        values = " · ".join(f"{bound(lim)[1]:g}" for lim in set_)
        return f"{op} {values} {set_[0].unit}".rstrip()
    return " · ".join("-" if lim is None else
                      lim.describe().replace("<= ", "≤ ").replace(">= ", "≥ ")
                      for lim in limits)


def _judging(m: Measurement, reported: Measurement | None) -> list[tuple[str, Measurement]]:
    """The figures of a row that a limit judges, each with the view it is (``true``,
    ``firmware``, or empty for a figure that is neither)."""
    if reported is None:
        return [] if m.limit is None else [("", m)]
    return [(view, f) for view, f in (("true", m), ("firmware", reported)) if f.limit is not None]


def _row(label: str, m: Measurement, cmp: ComparisonRow | None, paper: float | None, *,
         reported: Measurement | None = None, view: str = "",
         no_limit: str | None = None) -> ScoreRow:
    """A row showing ``m``; ``reported``: the firmware's figure beside the true ``m``. Such a
    row's limit and margin read ``true · firmware``, each judging its own figure ("-": none
    set); the row fails when either fails."""
    change, direction = ("", "") if cmp is None else change_text(cmp)
    judging = _judging(m, reported)
    if judging and reported is not None:  # true · firmware, each judging its own figure
        by_view = dict(judging)
        limit = _pair_limits([by_view[w].limit if w in by_view else None for w in _PAIR])
        # the margin shown is the tighter one, named; both are in its title
        view_name, tight = min(judging, key=lambda vf: margin(vf[1]) or 0.0)
        margins = f"{format_number(margin(tight), signed=True, unit=tight.unit)} " \
                  f"({_SHORT_VIEW[view_name]})"  # the unit is the limit's, beside it
        outcome = "fail" if any(f.outcome == "fail" for _, f in judging) else "pass"
    elif judging:
        limit = m.limit.describe() if m.limit else _NO_LIMIT
        margins = format_value(margin(m), m.unit, signed=True)
        outcome = m.outcome
    else:
        limit = no_limit or _NO_LIMIT
        margins, outcome = "-", m.outcome
    if not view and m.name.rpartition(".")[2].startswith("true_"):
        view = "true"  # a true figure on its own (a regressed one, say)
    warning = ""
    if m.unit == "years" and m.value < LIFE_WARN_YEARS:
        warning = f"⚠ < {LIFE_WARN_YEARS:g} years"
    return ScoreRow(
        label=label, metric=m.name, value=_human_value(m), limit=limit, margin=margins,
        outcome=outcome, change=change, direction=direction,
        paper="" if paper is None else format_value(paper, m.unit),
        reported="" if reported is None else format_value(reported.value, reported.unit),
        view=view, warning=warning, judges="+".join(w for w, _ in judging if w))


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
    else:
        has_truth = any(m.name.rpartition(".")[2].startswith("true_")
                        for m in suite.measurements)
        for h in headlines:
            found = headline_measurement(suite, h)
            if found is None:
                continue
            paper = None if h.paper is None else record.reference.get(h.paper)
            true = _true_of(suite, h, found)
            if (true or found).name in {r.metric for r in rows}:
                continue  # the true figure another headline already shows
            if true is not None:
                rows.append(_row(h.label, true, cmp_rows.get(true.name), paper,
                                 reported=found, view="true", no_limit=h.no_limit))
            else:
                view = ("encoders" if records_truth(suite.name) and not has_truth
                        and _positional(found) else "")
                rows.append(_row(h.label, found, cmp_rows.get(found.name), paper, view=view,
                                 no_limit=h.no_limit))
    shown = {r.metric for r in rows}
    by_name = {m.name: m for m in suite.measurements}
    for cmp in cmp_rows.values():  # every regression of this suite gets a row of its own
        got = by_name.get(cmp.name)
        if cmp.result == "REGRESSED" and got is not None and got.name not in shown:
            row = _row(got.name.split(".", 1)[-1], got, cmp, None)
            rows.append(row if got.limit is not None
                        else dataclasses.replace(row, limit=_NO_LIMIT))
    return rows


def _positional(m: Measurement) -> bool:
    """Whether ``m`` is a position or angle figure the encoders report (one a true reference
    would measure otherwise)."""
    return m.unit in ("mm", "mrad", "m", "rad", "deg") or m.name.endswith("ratio")

