"""The comparison page (``armbench compare A B --html OUT``): run B against baseline run A in the
run report's style. The answer first (regressed or not, the headline figures of each suite with
both values and the change in words), then per suite the headline figures of both runs side by
side, the paths of both runs overlaid when both ran the accuracy suite, and every compared metric
in a folded, filterable table. Same CSP and escaping as the run report; one offline file."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from armbench.record import (
    Comparison,
    Measurement,
    RunRecord,
    SuiteRecord,
    atomic_write_bytes,
)
from armbench.record.suite_contract import SAMPLE, Headline, UnknownContractError, contract
from armbench.reports.render import plots, plots_over_runs
from armbench.reports.render.format import format_value, jinja_environment
from armbench.reports.render.scorecard import HEADLINES, change_text, headline_figure
from armbench.reports.render.summary import measurement_row, missing_row, with_comparison
from armbench.reports.render.views import Figures, FigureView, MeasurementRow, ScoreRow, vec3

__all__ = ["build_compare_html", "render_compare"]


def _shown(suite: SuiteRecord, h: Headline) -> Measurement | None:
    """The figure a headline shows (the true one where the record holds it, as the run page)."""
    found = headline_figure(suite, h)
    return None if found is None else found[0]


def _headlines(a: RunRecord, b: RunRecord, comparison: Comparison) -> tuple[
        list[tuple[str, list[ScoreRow]]], list[FigureView], Figures]:
    """Per suite in both runs: scorecard rows (value in B, A's value in the ``paper`` slot's
    place, the change), and one bar plot of A against B."""
    figs = Figures()
    cmp = {r.name: r for r in comparison.rows}
    out: list[tuple[str, list[ScoreRow]]] = []
    figures: list[FigureView] = []
    for name, headlines in HEADLINES.items():
        sa, sb = a.suites.get(name), b.suites.get(name)
        if sa is None or sb is None:
            continue
        rows: list[ScoreRow] = []
        panels: list[plots_over_runs.PairPanel] = []
        for h in headlines:
            mb = _shown(sb, h)
            ma = _shown(sa, h)
            ref = mb if mb is not None else ma
            if ref is None:
                continue
            unit = ref.unit
            row = cmp.get(mb.name) if mb is not None else None
            change, direction = ("-", "") if row is None else change_text(row)
            true = ref.name.rpartition(".")[2].startswith("true_")
            rows.append(ScoreRow(
                label=h.label + (" (true)" if true else ""), metric=ref.name,
                value="-" if mb is None else format_value(mb.value, unit),
                limit="-" if mb is None else (
                    "none set" if mb.limit is None else mb.limit.describe()),
                margin="", outcome="unjudged" if mb is None else mb.outcome,
                change=change, direction=direction,
                paper="-" if ma is None else format_value(ma.value, unit)))
            limit = None if mb is None or mb.limit is None else (
                mb.limit.high if mb.limit.high is not None else mb.limit.low)
            panels.append(plots_over_runs.PairPanel(h.label, unit, None if ma is None else ma.value,
                                          None if mb is None else mb.value, limit))
        shown = {r.metric for r in rows}
        current = {m.name: m for m in sb.measurements}
        for r in comparison.regressions:  # every regression of the suite on the first screen
            m = current.get(r.name)
            if m is None or m.name in shown:
                continue
            change, direction = change_text(r)
            rows.append(ScoreRow(
                label=m.name.split(".", 1)[-1], metric=m.name,
                value=format_value(m.value, m.unit),
                limit="none set" if m.limit is None else m.limit.describe(), margin="",
                outcome=m.outcome, change=change, direction=direction,
                paper="-" if r.baseline is None else format_value(r.baseline, m.unit)))
        out.append((name, rows))
        if panels:
            figures.append(figs.make(
                plots_over_runs.compare_bars, (panels, ("A", "B")),
                f"{name}: headline figures, A and B",
                f"{name}: each headline figure in run A (hatched) and run B, the limit dashed.",
                "; ".join(f"{r.label}: A {r.paper}, B {r.value}" for r in rows)))
    return out, figures, figs


@runtime_checkable
class _LapNames(Protocol):
    """The names of the accuracy suite's contract the overlaid paths are read with."""

    @property
    def styles(self) -> tuple[str, ...]: ...
    @property
    def style(self) -> str: ...


#: The suite whose laps are overlaid (its contract is found in the registry by this name).
_PATH_SUITE = "accuracy"


def _paths(a: RunRecord, b: RunRecord, figs: Figures) -> FigureView | None:
    """Fig. 11 of both runs overlaid: the first lap of each style, A dashed, B solid."""
    sa, sb = a.suites.get(_PATH_SUITE), b.suites.get(_PATH_SUITE)
    if sa is None or sb is None:
        return None
    try:
        names = contract(_PATH_SUITE)
    except UnknownContractError:
        return None
    if not isinstance(names, _LapNames):
        return None
    panels = []
    for style in names.styles:
        runs = []
        for label, suite in (("A", sa), ("B", sb)):
            trial = next((t for t in suite.trials if t.params.get(names.style) == style
                          and t.samples), None)
            if trial is None:
                continue
            pts = [p for p in (vec3(s.get(SAMPLE.reported)) for s in trial.samples)
                   if p is not None]
            if pts:
                runs.append(plots.AttainedPath(f"run {label}", np.array(pts) * 1000.0))
        if runs:
            panels.append(plots.PathPanel(f"{style}: first lap of A and B", runs))
    if not panels:
        return None
    return figs.make(plots.paths_yz, (panels, None), "Accuracy: paths of runs A and B overlaid",
                     "The reported path of the first lap of each style in run A and run B, in "
                     "the YZ plane.")


def build_compare_html(a: RunRecord, b: RunRecord, comparison: Comparison) -> str:
    """The comparison page of run ``b`` against baseline ``a`` as HTML text."""
    scorecard, figures, figs = _headlines(a, b, comparison)
    paths = _paths(a, b, figs)
    if paths is not None:
        figures.insert(0, paths)
    current = b.suite_measurements()
    rows: list[MeasurementRow] = []
    for r in comparison.rows:
        m = current.get(r.name)
        rows.append(missing_row(r) if m is None else with_comparison(
            measurement_row(m, None, None), r))
    regressed = [r.name for r in comparison.regressions]
    verdict = "regression" if regressed else "pass"
    reasons = ([f"{len(regressed)} metric(s) regressed beyond tolerance: each is a row marked "
                "▲ worse below"]
               if regressed else ["no metric regressed beyond its tolerance"])
    counts = {s: sum(r.status == s for r in comparison.rows) for s in ("compared", "new",
                                                                        "missing")}
    reasons.append(f"{counts['compared']} compared, {counts['new']} new in B, "
                   f"{counts['missing']} missing from B")
    return jinja_environment().get_template("compare.html.j2").render(
        a=a, b=b, verdict=verdict, reasons=reasons, scorecard=scorecard, figures=figures,
        rows=rows)


def render_compare(a: RunRecord, b: RunRecord, comparison: Comparison,
                   out_path: str | os.PathLike[str]) -> Path:
    """Write the comparison page to ``out_path`` (atomically); returns the path written."""
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, build_compare_html(a, b, comparison).encode("utf-8"))
    return out
