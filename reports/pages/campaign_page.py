"""The page of a campaign record (``armbench campaign``): first the campaign's verdict (the
record's, with the ``campaign.*`` figures judged against their limits), then the drawn
conditions, the probability of passing each limit with its Wilson interval, recovery by state at
the cut (start-up recovery), and each judged metric's histogram (matplotlib, inline SVG) beside
a table of every metric's distribution. Self-contained like the run report: the same template
base, style and Content-Security-Policy (``reports/render/format.py``); it reads the record only."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from markupsafe import Markup
from matplotlib.figure import Figure

from armbench.bench.campaign.stats import (
    ALL_LIMITS,
    CAMPAIGN_KEY,
    MetricDistribution,
    collect,
    wilson_interval,
)
from armbench.record import RunRecord, SuiteRecord, atomic_write_bytes
from armbench.reports.render.format import format_value, jinja_environment
from armbench.reports.render.plots import safe_label, to_svg

__all__ = ["CAMPAIGN_PAGE", "build_campaign_html", "campaign_suite", "render_campaign"]

#: The campaign page's file name in the run directory.
CAMPAIGN_PAGE = "campaign.html"
#: Histograms drawn at most (judged metrics first); the table lists every metric.
MAX_HISTOGRAMS = 16


@dataclass(frozen=True, slots=True)
class _Rate:
    name: str
    limit: str
    passed: int
    judged: int
    pct: float
    low: float
    high: float


@dataclass(frozen=True, slots=True)
class _Judged:
    """A ``campaign.*`` figure the config has a limit for: the campaign's verdict rests on it."""

    name: str
    value: float
    unit: str
    limit: str
    outcome: str
    description: str


@dataclass(frozen=True, slots=True)
class _Row:
    name: str
    unit: str
    n: int
    mean: float
    std: float
    p05: float
    p50: float
    p95: float
    min: float
    max: float


@dataclass(frozen=True, slots=True)
class _Histogram:
    svg: Markup
    caption: str


def campaign_suite(record: RunRecord) -> SuiteRecord | None:
    """The campaign suite of ``record`` (its parameters hold ``campaign``), or None."""
    for suite in record.suites.values():
        if CAMPAIGN_KEY in suite.params:
            return suite
    return None


def _rate(name: str, limit: str, passed: int, judged: int) -> _Rate:
    low, high = wilson_interval(passed, judged)
    return _Rate(name, limit, passed, judged, 100.0 * passed / judged, 100.0 * low,
                 100.0 * high)


def _row(d: MetricDistribution) -> _Row:
    v = np.asarray(d.values, dtype=np.float64)
    q05, q50, q95 = (float(x) for x in np.quantile(v, [0.05, 0.5, 0.95]))
    return _Row(d.name, d.unit, int(v.size), float(v.mean()),
                float(v.std(ddof=1)) if v.size > 1 else 0.0, q05, q50, q95, float(v.min()),
                float(v.max()))


def _histogram(d: MetricDistribution, limits: Mapping[str, Any], k: int) -> _Histogram:
    v = np.asarray(d.values, dtype=np.float64)
    fig = Figure(figsize=(6.4, 2.6))
    ax = fig.add_subplot(1, 1, 1)
    bins = min(40, max(5, int(np.sqrt(v.size))))
    ax.hist(v, bins=bins if np.ptp(v) > 0 else 1, color="C0")
    for bound in (limits.get("low"), limits.get("high")):
        if bound is not None:
            ax.axvline(float(bound), color="C3", linestyle="--", linewidth=1.2)
    ax.set_xlabel(safe_label(f"{d.name} ({d.unit})" if d.unit else d.name))
    ax.set_ylabel("samples")
    fig.subplots_adjust(left=0.1, right=0.98, bottom=0.2, top=0.95)
    caption = f"{d.name}: {v.size} samples"
    if d.judged:
        caption += (f"; limit {d.limit} (dashed): {d.passed} of {d.judged} pass "
                    f"({100.0 * d.passed / d.judged:.1f} %)")
    return _Histogram(to_svg(fig, f"h{k}", caption), caption)


def _judged(suite: SuiteRecord) -> list[_Judged]:
    """The campaign's judged figures as the record holds them, failed ones first."""
    rows = [_Judged(m.name, m.value, m.unit, m.limit.describe() if m.limit else "-", m.outcome,
                    m.description) for m in suite.measurements if m.outcome != "unjudged"]
    return sorted(rows, key=lambda r: r.outcome != "fail")


