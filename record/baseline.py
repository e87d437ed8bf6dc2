"""Regression against a baseline run: each suite-level metric of a record against the same metric
of an earlier ``results.json``.

A metric regresses when it got worse, in its ``better`` direction, by more than its tolerance:
``|baseline| * tolerance_pct / 100 + tolerance_abs`` (metric unit), both from the limits file's
``[regression]`` table. Metrics without a direction, new metrics and missing metrics are listed,
never regressions. Trial-level measurements are not compared: trial *i* of one run against trial
*i* of another is noise, so suites put the figures worth tracking at suite level. Rules in
``docs/record.md``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

from armbench.drivers.model.errors import ArmbenchError
from armbench.record import (
    Comparison,
    ComparisonRow,
    Measurement,
    RecordError,
    RunRecord,
    load_record,
)
from armbench.record.limits import LimitsConfig

__all__ = [
    "BaselineError",
    "Comparison",
    "ComparisonRow",
    "check_suite_versions",
    "compare",
    "format_comparison",
    "load_baseline",
    "read_record",
]

class BaselineError(ArmbenchError, ValueError):
    """A baseline cannot be used: unreadable, another schema or limits spec, or a metric whose
    unit changed."""


def read_record(path: str | Path) -> RunRecord:
    """:func:`~armbench.record.load_record` (kept for its callers: it once added what
    ``load_record`` now does itself, a typed error for a record nested too deeply)."""
    return load_record(path)


def load_baseline(path: str | Path) -> RunRecord:
    """Read a baseline ``results.json``; any problem (missing, other schema, invalid field)
    raises :class:`BaselineError` naming the file."""
    try:
        return read_record(path)
    except RecordError as exc:
        raise BaselineError(f"baseline {exc}") from None


def check_suite_versions(baseline: RunRecord, versions: Mapping[str, str],
                         name: str | Path) -> None:
    """Refuse a baseline whose figures of a suite come from another version of it (they measure
    something else): ``versions`` maps this run's suites to their versions."""
    for suite, version in versions.items():
        theirs = baseline.suites.get(suite)
        if theirs is not None and theirs.version != version:
            raise BaselineError(f"baseline {name}: suites.{suite}.version {theirs.version!r} "
                                f"differs from this run's {version!r}; measure a new baseline")


def compare(record: RunRecord, baseline: RunRecord,
            config: LimitsConfig | None = None) -> Comparison:
    """Compare the suite-level measurements of ``record`` with those of ``baseline``.

    Tolerances come from ``config`` (defaults when None). The direction of a metric is the
    current measurement's ``better``. Raises :class:`BaselineError` when the records are of
    different schemas or were judged under different limits spec versions, or when a metric's
    unit or a suite's version differs between them.
    Store the result with ``writer.set_baseline(...)``.
    """
    cfg = config or LimitsConfig()
    if baseline.schema != record.schema:
        raise BaselineError(f"baseline {baseline.run_id}: record schema {baseline.schema!r} "
                            f"differs from this run's {record.schema!r}")
    ours = {v for v in (record.environment.limits_spec_version, cfg.spec_version) if v}
    theirs = baseline.environment.limits_spec_version
    if theirs is not None and ours - {theirs}:
        raise BaselineError(f"baseline {baseline.run_id}: limits spec version {theirs!r} differs "
                            f"from this run's {sorted(ours - {theirs})[0]!r}; measure a new "
                            "baseline")
    check_suite_versions(baseline, {n: s.version for n, s in record.suites.items()},
                         baseline.run_id)
    current = record.suite_measurements()
    before = baseline.suite_measurements()
    rows = [_row(m, before.get(name), cfg) for name, m in current.items()]
    rows += [_missing(m, cfg) for name, m in before.items() if name not in current]
    return Comparison(
        baseline_run_id=baseline.run_id,
        baseline_created=baseline.created,
        baseline_git_revision=baseline.environment.git_revision,
        rows=tuple(rows),
    )


def _row(m: Measurement, b: Measurement | None, cfg: LimitsConfig) -> ComparisonRow:
    tol = cfg.tolerance_for(m.name)
    if b is None:
        return ComparisonRow(m.name, m.unit, "new", None, m.value, None, None, None,
                             tol.tolerance_pct, tol.tolerance_abs, m.better, False)
    if b.unit != m.unit:
        raise BaselineError(f"metric {m.name!r}: unit {m.unit!r} in this run but {b.unit!r} in "
                            "the baseline; a changed unit needs a new metric name")
    change = m.value - b.value
    allowance = tol.allowance(b.value)
    worse = {"lower": change, "higher": -change, None: 0.0}[m.better]
    regressed = worse > allowance and not math.isclose(worse, allowance, rel_tol=1e-9,
                                                        abs_tol=1e-12)
    return ComparisonRow(
        name=m.name, unit=m.unit, status="compared", baseline=b.value, value=m.value,
        change_abs=change, change_pct=None if b.value == 0 else 100.0 * change / abs(b.value),
        tolerance=allowance, tolerance_pct=tol.tolerance_pct, tolerance_abs=tol.tolerance_abs,
        better=m.better, regressed=regressed,
    )


def _missing(b: Measurement, cfg: LimitsConfig) -> ComparisonRow:
    tol = cfg.tolerance_for(b.name)
    return ComparisonRow(b.name, b.unit, "missing", b.value, None, None, None, None,
                         tol.tolerance_pct, tol.tolerance_abs, b.better, False)


def _fmt(value: float | None, signed: bool = False) -> str:
    if value is None:
        return "-"
    return f"{value:+.4g}" if signed else f"{value:.4g}"


def format_comparison(comparison: Comparison, *, run_id: str | None = None) -> str:
    """A plain-text table of ``comparison`` for a terminal (``armbench compare A B``).

    Columns: metric, unit, baseline, value, change (unit), change (%), tolerance (unit, the
    allowed worsening) and result (``ok``, ``improved``, ``REGRESSED``, ``new``,
    ``missing``);
    a summary line follows.
    """
    header = ("metric", "unit", "baseline", "value", "change", "change %", "tolerance", "result")
    lines = [
        (r.name, r.unit, _fmt(r.baseline), _fmt(r.value), _fmt(r.change_abs, signed=True),
         _fmt(r.change_pct, signed=True), _fmt(r.tolerance), r.result)
        for r in comparison.rows
    ]
    widths = [max(len(row[i]) for row in (header, *lines)) for i in range(len(header))]

    def render(cells: tuple[str, ...]) -> str:
        out = [cells[0].ljust(widths[0]), cells[1].ljust(widths[1])]
        out += [c.rjust(w) for c, w in zip(cells[2:7], widths[2:7], strict=True)]
        out.append(cells[7])
        return "  ".join(out).rstrip()

    target = f"run {run_id}" if run_id else "this run"
    title = (f"{target} against baseline {comparison.baseline_run_id} "
             f"({comparison.baseline_created}, armbench git "
             f"{comparison.baseline_git_revision[:12]})")
    body = [render(header), "  ".join("-" * w for w in widths)]
    body += [render(cells) for cells in lines]
    counts = {s: sum(r.status == s for r in comparison.rows) for s in ("compared", "new",
                                                                         "missing")}
    summary = (f"{counts['compared']} compared, {len(comparison.regressions)} regressed, "
               f"{counts['new']} new, {counts['missing']} missing")
    return "\n".join([title, "", *body, "", summary])
