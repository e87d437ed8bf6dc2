"""Registration by entry point: how armbench finds its parts and those of other distributions.

Every part armbench looks up by name is registered once, as an entry point in a distribution's
``pyproject.toml``: a transport by its URL scheme, a suite's class, its contract and its report
section by the suite's name. armbench declares its own parts there exactly as a plug-in does, so
there is one way in and no list in code. Entry points are read from the installed
distributions' metadata (a wheel and an editable install both carry them; a checkout whose
entry points changed is installed again), and nothing is imported until a name is loaded.

A name that two distributions register with different values is ambiguous: loading it is an
:class:`EntryPointError` naming both, never a silent pick. Every failure to load (the module does
not import, the attribute is missing or is not what the group holds) is an
:class:`EntryPointError` naming the entry point (``group: name = module:attr``).
"""

from __future__ import annotations

import functools
import importlib.metadata
import sys
from collections.abc import Callable
from typing import TypeGuard, TypeVar

from armbench.drivers.model.errors import ArmbenchError

__all__ = ["EntryPointError", "load", "registered"]

_T = TypeVar("_T")


class EntryPointError(ArmbenchError):
    """An entry point that cannot be used: ambiguous, failing to import, or not what its group
    holds. Names the group, the entry point's name and its value (none for an ambiguous name,
    whose values the reason lists)."""

    def __init__(self, group: str, name: str, value: str, reason: str) -> None:
        named = f"{name} = {value}" if value else name
        super().__init__(f"entry point {group}: {named}: {reason}")
        self.group = group
        self.name = name
        self.value = value
        self.reason = reason


@functools.lru_cache(maxsize=8)
def _read_all(path: tuple[str, ...]) -> tuple[importlib.metadata.EntryPoint, ...]:
    """Every entry point found along ``path`` (``sys.path``, the key of the cache: a
    distribution put on the path is found at the next look-up), every group's: the
    distributions' metadata is read once, not once per group."""
    found = importlib.metadata.entry_points()
    return tuple(ep for group in sorted(found.groups) for ep in found.select(group=group))


def _read(group: str, path: tuple[str, ...]) -> tuple[importlib.metadata.EntryPoint, ...]:
    """The entry points of ``group`` found along ``path``, in the order the metadata has them."""
    return tuple(ep for ep in _read_all(path) if ep.group == group)


def _all(group: str, fold_case: bool) -> dict[str, list[importlib.metadata.EntryPoint]]:
    found: dict[str, list[importlib.metadata.EntryPoint]] = {}
    for ep in _read(group, tuple(sys.path)):
        key = ep.name.lower() if fold_case else ep.name
        same = found.setdefault(key, [])
        if all(ep.value != other.value for other in same):
            same.append(ep)
    return found


def registered(group: str, *, fold_case: bool = False) -> dict[str, importlib.metadata.EntryPoint]:
    """The entry points of ``group`` by name (lower case with ``fold_case``), without importing
    anything; for a name registered twice, the first found (loading it is an error)."""
    return {name: eps[0] for name, eps in _all(group, fold_case).items()}


def load(group: str, name: str, accept: Callable[[object], TypeGuard[_T]], kind: str, *,
         fold_case: bool = False) -> _T:
    """The object the entry point ``name`` of ``group`` names, imported now, if ``accept`` takes
    it (``kind`` says what it must be, for the error). :class:`LookupError` when nothing
    registers ``name``; :class:`EntryPointError` naming the entry point when two distributions
    register it differently, its module does not import, or the object is no ``kind``."""
    eps = _all(group, fold_case).get(name.lower() if fold_case else name)
    if not eps:
        raise LookupError(f"nothing registers {name!r} as an entry point of {group}")
    first = eps[0]
    if len(eps) > 1:
        raise EntryPointError(group, first.name, "", "registered differently by several "
                              "distributions: " + ", ".join(sorted(map(_origin, eps))))
    try:
        found = first.load()
    except Exception as exc:  # whatever the module raises: the entry point is named
        raise EntryPointError(group, first.name, first.value,
                              f"{type(exc).__name__}: {exc}") from exc
    if not accept(found):
        raise EntryPointError(group, first.name, first.value, f"{found!r} is not {kind}")
    return found


def _origin(ep: importlib.metadata.EntryPoint) -> str:
    """``value (distribution)`` of an entry point, for a message."""
    dist = ep.dist.name if ep.dist is not None else "unknown distribution"
    return f"{ep.value} ({dist})"
