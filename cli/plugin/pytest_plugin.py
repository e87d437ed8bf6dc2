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

A measurement outside its limit fails the test (after the test body has run, so every measurement
is kept). See ``docs/runner.md`` for the record's shape and the loop details.

A good guest in other projects' test runs: this module imports nothing but pytest. It adds the
options, and loads the fixtures and hooks (:mod:`armbench.cli.plugin.pytest_bench`) only when
pytest-asyncio (the ``armbench[pytest]`` extra, not a dependency) is installed; without it, a test
that asks for ``arm`` fails with a message saying what to install, and every other test runs as
before.
"""

from __future__ import annotations

import importlib
import importlib.util

import pytest

__all__ = ["CONFIG_OPTION", "FIXTURES_PLUGIN", "PORT_OPTION", "RECORD_MODE_OPTION",
           "RECORD_OPTION", "SETTINGS_OPTION", "pytest_addoption", "pytest_configure"]

#: The module holding the fixtures and hooks, registered under this name.
FIXTURES_PLUGIN = "armbench.cli.plugin.pytest_bench"
#: The options this plugin adds; the fixtures read them by these names (one spelling for both).
PORT_OPTION = "--arm-port"
SETTINGS_OPTION = "--arm-settings"
CONFIG_OPTION = "--arm-config"
RECORD_OPTION = "--arm-record"
RECORD_MODE_OPTION = "--arm-record-mode"


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


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "arm: a bench test using the armbench 'arm' fixture")
    manager = config.pluginmanager
    if manager.has_plugin(FIXTURES_PLUGIN):
        return
    if importlib.util.find_spec("pytest_asyncio") is None:
        manager.register(_WithoutAsyncio(), FIXTURES_PLUGIN)
        return
    module = importlib.import_module(FIXTURES_PLUGIN)
    manager.register(module, FIXTURES_PLUGIN)
    module.configure(config)


class _WithoutAsyncio:
    """Stands in for the fixtures when pytest-asyncio is missing: only ``arm`` users notice."""

    @pytest.fixture
    def arm(self) -> None:
        pytest.fail("the armbench 'arm' fixture needs pytest-asyncio: "
                    "pip install 'armbench[pytest]' (or pytest-asyncio>=1.4)", pytrace=False)
