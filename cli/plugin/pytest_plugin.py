"""pytest plugin: write bench tests in plain pytest against the arm and get them into a run record.

Registered as the ``armbench`` entry point of group ``pytest11`` (active once armbench is
installed); without installing, ``pytest -p armbench.cli.plugin.pytest_plugin``. Options:

``--arm-port PORT``      the arm (default ``fake://``: a fresh emulator per test, on virtual time)
``--arm-settings FILE``  robot settings TOML (``[emulator]`` too)
``--arm-config FILE``    limits file judging the measurements (``bench.toml``); optional
``--arm-record DIR``     write ``results.json`` (one suite ``pytest``, one trial per test),
                         ``junit.xml`` and ``report.html`` to DIR
``--arm-record-mode M``  ``new`` (default: refuse a DIR that holds a record), ``replace`` (start
                         a new record there) or ``resume`` (add this session's tests to it)
``--arm-scope S``        how long one ``arm`` lives: ``function`` (default; a new connection per
                         test), ``module`` or ``session`` (one connection, held between tests);
                         ini ``armbench_arm_scope``
``--arm-mismatch M``     a test whose markers do not fit the port's target: ``skip`` (default,
                         with the reason) or ``deselect``

Markers: ``@pytest.mark.armbench_target("fake", ...)`` (the port's scheme must be one of these;
``serial`` for a device name), ``@pytest.mark.hardware`` (no emulator behind the port),
``@pytest.mark.emulator`` (an emulator the bench drives: ``fake://``, ``avr://``).

Fixtures:

- ``arm`` — a connected :class:`armbench.drivers.host.arm.Arm` (async fixture; the test must be
  ``async def``; the plugin marks such a test ``asyncio`` itself, so it runs in pytest-asyncio's
  strict mode, the default, as in ``auto``). On ``fake://`` the test and the fixture run on a
  virtual-time loop (pytest-asyncio ≥ 1.4's ``pytest_asyncio_loop_factories`` hook), so minutes
  of robot time take milliseconds.
- ``bench_record`` — this test's trial: ``measure(name, value, unit, limit=...)``,
  ``sample(**fields)``, ``params``.
- ``record_measurement(name, value, unit, *, limit=None, better=None, description="")`` — the
  same ``measure``, as a function.
- ``truth`` — the arm's true pose (``true_position_m()``, ``true_joints_rad()``) where the target
  has ground truth (an emulator); the test is skipped, with the reason, where it has none.

A measurement outside its limit fails the test (after the test body has run, so every measurement
is kept). See ``docs/runner.md`` for the record's shape and the loop details.

A good guest in other projects' test runs: this module imports nothing but pytest. It adds the
options, and loads the fixtures and hooks (:mod:`armbench.cli.plugin.pytest_bench`, the record;
:mod:`armbench.cli.plugin.pytest_arm`, the arm, its loop and the markers) only when
pytest-asyncio (the ``armbench[pytest]`` extra, not a dependency) is installed; without it, a test
that asks for ``arm`` fails with a message saying what to install, and every other test runs as
before.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import warnings
from typing import Literal

import pytest

__all__ = ["ARM_PLUGIN", "ARM_SCOPES", "CONFIG_OPTION", "FIXTURES_PLUGIN", "MISMATCH_OPTION",
           "PORT_OPTION", "RECORD_MODE_OPTION", "RECORD_OPTION", "SCOPE_INI", "SCOPE_OPTION",
           "SETTINGS_OPTION", "ArmScope", "arm_scope", "pytest_addoption", "pytest_configure"]

#: The modules holding the fixtures and hooks (the record's; the arm's), registered by name.
FIXTURES_PLUGIN = "armbench.cli.plugin.pytest_bench"
ARM_PLUGIN = "armbench.cli.plugin.pytest_arm"
#: The options this plugin adds; the fixtures read them by these names (one spelling for both).
PORT_OPTION = "--arm-port"
SETTINGS_OPTION = "--arm-settings"
CONFIG_OPTION = "--arm-config"
RECORD_OPTION = "--arm-record"
RECORD_MODE_OPTION = "--arm-record-mode"
SCOPE_OPTION = "--arm-scope"
SCOPE_INI = "armbench_arm_scope"
MISMATCH_OPTION = "--arm-mismatch"
#: How long one ``arm`` lives.
ArmScope = Literal["session", "module", "function"]
#: The scopes, longest first.
ARM_SCOPES: tuple[ArmScope, ...] = ("session", "module", "function")
#: pytest-asyncio's reminder when a project sets no loop scope for its async fixtures.
_UNSET_SCOPE_WARNING = r'The configuration option "asyncio_default_fixture_loop_scope" is unset'


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("armbench", "armbench bench tests")
    group.addoption(PORT_OPTION, default="fake://", metavar="PORT",
                    help="the arm's port for the 'arm' fixture (default fake://: a fresh "
                         "emulator per test on virtual time)")
    group.addoption(SETTINGS_OPTION, default=None, metavar="FILE",
                    help="robot settings TOML for the 'arm' fixture")
    group.addoption(CONFIG_OPTION, default=None, metavar="FILE",
                    help="limits file (bench.toml) judging record_measurement values")
    group.addoption(RECORD_OPTION, default=None, metavar="DIR",
                    help="write the bench tests' run record (results.json, junit.xml, "
                         "report.html) to DIR")
    group.addoption(RECORD_MODE_OPTION, default="new", choices=("new", "replace", "resume"),
                    help="when DIR holds a record: new (default) refuses it, replace starts a "
                         "new record there, resume adds this session's tests to it")
    group.addoption(SCOPE_OPTION, default=None, choices=ARM_SCOPES,
                    help="how long one 'arm' lives: function (default: a connection per test), "
                         "module or session (one connection, the arm held still between "
                         f"tests); over the ini option {SCOPE_INI}")
    group.addoption(MISMATCH_OPTION, default="skip", choices=("skip", "deselect"),
                    help="a test whose armbench_target/hardware/emulator markers do not fit "
                         "the port: skip it with the reason (default) or deselect it")
    parser.addini(SCOPE_INI, "how long one 'arm' lives: function, module or session",
                  default="function")


def arm_scope(config: pytest.Config) -> ArmScope:
    """The ``arm`` fixture's scope: ``--arm-scope``, else the ini option, else ``function``."""
    given = str(config.getoption(SCOPE_OPTION) or config.getini(SCOPE_INI) or "function")
    for scope in ARM_SCOPES:
        if given == scope:
            return scope
    raise pytest.UsageError(f"{SCOPE_INI} = {given!r}: must be one of {', '.join(ARM_SCOPES)}")


