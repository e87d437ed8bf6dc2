"""The record's vocabulary and its JSON reading helpers: the outcome and status words, the
:class:`RecordError` every record problem raises, and checked accessors whose errors name the
dotted field of ``results.json`` they read."""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator, Mapping
from typing import Any, Literal

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.numbers import finite_float, is_real

__all__ = [
    "Better",
    "Outcome",
    "RecordError",
    "RowStatus",
    "SuiteStatus",
    "TrialStatus",
    "Verdict",
]

Outcome = Literal["pass", "fail", "unjudged"]
Better = Literal["lower", "higher"]
TrialStatus = Literal["done", "error"]
SuiteStatus = Literal["running", "done", "error"]
Verdict = Literal["pass", "fail", "regression", "error", "incomplete", "untested"]
RowStatus = Literal["compared", "new", "missing"]


class RecordError(ArmbenchError, ValueError):
    """A record is invalid, of another schema, or cannot be written; ``where`` names the field
    (dotted path into ``results.json``) or file."""

    def __init__(self, where: str, reason: str) -> None:
        super().__init__(f"{where}: {reason}")
        self.where = where
        self.reason = reason


def _obj(value: object, where: str) -> Mapping[str, object]:
    if not isinstance(value, Mapping):
        raise RecordError(where, f"expected an object, got {type(value).__name__}")
    return value


def _get(data: Mapping[str, object], key: str, where: str) -> object:
    if key not in data:
        raise RecordError(f"{where}.{key}" if where else key, "missing")
    return data[key]


def _str(value: object, where: str) -> str:
    if not isinstance(value, str):
        raise RecordError(where, f"expected a string, got {value!r}")
    return value


def _opt_str(value: object, where: str) -> str | None:
    return None if value is None else _str(value, where)


def _num(value: object, where: str) -> float:
    """A finite real number as a float (numpy scalars included, booleans not)."""
    if not is_real(value):
        raise RecordError(where, f"expected a number, got {value!r}")
    number = finite_float(value)
    if number is None:
        raise RecordError(where, f"{value!r} is not finite")
    return number


def _opt_num(value: object, where: str) -> float | None:
    return None if value is None else _num(value, where)


def _int(value: object, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise RecordError(where, f"expected an integer, got {value!r}")
    return value


def _bool(value: object, where: str) -> bool:
    if not isinstance(value, bool):
        raise RecordError(where, f"expected true or false, got {value!r}")
    return value


def _list(value: object, where: str) -> list[object]:
    if not isinstance(value, list):
        raise RecordError(where, f"expected a list, got {type(value).__name__}")
    return value


def _choice(value: object, where: str, choices: Iterable[str | None]) -> Any:
    allowed = tuple(choices)
    if value not in allowed:
        raise RecordError(where, f"{value!r} is not one of {', '.join(map(repr, allowed))}")
    return value


@contextlib.contextmanager
def _located(where: str) -> Iterator[None]:
    """Prefix ``where`` to a RecordError raised by a constructor's own checks."""
    try:
        yield
    except RecordError as exc:
        if exc.where.startswith(where):
            raise
        raise RecordError(where, str(exc)) from None

