"""``armbench calibrate``: fit the robot model of an arm and write it as a settings file.

``armbench calibrate --port PORT [--budget-s S] --out robot.toml`` runs the identification
procedure on any port (``fake://`` on virtual time); ``armbench calibrate --capture CAPTURE --out
robot.toml`` fits what an existing capture's traffic shows. Beside ``robot.toml`` go
``robot.json`` (every fitted value, its standard error, the observations), ``robot.html`` (the
calibration page) and, for ``--port``, ``robot.observations.json`` (saved as it is measured).
Exit status: 0 done, 2 bad input or an arm that does not move (the partial outputs are written).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from armbench.bench.calibrate import DEFAULT_BUDGET_S, calibrate_capture, calibrate_port
from armbench.bench.calibrate.output import CalibrationResult
from armbench.bench.commands.monitor import run_on_port
from armbench.bench.truth import load_tracker
from armbench.drivers.errors import InvalidTargetError
from armbench.drivers.settings import load_settings

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add the ``calibrate`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "calibrate", help="fit the robot model of an arm (settings with uncertainties)",
        description="Identify the arm's parameters (gear play, stick-slip, Hall positions, "
                    "stiffness, pull-out torque, DH errors, reply timing) from moves on PORT or "
                    "from a capture, and write a settings file with each fitted value's "
                    "standard error, the fit as JSON and an HTML calibration page.",
        epilog="Exit status: 0 done, 2 bad input or a joint that does not move (what was "
               "measured is written).")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--port", help="serial device, socket://HOST:PORT, rfc2217://HOST:PORT or "
                                    "fake://... (the emulator on virtual time)")
    src.add_argument("--capture", metavar="CAPTURE", help="fit an existing capture's traffic")
    p.add_argument("--out", required=True, metavar="FILE", help="settings TOML to write")
    p.add_argument("--budget-s", type=float, default=DEFAULT_BUDGET_S, metavar="S",
                   help=f"robot time the procedure may take (default {DEFAULT_BUDGET_S:g} s)")
    p.add_argument("--settings", metavar="FILE",
                   help="base settings: the nominal model and the priors (masses, payload) the "
                        "fit starts from (default: the default arm)")
    p.add_argument("--tracker", metavar="MODULE:CLASS",
                   help="reference instrument plug-in (a laser tracker driver implementing "
                        "PoseSource, as for run): the link side (play, stiffness, DH errors) "
                        "is then identified over any port")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    if not 0 < args.budget_s <= 24 * 3600:
        raise InvalidTargetError(None, "--budget-s", args.budget_s, "must be in (0, 86400] s")
    base = load_settings(args.settings)
    out = Path(args.out)
    if args.capture is not None:
        result = calibrate_capture(args.capture, base, out)
    else:
        port: str = args.port
        tracker = None if args.tracker is None else load_tracker(args.tracker, base)
        result = run_on_port(port, calibrate_port(
            port, base, out, budget_s=args.budget_s,
            progress=lambda m: print(m, file=sys.stderr, flush=True), tracker=tracker))
    _summary(result, out)
    return 0


def _summary(result: CalibrationResult, out: Path) -> None:
    identified = [f for f in result.fitted if f.identified]
    print(f"calibrated from {result.observations.source}: {len(identified)} parameters "
          f"identified, {len(result.fitted) - len(identified)} kept "
          f"({result.observations.robot_time_s:.1f} s of robot time)")
    for f in identified:
        if f.choice is not None:
            print(f"  {f.key:<48} {f.choice:>12}")
        else:
            print(f"  {f.key:<48} {f.value:>12.6g} ± {f.sigma or 0:.2g} {f.unit}")
    for suffix in ("", ".json", ".html"):
        print(f"  wrote {out.with_suffix(suffix) if suffix else out}")
    sys.stdout.flush()
