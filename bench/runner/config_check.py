"""Nothing in a config judges nothing: before any motion, every ``[limits."PATTERN"]`` and
``[regression.metrics."PATTERN"]`` pattern must match a metric name some suite records, and every
``[suites.NAME]`` table must name a suite (:func:`check_config`).

A misspelt limit would otherwise judge nothing and the run pass unmentioned; a misspelt suite table
would leave the suite at its defaults. The names a pattern may match are those of every registered
suite (:func:`~armbench.bench.suites.registered_suites`) and of the run's own suites, each with its
parameters from the config (``Suite.metric_names``), of a campaign over any of them and of
``armbench twin-check``: one config serves every command, so a limit of a suite this run does not
run is fine as long as some suite can record a match. The rule is documented in
``docs/record.md``.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

from armbench.bench.runner.options import PlannedSuite
from armbench.bench.suites import SuiteError, load_suite, registered_suites
from armbench.bench.suites.base import Suite
from armbench.bench.suites.twin_check_contract import TWIN_CHECK
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.record.limits import LimitsConfig, matches
from armbench.record.suite_contract import contracts

__all__ = ["check_config", "closest", "known_metric_names"]

#: How many close names an error message offers.
SUGGESTIONS = 3


def closest(word: str, candidates: Iterable[str]) -> list[str]:
    """The candidates closest to ``word`` (a misspelling's likely intent), best first. A wildcard
    pattern is compared with the patterns of the same shape the candidates give
    (:func:`_shaped`), else by its literal text (``startup.*_S`` as ``startup._S``)."""
    names = list(candidates)
    if "*" in word:
        near = difflib.get_close_matches(word, _shaped(word, names), n=SUGGESTIONS)
        if near:
            return near
        return difflib.get_close_matches(word.replace("*", ""), names, n=SUGGESTIONS,
                                         cutoff=0.5)
    return difflib.get_close_matches(word, names, n=SUGGESTIONS)


def _shaped(pattern: str, names: Iterable[str]) -> set[str]:
    """Each name in the shape of ``pattern``: its dotted parts before and after the parts of
    ``pattern`` that hold a wildcard, with those parts between (``repeatability.v50.p5.ap_mm``
    in the shape of ``repeatability.*.ap_nm`` is ``repeatability.*.ap_mm``), where they match
    the name's parts they stand for."""
    parts = pattern.split(".")
    starred = [i for i, part in enumerate(parts) if "*" in part]
    head, tail = parts[:starred[0]], parts[starred[-1] + 1:]
    middle = parts[starred[0]:starred[-1] + 1]
    wild = ".".join(middle)
    out = set()
    for name in names:
        own = name.split(".")
        end = len(own) - len(tail)
        if end > len(head) and matches(wild, ".".join(own[len(head):end])):
            out.add(".".join([*own[:len(head)], *middle, *own[end:]]))
    return out


def _suite_names(run: Sequence[PlannedSuite]) -> set[str]:
    """The names a ``[suites.NAME]`` table may have: every registered suite, every suite
    contract (``twin-check`` reads its table too) and the run's own suites by name or by the
    ``module:Class`` they were named with."""
    return ({*registered_suites(), *(c.suite for c in contracts())}
            | {ps.suite.name for ps in run} | {ps.ref for ps in run})


def _names_not_run(suite: Suite, settings: RobotSettings,
                   configured: Mapping[str, Any]) -> frozenset[str]:
    """The metric names of a suite this run does not run, with the config's parameters: unknown
    keys refused, values not validated (the suite's own checks run when it runs; ros2-square's
    need its extra), a value the names cannot be made of refused naming the table."""
    params = suite.configured_params(settings, configured)
    try:
        return suite.metric_names(params)
    except ArmbenchError:
        raise
    except Exception as exc:  # a wrongly typed value the suite did not check: as planning says
        raise SettingsError(f"suites.{suite.name}", dict(configured),
                            f"cannot be used: {type(exc).__name__}: {exc}") from exc


def known_metric_names(config: LimitsConfig, settings: RobotSettings,
                       run: Sequence[PlannedSuite] = ()) -> tuple[frozenset[str], list[str]]:
    """Every metric name a pattern of ``config`` may match (see the module doc), and the
    registered suites that could not be loaded (their names unknown), as ``name (why)``."""
    from armbench.record.campaign_names import CAMPAIGN

    by_suite = {ps.suite.name: ps.suite.metric_names(ps.params) for ps in run}
    unloadable = []
    for name in registered_suites():
        if name in by_suite:
            continue
        try:
            suite = load_suite(name)
        except SuiteError as exc:
            unloadable.append(f"{name} ({exc})")
            continue
        by_suite[name] = _names_not_run(suite, settings, config.suite_params(name))
    names = frozenset().union(*by_suite.values())
    sampled = {n for n in names if not n.startswith(f"{CAMPAIGN.prefix}.")}
    return names | CAMPAIGN.metric_names(sampled) | TWIN_CHECK.metric_names(), unloadable


def check_config(config: LimitsConfig, settings: RobotSettings,
                 run: Sequence[PlannedSuite] = ()) -> None:
    """Refuse, naming the dotted field and the closest right names, a ``[suites.NAME]`` table of
    no suite, an unknown key in the table of a suite this run does not run (the run's own are
    checked when planned) and a limit or tolerance pattern that matches no metric name (see the
    module doc); ``run``: the suites of this run, planned."""
    suites = _suite_names(run)
    for name, table in config.suites.items():
        if name not in suites:
            near = closest(name, suites)
            raise SettingsError(f"suites.{name}", dict(table),
                                "is not a suite"
                                + (f" (closest: {', '.join(near)})" if near else "")
                                + f"; known: {', '.join(sorted(suites))}")
    patterns = [(f'limits."{p}"', p, "judge") for p in config.limits]
    patterns += [(f'regression.metrics."{p}"', p, "apply to") for p in config.tolerances]
    names, unloadable = known_metric_names(config, settings, run)
    for where, pattern, effect in patterns:
        if pattern in names or ("*" in pattern and any(matches(pattern, n) for n in names)):
            continue
        near = closest(pattern, names)
        raise SettingsError(
            where, pattern,
            "matches no metric any suite records (with the config's suite parameters): it "
            f"would {effect} nothing"
            + (f"; closest: {', '.join(near)}" if near else "")
            + (f"; suites that could not be loaded: {'; '.join(unloadable)}"
               if unloadable else ""))
