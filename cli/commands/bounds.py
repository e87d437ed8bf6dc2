"""The command line's number options and their bounds: declared with the option, checked after
parsing by the robot model's one bounds checker (:mod:`armbench.drivers.model.bounds`).

``add_bounded(parser, "--pace-timeout", Bound(0, 3600, "s", low_open=True), default=5.0, ...)``
adds a number option (a float, or an int for a ``whole`` bound) and records its bound on the
parser; ``armbench``'s main runs :func:`check_bounds` before the command, which refuses a value
outside it in one line naming the option, the value and the range
(:class:`~armbench.drivers.model.errors.InvalidTargetError`, exit 2).
So no option takes NaN, an infinity, or a value so large or so small that a sleep, a timer or a
conversion overflows (``--pace-timeout 1e300``, ``--realtime-factor 1e-300``), and the range of
each is in one place. Every float option of every command is declared so, but the targets and
coordinates, which the robot model checks (joint limits, reach); ``tests/test_cli_bounds.py``
keeps it so.
"""

from __future__ import annotations

import argparse
from typing import Any

from armbench.drivers.model.bounds import Bound, check, option_refused

__all__ = ["CAPTURE_MAX_MB", "DURATION_S", "REPLY_TIMEOUT_S", "TIMEOUT_S", "add_bounded",
           "bounds_of", "check_bounds"]

_DEST = "_number_bounds"


#: How long a command runs (``--duration``): any finite time, a few decades at most.
DURATION_S = Bound(0.0, 1e9, "s", low_open=True)
#: How long a command waits for something (a connection, a move, an idle client): up to a day.
TIMEOUT_S = Bound(0.0, 86_400.0, "s", low_open=True)
#: A run's capture size bound (``--capture-max-mb``): a byte to a petabyte.
CAPTURE_MAX_MB = Bound(1e-6, 1e9, "MB")
#: Silence after which the arm is reported silent: at least a few of its reply periods (~2.4 ms;
#: shorter, every gap between two replies would count), at most an hour.
REPLY_TIMEOUT_S = Bound(0.01, 3600.0, "s")


def add_bounded(parser: argparse.ArgumentParser, flag: str, bound: Bound,
                **kwargs: Any) -> argparse.Action:
    """``parser.add_argument(flag, type=float, **kwargs)`` (``type=int`` for a ``whole``
    bound), its values to be within ``bound`` (checked by :func:`check_bounds`; a default of None
    is "not given" and not checked)."""
    action = parser.add_argument(flag, type=int if bound.whole else float, **kwargs)
    known = dict(bounds_of(parser))
    known[action.dest] = (flag, bound)
    parser.set_defaults(**{_DEST: known})
    return action


def bounds_of(parser: argparse.ArgumentParser) -> dict[str, tuple[str, Bound]]:
    """The bounded options of ``parser``: by destination, the flag and its bound."""
    known: dict[str, tuple[str, Bound]] = parser.get_default(_DEST) or {}
    return known


def check_bounds(args: argparse.Namespace) -> None:
    """Refuse the first bounded option of ``args`` whose value (or one of whose values) is out
    of its bound: :class:`InvalidTargetError` naming the option, the value and the range."""
    known: dict[str, tuple[str, Bound]] = getattr(args, _DEST, {})
    for dest, (flag, bound) in known.items():
        value = getattr(args, dest, None)
        for v in value if isinstance(value, list) else [] if value is None else [value]:
            check(flag, v, bound, option_refused)
