"""What every suite and its report section agree on, and where each suite's contract is found.

A suite's contract names what the suite records and the report reads: the suite's name, its
metric names, its trial and suite parameters, the keys of its samples and events, and the
headline figures the report leads with. Each contract is defined with its suite, in a light
module of plain data (no numpy, no driver) that the suite and its report section both import.
This module holds what every contract shares
(:class:`Headline`, :class:`SampleKeys`, the samples' rounding) and the registry: record readers
(the record, the metrics, the report) find a contract by its suite's name with :func:`contract`,
never by importing a suite.

The registry is filled on first use from the entry points of the group :data:`ENTRY_POINT_GROUP`
(``<suite> = "package.module:CONTRACT"``), armbench's own suites' as another distribution's
(:mod:`armbench.drivers.model.entry_points`): only those light modules are imported, never the
suites themselves.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Final, Protocol, TypeGuard, TypeVar, runtime_checkable

from armbench.drivers.model import entry_points

__all__ = [
    "ENTRY_POINT_GROUP",
    "LIFE_WARN_YEARS",
    "POS_DECIMALS",
    "RAD_DECIMALS",
    "SAMPLE",
    "Headline",
    "SampleKeys",
    "SuiteContract",
    "UnknownContractError",
    "contract",
    "contracts",
    "forget",
    "lacks",
    "records_truth",
    "register",
    "resolution",
]

#: Decimal places of positions in samples (m): 0.1 µm, far below any error the bench reports.
POS_DECIMALS: Final = 7
#: Decimal places of joint angles in samples (rad): 1 µrad (the wire resolution is 100 µrad).
RAD_DECIMALS: Final = 6

#: A projected lifetime (unit ``years``) below this is flagged in the report (a bench arm is
#: kept for years).
LIFE_WARN_YEARS: Final = 5.0

#: The smallest step a figure in this unit can resolve, given the samples' rounding: a figure
#: (a spread, a bias) below it is zero as far as the measurement can tell.
_RESOLUTION: Final[dict[str, float]] = {
    "m": 10.0 ** -POS_DECIMALS,
    "mm": 10.0 ** -(POS_DECIMALS - 3),
    "rad": 10.0 ** -RAD_DECIMALS,
    "mrad": 10.0 ** -(RAD_DECIMALS - 3),
    "s": 1e-6,
}


def resolution(unit: str) -> float | None:
    """The resolution of a figure in ``unit`` (None for a unit with no known resolution)."""
    return _RESOLUTION.get(unit)


@dataclass(frozen=True, slots=True)
class Headline:
    """A headline figure of a suite: the metric's name (or, with ``worst_of``, the ``fnmatch``
    pattern of the metrics whose worst value is shown), a label for people, whether higher is
    worse, the key of the paper's reference figure in the record's ``reference`` table where
    the paper has one, and why the figure has no limit where it is meant to have none."""

    label: str
    metric: str
    worst_of: bool = False
    higher_is_worse: bool = True
    paper: str | None = None
    no_limit: str | None = None


@dataclass(frozen=True, slots=True)
class SampleKeys:
    """Keys of the samples every suite records (see ``bench/suites/_common.py``)."""

    t: str = "t_s"
    q: str = "q_rad"
    reported: str = "reported_m"
    true: str = "true_m"
    commanded: str = "commanded_m"
    kind: str = "kind"
    pose: str = "pose"
    direction: str = "direction"
    event: str = "event"


SAMPLE: Final = SampleKeys()


@runtime_checkable
class SuiteContract(Protocol):
    """What every suite's contract says: the suite's name, its place in the default run and in
    the report (``order``: lower first), whether it records true figures beside the encoders',
    and the headline figures the report leads with. What runs the suite is registered beside it
    (the entry points of ``armbench.suites``), not named here: this layer imports no suite."""

    @property
    def suite(self) -> str: ...

    @property
    def order(self) -> int: ...

    @property
    def has_true_figures(self) -> bool: ...

    @property
    def headlines(self) -> tuple[Headline, ...]: ...


#: Entry-point group of every suite's contract, by the suite's name: ``<suite> =
#: "package.module:CONTRACT"`` (the module is imported, the object registered).
ENTRY_POINT_GROUP: Final = "armbench.suite_contracts"

_CONTRACTS: dict[str, SuiteContract] = {}
_discovery = {"done": False}
_C = TypeVar("_C")


class UnknownContractError(LookupError):
    """No registered contract for a suite name (or not one of the shape the reader needs)."""


def register(contract: _C) -> _C:
    """Add a suite's contract to the registry (the discovery's, or a test's suite in this
    process); a second contract of the same suite name is a bug."""
    if not isinstance(contract, SuiteContract):
        raise TypeError(f"{contract!r} is not a suite contract (suite, order, has_true_figures, "
                        "headlines)")
    if contract.suite in _CONTRACTS:
        raise ValueError(f"two contracts of suite {contract.suite!r}")
    _CONTRACTS[contract.suite] = contract
    return contract


def _is_contract(found: object) -> TypeGuard[SuiteContract]:
    return isinstance(found, SuiteContract)


def _discover() -> None:
    """Load every contract's entry point once. A contract that cannot be loaded, or that is
    registered under another suite's name, is left out with a warning naming its entry point
    (its suite is then shown as any unknown suite), so one broken plug-in does not stop a
    record from being read."""
    if _discovery["done"]:
        return
    _discovery["done"] = True
    for name, ep in entry_points.registered(ENTRY_POINT_GROUP).items():
        try:
            found = entry_points.load(ENTRY_POINT_GROUP, name, _is_contract, "a suite contract "
                                      "(suite, order, has_true_figures, headlines)")
            if found.suite != name:
                raise entry_points.EntryPointError(ENTRY_POINT_GROUP, name, ep.value,
                                                   f"its contract is of suite {found.suite!r}")
            if _CONTRACTS.get(name) is not found:
                register(found)
        except (entry_points.EntryPointError, ValueError) as exc:  # reported, not fatal
            warnings.warn(str(exc), RuntimeWarning, stacklevel=2)


def forget(suite: str) -> None:
    """Remove a suite's contract and discover again on next use (a test's suite, unregistered)."""
    _CONTRACTS.pop(suite, None)
    _discovery["done"] = False


def contracts() -> tuple[SuiteContract, ...]:
    """Every suite's contract, by ``order`` (then by name): the default run's and the report's
    order of suites."""
    _discover()
    return tuple(sorted(_CONTRACTS.values(), key=lambda c: (c.order, c.suite)))


def contract(suite: str) -> SuiteContract:
    """The registered contract of ``suite``; :class:`UnknownContractError` when there is none. A
    reader that needs more names checks them with ``isinstance`` against a ``runtime_checkable``
    protocol of those names and fails with the suite's name (:func:`lacks`)."""
    _discover()
    found = _CONTRACTS.get(suite)
    if found is None:
        raise UnknownContractError(f"no contract of suite {suite!r} (known: "
                                   f"{', '.join(c.suite for c in contracts())})")
    return found


def records_truth(suite: str) -> bool:
    """Whether ``suite`` records a ``true_`` figure beside each reported position figure when the
    run has a reference instrument (False for a suite with no contract)."""
    try:
        return contract(suite).has_true_figures
    except UnknownContractError:
        return False


def lacks(suite: str, shape: type) -> UnknownContractError:
    """The error of a reader whose protocol ``shape`` the contract of ``suite`` does not meet."""
    return UnknownContractError(f"the contract of suite {suite!r} lacks names "
                                f"{shape.__name__} needs")
