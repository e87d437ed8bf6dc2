"""The pytest plugin: a user's bench tests in plain pytest, over fake://, into a run record."""

from __future__ import annotations

import importlib.metadata
import json
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

# Imported here, not first by an inner session: pytester drops the modules an inner session
# imported, and numpy (which the driver imports) cannot be imported twice in one process.
from armbench.record import load_record

pytest_plugins = ["pytester"]


#: Plugins of this test environment that ``armbench[pytest]`` does not bring, kept out of the
#: users' sessions: labgrid's (the labgrid extra), as a user without a lab would; Hypothesis's
#: (the test extra) and anyio's (here through httpx), which import their packages (and trio)
#: at every session's start, most of a short session's CPU.
NOT_A_USERS = ["-p", "no:labgrid", "-p", "no:hypothesispytest", "-p", "no:anyio"]


def plugin() -> list[str]:
    """``-p armbench.cli.plugin.pytest_plugin`` unless the installed ``pytest11`` entry point loads
    it already (registering the module twice under two names is an error); and
    :data:`NOT_A_USERS` kept out of the users' sessions. The sessions run in processes of their
    own, as a user's do (in-process, pytester would drop what a session imported, and numpy
    cannot be imported twice in one process)."""
    installed = any(ep.value == "armbench.cli.plugin.pytest_plugin"
                    for ep in importlib.metadata.entry_points(group="pytest11"))
    ours = [] if installed else ["-p", "armbench.cli.plugin.pytest_plugin"]
    return [*NOT_A_USERS, *ours]

USER_TESTS = '''
import asyncio

import pytest

from armbench.fakes.clock.vclock import VirtualTimeLoop


async def test_joint1_reaches_its_target(arm, record_measurement, bench_record):
    loop = asyncio.get_running_loop()
    assert isinstance(loop, VirtualTimeLoop)       # fake:// runs on virtual time
    t0 = loop.time()
    state = await arm.move_joints([0.4, 0.0, 0.0, 0.0], 90)
    bench_record.sample(t_s=loop.time() - t0, q_rad=list(state.q_rad))
    record_measurement("lab.j1.error_mrad", abs(state.q_rad[0] - 0.4) * 1000, "mrad",
                       limit=(None, 1.0))
    record_measurement("lab.j1.move_s", loop.time() - t0, "s", limit={"high": 60.0})
    truth = arm.ground_truth()
    assert truth is not None and abs(truth.true_rad[0] - 0.4) < 3e-3  # gear play ≈ 2 mrad


async def test_too_strict_a_limit_fails(arm, record_measurement):
    state = await arm.move_joints([0.2, 0.0, 0.0, 0.0], 90)
    record_measurement("lab.j1.error_mrad2", abs(state.q_rad[0] - 0.2) * 1000 + 5.0, "mrad",
                       limit=(None, 1.0))
    record_measurement("lab.kept_after_failure", 1.0, "")


async def test_assertion_failure_is_a_done_trial(arm):
    assert arm.state.q_rad[0] == 123.0


async def test_driver_error_is_an_error_trial(arm):
    from armbench.drivers.model.errors import PortLostError

    raise PortLostError(arm.port, "cable pulled (test)")


def test_not_a_bench_test():
    assert True


@pytest.mark.skip(reason="not today")
async def test_skipped(arm):
    pass


async def test_plain_async_test_keeps_the_default_loop():
    assert not isinstance(asyncio.get_running_loop(), VirtualTimeLoop)
'''


@pytest.fixture
def user_tests(pytester: pytest.Pytester) -> pytest.Pytester:
    pytester.makeini("[pytest]\nasyncio_mode = auto\n"
                     "asyncio_default_fixture_loop_scope = function\n")
    pytester.makepyfile(test_bench=USER_TESTS)
    return pytester


