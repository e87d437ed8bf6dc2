"""The bench suites, by name: what ``armbench run SUITE ...`` runs.

Each suite is registered by three entry points under its name, armbench's own as another
distribution's (:mod:`armbench.drivers.model.entry_points`): its class in the group
:data:`ENTRY_POINT_GROUP` (``armbench.suites``), its light contract in
``armbench.suite_contracts`` (:mod:`armbench.record.suite_contract`) and its report section in
``armbench.report_sections``. A suite's module is imported only when the suite is loaded, so a
broken or slow suite module costs nothing to the others. :data:`SUITES` is the default run:
armbench's own suites that need no extra (``ros2-square`` needs ``armbench[ros2]``), in their
contracts' order; another distribution's suite runs when named. Besides a registered name,
:func:`load_suite` accepts a ``"package.module:Class"`` of any
:class:`~armbench.bench.suites.base.Suite` subclass (a lab's own suite, a test's tiny suite) when
the user names it on the command line; a run record only ever names registered suites
(:func:`registered_suites`), so resuming a folder never imports code the folder names.
"""

from __future__ import annotations

import importlib
import importlib.metadata
from typing import TYPE_CHECKING, Any, TypeGuard

from armbench.drivers.model import entry_points
from armbench.drivers.model.errors import ArmbenchError
from armbench.record.suite_contract import UnknownContractError, contract

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


#: Entry-point group of every suite's class, by the suite's name.
ENTRY_POINT_GROUP = "armbench.suites"
#: The distribution whose suites (those needing no extra) are the default run.
_OWN_DISTRIBUTION = "armbench"


def _target(ep: importlib.metadata.EntryPoint) -> str:
    """``"module:Class"`` of a suite's entry point (its extras left out)."""
    return f"{ep.module}:{ep.attr}"


def _order(name: str) -> tuple[int, str]:
    """A suite's place in the default run: its contract's ``order``, then its name; a suite
    without a contract last."""
    try:
        return contract(name).order, name
    except UnknownContractError:
        return 1 << 30, name


def _suites() -> dict[str, str]:
    """:data:`SUITES`, built on first use: suite name on the command line → ``"module:Class"``
    (imported lazily), in the default order: the entry points of :data:`ENTRY_POINT_GROUP` that
    armbench declares without an extra. The same dict on every access (a test may add to
    it)."""
    if not _built:
        _built.append(True)
        own = {name: _target(ep) for name, ep in entry_points.registered(ENTRY_POINT_GROUP).items()
               if ep.dist is not None and ep.dist.name == _OWN_DISTRIBUTION and not ep.extras}
        _SUITES.update((name, own[name]) for name in sorted(own, key=_order))
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
    :data:`ENTRY_POINT_GROUP`, and the default run's (:data:`SUITES`) over them. No suite module
    is imported."""
    found = {name: _target(ep)
             for name, ep in entry_points.registered(ENTRY_POINT_GROUP).items()}
    return {**found, **_suites()}


def is_suite_spec(name: str) -> bool:
    """True for a ``"package.module:Class"`` reference (rather than a registered name)."""
    module, sep, cls = name.partition(":")
    return bool(sep and module and cls)


def _is_suite_class(found: object) -> TypeGuard[type[Suite]]:
    from armbench.bench.suites.base import Suite

    return isinstance(found, type) and issubclass(found, Suite)


def suite_class(name: str) -> type[Suite]:
    """The Suite class of a registered name or a ``"module:Class"`` reference.

    Raises :class:`UnknownSuiteError` for an unknown name and :class:`SuiteError` when the module
    cannot be imported or the attribute is not a :class:`Suite` subclass (naming the entry point
    of a registered suite).
    """
    target = _suites().get(name)
    ep = entry_points.registered(ENTRY_POINT_GROUP).get(name)
    if ep is not None and target in (None, _target(ep)):
        try:
            return entry_points.load(ENTRY_POINT_GROUP, name, _is_suite_class, "a Suite subclass")
        except entry_points.EntryPointError as exc:
            raise SuiteError(f"suite {name!r}: {exc}") from exc
    if target is None:
        if not is_suite_spec(name):
            raise UnknownSuiteError(name)
        target = name
    module_name, _, class_name = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise SuiteError(f"suite {name!r}: module {module_name} cannot be imported: "
                         f"{exc}") from exc
    cls = getattr(module, class_name, None)
    if not _is_suite_class(cls):
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
