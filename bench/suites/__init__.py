"""The bench suites, by name: what ``armbench run SUITE ...`` runs.

Each suite is its module (or folder) here plus a light contract module ``<suite>_contract.py``
that registers what the suite records (:mod:`armbench.record.suite_contract`). :data:`SUITES`
maps each suite's command-line name to ``"module:Class"``, as its contract names it, built on
first use from the registered contracts (so importing this package to reach a contract module
discovers nothing and imports no suite); the module is imported only when the suite is loaded,
so a broken or slow suite module costs nothing to the others. Other distributions register
suites as entry points of the group :data:`ENTRY_POINT_GROUP` (``armbench.suites``), as
transports are registered. Besides a registered name, :func:`load_suite` accepts a
``"package.module:Class"`` of any :class:`~armbench.bench.suites.base.Suite` subclass (a lab's
own suite, a test's tiny suite) when the user names it on the command line; a run record only
ever names registered suites (:func:`registered_suites`), so resuming a folder never imports
code the folder names.
"""

from __future__ import annotations

import importlib
import importlib.metadata
from typing import TYPE_CHECKING, Any

from armbench.drivers.model.errors import ArmbenchError
from armbench.record.suite_contract import BUILTIN_PACKAGE, contracts

if TYPE_CHECKING:
    from armbench.bench.suites.base import (
        PoseSource,
        PowerSwitch,
        Progress,
        ReReferencing,
        Suite,
        SuiteContext,
    )

    SUITES: dict[str, str]

__all__ = [
    "ENTRY_POINT_GROUP",
    "SUITES",
    "PoseSource",
    "PowerSwitch",
    "Progress",
    "ReReferencing",
    "Suite",
    "SuiteContext",
    "SuiteError",
    "UnknownSuiteError",
    "is_suite_spec",
    "load_suite",
    "registered_suites",
    "suite_class",
    "suite_names",
]

_SUITES: dict[str, str] = {}
_built: list[bool] = []


def _suites() -> dict[str, str]:
    """:data:`SUITES`, built on first use: suite name on the command line → ``"module:Class"``
    (imported lazily), in the default order: every contract of this package that names its
    implementation (:func:`armbench.record.suite_contract.contracts`), so adding a suite edits no
    list here. The same dict on every access (a test may add to it)."""
    if not _built:
        _built.append(True)
        _SUITES.update((c.suite, c.implementation) for c in contracts()
                       if c.implementation is not None
                       and type(c).__module__.startswith(BUILTIN_PACKAGE + "."))
    return _SUITES


#: The interface's names, re-exported from :mod:`.base` when first asked for, so importing this
#: package (to reach a light ``*_contract`` module) imports nothing of the suites' interface.
_BASE_NAMES = frozenset({"PoseSource", "PowerSwitch", "Progress", "ReReferencing", "Suite",
                         "SuiteContext"})


def __getattr__(name: str) -> Any:
    if name == "SUITES":
        return _suites()
    if name in _BASE_NAMES:
        from armbench.bench.suites import base

        return getattr(base, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: Entry-point group under which distributions register suites by name.
ENTRY_POINT_GROUP = "armbench.suites"


class SuiteError(ArmbenchError, ValueError):
    """A suite cannot be loaded: its module fails to import or is not a Suite class."""


class UnknownSuiteError(SuiteError):
    """A suite name that is neither registered nor a ``module:Class``; lists the known names."""

    def __init__(self, name: str) -> None:
        known = [*suite_names(), *(n for n in registered_suites() if n not in _suites())]
        super().__init__(f"unknown suite {name!r} (known: {', '.join(known)}; or give "
                         "package.module:Class of a Suite subclass)")
        self.name = name


def suite_names() -> list[str]:
    """The registered suite names, in the default run order."""
    return list(_suites())


def registered_suites() -> dict[str, str]:
    """Every registered suite name → ``"module:Class"``: the entry points of
    :data:`ENTRY_POINT_GROUP`, the suites other distributions' contracts name
    (:data:`armbench.record.suite_contract.ENTRY_POINT_GROUP`), and the built-ins over them.
    No suite module is imported."""
    found = {ep.name: f"{ep.module}:{ep.attr}"
             for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}
    found.update((c.suite, c.implementation) for c in contracts()
                 if c.implementation is not None)
    return {**found, **_suites()}


def is_suite_spec(name: str) -> bool:
    """True for a ``"package.module:Class"`` reference (rather than a registered name)."""
    module, sep, cls = name.partition(":")
    return bool(sep and module and cls)


def suite_class(name: str) -> type[Suite]:
    """The Suite class of a registered name or a ``"module:Class"`` reference.

    Raises :class:`UnknownSuiteError` for an unknown name and :class:`SuiteError` when the module
    cannot be imported or the attribute is not a :class:`Suite` subclass.
    """
    target = _suites().get(name) or registered_suites().get(name)
    if target is None:
        if not is_suite_spec(name):
            raise UnknownSuiteError(name)
        target = name
    from armbench.bench.suites.base import Suite

    module_name, _, class_name = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise SuiteError(f"suite {name!r}: module {module_name} cannot be imported: "
                         f"{exc}") from exc
    cls = getattr(module, class_name, None)
    if not (isinstance(cls, type) and issubclass(cls, Suite)):
        raise SuiteError(f"suite {name!r}: {target} is not a Suite subclass")
    return cls


def load_suite(name: str) -> Suite:
    """A new instance of the suite ``name`` (registered name or ``"module:Class"``)."""
    cls = suite_class(name)
    try:
        suite = cls()
    except TypeError as exc:
        raise SuiteError(f"suite {name!r}: {cls.__qualname__}() cannot be created without "
                         f"arguments: {exc}") from exc
    if not suite.name:
        raise SuiteError(f"suite {name!r}: {cls.__qualname__}.name is empty")
    return suite
