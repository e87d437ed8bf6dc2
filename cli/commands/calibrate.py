"""``armbench calibrate``: fit the robot model of an arm and write it as a settings file.

``armbench calibrate --port PORT [--budget-s S] --out DIR`` runs the identification procedure on
any port (``fake://`` on virtual time); ``armbench calibrate --capture CAPTURE --out DIR`` fits
what an existing capture's traffic shows. ``--out`` is a folder, as for every other command:
``DIR/robot.toml`` (the settings), ``DIR/robot.json`` (every fitted value, its standard error,
the observations), ``DIR/robot.html`` (the calibration page) and, for ``--port``,
``DIR/robot.observations.json`` (saved as it is measured). ``--out FILE.toml`` (the former form)
still writes FILE.toml with FILE.json, FILE.html beside it, with a deprecation note.
Every output is checked before the arm moves or the capture is read: an existing one is
overwritten only with ``--force``, a file of a run's record never, an unwritable path is refused.
Exit status: 0 done, 2 bad input or an arm that does not move (the partial outputs are written).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from armbench.bench.calibrate import DEFAULT_BUDGET_S, calibrate_capture, calibrate_port
from armbench.bench.calibrate.output import CalibrationResult, output_paths
from armbench.bench.outputs import check_out_dir, check_out_files
from armbench.bench.truth import load_tracker
from armbench.cli.commands.monitor import run_on_port
from armbench.drivers.errors import InvalidTargetError
from armbench.drivers.settings import load_settings
from armbench.reports.calibration_page import render_page

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add the ``calibrate`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "calibrate",
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
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder to write robot.toml (the settings), robot.json and robot.html "
                        "to (created if missing); a path ending in .toml is the former form, "
                        "deprecated: FILE.toml with FILE.json and FILE.html beside it")
    p.add_argument("--force", "--overwrite", action="store_true",
                   help="overwrite outputs that exist (never a file of a run's record)")
    p.add_argument("--budget-s", type=float, default=DEFAULT_BUDGET_S, metavar="S",
                   help=f"robot time the procedure may take (default {DEFAULT_BUDGET_S:g} s)")
    p.add_argument("--reply-timeout", type=float, default=0.5, metavar="S",
                   help="with --port: give up after S s without a reply from the arm "
                        "(default 0.5)")
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
    if not (math.isfinite(args.reply_timeout) and args.reply_timeout > 0):
        raise InvalidTargetError(None, "--reply-timeout", args.reply_timeout, "must be > 0")
    out = _settings_path(Path(args.out))
    if out.parent.is_dir() or out == Path(args.out):  # a folder there, or the former FILE.toml
        check_out_files("--out", output_paths(out, observations=args.port is not None),
                        force=args.force)
    else:  # a new folder: nothing in it to overwrite; made once its parent is known writable
        check_out_dir("--out", out.parent, [])
        if args.capture is not None:  # on a port: once the arm answered (calibrate_port)
            out.parent.mkdir(parents=True)
    base = load_settings(args.settings)
    if args.capture is not None:
        result = calibrate_capture(args.capture, base, out, page=render_page)
    else:
        port: str = args.port
        tracker = None if args.tracker is None else load_tracker(args.tracker, base)
        result = run_on_port(port, calibrate_port(
            port, base, out, budget_s=args.budget_s,
            progress=lambda m: print(m, file=sys.stderr, flush=True), tracker=tracker,
            page=render_page, reply_timeout_s=args.reply_timeout))
    _summary(result, output_paths(out, observations=args.port is not None))
    return 0


#: The settings file of a calibration written to ``--out DIR``.
SETTINGS_NAME = "robot.toml"


def _settings_path(out: Path) -> Path:
    """The settings file ``--out`` names: ``DIR/robot.toml``, or (deprecated) ``FILE.toml``."""
    if out.suffix.lower() == ".toml" and not out.is_dir():
        print(f"armbench calibrate: note: --out {out} (a .toml file) is deprecated: --out is a "
              f"folder, as for every other command (--out {out.parent / out.stem} writes "
              f"{out.parent / out.stem / SETTINGS_NAME}, .json, .html)", file=sys.stderr)
        return out
    return out / SETTINGS_NAME


def _summary(result: CalibrationResult, written: list[Path]) -> None:
    identified = [f for f in result.fitted if f.identified]
    print(f"calibrated from {result.observations.source}: {len(identified)} parameters "
          f"identified, {len(result.fitted) - len(identified)} kept "
          f"({result.observations.robot_time_s:.1f} s of robot time)")
    for f in identified:
        if f.choice is not None:
            print(f"  {f.key:<48} {f.choice:>12}")
        else:
            print(f"  {f.key:<48} {f.value:>12.6g} ± {f.sigma or 0:.2g} {f.unit}")
    for path in written:
        print(f"  wrote {path}")
    sys.stdout.flush()
