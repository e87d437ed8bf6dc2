"""The short Markdown summary of a run (``armbench run --summary FILE.md``), for a CI job's step
summary (``$GITHUB_STEP_SUMMARY``, a GitLab job's artifact).

It says what the record says and judges nothing again: the verdict and exit status, what was
tested (the unit under test and its code, the CI job), the count of measurements (trial-level and
suite-level, as the report counts them) judged and failed, the regressions against the baseline,
trials in error, and where the full report is. Long lists are cut to :data:`MAX_LINES` lines with
a note of how many more there are.
"""

from __future__ import annotations

from pathlib import Path

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.user_files import (
    FileRefused,
    append_regular_file,
    check_appendable_file,
)
from armbench.record import REPORT_FILE, RunRecord
from armbench.record.claims import truth_line, uncovered_lines
from armbench.record.verdict import exit_status

__all__ = ["MAX_LINES", "SummaryError", "append_summary", "check_summary_file", "markdown_summary",
           "write_step_summary"]

#: Failed measurements, regressions and errors listed at most (each list).
MAX_LINES = 20

_ICON = {"pass": "✅", "fail": "❌", "regression": "📉", "error": "⚠️", "incomplete": "⚠️",
         "untested": "⭕"}


def _cell(text: str) -> str:
    """``text`` safe in a Markdown table cell."""
    return text.replace("|", "\\|").replace("\n", " ")


def _capped(lines: list[str], what: str) -> list[str]:
    if len(lines) <= MAX_LINES:
        return lines
    return [*lines[:MAX_LINES], f"| … | {len(lines) - MAX_LINES} more {what} | | |"]


def markdown_summary(record: RunRecord, *, status: int | None = None,
                     report: str | Path | None = None) -> str:
    """The Markdown summary of ``record``; ``status`` is the exit status of the run (default: the
    verdict's), ``report`` the path of its HTML report."""
    verdict = record.verdict
    code = exit_status(verdict) if status is None else status
    every = [(s.name, t, m) for s, t, m in record.iter_measurements()]
    judged = [x for x in every if x[2].outcome != "unjudged"]
    failed = [x for x in judged if x[2].outcome == "fail"]
    lines = [f"### armbench run `{record.run_id}`: {_ICON.get(verdict, '')} {verdict.upper()} "
             f"(exit {code})", "",
             f"{len(every)} measurements, {len(judged)} judged against limits, "
             f"{len(failed)} outside them; suites: {', '.join(record.planned_suites)}; port "
             f"`{record.environment.port}`, seed {record.environment.seed}.", "",
             *_tested(record)]
    if failed:
        rows = [f"| {_cell(suite)} | {_cell(m.name)}"
                + (f" (trial {t.index})" if t is not None else "")
                + f" | {m.value:.6g} {_cell(m.unit)} | "
                + f"{_cell(m.limit.describe()) if m.limit else '-'} |"
                for suite, t, m in failed]
        lines += ["| suite | outside its limit | value | limit |", "|---|---|---|---|",
                  *_capped(rows, "measurements"), ""]
    baseline = record.baseline
    if baseline is not None:
        regressions = baseline.regressions
        lines.append(f"Against baseline `{baseline.baseline_run_id}`: "
                     f"{sum(r.status == 'compared' for r in baseline.rows)} compared, "
                     f"{len(regressions)} regressed.")
        lines.append("")
        if regressions:
            rows = [f"| {_cell(r.name)} | {r.baseline:.6g} | {r.value:.6g} {_cell(r.unit)} | "
                    f"{r.tolerance:.3g} |" for r in regressions
                    if r.baseline is not None and r.value is not None and r.tolerance is not None]
            lines += ["| regressed | baseline | value | tolerance |", "|---|---|---|---|",
                      *_capped(rows, "regressions"), ""]
    errors = [f"- {s.name} trial {t.index}: {t.error}" for s in record.suites.values()
              for t in s.trials if t.status == "error"]
    errors += [f"- {s.name}: {s.error}" for s in record.suites.values()
               if s.error and not any(t.status == "error" for t in s.trials)]
    errors += [f"- {name}: not started" for name in record.planned_suites
               if name not in record.suites]
    if errors:
        lines += ["Not measured:", "", *errors[:MAX_LINES]]
        if len(errors) > MAX_LINES:
            lines.append(f"- … {len(errors) - MAX_LINES} more")
        lines.append("")
    uncovered = uncovered_lines(record)
    if uncovered:
        lines += ["Not covered by the verdict (untested or not judged, never a pass):", "",
                  *(f"- {_cell(line)}" for line in uncovered[:MAX_LINES]), ""]
    lines += [truth_line(record), ""]
    if report is not None:
        lines += [f"Full report: `{report}`", ""]
    return "\n".join(lines) + "\n"


def _code(text: str) -> str:
    """``text`` as inline code (a backtick in it cannot end the span early)."""
    return f"`{text.replace('`', chr(39))}`"


def _tested(record: RunRecord) -> list[str]:
    """The lines that say what was tested: the unit under test, the CI job (none when the
    record knows neither)."""
    env = record.environment
    lines = []
    if env.dut:
        lines.append("Unit under test: " + ", ".join(
            f"{key.replace('_', ' ')} {_code(value)}" for key, value in env.dut.items()) + ".")
    if env.ci is not None:
        ci = env.ci
        lines.append(f"CI: {ci.system}" + "".join(
            f", {key.replace('_', ' ')} {_code(value)}" for key, value in ci.items()
            if key != "system") + ".")
    return [*lines, ""] if lines else []


class SummaryError(ArmbenchError):
    """The ``--summary`` file cannot be written; names it and says why."""


def _summary_error(exc: FileRefused) -> SummaryError:
    return SummaryError(f"--summary {exc}")


def check_summary_file(path: str | Path) -> None:
    """Refuse, before the run, a ``--summary`` path that cannot be appended to: a directory, a
    device (``/dev/full``), a FIFO (appending would block until someone reads it), a missing
    folder, a place nothing can be written (:class:`SummaryError`)."""
    try:
        check_appendable_file(path, "a summary file")
    except FileRefused as exc:
        raise _summary_error(exc) from None


def append_summary(path: str | Path, text: str) -> None:
    """Append ``text`` to ``path`` (created if missing): a step summary file may hold what
    earlier steps wrote, which is never lost. Only a regular file is written, without blocking;
    a failure (a full disk) is a :class:`SummaryError`."""
    try:
        append_regular_file(path, text.encode("utf-8"), "a summary file")
    except FileRefused as exc:
        raise _summary_error(exc) from None


def write_step_summary(path: str | Path, record: RunRecord, out_dir: Path, status: int) -> None:
    """Append the summary of the run ``record`` in ``out_dir``, which exited with ``status``,
    to ``path`` (``armbench run --summary``), naming its report when there is one."""
    report = out_dir / REPORT_FILE
    append_summary(path, markdown_summary(record, status=status,
                                          report=report if report.exists() else None))
