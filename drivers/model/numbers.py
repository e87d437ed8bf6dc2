"""The one check for "a finite number" that settings, records, captures and suites share.

A real number is any ``numbers.Real`` but a boolean (TOML and JSON ``true`` is not 1): Python
ints and floats, numpy scalars. It imports nothing of armbench, so the emulator, the driver and
the bench may all use it; each caller raises its own typed error with its own wording.
"""

from __future__ import annotations

import math
import numbers
from typing import TypeGuard

__all__ = ["finite_float", "is_real"]


def is_real(value: object) -> TypeGuard[numbers.Real]:
    """Whether ``value`` is a real number (booleans are not)."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def finite_float(value: object) -> float | None:
    """``value`` as a float when it is a finite real number, else None (not a number, a boolean,
    NaN, an infinity, or an integer too large for a float)."""
    if not is_real(value):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    return number if math.isfinite(number) else None