def _verdict_reasons(record: RunRecord, suite: SuiteRecord, judged: Sequence[_Judged],
                     samples_error: int) -> list[str]:
    """Why the record's verdict is what it is, in the words of the campaign's figures."""
    reasons = []
    if suite.status == "error":
        reasons.append(f"the campaign stopped on an error: {suite.error or 'no reason given'}")
    elif suite.status == "running":
        reasons.append("the campaign did not finish (continue with armbench campaign --resume)")
    if samples_error:
        reasons.append(f"{samples_error} sample(s) could not be measured")
    for j in judged:
        reasons.append(f"{j.name} = {format_value(j.value, j.unit)} (limit {j.limit}): "
                       f"{'FAIL' if j.outcome == 'fail' else 'pass'}")
    if not judged:
        reasons.append("no campaign.* limit in the config: the figures are not judged, the "
                       "samples' failures are findings (the pass probabilities below)")
    if record.baseline is not None and record.baseline.regressed:
        reasons.append(f"{len(record.baseline.regressions)} figure(s) regressed against "
                       f"baseline {record.baseline.baseline_run_id}")
    return reasons


def _conditions(suite: SuiteRecord) -> list[_Rate]:
    """Start-up recovery: the rate of ``startup.recovered`` per drawn condition."""
    counts: dict[str, list[int]] = {}
    for t in suite.trials:
        if t.status != "done":
            continue
        inner = t.params.get("trials") or [{}]
        condition = inner[0].get("condition") if isinstance(inner[0], Mapping) else None
        recovered = next((m.value for m in t.measurements if m.name == "startup.recovered"),
                         None)
        if condition is None or recovered is None:
            continue
        c = counts.setdefault(str(condition), [0, 0])
        c[0] += recovered > 0.5
        c[1] += 1
    return [_rate(name, "", p, n) for name, (p, n) in sorted(counts.items())]


def _conditions_plot(rates: Sequence[_Rate]) -> Markup:
    fig = Figure(figsize=(6.4, 2.8))
    ax = fig.add_subplot(1, 1, 1)
    x = np.arange(len(rates))
    pct = np.array([r.pct for r in rates])
    err = np.array([[r.pct - r.low for r in rates], [r.high - r.pct for r in rates]])
    ax.bar(x, pct, color="C0")
    ax.errorbar(x, pct, yerr=err, fmt="none", ecolor="black", capsize=3)
    ax.set_xticks(x, [safe_label(r.name) for r in rates], rotation=40, ha="right", fontsize=7)
    ax.set_ylabel("recovered (%)")
    ax.set_ylim(0, 105)
    fig.subplots_adjust(left=0.1, right=0.98, bottom=0.35, top=0.95)
    return to_svg(fig, "conditions", "recovery rate per condition")


def build_campaign_html(record: RunRecord) -> str:
    """The campaign page of ``record`` as HTML text; a :class:`ValueError` for a record that
    holds no campaign."""
    suite = campaign_suite(record)
    if suite is None:
        raise ValueError(f"run {record.run_id} holds no campaign")
    c = suite.params[CAMPAIGN_KEY]
    dists = collect(suite.trials)
    limits: dict[str, Mapping[str, Any]] = {}
    for t in suite.trials:
        for m in t.measurements:
            if m.limit is not None:
                limits.setdefault(m.name, m.limit.to_json())
    passes = [_rate("every limit" if d.name == ALL_LIMITS else d.name, d.limit or "all",
                    d.passed, d.judged) for d in dists.values() if d.judged]
    shown = sorted((d for d in dists.values() if d.values and d.name != ALL_LIMITS),
                   key=lambda d: (not d.judged, d.name))[:MAX_HISTOGRAMS]
    conditions = _conditions(suite)
    done = sum(t.status == "done" for t in suite.trials)
    judged = _judged(suite)
    page = jinja_environment().get_template("campaign.html.j2").render(
        record=record, suite=suite.name, verdict=record.verdict, judged=judged,
        reasons=_verdict_reasons(record, suite, judged, len(suite.trials) - done),
        seed=c.get("seed"), samples_planned=c.get("samples"),
        samples_done=done, samples_error=len(suite.trials) - done,
        uncertain=c.get("uncertain", []), passes=passes, conditions=conditions,
        conditions_plot=_conditions_plot(conditions) if conditions else None,
        histograms=[_histogram(d, limits.get(d.name, {}), k) for k, d in enumerate(shown)],
        table=[_row(d) for d in dists.values() if d.values])
    return str(page)


def render_campaign(record: RunRecord, path: str | Path) -> Path:
    """Write the campaign page of ``record`` to ``path``; returns it."""
    out = Path(path)
    atomic_write_bytes(out, build_campaign_html(record).encode("utf-8"))
    return out
