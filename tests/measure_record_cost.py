"""Measure what an accuracy run of N laps costs: bytes written, peak memory, final file sizes.

Runs ``armbench run accuracy`` on ``fake://`` with ``--workers 1`` (every write in one process)
and ``[suites.accuracy] laps = N`` in a child process that reports, as it exits, its
``/proc/self/io`` counters (``wchar``: bytes handed to ``write``) and its peak resident memory,
also as it was when the reports (``junit.xml``, ``report.html``) began.
Used for the figures in ``measurements/reliability.md``::

    python3 tests/measure_record_cost.py 10 200
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

_CHILD = """
import atexit, json, resource, sys
import armbench.cli.commands.run as runner
figures = {}
def _peak_kb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
_write_reports = runner.write_reports
def write_reports(*args, **kwargs):
    figures["max_rss_before_reports_kb"] = _peak_kb()
    return _write_reports(*args, **kwargs)
runner.write_reports = write_reports
def _report():
    io = dict(line.split(": ") for line in open("/proc/self/io").read().splitlines())
    with open(sys.argv[1], "w") as fh:
        json.dump({"wchar": int(io["wchar"]), "max_rss_kb": _peak_kb(), **figures}, fh)
atexit.register(_report)
from armbench.cli.main import main
sys.exit(main(sys.argv[2:]))
"""


def measure(laps: int, root: Path) -> dict[str, float]:
    """One run of ``laps`` laps in ``root``; its figures (bytes, MB)."""
    config = root / f"laps{laps}.toml"
    config.write_text(f'spec_version = "armbench-limits/1"\n[suites.accuracy]\nlaps = {laps}\n')
    out, stats = root / f"run{laps}", root / f"stats{laps}.json"
    proc = subprocess.run(
        [sys.executable, "-c", _CHILD, str(stats), "run", "accuracy", "--config", str(config),
         "--out", str(out), "--workers", "1", "--seed", "0"],
        capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"run of {laps} laps failed ({proc.returncode}): {proc.stderr[-2000:]}")
    figures = json.loads(stats.read_text())
    final = {p.name: p.stat().st_size for p in out.iterdir() if p.is_file()}
    return {"laps": laps, "written_bytes": figures["wchar"], "final_bytes": sum(final.values()),
            "results_json_bytes": final.get("results.json", 0),
            "written_per_final": figures["wchar"] / sum(final.values()),
            "peak_rss_mb": figures["max_rss_kb"] / 1024.0,
            "peak_rss_before_reports_mb": figures.get("max_rss_before_reports_kb", 0) / 1024.0}


def main(argv: list[str]) -> None:
    """Measure each lap count given (default 10 and 200) and print one JSON line each."""
    with tempfile.TemporaryDirectory(prefix="armbench-record-cost-") as tmp:
        for laps in [int(a) for a in argv] or [10, 200]:
            print(json.dumps(measure(laps, Path(tmp))), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
