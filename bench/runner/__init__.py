"""The bench runner behind ``armbench run``: :func:`prepare` validates everything a run reads
(``plan``), :func:`execute` and :func:`run_sync` run it (``run``), trial by trial (``trials``),
in worker processes when it can (``parallel``), on several arms at once (``fleet``), showing
progress (``progress``) and keeping the traffic capture one stream (``capture``)."""

from armbench.bench.runner.execute import execute, run_bench, run_sync
from armbench.bench.runner.fleet_run import FleetOutcome, run_fleet_sync
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
    "BenchPlan",
    "EmulatorFactory",
    "FleetOutcome",
    "PlannedSuite",
    "ProgressPrinter",
    "RunAborted",
    "RunOptions",
    "RunOutcome",
    "derive_seed",
    "execute",
    "exit_status",
    "prepare",
    "run_bench",
    "run_fleet_sync",
    "run_sync",
]
