"""The one judgement of the bench: which config a run is judged with, and the exit status of a
verdict, shared by ``armbench run``, ``armbench compare``, ``armbench campaign`` and the fleet.

A CI job tells the outcomes apart by the exit status alone:

====  ===========================================================================
0     pass: every judged measurement within its limits, nothing regressed
1     a limit failed (a measurement, or a campaign's pass probability, out of bounds)
2     bad input: the bench could not run (reported before the arm moves)
3     regressed against the baseline (every limit held)
4     incomplete: a trial in error, a lost arm, a planned suite not finished
5     untested: every limit held, but a required suite or figure measured nothing
130   interrupted (continue with ``armbench run --resume DIR``)
====  ===========================================================================

Regression tolerances and limits come from one file, ``--config`` (default: the packaged
``default_bench.toml``), whichever command judges; ``armbench config show`` prints it with the
parameters of a run, defaults written out.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Final

from armbench.record import Verdict
from armbench.record.limits import LimitsConfig, load_limits

__all__ = [
    "DEFAULT_CONFIG", "EXIT_ERROR", "EXIT_FAIL", "EXIT_INCOMPLETE", "EXIT_INTERRUPTED",
    "EXIT_PASS", "EXIT_REGRESSION", "EXIT_STATUS_EPILOG", "EXIT_UNTESTED", "exit_status",
    "load_config", "worst_exit_status",
]

#: The limits file used when ``--config`` is not given (shipped with the package).
DEFAULT_CONFIG: Final = Path(__file__).resolve().parent / "default_bench.toml"

EXIT_PASS: Final = 0
EXIT_FAIL: Final = 1
EXIT_ERROR: Final = 2
EXIT_REGRESSION: Final = 3
EXIT_INCOMPLETE: Final = 4
EXIT_UNTESTED: Final = 5
EXIT_INTERRUPTED: Final = 130

_EXIT_BY_VERDICT: Final[dict[Verdict, int]] = {
    "pass": EXIT_PASS, "fail": EXIT_FAIL, "regression": EXIT_REGRESSION,
    "error": EXIT_INCOMPLETE, "incomplete": EXIT_INCOMPLETE, "untested": EXIT_UNTESTED,
}

#: From the worst: the status of several outcomes (a fleet's arms) is the first one present.
_SEVERITY: Final = (EXIT_INTERRUPTED, EXIT_ERROR, EXIT_INCOMPLETE, EXIT_FAIL, EXIT_UNTESTED,
                    EXIT_REGRESSION, EXIT_PASS)

#: The exit-status paragraph of every ``--help`` whose command can produce them.
EXIT_STATUS_EPILOG: Final = (
    "Exit status: 0 pass, 1 a limit failed, 2 bad input (the bench could not run), 3 regressed "
    "against the baseline (limits held), 4 incomplete run (a trial in error, a lost arm), 5 "
    "untested (a required suite or figure measured nothing), 130 interrupted (continue with "
    "--resume DIR). See docs/ci.md.")


def exit_status(verdict: Verdict) -> int:
    """The exit status of a run with this verdict: 0 pass, 1 fail, 3 regression, 4 error or
    incomplete, 5 untested."""
    return _EXIT_BY_VERDICT[verdict]


def worst_exit_status(statuses: Iterable[int]) -> int:
    """The status of several outcomes: interrupted, else bad input, incomplete, a limit failed,
    untested, a regression, pass (an unknown status counts as bad input)."""
    present = {s if s in _SEVERITY else EXIT_ERROR for s in statuses}
    return next((s for s in _SEVERITY if s in present), EXIT_PASS)


def load_config(path: str | Path | None) -> LimitsConfig:
    """The config a run is judged with: ``path``, else the packaged ``default_bench.toml``."""
    return load_limits(DEFAULT_CONFIG if path is None else path)
