"""What a verdict claims, in words every reader of a record prints the same way (the terminal,
the Markdown summary, the HTML report): what the run did not test, and whose figures it judged —
the arm's truth from a reference instrument, or the firmware's belief from its encoders alone."""

from __future__ import annotations

from fnmatch import fnmatchcase

from armbench.record.run_record import RunRecord
from armbench.record.suite_contract import contract, records_truth

__all__ = ["encoder_headlines", "truth_line", "uncovered_lines"]


def uncovered_lines(record: RunRecord) -> list[str]:
    """What the verdict does not cover, a line each: every suite or required figure the run
    measured nothing of (:meth:`RunRecord.untested`), every suite some of whose trials were
    skipped, and every suite whose figures no limit judged."""
    untested = record.untested()
    lines = [f"{name}: untested, {reason}" + ("" if required else
                                              " (optional: the verdict does not count it)")
             for name, reason, required in untested]
    named = {name for name, _, _ in untested}
    for suite in record.suites.values():
        skipped = suite.skipped_trials()
        if skipped and suite.name not in named:
            why = "; ".join(dict.fromkeys(str(t.skipped) for t in skipped))
            lines.append(f"{suite.name}: {len(skipped)} of {len(suite.trials)} trials skipped "
                         f"(measured nothing): {why}")
        if suite.name not in named and (n := suite.unjudged_figures()):
            lines.append(f"{suite.name}: {n} figures recorded, none judged (no limit in the "
                         "config): its pass claims nothing")
    return lines


def truth_line(record: RunRecord) -> str:
    """Whose figures the verdict judged: the arm's truth (the run's reference instrument, how
    many true figures were judged and how many fell outside) or the encoders alone (the position
    figures of which suites)."""
    source = record.environment.truth_source
    true = [m for _, _, m in record.iter_measurements()
            if m.name.rpartition(".")[2].startswith("true_")]
    if source is not None or true:
        judged = [m for m in true if m.outcome != "unjudged"]
        failed = sum(m.outcome == "fail" for m in judged)
        return (f"truth judged: {len(judged)} true figures ({source or 'from the record'}), "
                f"{failed} outside their limits; the firmware's belief beside them")
    alone = encoder_headlines(record)
    shown = ", ".join(alone[:8]) + (f" and {len(alone) - 8} more" if len(alone) > 8 else "")
    return ("no reference instrument: the figures are the firmware's belief from its encoders"
            + (f"; headline figures resting on the encoders alone: {shown}" if alone else ""))


#: Units of the position figures a reference instrument would measure otherwise.
_POSITION_UNITS = frozenset({"mm", "m", "mrad", "rad", "deg"})


def encoder_headlines(record: RunRecord) -> list[str]:
    """The headline figures (``"suite: label"``) of the suites that record a true figure beside
    each position figure when they can, where this run recorded the position figure alone."""
    out = []
    for suite in record.suites.values():
        if not records_truth(suite.name):
            continue
        names = {m.name: m.unit for m in suite.measurements}
        for h in contract(suite.name).headlines:
            units = [u for n, u in names.items()
                     if (fnmatchcase(n, h.metric) if h.worst_of else n == h.metric)]
            if units and units[0] in _POSITION_UNITS:
                out.append(f"{suite.name}: {h.label}")
    return out
