"""``armbench twin-check CAPTURE [--settings robot.toml] [--config bench.toml] [--json]
[--out DIR]``: replay a capture's commands into the twin on virtual time and compare the reply
streams (see :mod:`armbench.bench.twin_check.check`); with ``--out`` the check is also a run record
with its ``report.html`` and ``junit.xml`` (see :mod:`armbench.bench.twin_check.twin_record`).

Exit status: 0 the twin is within the config's tolerance (``twin.*`` limits), 1 it is not, 2 bad
input (a truncated or damaged capture, another robot model's, one without commands or traffic, an
``--out`` that already holds a record or a file the check writes, or cannot be written, checked
before the capture is read): nothing is written then.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from armbench.bench.calibrate.capture_data import load_capture
from armbench.bench.twin_check.check import DEFAULT_CONFIG, TwinCheck, twin_check
from armbench.bench.twin_check.twin_record import TwinInputs, check_out_dir, write_twin_record
from armbench.cli.commands.run_files import write_reports
from armbench.drivers.model.settings import load_settings
from armbench.record import Measurement
from armbench.record.limits import load_limits

__all__ = ["format_failures", "format_twin_check", "register"]


def register(sub: Any) -> None:
    """Add the ``twin-check`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "twin-check",
        description="Replay the commands of CAPTURE, with their timing, into the emulator built "
                    "from --settings (the twin) on virtual time, and compare the reply streams: "
                    "per-joint RMS and largest divergence of the reported angle, arrival-time "
                    "differences per move.",
        epilog="Exit status: 0 within the tolerance of the config, 1 not, 2 bad input.")
    p.add_argument("capture", metavar="CAPTURE",
                   help="capture of the arm (capture.mcap or capture.jsonl)")
    p.add_argument("--settings", metavar="FILE",
                   help="the twin's settings (e.g. the output of armbench calibrate)")
    p.add_argument("--config", metavar="FILE",
                   help="limits file with twin.* limits (default: the packaged twin_check.toml, "
                        "RMS <= 3 counts)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="DIR",
                   help="also write the check as a run record: DIR/results.json (suite "
                        "twin-check: figures, verdict, inputs, the arm-vs-twin series), "
                        "report.html and junit.xml")
    p.set_defaults(func=_run)


def format_twin_check(result: TwinCheck, capture: str) -> str:
    """The text report of ``result`` for a terminal: verdict, per-joint divergence (under a
    failing joint what it looks like and what to do), arrivals, the TCP divergence and every
    judged figure (``--json`` has the same as one object)."""
    lines = [f"twin-check {capture}: verdict {result.verdict} "
             f"({result.replies_compared} replies, {result.moves} commands)"]
    for j in range(4):
        lines.append(f"  j{j + 1}: RMS {result.rms_counts[j]:8.2f} counts "
                     f"({result.rms_rad[j]:.3g} rad), max {result.max_counts[j]:8.1f} counts")
        diagnosis = result.diagnoses[j]
        if diagnosis is not None:
            lines.extend(f"      {line}" for line in diagnosis.lines())
    body = result.to_json()["arrival"]
    if body["compared"]:
        lines.append(f"  arrivals: {body['compared']} moves compared, mean twin − arm "
                     f"{body['mean_dt_s'] * 1e3:+.1f} ms, largest |Δ| "
                     f"{body['max_abs_dt_s'] * 1e3:.1f} ms")
    tcp = result.tcp
    if tcp is None:
        lines.append("  TCP: no truth in the capture")
    else:
        lines.append(f"  TCP: RMS {tcp['rms_mm']:.3f} mm, max {tcp['max_mm']:.3f} mm (floor "
                     f"{tcp['floor_mm']:.3f} mm, {int(tcp['samples'])} samples)")
    lines.extend(_judged(m) for m in result.measurements if m.outcome != "unjudged")
    return "\n".join(lines)


def format_failures(result: TwinCheck) -> list[str]:
    """Per failing joint, its RMS against its allowance and what its divergence looks like and
    what to do; then every judged figure outside its limit."""
    lines = []
    for j, diagnosis in enumerate(result.diagnoses):
        if diagnosis is not None:
            lines.append(f"  j{j + 1}: RMS {result.rms_counts[j]:.2f} counts, allowed "
                         f"{result.allowed_counts[j]:.2f}")
            lines.extend(f"      {line}" for line in diagnosis.lines())
    lines.extend(_judged(m) for m in result.measurements if m.outcome == "fail")
    return lines


def _judged(m: Measurement) -> str:
    """A judged figure's line: its outcome, value and limit."""
    return (f"  {'FAIL' if m.outcome == 'fail' else 'pass':<4}  {m.name} = {m.value:.4g} "
            f"{m.unit}".rstrip() + f" (limit {m.limit.describe() if m.limit else '-'})")


def _run(args: argparse.Namespace) -> int:
    out = None if args.out is None else Path(args.out)
    if out is not None:
        check_out_dir(out)
    settings = load_settings(args.settings)
    config = DEFAULT_CONFIG if args.config is None else Path(args.config)
    limits = load_limits(config)
    t0 = time.monotonic()

    def progress(text: str) -> None:
        """A long capture takes a while: say on a terminal what is going on (a pipe or a log
        gets the result only, and bad input stays one line)."""
        if sys.stderr.isatty():
            print(f"[{time.monotonic() - t0:5.1f} s] {text}", file=sys.stderr, flush=True)

    progress(f"reading {args.capture}")
    data = load_capture(args.capture, settings)
    progress("replaying the commands into the twin and comparing")
    result = twin_check(data, settings, config)
    progress("done")
    if out is not None:
        inputs = TwinInputs(Path(args.capture),
                            None if args.settings is None else Path(args.settings), config)
        write_reports(write_twin_record(result, inputs, settings, limits, out), out)
    if args.json:
        print(json.dumps(result.to_json()))
    else:
        print(format_twin_check(result, args.capture))
    if out is not None and not args.json:
        print(f"  record: {out}")
    sys.stdout.flush()
    return 0 if result.verdict == "pass" else 1
