"""Fleet figures: many arms driven by one ``armbench run`` process at once.

* ``fleet.pty_reply_rate_min_ratio`` — ``ARMS`` (8) arms, each served by its own
  ``armbench emulate --pty`` process, driven by one ``armbench run accuracy --port ... --port ...``
  process (one lap per style, real time). Each arm's reply rate is read from its own
  ``capture.mcap``: replies received (well-formed ``in`` frames) per second between the first
  and the last one, i.e. over the whole run. The value is the lowest arm's rate, the bound that
  of :func:`armbench.cli.perf.driver_perf.reply_rate_bound` (the bound of ``driver.pty_reply_rate``,
  the one-arm figure), the ratio (the figure's name) their quotient; the note lists every arm's
  rate. Target ratio 0.9.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
import tempfile
from pathlib import Path

from armbench.bench.runner.options import CAPTURE_FILE, DEFAULT_CONFIG
from armbench.cli.perf import Figure, PerfOptions
from armbench.cli.perf.driver_perf import reply_rate_bound, serve_pty
from armbench.drivers.capture.read import open_capture
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.firmware.emulator_settings import emulator_settings

__all__ = ["ARMS", "capture_reply_rate", "run"]

#: Arms of the fleet figure, each with an emulator process of its own.
ARMS = 8


def capture_reply_rate(capture: Path) -> float:
    """Replies per second in a capture: well-formed frames from the arm, first to last."""
    times = [r.t_s for r in open_capture(capture) if r.dir == "in" and r.error is None]
    if len(times) < 2 or times[-1] <= times[0]:
        return 0.0
    return (len(times) - 1) / (times[-1] - times[0])


def _fleet_rates(arms: int, laps: int, folder: Path) -> dict[str, float]:
    """Run the accuracy suite on ``arms`` pty emulators from one ``armbench run``; each arm's
    reply rate from its capture."""
    config = folder / "fleet.toml"
    config.write_text(DEFAULT_CONFIG.read_text(encoding="utf-8")
                      + f"\n[suites.accuracy]\nlaps = {laps}\n", encoding="utf-8")
    names = [f"arm{k}" for k in range(arms)]
    with contextlib.ExitStack() as stack:
        ports = [f"{n}={stack.enter_context(serve_pty())}" for n in names]
        done = subprocess.run(
            [sys.executable, "-m", "armbench", "run", "accuracy", "--config", str(config),
             "--out", str(folder / "run"), *(x for p in ports for x in ("--port", p))],
            capture_output=True, text=True, timeout=900, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"armbench run over {arms} arms exited {done.returncode}: "
                           f"{done.stdout[-2000:]}{done.stderr[-2000:]}")
    return {n: capture_reply_rate(folder / "run" / n / CAPTURE_FILE) for n in names}


def run(options: PerfOptions) -> list[Figure]:
    """Measure the fleet figures (see the module docstring)."""
    robot = RobotSettings()
    bound = reply_rate_bound(robot.serial, emulator_settings(robot))
    with tempfile.TemporaryDirectory(prefix="armbench-fleet-") as tmp:
        rates = _fleet_rates(ARMS, 1, Path(tmp))
    worst = min(rates.values())
    return [Figure(
        "fleet.pty_reply_rate_min_ratio", worst, "replies/s", bound, worst / bound,
        note=f"{ARMS} armbench emulate --pty arms driven by one armbench run (accuracy, one "
             f"lap per style); replies/s per arm from its capture: "
             + ", ".join(f"{n} {r:.1f}" for n, r in rates.items())
             + f"; bound {bound:.1f}/s (as driver.pty_reply_rate); target 0.9")]
