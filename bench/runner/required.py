"""What a run must measure to pass: the one rule that turns the suites named, the config's
``required``/``optional`` lists and the ``--require``/``--optional`` flags into the record's
``required`` list (docs/ci.md, "Untested is not pass").

Every suite the run plans is required, named on the command line or run by default, unless the
config or a flag declares it optional: a hardware run without a power switch that skips every
power cut is ``untested`` (exit 5), never a pass. Metric names or ``*`` patterns in the list must
be measured too (a lab with a tracker requires ``accuracy.*.true_mean_mm``).
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Sequence

from armbench.drivers.model.settings import SettingsError
from armbench.record.limits import LimitsConfig

__all__ = ["required_of", "truth_source_of"]

#: How the record names a target's own ground truth, by port scheme.
_OWN_TRUTH = {"fake": "the emulator's ground truth", "avr": "the simavr harness's ground truth"}


def _is_metric(name: str) -> bool:
    """Metric names are dotted (``startup.recovery_time_s``); suite names never are."""
    return "." in name or "*" in name


def _check_suites(where: str, names: Iterable[str], planned: Sequence[str]) -> None:
    """Each suite name of ``names`` is one the run plans, else a SettingsError naming it and the
    closest planned names (a list that names nothing of the run judges nothing)."""
    for name in names:
        if not _is_metric(name) and name not in planned:
            close = difflib.get_close_matches(name, planned, n=3)
            hint = f"; did you mean {', '.join(close)}?" if close else ""
            raise SettingsError(where, name, f"is not a suite of this run (suites: "
                                             f"{', '.join(planned)}){hint}")


def required_of(planned: Sequence[str], config: LimitsConfig, *,
                require: Sequence[str] = (), optional: Sequence[str] = ()) -> list[str]:
    """The record's ``required`` list: the planned suites less the optional ones (config, then
    ``--optional``), then the config's and ``--require``'s metric patterns and suites."""
    _check_suites("--optional", optional, planned)
    _check_suites("--require", require, planned)
    for name in config.optional:
        if _is_metric(name):
            raise SettingsError("optional", name, "names a metric; optional takes suite names")
    dropped = set(config.optional) | set(optional)
    wanted = [*(s for s in planned if s not in dropped), *config.required, *require]
    return list(dict.fromkeys(wanted))


def truth_source_of(tracker: str | None, target_truth: bool, scheme: str | None) -> str | None:
    """What the record names as the run's reference instrument: the ``--tracker`` plug-in, the
    target's own ground truth (the emulator's, the firmware harness's), or None (encoders
    alone)."""
    if tracker:
        return f"tracker {tracker}"
    if target_truth:
        return _OWN_TRUTH.get(scheme or "", f"the {scheme or 'target'}'s ground truth")
    return None
