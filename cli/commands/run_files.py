"""The human-facing files of a run record: ``junit.xml`` and ``report.html``, written by whoever
ran the bench (the ``run`` command, the pytest plugin) once the record is on disk, and the
Markdown step summary of ``run --summary``. The runner
itself only writes the record; the report package is imported here, when a report is asked
for."""

from __future__ import annotations

import html
import logging
import queue
import sys
import threading
from pathlib import Path

from armbench.bench.runner.options import CAPTURE_FILE, JUNIT_FILE, REPORT_FILE, RunOutcome
from armbench.drivers.model.errors import ArmbenchError
from armbench.record import RunRecord, atomic_write_bytes, path_inside

__all__ = ["ReportAhead", "step_summary", "text_summary", "write_reports"]

log = logging.getLogger("armbench.runner")


def write_reports(record: RunRecord, out_dir: Path, *,
                  capture_max_bytes: int | None = None) -> None:
    """``junit.xml`` and ``report.html`` of ``record`` in ``out_dir``. The HTML report comes from
    ``reports.render_report`` when that package is available; otherwise (or if it fails) a plain
    text summary wrapped in HTML is written, so the file always exists. The report is attached
    to the run's ``capture.mcap`` (zstd) when the capture's size bound leaves room for it."""
    _write_pages(record, out_dir)
    _attach_report(out_dir, capture_max_bytes)


class ReportAhead:
    """The report's work done while the trials go on (a
    :class:`~armbench.bench.runner.options.RunAhead`): once the run is under way, a thread of its
    own imports the report's modules (its pages, matplotlib, Jinja2) and compiles its templates
    (``reports.pages.page.load_templates``); then it draws the plots of each suite whose summary
    is in the record (``reports.pages.page.draw_ahead``), while the next suite's trials run; the
    report written when the run ends (after :meth:`finish`) finds them compiled and drawn.
    Without the report package (a minimal install) nothing is done; a plot that fails to draw
    now is drawn (or reported) by the report itself."""

    def __init__(self) -> None:
        self._todo: queue.SimpleQueue[tuple[RunRecord, str] | None] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._finished = False

    def started(self) -> None:
        with self._lock:
            if self._thread is None and not self._finished:
                self._thread = threading.Thread(target=self._work, name="armbench-report-ahead",
                                                daemon=True)
                self._thread.start()

    def summarized(self, record: RunRecord, suite: str) -> None:
        with self._lock:
            if not self._finished:
                self._todo.put((record, suite))

    def finish(self) -> None:
        """Wait for the plots of the suites summarized so far (the report would draw them
        itself; two threads must not draw at once: matplotlib's settings are the process's),
        then stop: a suite summarized later is left to the report."""
        with self._lock:
            self._finished = True
            thread = self._thread
        self._todo.put(None)
        if thread is not None:
            thread.join()

    def _work(self) -> None:
        try:
            import armbench.reports.files.junit  # noqa: F401
            from armbench.reports.pages.page import draw_ahead, load_templates

            load_templates()
        except ImportError:
            return
        except Exception:  # the report itself says what is wrong, when it is written
            log.debug("the report's modules could not be loaded in advance", exc_info=True)
            return
        while (item := self._todo.get()) is not None:
            try:
                draw_ahead(*item)
            except Exception:  # the record changed under the drawing: the report draws it
                log.debug("the plots of %s were not drawn ahead", item[1], exc_info=True)


def _attach_report(out_dir: Path, capture_max_bytes: int | None) -> None:
    from armbench.bench.runner.capture_run import CLOSING_BYTES
    from armbench.drivers.capture.append import ZSTD_MEDIA_TYPE, append_attachment, zstd_attachment
    from armbench.drivers.capture.read import capture_stopped, is_mcap

    capture, report = out_dir / CAPTURE_FILE, out_dir / REPORT_FILE
    try:
        if not capture.exists() or not report.exists() or not is_mcap(capture):
            return
        name, data = zstd_attachment(REPORT_FILE, report)
        if capture_max_bytes is not None and (
                capture.stat().st_size + len(data) + CLOSING_BYTES > capture_max_bytes
                or capture_stopped(capture)):
            log.warning("report.html not attached to %s: its size bound", capture)
            return
        append_attachment(capture, name, data, ZSTD_MEDIA_TYPE)
    except (OSError, ArmbenchError) as exc:
        log.warning("report.html not attached to %s: %s", capture, exc)


def _write_pages(record: RunRecord, out_dir: Path) -> None:
    from armbench.reports.files.junit import write_junit

    try:
        write_junit(record, path_inside(out_dir, JUNIT_FILE))
    except ArmbenchError as exc:
        log.warning("junit.xml not written: %s", exc)
    report = path_inside(out_dir, REPORT_FILE)
    try:
        from armbench.reports.pages.page import render_report

        capture = out_dir / CAPTURE_FILE
        render_report(record, report, capture=capture if capture.exists() else None)
        return
    except ImportError:
        pass
    except Exception as exc:
        log.warning("the HTML report failed (%s: %s); writing a plain summary", type(exc).__name__,
                    exc)
    text = text_summary(record)
    page = ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>armbench run "
            f"{html.escape(record.run_id)}</title></head>\n<body><pre>{html.escape(text)}</pre>"
            "</body></html>\n")
    atomic_write_bytes(report, page.encode("utf-8"))


def text_summary(record: RunRecord) -> str:
    """A plain-text summary of a record: verdict, suites, failed measurements, regressions."""
    lines = [f"armbench run {record.run_id}  created {record.created}  verdict {record.verdict}",
             f"port {record.environment.port}  seed {record.environment.seed}  "
             f"armbench git {record.environment.git_revision}"]
    if record.environment.dut:
        lines.append("unit under test: " + ", ".join(
            f"{key} {value}" for key, value in record.environment.dut.items()))
    lines.append("")
    for name in record.planned_suites:
        s = record.suites.get(name)
        if s is None:
            lines.append(f"{name}: not started")
            continue
        errors = sum(t.status == "error" for t in s.trials)
        lines.append(f"{name}: {s.status}, {len(s.trials)} trial(s)"
                     + (f", {errors} in error" if errors else "")
                     + (f" — {s.error}" if s.error else ""))
        for m in s.measurements:
            limit = "" if m.limit is None else f"  (limit {m.limit.describe()})"
            lines.append(f"  {m.outcome:>8}  {m.name} = {m.value:.6g} {m.unit}{limit}")
        for t in s.trials:
            for m in t.measurements:
                if m.outcome == "fail":
                    lines.append(f"      fail  trial {t.index}: {m.name} = {m.value:.6g} "
                                 f"{m.unit}  (limit {m.limit.describe() if m.limit else '-'})")
    if record.baseline is not None:
        from armbench.record.baseline import format_comparison

        lines += ["", f"baseline {record.baseline.baseline_run_id}:",
                  format_comparison(record.baseline)]
    return "\n".join(lines) + "\n"


def step_summary(path: str, outcome: RunOutcome) -> None:
    """Append the run's Markdown summary to ``path`` (``--summary``); a failure now (the disk
    filled, the file was replaced by a FIFO) is one line on stderr and changes nothing else: the
    run's results are on disk and its exit status stands."""
    from armbench.reports.files.run_summary import SummaryError, write_step_summary

    try:
        write_step_summary(path, outcome.record, outcome.out_dir, outcome.exit_status)
    except SummaryError as exc:
        print(f"armbench run: warning: {exc}; the run's results are in {outcome.out_dir}",
              file=sys.stderr, flush=True)
