"""The armbench pytest plugin's ``arm`` and ``truth`` fixtures, the loop they run on and the
target markers (options in :mod:`armbench.cli.plugin.pytest_plugin`, the record in
:mod:`armbench.cli.plugin.pytest_bench`).

**Scope.** ``--arm-scope`` (ini ``armbench_arm_scope``) says how long one arm lives:
``function`` opens the port for every test (an Arduino resets when its port opens: its start-up
procedure runs before each test); ``module`` and ``session`` open it once and hand the same
connection to every test, reset in between without a power cycle or a new connection: the arm is
held still where the previous test left it (:meth:`~armbench.drivers.host.arm.Arm.stop`). The
tests that take ``arm`` (or ``truth``) are marked ``asyncio`` with the arm's loop scope, so they
run on the loop the arm lives on (on ``fake://`` a virtual-time loop).

**Markers.** ``armbench_target("fake", ...)``, ``hardware`` and ``emulator`` say which targets a
test is for; a test whose markers do not fit the port's target is skipped with the reason
(``--arm-mismatch skip``, the default) or deselected (``deselect``). ``-m hardware`` and
``-m "not hardware"`` select by the markers as pytest always does.
"""

from __future__ import annotations

import asyncio
import inspect
from collections.abc import AsyncIterator, Callable, Mapping
from contextlib import asynccontextmanager
from typing import Any

import pytest
import pytest_asyncio

from armbench.cli.plugin.pytest_bench import BenchTrial, bench_session
from armbench.cli.plugin.pytest_plugin import MISMATCH_OPTION, PORT_OPTION, ArmScope, arm_scope
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.transports.base import emulated
from armbench.drivers.transports.capabilities import FreshArm
from armbench.drivers.transports.target import Target, target_of

__all__ = ["ARM_FIXTURES", "arm_fixtures", "configure", "target_mismatch", "truth"]

#: The fixtures that bring the arm into a test: such a test runs on the arm's loop.
ARM_FIXTURES = ("arm", "truth")


@asynccontextmanager
async def _connected(request: pytest.FixtureRequest, capture_name: str) -> AsyncIterator[Any]:
    """The session's arm, connected (counted in :attr:`BenchSession.arms_opened`): on a target
    that starts fresh arms (``fake://``) a new one, built from the session's settings, seed and
    faults; its traffic capture ``captures/<capture_name>.jsonl`` with ``--arm-record``."""
    from armbench.drivers.host.arm import Arm

    session = bench_session(request.config)
    transport = None
    if session.target.capabilities.fresh_per_trial:
        inputs = session.inputs
        transport = session.target.fresh(session.settings.serial, FreshArm(
            session.settings, inputs.seed if inputs.seed is not None else 0, inputs.faults))
    emulator = emulated(transport)
    connection = Arm.connect(session.port, session.settings,
                             capture=session.capture_path(capture_name), transport=transport)
    session.arms_opened += 1
    try:
        async with connection as connected:
            yield connected
    finally:
        emulator = emulated(transport) or emulator
        if emulator is not None:
            await emulator.close()


def _per_test_name(trial: BenchTrial) -> str:
    return f"{trial.index:04d}-{trial.test_name}"


def arm_fixtures(scope: ArmScope) -> object:
    """The ``arm`` fixture of ``scope`` (a plugin object holding it)."""
    if scope == "function":
        class PerTest:
            @pytest_asyncio.fixture(loop_scope="function")
            async def arm(self, request: pytest.FixtureRequest,
                          bench_record: BenchTrial) -> AsyncIterator[Any]:
                """A connected :class:`~armbench.drivers.host.arm.Arm` on ``--arm-port`` for
                this test alone, closed after it."""
                bench_session(request.config).arm_tests += 1
                async with _connected(request, _per_test_name(bench_record)) as connected:
                    yield connected

        return PerTest()

    class Shared:
        @pytest_asyncio.fixture(scope=scope, loop_scope=scope)
        async def armbench_shared_arm(self, request: pytest.FixtureRequest) -> AsyncIterator[Any]:
            """The arm every test of the scope shares, opened once."""
            where = "session" if scope == "session" else f"module-{request.node.name}"
            async with _connected(request, where) as connected:
                yield connected

        @pytest_asyncio.fixture(loop_scope=scope)
        async def arm(self, request: pytest.FixtureRequest, armbench_shared_arm: Any,
                      bench_record: BenchTrial) -> Any:
            """The shared arm, held still where the previous test left it (no new connection,
            no power cycle); a link lost in an earlier test is this test's error."""
            bench_session(request.config).arm_tests += 1
            await armbench_shared_arm.stop()
            return armbench_shared_arm

    return Shared()


