"""The bench runner behind ``armbench run``: :func:`lay_out` says which arms a run has and where
each writes (``arms``), :func:`prepare` validates everything an arm's run reads (``plan``),
:func:`run_arms_sync` runs every arm of a run, one or several at once, through the same path
(``fleet_run``; :func:`run_sync` for a run of one arm), :func:`execute` one arm's run
(``execute``), trial by trial (``trials``), in worker processes when it can (``parallel``),
showing progress (``progress``) and keeping the traffic capture one stream (``capture_run``)."""

from armbench.bench.runner.arms import ArmRun, RunLayout, lay_out
from armbench.bench.runner.execute import execute
from armbench.bench.runner.fleet_run import RunResult, run_arms, run_arms_sync, run_bench, run_sync
from armbench.bench.runner.options import (
    CAPTURE_FILE,
    DEFAULT_CONFIG,
    EXIT_ERROR,
    EXIT_FAIL,
    EXIT_INCOMPLETE,
    EXIT_INTERRUPTED,
    EXIT_PASS,
    EXIT_REGRESSION,
    JUNIT_FILE,
    REPORT_FILE,
    RUNNER_FILE,
    BenchPlan,
    EmulatorFactory,
    PlannedSuite,
    RunAborted,
    RunOptions,
    RunOutcome,
    derive_seed,
    exit_status,
)
from armbench.bench.runner.plan import prepare
from armbench.bench.runner.progress import ProgressPrinter

__all__ = [
    "CAPTURE_FILE",
    "DEFAULT_CONFIG",
    "EXIT_ERROR",
    "EXIT_FAIL",
    "EXIT_INCOMPLETE",
    "EXIT_INTERRUPTED",
    "EXIT_PASS",
    "EXIT_REGRESSION",
    "JUNIT_FILE",
    "REPORT_FILE",
    "RUNNER_FILE",
    "ArmRun",
    "BenchPlan",
    "EmulatorFactory",
    "PlannedSuite",
    "ProgressPrinter",
    "RunAborted",
    "RunLayout",
    "RunOptions",
    "RunOutcome",
    "RunResult",
    "derive_seed",
    "execute",
    "exit_status",
    "lay_out",
    "prepare",
    "run_arms",
    "run_arms_sync",
    "run_bench",
    "run_sync",
]
