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
``--check HELD_OUT`` then twin-checks the fitted settings on a capture the fit did not use (read
before the arm moves) and prints, per failing joint, what its divergence looks like and what to do
(:mod:`armbench.bench.twin_check.diagnosis`). The geometry from what a lab has: ``--reference
poses.csv`` (tool positions measured at known joint angles; with a port, a capture or alone) and
``--touch-off plate.toml`` (with a port: the operator jogs the tool onto the plate's points at
the terminal, :mod:`armbench.cli.commands.touch_operator`), both read before the arm moves.
Exit status: 0 done, 1 the held-out check failed (the outputs are written), 2 bad input or an arm
that does not move (the partial outputs are written).
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path
from typing import Any

from armbench.bench.calibrate import DEFAULT_BUDGET_S, calibrate_capture, calibrate_port
from armbench.bench.calibrate.calibration import calibrate_reference
from armbench.bench.calibrate.capture_data import CaptureData, load_capture
from armbench.bench.calibrate.model import CalibrationError
from armbench.bench.calibrate.output import CalibrationResult, output_paths
from armbench.bench.calibrate.reference import read_plate, read_reference
from armbench.bench.runner.outputs import check_out_dir, check_out_files
from armbench.bench.runner.truth import load_tracker
from armbench.bench.twin_check.check import twin_check
from armbench.cli.commands.bounds import REPLY_TIMEOUT_S, add_bounded
from armbench.cli.commands.monitor import run_on_port
from armbench.cli.commands.touch_operator import TerminalOperator
from armbench.cli.commands.twin_check import format_failures
from armbench.drivers.capture.jsonl import open_capture_file
from armbench.drivers.model.bounds import Bound
from armbench.drivers.model.settings import load_settings
from armbench.reports.pages.calibration_page import render_page

__all__ = ["register"]


def register(sub: Any) -> None:
    """Add the ``calibrate`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "calibrate",
        description="Identify the arm's parameters (gear play, stick-slip, Hall positions, "
                    "stiffness, pull-out torque, DH errors, reply timing) from moves on PORT or "
                    "from a capture, and write a settings file with each fitted value's "
                    "standard error, the fit as JSON and an HTML calibration page.",
        epilog="Exit status: 0 done, 1 the held-out check (--check) failed, 2 bad input or a "
               "joint that does not move (what was measured is written).")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--port", help="serial device, socket://HOST:PORT, rfc2217://HOST:PORT or "
                                    "fake://... (the emulator on virtual time)")
    src.add_argument("--capture", metavar="CAPTURE", help="fit an existing capture's traffic")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder to write robot.toml (the settings), robot.json and robot.html "
                        "to (created if missing); a path ending in .toml is the former form, "
                        "deprecated: FILE.toml with FILE.json and FILE.html beside it")
    p.add_argument("--force", "--overwrite", action="store_true",
                   help="overwrite outputs that exist (never a file of a run's record)")
    add_bounded(p, "--budget-s", Bound(0.0, 86_400.0, "s", low_open=True),
                default=DEFAULT_BUDGET_S, metavar="S",
                help=f"robot time the procedure may take (default {DEFAULT_BUDGET_S:g} s)")
    add_bounded(p, "--reply-timeout", REPLY_TIMEOUT_S, default=0.5, metavar="S",
                help="with --port: give up after S s without a reply from the arm (default 0.5)")
    p.add_argument("--settings", metavar="FILE",
                   help="base settings: the nominal model and the priors (masses, payload) the "
                        "fit starts from (default: the default arm)")
    p.add_argument("--tracker", metavar="MODULE:CLASS",
                   help="reference instrument plug-in (a laser tracker driver implementing "
                        "PoseSource, as for run): the link side (play, stiffness, DH errors) "
                        "is then identified over any port")
    p.add_argument("--reference", metavar="CSV",
                   help="tool positions a lab measured (a caliper, a CMM, a camera) at known joint "
                        "angles, with their uncertainty: the DH lengths, joint offsets and play "
                        "are fitted from them (with --port, --capture or alone)")
    p.add_argument("--touch-off", metavar="PLATE",
                   help="with --port: after the procedure, jog the tool onto each known point of "
                        "the plate (a TOML file) at the terminal; the joint readings fit the DH "
                        "lengths, joint offsets and play")
    p.add_argument("--check", metavar="CAPTURE",
                   help="a held-out capture of the same arm (not the one fitted): twin-check the "
                        "fitted settings on it and, per failing joint, say what its divergence "
                        "looks like and what to do (exit status 1 when it fails)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    if args.touch_off is not None and args.port is None:
        raise CalibrationError("--touch-off needs --port (the arm is jogged onto the plate)")
    if args.port is None and args.capture is None and args.reference is None:
        raise CalibrationError("give --port, --capture or --reference")
    # read before anything is written or moved: a bad file is bad input (exit status 2)
    args.references = [] if args.reference is None else read_reference(args.reference)
    args.plate = None if args.touch_off is None else read_plate(args.touch_off)
    out = _settings_path(Path(args.out))
    new_folder = not (out.parent.is_dir() or out == Path(args.out))  # else the former FILE.toml
    if new_folder:  # nothing in it to overwrite; made once its parent is known writable
        check_out_dir("--out", out.parent, [])
    else:
        check_out_files("--out", output_paths(out, observations=args.port is not None),
                        force=args.force)
    if args.capture is not None:  # missing, a FIFO, a device: refused before --out is made
        open_capture_file(args.capture).close()
    held_out = (None if args.check is None
                else load_capture(args.check, load_settings(args.settings)))
    if new_folder and args.port is None:  # on a port: once the arm answered
        out.parent.mkdir(parents=True)
    try:
        result = _calibrate(args, out)
    except BaseException:
        if new_folder:  # a capture refused, an arm that failed: no empty folder is left
            with contextlib.suppress(OSError):
                out.parent.rmdir()
        raise
    _summary(result, output_paths(out, observations=args.port is not None))
    return 0 if held_out is None else _held_out_check(result, held_out, args.check)


def _held_out_check(result: CalibrationResult, data: CaptureData, capture: str) -> int:
    """Twin-check the fitted settings on a capture the fit did not use; print the verdict and,
    per failing joint, what its divergence looks like and what to do. 0 pass, 1 fail."""
    print(f"checking the fitted twin on {capture}", file=sys.stderr, flush=True)
    check = twin_check(data, result.settings)
    print(f"held-out check on {capture}: verdict {check.verdict} "
          f"({check.replies_compared} replies, {check.moves} commands)")
    for line in format_failures(check):
        print(line)
    sys.stdout.flush()
    return 0 if check.verdict == "pass" else 1


def _calibrate(args: argparse.Namespace, out: Path) -> CalibrationResult:
    base = load_settings(args.settings)
    if args.capture is not None:
        return calibrate_capture(args.capture, base, out, page=render_page,
                                 references=args.references)
    if args.port is None:
        return calibrate_reference(args.reference, args.references, base, out, page=render_page)
    port: str = args.port
    tracker = None if args.tracker is None else load_tracker(args.tracker, base)
    touch = None if args.plate is None else (args.plate, TerminalOperator())
    return run_on_port(port, calibrate_port(
        port, base, out, budget_s=args.budget_s,
        progress=lambda m: print(m, file=sys.stderr, flush=True), tracker=tracker,
        page=render_page, reply_timeout_s=args.reply_timeout, references=args.references,
        touch=touch))


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
