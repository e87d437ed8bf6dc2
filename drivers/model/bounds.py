"""The one check of a number against its bounds, for every number a user gives: the settings
files, the emulator's table, the limits file, the suites' parameters, the driver's options and
the command line's.

A :class:`Bound` says what is valid (its ends, each open or closed, its unit, whether only whole
numbers are, and why, when the range needs a reason); :func:`check` returns the value as a float
or raises the caller's typed error (:class:`~armbench.drivers.model.errors.SettingsError` unless
told otherwise) naming the field, the value and the range::

    check("bench.settle_s", 900, Bound(0, 600, "s"))
    # SettingsError: bench.settle_s: 900 must be in [0, 600] s

NaN, an infinity, a boolean (TOML's ``true`` is not 1) and anything that is not a real number are
refused by every bound. A comparison of a value with its limits that raises one of those errors
lives here and nowhere else (``tests/test_bounds.py`` scans the package for another).
"""

from __future__ import annotations

import functools
import math
import numbers
from collections.abc import Callable
from dataclasses import dataclass, replace

from armbench.drivers.model.errors import InvalidTargetError, SettingsError
from armbench.drivers.model.numbers import finite_float, is_real

__all__ = ["Bound", "Refusal", "check", "check_whole", "option_refused"]

Refusal = Callable[[str, object, str], Exception]
"""Builds the error of a refused value from its name, the value and the reason."""

#: An option of the driver or of the command line that is out of its bound: the driver's
#: :class:`~armbench.drivers.model.errors.InvalidTargetError` naming the option.
option_refused: Refusal = functools.partial(InvalidTargetError, None)


def _number_text(x: float) -> str:
    """``x`` as the range shows it, short: ``0.01``, ``600``, ``1e+12``, ``1048576`` (a whole
    number exact; another to 12 digits, so that ``70`` is not ``69.99999999999999``)."""
    x = float(x)
    if not x.is_integer():
        return f"{x:.12g}"
    exact = str(int(x))
    short = f"{x:g}"
    return short if len(short) < len(exact) and float(short) == x else exact


@dataclass(frozen=True, slots=True)
class Bound:
    """Valid values from ``low`` to ``high`` in ``unit``, each end included unless it is open
    (an infinite end: no bound on that side); ``whole``: only whole numbers; ``why``: the reason
    for the range, shown after it in a refusal."""

    low: float = -math.inf
    high: float = math.inf
    unit: str = ""
    low_open: bool = False
    high_open: bool = False
    whole: bool = False
    why: str = ""

    def holds(self, value: float) -> bool:
        """Whether the number ``value`` is inside (NaN and the infinities never are; nor is a
        fraction where only whole numbers are)."""
        if not math.isfinite(value) or (self.whole and not float(value).is_integer()):
            return False
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def __str__(self) -> str:
        """The range: ``[0, 600] s``, ``(0, 1]``, ``> 0 s``, ``<= 10``; empty without ends."""
        low, high = math.isfinite(self.low), math.isfinite(self.high)
        if low and high:
            text = (f"{'(' if self.low_open else '['}{_number_text(self.low)}, "
                    f"{_number_text(self.high)}{')' if self.high_open else ']'}")
        elif low:
            text = f"{'>' if self.low_open else '>='} {_number_text(self.low)}"
        elif high:
            text = f"{'<' if self.high_open else '<='} {_number_text(self.high)}"
        else:
            return ""
        return f"{text} {self.unit}".rstrip()

    def reason(self, value: object) -> str:
        """Why ``value`` is refused: what it must be, the range and the bound's ``why``."""
        both = math.isfinite(self.low) and math.isfinite(self.high)
        noun = ("a whole number" if self.whole else "a number" if not is_real(value)
                else "a finite number" if finite_float(value) is None and not both else "")
        interval = str(self)
        where = f"in {interval}" if both else interval
        text = " ".join(part for part in ("must be", noun, where) if part)
        return f"{text} ({self.why})" if self.why else text


def check(name: str, value: object, bound: Bound, refuse: Refusal = SettingsError) -> float:
    """``value`` as a float if it is a real number within ``bound``; else ``refuse(name, value,
    reason)`` is raised, the reason naming the range (:meth:`Bound.reason`)."""
    number = finite_float(value)
    if number is None or not bound.holds(number) or (
            bound.whole and not isinstance(value, numbers.Integral)):
        raise refuse(name, value, bound.reason(value))
    return number


def check_whole(name: str, value: object, bound: Bound, refuse: Refusal = SettingsError) -> int:
    """``value`` as an int if it is a whole number (of any integer type, not a boolean and not a
    float) within ``bound``; else ``refuse(name, value, reason)`` is raised."""
    check(name, value, bound if bound.whole else replace(bound, whole=True), refuse)
    assert isinstance(value, numbers.Integral)
    return int(value)
