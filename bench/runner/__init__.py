"""The bench runner behind ``armbench run``: :func:`lay_out` says which arms a run has and where
each writes (``arms``), :func:`prepare` validates everything an arm's run reads (``plan``),
:func:`run_arms_sync` runs every arm of a run, one or several at once, through the same path
(``fleet_run``; :func:`run_sync` for a run of one arm), ``execute.execute`` runs one arm's run
trial by trial (``trials``), in worker processes when it can (``parallel``),
showing progress (``progress``) and keeping the traffic capture one stream (``capture_run``).
Each name loads its module on first use, so that a worker process importing one module of the
runner does not import the others (``execute`` is therefore the module, not its function: a lazy
name cannot share a submodule's)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from armbench.drivers.model.lazy_names import lazy_name

if TYPE_CHECKING:
    from armbench.bench.runner.arms import ArmRun, RunLayout, lay_out
    from armbench.bench.runner.fleet_run import (
        RunResult,
        run_arms,
        run_arms_sync,
        run_bench,
        run_sync,
    )
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
    "exit_status",
    "lay_out",
    "prepare",
    "run_arms",
    "run_arms_sync",
    "run_bench",
    "run_sync",
]

_LAZY = {
    "ArmRun": "armbench.bench.runner.arms",
    "BenchPlan": "armbench.bench.runner.options",
    "CAPTURE_FILE": "armbench.bench.runner.options",
    "DEFAULT_CONFIG": "armbench.bench.runner.options",
    "EXIT_ERROR": "armbench.bench.runner.options",
    "EXIT_FAIL": "armbench.bench.runner.options",
    "EXIT_INCOMPLETE": "armbench.bench.runner.options",
    "EXIT_INTERRUPTED": "armbench.bench.runner.options",
    "EXIT_PASS": "armbench.bench.runner.options",
    "EXIT_REGRESSION": "armbench.bench.runner.options",
    "EmulatorFactory": "armbench.bench.runner.options",
    "JUNIT_FILE": "armbench.bench.runner.options",
    "PlannedSuite": "armbench.bench.runner.options",
    "ProgressPrinter": "armbench.bench.runner.progress",
    "REPORT_FILE": "armbench.bench.runner.options",
    "RUNNER_FILE": "armbench.bench.runner.options",
    "RunAborted": "armbench.bench.runner.options",
    "RunLayout": "armbench.bench.runner.arms",
    "RunOptions": "armbench.bench.runner.options",
    "RunOutcome": "armbench.bench.runner.options",
    "RunResult": "armbench.bench.runner.fleet_run",
    "derive_seed": "armbench.bench.runner.options",
    "exit_status": "armbench.bench.runner.options",
    "lay_out": "armbench.bench.runner.arms",
    "prepare": "armbench.bench.runner.plan",
    "run_arms": "armbench.bench.runner.fleet_run",
    "run_arms_sync": "armbench.bench.runner.fleet_run",
    "run_bench": "armbench.bench.runner.fleet_run",
    "run_sync": "armbench.bench.runner.fleet_run",
}


def __getattr__(name: str) -> object:
    return lazy_name(__name__, _LAZY, name)
