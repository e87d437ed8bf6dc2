"""HTML reports of bench runs: one self-contained page per run (``render_report``) and an index
over many runs with trends (``render_index``), and the comparison of two runs
(``render_compare``). They read ``results.json`` (and ``capture.jsonl``
beside it) only; see ``docs/reports.md``."""

from __future__ import annotations

from armbench.record import REPORT_FILE
from armbench.reports.pages.compare_page import render_compare
from armbench.reports.pages.index import INDEX_FILE, render_index
from armbench.reports.pages.page import build_report_html, render_report
from armbench.reports.render.format import (
    CSP,
    VERDICT_MARKS,
    format_duration,
    format_number,
    format_value,
)

if __name__ != "armbench.reports":  # the checkout's folder imported by its bare name: a second copy
    raise ImportError(f"{__name__!r} installs as armbench.reports: import it by that name")

__all__ = [
    "CSP",
    "INDEX_FILE",
    "REPORT_FILE",
    "VERDICT_MARKS",
    "build_report_html",
    "format_duration",
    "format_number",
    "format_value",
    "render_compare",
    "render_index",
    "render_report",
]
