"""The traffic section: what the capture of the serial line holds (frames each way, framing
errors and resyncs over time, an excerpt), from ``capture.mcap`` (or ``.jsonl``) beside the
record."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

from armbench.drivers.capture.jsonl import CaptureError
from armbench.reports.render import plots
from armbench.reports.render.capture_summary import CaptureLine, summarize_capture
from armbench.reports.render.format import format_duration
from armbench.reports.render.views import Figures, FigureView

__all__ = ["TrafficView", "traffic_section"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class TrafficView:
    """What the traffic template shows."""

    figures: list[FigureView]
    href: str
    name: str
    size: str
    stats: list[tuple[str, str]]
    reasons: list[tuple[str, int]]
    head: list[CaptureLine]
    first_errors: list[CaptureLine]
    notes: list[str]


def _size(n: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n} B"


def traffic_section(capture: Path, out_dir: Path, figs: Figures) -> TrafficView | None:
    try:
        c = summarize_capture(capture)
    except OSError:
        return None
    except CaptureError as exc:  # a damaged capture: the rest of the report still stands
        log.warning("traffic section left out: %s", exc)
        return None
    rel = os.path.relpath(capture.resolve(), out_dir.resolve())
    href = quote(Path(rel).as_posix(), safe="/")
    frames = c.frames_in + c.frames_out
    errors = c.errors_in + c.errors_out
    rate = frames / c.duration_s if c.duration_s > 0 else None
    stats = [
        ("records", f"{c.records:,}" + (f" analysed, {c.skipped_records:,} more not read"
                                        if c.skipped_records else "")),
        ("duration", format_duration(c.duration_s)),
        ("frames", f"{c.frames_out:,} out (host → arm), {c.frames_in:,} in (arm → host)"),
        ("mean frame rate", "-" if rate is None else f"{rate:,.1f} frames/s"),
        ("framing errors", f"{errors:,} ({c.errors_out:,} out, {c.errors_in:,} in)"),
        ("resyncs", f"{c.resyncs:,} (a valid frame after an error)"),
    ]
    notes = []
    if c.bad_lines:
        notes.append(f"{c.bad_lines:,} line(s) of the file are not capture records and were "
                     "skipped.")
    figures = []
    if c.records:
        figures.append(figs.make(
            plots.traffic_plot, (c.bin_start_s, c.rate_in, c.rate_out, c.errors_per_bin,
                               c.resyncs_per_bin, c.bin_s),
            "Traffic over time",
            "Frames per second in each direction over the capture"
            + ("; below, framing errors and resynchronisations per bin."
               if bool(c.errors_per_bin.any() or c.resyncs_per_bin.any())
               else " (no framing error and no resynchronisation: no panel for them).")))
    return TrafficView(figures=figures, href=href, name=capture.name, size=_size(c.size_bytes),
                       stats=stats, reasons=c.reasons, head=c.head,
                       first_errors=c.first_errors, notes=notes)


