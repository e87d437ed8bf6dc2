"""The foreign-arm figures of measurements/calibration.md for one arm: calibrate it over TCP in real
time, run a held-out accuracy run, and twin-check that capture with the default twin and with
the fitted one (RMS, floor and allowance in counts, j1..j4).

    python scripts/foreign_arm_figures.py NAME OUT [ARM ARGS...] [--skip-calibration]
        [--budget-s S]

NAME is an arm of ``tests/foreign_arms/serve.py`` (``stall``, ``jitter``, ``tracker``,
``shared``, ``threshold``); ARM ARGS go to it (``--physics`` for the shared arm); the
calibration's budget is 90 s unless ``--budget-s`` says otherwise. Logs and JSON land in OUT.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1] / "tests"
sys.path.insert(0, str(TESTS))

from foreign_arms.serve import foreign_arm  # noqa: E402


def _load() -> str:
    with open("/proc/loadavg", encoding="ascii") as f:
        return " ".join(f.read().split()[:3])


def _run(cmd: list[str], log: Path) -> int:
    """Run ``python -m armbench CMD``, its output into ``log``; print the wall time and load."""
    t0, load0 = time.monotonic(), _load()
    with open(log, "w", encoding="utf-8") as f:
        rc = subprocess.call([sys.executable, "-m", "armbench", *cmd], stdout=f,
                             stderr=subprocess.STDOUT)
    print(f"{log.name}: exit {rc}, {time.monotonic() - t0:.1f} s, load {load0} -> {_load()}",
          flush=True)
    return rc


def main(argv: list[str]) -> int:
    skip = "--skip-calibration" in argv
    budget = "90"
    if "--budget-s" in argv:
        k = argv.index("--budget-s")
        budget = argv[k + 1]
        argv = argv[:k] + argv[k + 2:]
    name, out, *arm_args = [a for a in argv if a != "--skip-calibration"]
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    with foreign_arm(name, *arm_args) as arm:
        extra: list[str] = []
        if arm.tracker:
            extra = ["--tracker", "tracker_plugin:TrackerArmSource"]
            os.environ["ARMBENCH_TRACKER"] = f"{arm.tracker[0]}:{arm.tracker[1]}"
            os.environ["PYTHONPATH"] = str(TESTS)
        if not skip:
            _run(["calibrate", "--port", arm.url, "--budget-s", budget, "--reply-timeout", "5",
                  "--out", str(folder / "fit"), "--force", *extra], folder / "calibrate.log")
        # a loaded machine may starve the arm's process for seconds: not the arm's doing
        patient = folder / "patient.toml"
        patient.write_text('spec_version = "armbench-limits/1"\n\n[bench]\n'
                           "reply_timeout_s = 5.0\nconnect_timeout_s = 30.0\n"
                           "move_timeout_scale = 10.0\n", encoding="utf-8")
        _run(["run", "accuracy", "--port", arm.url, "--config", str(patient), "--out",
              str(folder / "held"), "--workers", "1"], folder / "accuracy.log")
    capture = folder / "held" / "capture.mcap"
    for label, settings in (("default", []), ("fitted", ["--settings",
                                                         str(folder / "fit" / "robot.toml")])):
        done = subprocess.run([sys.executable, "-m", "armbench", "twin-check", str(capture),
                               *settings, "--json"], capture_output=True, text=True, check=False)
        (folder / f"twin-check-{label}.json").write_text(done.stdout + done.stderr,
                                                         encoding="utf-8")
        try:
            result = json.loads(done.stdout)
        except ValueError:
            print(f"{label}: exit {done.returncode}: {done.stderr[-500:]}", flush=True)
            continue
        figures = {k: [round(v, 1) for v in result.get(k) or []]
                   for k in ("rms_counts", "floor_counts", "allowed_counts")}
        print(f"{label}: {result.get('verdict')} {figures}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