def test_user_bench_tests_land_in_the_record(user_tests: pytest.Pytester) -> None:
    out = user_tests.path / "record"
    result = user_tests.runpytest_subprocess(*plugin(), "--arm-port", "fake://?profile=ideal",
                                  "--arm-record", str(out))
    result.assert_outcomes(passed=3, failed=3, skipped=1)
    result.stdout.fnmatch_lines(["*lab.j1.error_mrad2 = * mrad (limit <= 1 mrad)*"])

    record = load_record(out / "results.json")
    assert record.planned_suites == ["pytest"]
    suite = record.suites["pytest"]
    assert suite.status == "done"
    by_test = {t.params["test"].split("::")[-1]: t for t in suite.trials}
    # Only the tests that touched the bench are trials, in execution order.
    assert list(by_test) == ["test_joint1_reaches_its_target", "test_too_strict_a_limit_fails",
                             "test_assertion_failure_is_a_done_trial",
                             "test_driver_error_is_an_error_trial"]
    assert [t.index for t in suite.trials] == [0, 1, 2, 3]

    ok = by_test["test_joint1_reaches_its_target"]
    assert ok.status == "done" and len(ok.samples) == 1
    m = {x.name: x for x in ok.measurements}
    assert m["lab.j1.error_mrad"].outcome == "pass"
    assert m["lab.j1.error_mrad"].limit is not None and m["lab.j1.error_mrad"].limit.high == 1.0
    assert m["lab.j1.move_s"].value > 0.5  # simulated seconds of a real move
    assert m["pytest.passed"].value == 1.0

    strict = {x.name: x for x in by_test["test_too_strict_a_limit_fails"].measurements}
    assert strict["lab.j1.error_mrad2"].outcome == "fail"
    assert "lab.kept_after_failure" in strict
    assert strict["pytest.passed"].value == 1.0  # the body passed; the limit failed the test

    asserted = by_test["test_assertion_failure_is_a_done_trial"]
    assert asserted.status == "done"
    assert {x.name: x.outcome for x in asserted.measurements} == {"pytest.passed": "fail"}

    errored = by_test["test_driver_error_is_an_error_trial"]
    assert errored.status == "error" and "PortLostError" in (errored.error or "")

    # Suite level: each metric once, judged against the same limit.
    summary = {x.name: x for x in suite.measurements}
    assert summary["lab.j1.error_mrad"].outcome == "pass"
    assert summary["lab.j1.error_mrad2"].outcome == "fail"
    assert record.verdict == "error"  # the errored trial

    # JUnit and report beside it; one capture per bench test.
    ET.parse(out / "junit.xml")
    assert (out / "report.html").exists()
    captures = sorted(p.name for p in (out / "captures").iterdir())
    assert captures[0].startswith("0000-test_joint1_reaches_its_target")
    first = json.loads((out / "captures" / captures[0]).read_text().splitlines()[0])
    assert first["dir"] in ("in", "out")


DOC_EXAMPLE = '''
async def test_joint1_reaches_its_target(arm, record_measurement):
    state = await arm.move_joints([0.5, 0.0, 0.0, 0.0], 80)
    record_measurement("lab.j1.error_mrad", abs(state.q_rad[0] - 0.5) * 1000, "mrad",
                       limit=(None, 5.0))


async def test_second(arm):
    assert arm.state is not None
'''


def test_the_documented_example_passes_in_strict_mode(pytester: pytest.Pytester) -> None:
    """No asyncio_mode in the project (pytest-asyncio's default, strict): the plugin marks the
    async tests that take ``arm`` itself (they once failed as 'not natively supported')."""
    pytester.makeini("[pytest]\n")
    pytester.makepyfile(test_my_bench=DOC_EXAMPLE)
    result = pytester.runpytest_subprocess(*plugin(), "--arm-port", "fake://")
    result.assert_outcomes(passed=2)
    assert "not natively supported" not in result.stdout.str()


def test_arm_record_mode_replace_and_resume(pytester: pytest.Pytester) -> None:
    pytester.makeini("[pytest]\n")
    pytester.makepyfile(test_my_bench=DOC_EXAMPLE)
    out = pytester.path / "rec"
    pytester.runpytest_subprocess(*plugin(), "--arm-record", str(out)).assert_outcomes(passed=2)
    again = pytester.runpytest_subprocess(*plugin(), "--arm-record", str(out))
    assert again.ret == pytest.ExitCode.USAGE_ERROR
    assert "already holds a run record" in again.stderr.str()
    resumed = pytester.runpytest_subprocess(*plugin(), "--arm-record", str(out),
                                            "--arm-record-mode", "resume")
    resumed.assert_outcomes(passed=2)
    record = load_record(out / "results.json")
    suite = record.suites["pytest"]
    assert [t.index for t in suite.trials] == [0, 1, 2, 3] and suite.status == "done"
    assert len(record.resumed) == 1 and suite.measurements
    replaced = pytester.runpytest_subprocess(*plugin(), "--arm-record", str(out),
                                             "--arm-record-mode", "replace")
    replaced.assert_outcomes(passed=2)
    record = load_record(out / "results.json")
    assert [t.index for t in record.suites["pytest"].trials] == [0, 1] and not record.resumed


def test_a_port_that_cannot_be_an_arm_is_a_usage_error(pytester: pytest.Pytester) -> None:
    """Checked as ``armbench run`` checks it, before a test runs or a record is made."""
    pytester.makeini("[pytest]\n")
    pytester.makepyfile(test_my_bench=DOC_EXAMPLE)
    fifo = pytester.path / "a-fifo"
    os.mkfifo(fifo)
    out = pytester.path / "rec"
    result = pytester.runpytest_subprocess(*plugin(), "--arm-port", str(fifo), "--arm-record",
                                           str(out))
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    result.stderr.fnmatch_lines(["*a-fifo: is a FIFO, not a serial device*"])
    assert not out.exists()