@pytest.fixture
def truth(request: pytest.FixtureRequest) -> Any:
    """The arm's true pose as a :class:`~armbench.bench.suites.base.PoseSource`
    (``true_position_m()``, m; ``true_joints_rad()``): the emulator's ground truth. Where the
    target has none (a hardware arm, ``socket://``) the test is skipped, saying why, before the
    arm is opened."""
    session = bench_session(request.config)
    if not session.target.capabilities.truth:
        pytest.skip(f"no ground truth over {session.port}: the target has no emulator behind "
                    "it (a reference instrument measures the true pose of a hardware arm)")
    from armbench.bench.runner.truth import EmulatorTruth

    return EmulatorTruth(request.getfixturevalue("arm"))


# --------------------------------------------------------------------------------------------
# The loop and the markers
# --------------------------------------------------------------------------------------------


def configure(config: pytest.Config) -> None:
    """Register the ``arm`` fixture of the session's scope and, with pytest-asyncio ≥ 1.4, the
    virtual-time loops."""
    config.pluginmanager.register(arm_fixtures(arm_scope(config)), "armbench-arm-fixture")
    if config.pluginmanager.has_plugin("asyncio") and hasattr(
            config.hook, "pytest_asyncio_loop_factories"):
        config.pluginmanager.register(_VirtualLoops(), "armbench-virtual-loops")


class _VirtualLoops:
    """Runs tests that use the ``arm`` fixture on a virtual-time loop when the port's target runs
    on the virtual clock, as ``fake://`` does (pytest-asyncio ≥ 1.4). Every other async test gets
    the default loop, exactly as without this plugin. ``trylast``: a project's own implementation
    of the hook wins."""

    @pytest.hookimpl(trylast=True)
    def pytest_asyncio_loop_factories(self, config: pytest.Config,
                                      item: pytest.Item) -> Mapping[str, Callable[[], Any]]:
        names = getattr(item, "fixturenames", ())
        target = _target(config)
        if any(n in names for n in ARM_FIXTURES) and target is not None and target.virtual:
            from armbench.fakes.clock.vclock import virtual_loop_factory

            return {"virtual_time": virtual_loop_factory}
        return {"asyncio": asyncio.new_event_loop}


def _target(config: pytest.Config) -> Target | None:
    """The port's target, None for a port that names none (the ``arm`` fixture reports it)."""
    try:
        return target_of(str(config.getoption(PORT_OPTION)))
    except ArmbenchError:
        return None


@pytest.hookimpl(tryfirst=True)
def pytest_pycollect_makeitem(collector: pytest.Collector, name: str, obj: object) -> None:
    """Mark an ``async def`` test that takes ``arm`` or ``truth`` ``asyncio`` with the arm's loop
    scope, so that bench tests run on the arm's loop whatever the project's ``asyncio_mode``
    (strict by default: unmarked async tests would fail as "not natively supported"). Runs
    before pytest-asyncio turns the function into a test item; a test marked ``asyncio`` by
    its author keeps that mark."""
    if not (inspect.iscoroutinefunction(obj) and isinstance(collector, pytest.Class | pytest.Module)
            and collector.funcnamefilter(name)):
        return
    try:
        takes_arm = any(n in inspect.signature(obj).parameters for n in ARM_FIXTURES)
    except (TypeError, ValueError):
        return
    marks = getattr(obj, "pytestmark", [])
    if takes_arm and not any(getattr(m, "name", None) == "asyncio" for m in marks):
        pytest.mark.asyncio(loop_scope=arm_scope(collector.config))(obj)


def target_mismatch(item: pytest.Item, target: Target) -> str | None:
    """Why ``item``'s markers do not fit ``target``, None when they do."""
    scheme = target.scheme or "serial"
    caps = target.capabilities
    emulator = caps.truth or caps.fresh_per_trial
    for mark in item.iter_markers("armbench_target"):
        if scheme not in mark.args:
            return (f"for {', '.join(f'{s}://' for s in mark.args)} only; the arm is "
                    f"{target.port}")
    if item.get_closest_marker("hardware") is not None and emulator:
        return f"for a hardware arm only; {target.port} is an emulator"
    if item.get_closest_marker("emulator") is not None and not emulator:
        return f"for an emulated arm only; {target.port} has no emulator behind it"
    return None


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Skip (or deselect, ``--arm-mismatch deselect``) the tests whose markers do not fit the
    port's target."""
    target = _target(config)
    if target is None:
        return
    deselect = config.getoption(MISMATCH_OPTION) == "deselect"
    kept, dropped = [], []
    for item in items:
        why = target_mismatch(item, target)
        if why is None:
            kept.append(item)
        elif deselect:
            dropped.append(item)
        else:
            item.add_marker(pytest.mark.skip(reason=why))
            kept.append(item)
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        items[:] = kept


def pytest_terminal_summary(terminalreporter: Any, config: pytest.Config) -> None:
    """How often the arm was opened for the bench tests: once per test (``function``), once per
    module or once in all (``session``)."""
    session = bench_session(config, create=False)
    if session is None or not session.arms_opened:
        return
    terminalreporter.write_line(
        f"armbench: {session.port}: the arm was opened {session.arms_opened} time(s) for "
        f"{session.arm_tests} bench test(s) (arm scope {arm_scope(config)})")
