"""``armbench run``: run bench suites against the arm and judge them (see ``docs/runner.md``).

``armbench run [SUITE ...] [--port PORT] [--config bench.toml] [--out DIR] [--baseline FILE]
[--resume DIR] [--seed N] [--settings FILE] [--faults FILE] [--tracker MODULE:CLASS]
[--power-command CMD_OFF CMD_ON | --power-manual] [--retries N] [--workers N] [--no-capture]
[--capture-max-mb MB] [--scheduler tcp://HOST:PORT] [--shard I/N] [--dut NAME]
[--meta KEY=VALUE ...]``

Exit status (:mod:`armbench.record.verdict`): 0 every measurement within its limits and no
regression, 1 a limit failed, 2 bad input (reported before the arm moves), 3 regressed against
the baseline (every limit held), 4 the run is incomplete (a lost arm, a trial in error), 5 a
required suite or figure measured nothing (untested: ``--require``, ``--optional``), 130
interrupted (resume with ``--resume DIR``). With several ``--port``: the worst arm's status, one
line per arm (``docs/fleet.md``). ``--summary FILE.md`` appends a short Markdown summary for a CI
job's step summary (``docs/ci.md``).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import IO, Any, cast

from armbench.bench.runner import JUNIT_FILE, RunOptions, RunOutcome, run_arms_sync
from armbench.bench.runner.progress import PER_SUITE, PER_TRIAL, ProgressStream
from armbench.bench.suites import suite_names
from armbench.cli.commands.bounds import CAPTURE_MAX_MB, add_bounded
from armbench.cli.commands.fleet import fleet_summary
from armbench.cli.commands.run_files import ReportAhead, step_summary, write_reports
from armbench.record import CAPTURE_FILE, REPORT_FILE, RESULTS_FILE
from armbench.record.claims import truth_line, uncovered_lines
from armbench.record.verdict import EXIT_STATUS_EPILOG

__all__ = ["LATEST_LINK", "link_latest", "progress_stream", "register"]

#: The link beside the default run folders to the newest one (``runs/latest``).
LATEST_LINK = "latest"


def register(sub: Any) -> None:
    """Add the ``run`` subcommand."""
    p: argparse.ArgumentParser = sub.add_parser(
        "run",
        description="Run bench suites against the arm (the built-in emulator on virtual time "
                    "unless --port is given), write results.json after every trial, then "
                    "junit.xml, report.html and the traffic capture capture.mcap.",
        epilog=EXIT_STATUS_EPILOG)
    p.add_argument("suites", nargs="*", metavar="SUITE",
                   help=f"suites to run (default: all: {', '.join(suite_names())}); "
                        "package.module:Class runs a suite of your own")
    p.add_argument("--port", action="append", default=None, metavar="[NAME=]PORT",
                   help="serial device, socket://HOST:PORT, rfc2217://HOST:PORT, "
                        "labgrid://PLACE or fake:// (default fake://, the emulator on virtual "
                        "time); given several times, every arm at once, each in OUT/NAME/ "
                        "(see docs/fleet.md)")
    p.add_argument("--config", metavar="FILE",
                   help="limits and suite parameters (default: the packaged default_bench.toml)")
    add_dut_arguments(p)
    p.add_argument("--out", metavar="DIR",
                   help="run directory (default runs/<run id>/, and runs/latest links to it)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the run --out holds (its record, reports, capture and suite "
                        "folders; nothing else in DIR is touched); without it such a DIR is "
                        "refused")
    p.add_argument("--baseline", metavar="FILE",
                   help="results.json of an earlier run: fail on regressions against it (with "
                        "several --port: the folder of an earlier fleet run, each arm against "
                        "its own)")
    p.add_argument("--summary", metavar="FILE.md",
                   help="append a short Markdown summary of the run (verdict, exit status, "
                        "failures, regressions) to FILE.md, e.g. \"$GITHUB_STEP_SUMMARY\" "
                        "(see docs/ci.md)")
    p.add_argument("--resume", metavar="DIR",
                   help="continue the interrupted run in DIR (finished trials are kept)")
    p.add_argument("--seed", type=int, default=None, metavar="N",
                   help="seed of the run's random choices and of the emulator (default 0)")
    p.add_argument("--settings", metavar="FILE", help="robot settings TOML ([emulator] too)")
    p.add_argument("--faults", metavar="FILE",
                   help="fault list TOML ([[faults]]) injected into the emulator (fake:// only)")
    p.add_argument("--tracker", metavar="MODULE:CLASS",
                   help="measurement source plug-in (a laser tracker driver implementing "
                        "PoseSource)")
    power = p.add_mutually_exclusive_group()
    power.add_argument("--power-command", nargs=2, metavar=("CMD_OFF", "CMD_ON"),
                       help="commands that cut and restore the arm's power (a relay script)")
    power.add_argument("--power-manual", action="store_true",
                       help="ask the operator to switch the power and wait for Enter")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="processes measuring fake:// trials at once (default: [bench] workers, "
                        "else one per CPU, at most 2; 1: in turn on one loop)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="measure fake:// trials on this Dask scheduler's workers (default: "
                        "[bench] scheduler, else the local processes of --workers)")
    p.add_argument("--shard", type=shard_arg, metavar="I/N",
                   help="measure only shard I of N of the trials (CI); join the shards with "
                        "armbench merge")
    p.add_argument("--retries", type=int, default=None, metavar="N",
                   help="measure a trial that ended in error up to N more times (default: "
                        "[bench] retries, else 0)")
    p.add_argument("--no-capture", dest="capture", action="store_false", default=None,
                   help="do not capture the traffic (default: [bench] capture, else capture)")
    p.add_argument("--require", action="append", default=[], metavar="SUITE|METRIC",
                   help="a suite or figure (metric name or * pattern) the run must measure, else "
                        "its verdict is untested (exit 5); repeatable. Every planned suite is "
                        "required unless --optional or the config's optional list names it")
    p.add_argument("--optional", action="append", default=[], metavar="SUITE",
                   help="a planned suite that may measure nothing (no power switch, say) without "
                        "making the run untested; repeatable")
    add_bounded(p, "--capture-max-mb", CAPTURE_MAX_MB, default=None, metavar="MB",
                help="stop the capture (a capture_stopped event says so) before capture.mcap "
                     "would exceed MB megabytes; the run goes on (default: [bench] "
                     "capture_max_bytes, else unbounded)")
    p.set_defaults(func=_run)


def add_dut_arguments(p: argparse.ArgumentParser) -> None:
    """``--dut NAME`` and ``--meta KEY=VALUE``: the unit under test, over the config's
    ``[dut]`` table (``armbench run`` and ``armbench config show``)."""
    p.add_argument("--dut", metavar="NAME",
                   help="the unit under test's name (over the config's [dut] name); recorded "
                        "in results.json, junit.xml, the report and the summary")
    p.add_argument("--meta", action="append", default=[], metavar="KEY=VALUE",
                   help="a fact about the unit under test, repeatable: serial, firmware_commit "
                        "or host_commit set that [dut] key, any other KEY is free")


def shard_arg(text: str) -> tuple[int, int]:
    """``I/N`` → ``(I, N)`` with 1 <= I <= N (an argparse type)."""
    i, sep, n = text.partition("/")
    try:
        shard = (int(i), int(n))
    except ValueError:
        shard = (0, 0)
    if not sep or not 1 <= shard[0] <= shard[1]:
        raise argparse.ArgumentTypeError(f"{text!r} is not I/N with 1 <= I <= N")
    return shard


def _run(args: argparse.Namespace) -> int:
    if args.summary is not None:  # before anything moves: not a traceback after the whole run
        from armbench.reports.files.run_summary import check_summary_file

        check_summary_file(args.summary)
    options = RunOptions(
        suites=list(args.suites), ports=list(args.port or ()), config=args.config, out=args.out,
        overwrite=args.overwrite,
        baseline=args.baseline, resume=args.resume, seed=args.seed, settings=args.settings,
        faults=args.faults, tracker=args.tracker,
        power_command=tuple(args.power_command) if args.power_command else None,
        power_manual=args.power_manual, retries=args.retries,
        workers=args.workers, capture=args.capture, capture_max_mb=args.capture_max_mb,
        scheduler=args.scheduler, shard=args.shard, require=list(args.require),
        optional=list(args.optional), dut=args.dut,
        meta=tuple(args.meta))
    level = args.verbose - args.quiet
    # each record is on disk: now its reports, while the run folder is still locked
    ahead = ReportAhead()

    def reports(done: RunOutcome) -> None:
        ahead.finish()
        write_reports(done.record, done.out_dir, capture_max_bytes=done.capture_max_bytes)

    result = run_arms_sync(options, progress=progress_stream(level), then=reports, ahead=ahead)
    if args.out is None and args.resume is None:
        link_latest(result.out_dir)
    if result.fleet:
        fleet_summary(result)
    else:
        _summary(result.only(), verdict_only=level < 0)
    if args.summary is not None:
        for outcome in result.outcomes:
            if outcome is not None:
                step_summary(args.summary, outcome)
    return result.exit_status


def link_latest(out_dir: Path) -> None:
    """Point ``latest`` beside the new run folder ``out_dir`` (``runs/latest``) at it. A
    ``latest`` that is not such a link (a file or folder of the user's, a link elsewhere) is
    left as it is, with a warning; so is one the system cannot make (no symlinks)."""
    latest = out_dir.parent / LATEST_LINK
    if os.path.lexists(latest) and not (latest.is_symlink()
                                        and Path(os.readlink(latest)).parent == Path()):
        print(f"armbench run: warning: {latest} is not a link to a run: not updated",
              file=sys.stderr)
        return
    temporary = out_dir.parent / f".{LATEST_LINK}.{os.getpid()}.tmp"
    try:
        temporary.unlink(missing_ok=True)
        os.symlink(out_dir.name, temporary, target_is_directory=True)
        os.replace(temporary, latest)
    except OSError as exc:
        temporary.unlink(missing_ok=True)
        print(f"armbench run: warning: {latest} not updated: {exc.strerror or exc}",
              file=sys.stderr)


def progress_stream(level: int) -> IO[str] | None:
    """The run's progress on stderr as the verbosity ``level`` (``-v`` minus ``-q``) asks: a
    line per suite (0), a line per trial and every message (1 and more), nothing (below 0: the
    verdict only)."""
    if level < 0:
        return None
    return cast(IO[str], ProgressStream(sys.stderr, PER_TRIAL if level > 0 else PER_SUITE))


def _summary(outcome: RunOutcome, *, verdict_only: bool = False) -> None:
    record = outcome.record
    out = sys.stdout
    notes = ([outcome.error] if outcome.error else []) + [
        f"warning: {w}" for w in outcome.warnings]
    if (disturbed := record.disturbance_note()) is not None:
        notes.append(f"warning: {disturbed}")
    print(f"run {record.run_id}: verdict {record.verdict} (exit {outcome.exit_status})"
          + (f" ({'; '.join(notes)})" if notes else ""), file=out)
    if verdict_only:
        out.flush()
        return
    for line in [*uncovered_lines(record), truth_line(record)]:
        print(f"  {line}", file=out)
    for suite in record.suites.values():
        for trial in suite.trials:
            if trial.status == "error":
                print(f"  error  {suite.name} trial {trial.index}: {trial.error}", file=out)
            for m in trial.measurements:
                if m.outcome == "fail":
                    print(f"  FAIL   {suite.name} trial {trial.index}: {m.name} = {m.value:.6g} "
                          f"{m.unit} (limit {m.limit.describe() if m.limit else '-'})", file=out)
        if suite.error and not any(t.status == "error" for t in suite.trials):
            print(f"  error  {suite.name}: {suite.error}", file=out)
        for m in suite.measurements:
            if m.outcome == "fail":
                print(f"  FAIL   {m.name} = {m.value:.6g} {m.unit} "
                      f"(limit {m.limit.describe() if m.limit else '-'})", file=out)
    if record.baseline is not None:
        for row in record.baseline.regressions:
            print(f"  REGRESSED  {row.name}: {row.baseline:.6g} -> {row.value:.6g} {row.unit} "
                  f"(tolerance {row.tolerance:.3g})", file=out)
    for name in (RESULTS_FILE, REPORT_FILE, JUNIT_FILE, CAPTURE_FILE):
        path = outcome.out_dir / name
        if path.exists():
            print(f"  {name:<13} {path}", file=out)
    if outcome.exit_status in (2, 130) and record.verdict in ("incomplete", "error"):
        print(f"  continue with: armbench run --resume {outcome.out_dir}", file=out)
    out.flush()