@pytest.hookimpl(tryfirst=True)
def pytest_configure(config: pytest.Config) -> None:
    for line in ("arm: a bench test using the armbench 'arm' fixture",
                 "armbench_target(*schemes): runs only where the arm's port has one of these "
                 "schemes (fake, avr, socket, rfc2217, labgrid, serial for a device name)",
                 "hardware: runs only on an arm with no emulator behind its port",
                 "emulator: runs only on an emulated arm (fake://, avr://)"):
        config.addinivalue_line("markers", line)
    manager = config.pluginmanager
    if manager.has_plugin(FIXTURES_PLUGIN):
        return
    if importlib.util.find_spec("pytest_asyncio") is None:
        manager.register(_WithoutAsyncio(), FIXTURES_PLUGIN)
        return
    arm_scope(config)  # a bad ini value is a usage error now
    _quiet_unset_loop_scope(config)
    for name in (FIXTURES_PLUGIN, ARM_PLUGIN):
        module = importlib.import_module(name)
        manager.register(module, name)
        module.configure(config)


def _quiet_unset_loop_scope(config: pytest.Config) -> None:
    """The armbench fixtures set their loop scopes themselves: a project that sets no
    ``asyncio_default_fixture_loop_scope`` keeps pytest-asyncio's behaviour without its
    deprecation reminder on every run ("nothing else to set up"). Runs before pytest-asyncio's
    ``pytest_configure`` (``tryfirst``); the filter is dropped when the session ends."""
    try:
        if config.getini("asyncio_default_fixture_loop_scope"):
            return
    except ValueError:  # pytest-asyncio registers no such option
        return
    warnings.filterwarnings("ignore", message=_UNSET_SCOPE_WARNING,
                            category=pytest.PytestDeprecationWarning)
    added = warnings.filters[0]

    def drop() -> None:
        filters: list[object] = warnings.filters  # type: ignore[assignment]  # a list at run time
        with contextlib.suppress(ValueError):
            filters.remove(added)

    config.add_cleanup(drop)


class _WithoutAsyncio:
    """Stands in for the fixtures when pytest-asyncio is missing: only ``arm`` users notice."""

    @pytest.fixture
    def arm(self) -> None:
        pytest.fail("the armbench 'arm' fixture needs pytest-asyncio: "
                    "pip install 'armbench[pytest]' (or pytest-asyncio>=1.4)", pytrace=False)

    @pytest.fixture
    def truth(self) -> None:
        pytest.fail("the armbench 'truth' fixture needs pytest-asyncio: "
                    "pip install 'armbench[pytest]' (or pytest-asyncio>=1.4)", pytrace=False)