def test_without_a_record_measurements_still_fail_tests(user_tests: pytest.Pytester) -> None:
    result = user_tests.runpytest_subprocess(*plugin(), "--arm-port", "fake://?profile=ideal",
                                             "-k", "strict or target")
    result.assert_outcomes(passed=1, failed=1)
    assert not (user_tests.path / "results.json").exists()


def test_limits_file_judges_measurements_without_inline_limits(
        pytester: pytest.Pytester) -> None:
    pytester.makeini("[pytest]\nasyncio_mode = auto\n"
                     "asyncio_default_fixture_loop_scope = function\n")
    pytester.makefile(".toml", lab='spec_version = "armbench-limits/1"\n'
                                   '[limits."lab.*_mm"]\nhigh = 2.0\nunit = "mm"\n')
    pytester.makepyfile(test_lab='''
def test_small(record_measurement):
    assert record_measurement("lab.a_mm", 1.5, "mm").outcome == "pass"

def test_large(record_measurement):
    record_measurement("lab.b_mm", 2.5, "mm")

def test_unit_mismatch(record_measurement):
    import pytest
    from armbench.record.limits import Limit
    from armbench.record import RecordError
    with pytest.raises(RecordError, match="unit"):
        record_measurement("lab.c", 1.0, "mm", limit=Limit("lab.c", "s", high=1.0))
    with pytest.raises(RecordError, match="twice"):
        record_measurement("lab.a_mm", 1.0, "mm")
        record_measurement("lab.a_mm", 1.0, "mm")
''')
    out = pytester.path / "rec"
    result = pytester.runpytest_subprocess(*plugin(), "--arm-config", "lab.toml",
                                "--arm-record", str(out))
    result.assert_outcomes(passed=2, failed=1)
    record = load_record(out / "results.json")
    assert record.environment.limits_spec_version == "armbench-limits/1"
    outcomes = {m.name: m.outcome for m in record.suites["pytest"].measurements}
    assert outcomes["lab.a_mm"] == "pass" and outcomes["lab.b_mm"] == "fail"
    assert record.verdict == "fail"
    # A second session into the same directory is refused, not overwritten.
    again = pytester.runpytest_subprocess(*plugin(), "--arm-record", str(out))
    assert again.ret == pytest.ExitCode.USAGE_ERROR
    again.stderr.fnmatch_lines(["*already holds a run record*"])


def test_record_measurement_refuses_bad_limits(tmp_path: Path) -> None:
    from armbench.cli.plugin.pytest_bench import BenchTrial
    from armbench.record import RecordError

    trial = BenchTrial(index=0, nodeid="t", test_name="t", limits=None, started_s=0.0)
    for bad in ((3.0, 1.0), {"hi": 1.0}, (None, None), 5.0, (None, float("nan"))):
        with pytest.raises(RecordError):
            trial.measure("x", 1.0, "mm", limit=bad)  # type: ignore[arg-type]
    with pytest.raises(RecordError, match="finite"):
        trial.measure("y", float("inf"), "mm")
    assert trial.measure("z", 1.0, "mm").outcome == "unjudged"


TOY_TESTS = '''
import asyncio

from armbench.fakes.clock.vclock import VirtualTimeLoop
from toy_target import ToyTransport


async def test_a_fresh_toy_arm_on_virtual_time(arm):
    assert isinstance(asyncio.get_running_loop(), VirtualTimeLoop)
    assert ToyTransport.fresh_arms == 1
    assert arm.ground_truth() is not None


async def test_another_fresh_toy_arm(arm):
    assert ToyTransport.fresh_arms == 2
'''


def test_a_simulator_registered_by_entry_point_serves_the_arm_fixture(
        pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch) -> None:
    """The plugin asks the port's target: a third-party simulator (``tests/toy_target.py``,
    registered by an entry point of an installed distribution) declaring the virtual clock and
    fresh arms gets a fresh arm per test on virtual time."""
    info = pytester.path / "toy_target-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-target\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(
        "[armbench.transports]\ntoy = toy_target:ToyTransport\n")
    (pytester.path / "toy_target.py").write_text(
        (Path(__file__).parent / "toy_target.py").read_text())
    monkeypatch.setenv("PYTHONPATH", str(pytester.path))
    pytester.makeini("[pytest]\nasyncio_mode = auto\n")
    pytester.makepyfile(test_toy=TOY_TESTS)
    result = pytester.runpytest_subprocess(*plugin(), "-p", "no:randomly", "--arm-port",
                                           "toy://?caps=virtual,fresh,truth")
    result.assert_outcomes(passed=2)
