"""Every number option of the command line has a range (:mod:`armbench.cli.commands.bounds`), and a
value outside it is one line naming the option, the value and the range, exit 2, before anything
runs.

Found by issue 38: ``armbench ros2 --pace-timeout 1e300`` and ``--realtime-factor 1e-300`` died
of an ``OverflowError``, ``monitor --reply-timeout 1e-300`` hung, ``monitor --rate nan`` and
``move --tolerance 1e300`` were taken. The targets and coordinates are not bounded here: the
robot model checks them (joint limits, reach) with errors of its own.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Iterator

import pytest
from conftest import cli, one_line_error

from armbench.cli.commands.bounds import bounds_of
from armbench.cli.main import build_parser
from armbench.drivers.model.bounds import Bound

#: Float options the robot model checks instead: (command, destination).
TARGETS = {("fk", "q1"), ("fk", "q2"), ("fk", "q3"), ("fk", "q4"), ("ik", "x"), ("ik", "y"),
           ("ik", "z"), ("ik", "roll"), ("move", "q"), ("move", "xyz"), ("move", "roll")}
#: What each command needs besides the option to parse (nothing of it runs: the bound is first).
PREFIX = {"run": ["run"], "fk": ["fk", "0", "0", "0", "0"], "ik": ["ik", "0.3", "0", "0.5"],
          "emulate": ["emulate", "--pty"], "monitor": ["monitor"],
          "move": ["move", "0", "0", "0", "0"], "config show": ["config", "show"],
          "calibrate": ["calibrate", "--port", "fake://", "--out", "never-written"],
          "ros2": ["ros2"]}


def _parsers() -> Iterator[tuple[str, argparse.ArgumentParser]]:
    """Every command's parser (``config show`` and the like by their two words)."""
    top = build_parser(None)
    for action in top._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, parser in action.choices.items():
                yield name, parser
                for inner in parser._actions:
                    if isinstance(inner, argparse._SubParsersAction):
                        for word, nested in inner.choices.items():
                            yield f"{name} {word}", nested


def _float_options() -> list[tuple[str, argparse.Action, Bound | None]]:
    return [(command, action, bounds_of(parser).get(action.dest, ("", None))[1])
            for command, parser in _parsers() for action in parser._actions
            if action.type is float]


def test_every_float_option_has_a_bound_but_the_targets() -> None:
    options = _float_options()
    assert len(options) > 20  # the walk found them
    unbounded = {(c, a.dest) for c, a, bound in options if bound is None}
    assert unbounded == TARGETS


def _out_of_bounds() -> list[tuple[str, str, str, Bound]]:
    cases = []
    for command, action, bound in _float_options():
        if bound is None:
            continue
        below = f"{bound.low:g}" if bound.low_open else (f"{bound.low / 10:g}" if bound.low > 0
                                                          else "-1")
        for value in ("nan", "inf", f"{bound.high * 10:g}", below):
            cases.append((command, action.option_strings[0], value, bound))
    return cases


@pytest.mark.parametrize(("command", "flag", "value", "bound"), _out_of_bounds())
def test_a_number_out_of_its_bound_is_one_line_naming_it_and_the_range(
        capsys: pytest.CaptureFixture[str], command: str, flag: str, value: str,
        bound: Bound) -> None:
    status, _, err = cli(capsys, *PREFIX[command], flag, value)
    one_line_error(status, err, f"{flag}: ", f"must be in {bound}")
    shown = err.split(f"{flag}: ", 1)[1].split(" must", 1)[0]
    assert math.isnan(float(shown)) if value == "nan" else float(shown) == float(value)


@pytest.mark.parametrize("bound", [Bound(0.0, 1.0, "s", low_open=True), Bound(0.001, 1e6)])
def test_a_bound_holds_its_ends_as_it_says(bound: Bound) -> None:
    assert bound.holds(bound.high) and not bound.holds(math.nextafter(bound.high, math.inf))
    assert bound.holds(bound.low) is not bound.low_open
    assert not bound.holds(math.nan) and not bound.holds(math.inf)
