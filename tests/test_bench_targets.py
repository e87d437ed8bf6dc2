"""The bench target (``drivers/transports/target.py``): what each port declares it can do, a
third-party simulator getting what it declares, and one source per setting."""

from __future__ import annotations

import asyncio
import io
import json
from collections.abc import Coroutine, Iterator
from pathlib import Path
from typing import Any, TypeVar

import pytest
from conftest import cli, one_line_error
from toy_target import ToyTransport

from armbench.bench.runner import RunOptions, run_sync
from armbench.bench.runner.plan import prepare
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import SettingsError
from armbench.drivers.transports.capabilities import Capabilities, Given
from armbench.drivers.transports.target import given_by, resolve, target_of

T = TypeVar("T")

JOINTS_CONFIG = ('spec_version = "armbench-limits/1"\n[suites.joints]\njoints = [1, 2]\n'
                 "cycles = 2\ntargets_frac = [0.3, 0.7]\n")


@pytest.mark.parametrize(("port", "expected"), [
    ("fake://", Capabilities(clock="virtual", fresh_per_trial=True, parallel=True, truth=True,
                             power=True, faults=True, i2c_bus=True)),
    ("fake://?seed=3", Capabilities(clock="virtual", fresh_per_trial=True, parallel=True,
                                    truth=True, power=True, faults=True, i2c_bus=True)),
    ("avr://", Capabilities(clock="virtual", fresh_per_trial=True, parallel=True, truth=True,
                            power=True)),
    ("avr://?control=/tmp/fifo", Capabilities(clock="real", power=True)),
    ("avr://?eeprom=/tmp/arm", Capabilities(clock="real", power=True)),
    ("/dev/ttyUSB0", Capabilities()),
    ("socket://localhost:4001", Capabilities()),
    ("rfc2217://localhost:4001", Capabilities()),
    ("labgrid://bench-3", Capabilities(power=True)),  # the place's power resource, if any
])
def test_each_built_in_target_declares_what_it_can_do(port: str, expected: Capabilities) -> None:
    assert target_of(port).capabilities == expected


def test_parallel_workers_need_fresh_arms_on_virtual_time() -> None:
    with pytest.raises(ArmbenchError, match="parallel workers need"):
        Capabilities(parallel=True)
    with pytest.raises(ArmbenchError, match="parallel workers need"):
        Capabilities(clock="virtual", parallel=True)
    with pytest.raises(ArmbenchError, match="parallel workers need"):
        Capabilities(fresh_per_trial=True, parallel=True)
    assert Capabilities(clock="virtual", fresh_per_trial=True, parallel=True).parallel


def test_unknown_scheme_is_refused_naming_the_port() -> None:
    with pytest.raises(ArmbenchError, match=r"nosuch://x.*unknown transport scheme"):
        target_of("nosuch://x")


# --- one source per setting -----------------------------------------------------------------


def test_resolve_takes_each_setting_from_the_first_source_that_gives_it() -> None:
    flags = given_by({"seed": "--seed"}, seed=5, settings=None)
    query = given_by("the query", seed=3, settings="q.toml", faults="f.toml")
    chosen = resolve(flags, query)
    assert (chosen.seed, chosen.settings, chosen.faults) == (5, "q.toml", "f.toml")
    assert chosen.source("seed") == "--seed"
    assert chosen.source("settings") == "the query"
    assert resolve(Given(), Given()) == Given()


@pytest.fixture
def robot_file(tmp_path: Path) -> Path:
    path = tmp_path / "robot.toml"
    path.write_text('[emulator]\nseed = 9\n\n[[faults]]\nkind = "power_cut"\nat_s = 2.0\n')
    return path


def _faults(tmp_path: Path, name: str, kind: str) -> Path:
    path = tmp_path / name
    path.write_text(f'[[faults]]\nkind = "{kind}"\njoint = 2\nat_s = 1.0\n')
    return path


def _plan(tmp_path: Path, port: str, **options: Any) -> Any:
    return prepare(RunOptions(suites=["joints"], ports=[port], out=tmp_path / "run", **options))


def test_the_settings_file_gives_what_no_flag_or_query_gives(tmp_path: Path,
                                                           robot_file: Path) -> None:
    plan = _plan(tmp_path, f"fake://?settings={robot_file}")
    assert plan.settings_path == str(robot_file)
    assert plan.seed == 9
    assert [f.kind for f in plan.faults] == ["power_cut"]
    default = _plan(tmp_path, "fake://")
    assert (default.seed, default.faults, default.settings_path) == (0, [], None)


def test_the_query_wins_over_the_settings_file(tmp_path: Path, robot_file: Path) -> None:
    stall = _faults(tmp_path, "stall.toml", "stall")
    plan = _plan(tmp_path, f"fake://?settings={robot_file}&seed=4&faults={stall}")
    assert plan.seed == 4
    assert [f.kind for f in plan.faults] == ["stall"]  # replaced, not added


def test_a_flag_wins_over_the_query(tmp_path: Path, robot_file: Path) -> None:
    stall = _faults(tmp_path, "stall.toml", "stall")
    slip = tmp_path / "reset.toml"
    slip.write_text('[[faults]]\nkind = "slave_reset"\njoint = 3\nat_s = 0.5\n')
    other = tmp_path / "other.toml"
    other.write_text("[emulator]\nprofile = \"ideal\"\n")
    plan = _plan(tmp_path, f"fake://?settings={robot_file}&seed=4&faults={stall}",
                 seed=5, faults=slip, settings=other)
    assert plan.seed == 5
    assert [f.kind for f in plan.faults] == ["slave_reset"]
    assert plan.settings_path == str(other)
    assert plan.settings.sections["emulator"]["profile"] == "ideal"


def test_faults_on_a_target_that_takes_none_are_refused_naming_the_flag(tmp_path: Path) -> None:
    stall = _faults(tmp_path, "stall.toml", "stall")
    with pytest.raises(ArmbenchError, match="--faults: faults are injected into a simulated arm"):
        _plan(tmp_path, "socket://localhost:9", faults=stall)


def test_the_pytest_plugin_resolves_the_same_way(robot_file: Path) -> None:
    from armbench.cli.plugin.pytest_bench import BenchSession

    target = target_of(f"fake://?settings={robot_file}&seed=4")
    inputs = target.inputs(given_by({"settings": "--arm-settings"}, settings=None))
    session = BenchSession(target.port, inputs.robot, inputs.given.settings, None, None,
                           target=target, inputs=inputs)
    assert (session.settings_path, session.inputs.seed) == (str(robot_file), 4)
    assert [f.kind for f in session.inputs.faults] == ["power_cut"]


# --- a third-party simulator -----------------------------------------------------------------


@pytest.fixture
def toy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """``toy://`` registered as an entry point of ``armbench.transports`` by an installed
    distribution (its ``.dist-info`` on ``sys.path``, which spawned workers inherit)."""
    site = tmp_path / "site"
    info = site / "toy_target-1.0.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-target\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(
        "[armbench.transports]\ntoy = toy_target:ToyTransport\n")
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setattr(ToyTransport, "fresh_arms", 0)
    yield


def test_a_simulator_registered_by_entry_point_is_a_target(toy: None) -> None:
    target = target_of("toy://?caps=virtual,fresh,truth,power")
    assert target.transport_class is ToyTransport
    assert target.capabilities == Capabilities(clock="virtual", fresh_per_trial=True, truth=True,
                                               power=True)
    assert target.name() == "toy"


def _run_toy(tmp_path: Path, port: str, name: str, **options: Any) -> tuple[Any, str, bool]:
    """Run the joints suite (two trials) on ``port``: the outcome, the progress text, whether the
    run went on a virtual-time loop."""
    from armbench.fakes.clock import vclock
    config = tmp_path / "bench.toml"
    config.write_text(JOINTS_CONFIG)
    used: list[bool] = []
    real_run_virtual = vclock.run_virtual

    def spy(main: Coroutine[Any, Any, T]) -> T:
        used.append(True)
        return real_run_virtual(main)

    progress = io.StringIO()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(vclock, "run_virtual", spy)
        outcome = run_sync(RunOptions(suites=["joints"], ports=[port], config=config,
                                      out=tmp_path / name, **options), progress=progress)
    return outcome, progress.getvalue(), bool(used)


def _names(outcome: Any) -> set[str]:
    record = json.loads(outcome.results_path.read_text())
    return {m["name"] for m in record["suites"]["joints"]["measurements"]}


def test_a_simulator_gets_virtual_time_fresh_arms_and_truth_it_declares(tmp_path: Path,
                                                                      toy: None) -> None:
    outcome, _, virtual = _run_toy(tmp_path, "toy://?caps=virtual,fresh,truth,power", "a",
                                   workers=1)
    assert outcome.exit_status == 0, outcome.error
    assert virtual
    assert ToyTransport.fresh_arms == 2  # one per trial
    assert "joints.j1.true_reversal_mrad" in _names(outcome)


def test_a_simulator_without_truth_gets_none(tmp_path: Path, toy: None) -> None:
    outcome, _, virtual = _run_toy(tmp_path, "toy://?caps=virtual,fresh", "b", workers=1)
    assert outcome.exit_status == 0, outcome.error
    assert virtual
    names = _names(outcome)
    assert "joints.j1.reversal_mrad" in names
    assert not any("true_" in n for n in names)


def test_a_simulator_declaring_parallel_runs_in_workers(tmp_path: Path,
                                                       toy: None) -> None:
    outcome, progress, virtual = _run_toy(
        tmp_path, "toy://?caps=virtual,fresh,parallel,truth", "c", workers=2)
    assert outcome.exit_status == 0, outcome.error
    assert virtual
    assert "job(s) took" in progress  # measured in worker processes
    assert ToyTransport.fresh_arms == 0  # none in this process
    assert "joints.j1.true_reversal_mrad" in _names(outcome)


def test_a_real_time_target_gets_one_arm_for_the_run(tmp_path: Path, toy: None) -> None:
    plan = _plan(tmp_path, "toy://?caps=truth")
    assert plan.isolation == "run"
    assert not plan.target.virtual
    config = tmp_path / "trial.toml"
    config.write_text('spec_version = "armbench-limits/1"\n[bench]\nisolation = "trial"\n')
    with pytest.raises(SettingsError, match="needs a target that starts one"):
        _plan(tmp_path, "toy://?caps=truth", config=config)
    with pytest.raises(ArmbenchError, match="runs on virtual time"):
        _plan(tmp_path, "toy://?caps=virtual,fresh", power_manual=True)


def test_monitor_and_i2c_ask_the_target(toy: None, capsys: pytest.CaptureFixture[str]) -> None:
    from armbench.cli.commands.monitor import run_on_port
    from armbench.fakes.clock.vclock import VirtualTimeLoop

    async def loop_kind() -> bool:
        return isinstance(asyncio.get_running_loop(), VirtualTimeLoop)

    assert run_on_port("toy://?caps=virtual", loop_kind())
    assert not run_on_port("toy://", loop_kind())
    status, _, err = cli(capsys, "i2c", "scan", "--port", "toy://?caps=virtual,fresh")
    one_line_error(status, err, "only an emulated bus")
    status, out, _ = cli(capsys, "i2c", "scan", "--port", "toy://?caps=virtual,bus", "--json")
    assert status == 0 and json.loads(out)["ok"]


def test_the_capture_names_the_targets_clock(toy: None) -> None:
    from armbench.bench.runner.capture_run import _clock_of

    assert _clock_of("fake://?seed=2") == "virtual"
    assert _clock_of("toy://?caps=virtual") == "virtual"
    assert _clock_of("toy://") == "real"
    assert _clock_of("socket://localhost:9") == "real"
    assert _clock_of("nosuch://x") == "real"
    assert _clock_of(None) == "real"


def test_a_command_s_settings_flag_reaches_the_emulator_over_the_query(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``i2c scan --settings B --port fake://?settings=A``: the emulated arm plays B, as the
    driver does (the flag wins over the query), so B's joint addresses answer."""
    moved = tmp_path / "moved.toml"
    moved.write_text("[joints.j4]\ni2c_address = 0x40\n")
    plain = tmp_path / "plain.toml"
    plain.write_text("")
    status, out, err = cli(capsys, "i2c", "scan", "--port", f"fake://?settings={plain}",
                           "--settings", str(moved), "--json")
    assert status == 0, err
    result = json.loads(out)
    assert "0x40" in result["found"] and "0x12" not in result["found"]
    status, out, _ = cli(capsys, "i2c", "scan", "--port", f"fake://?settings={moved}", "--json")
    assert status == 0 and "0x40" in json.loads(out)["found"]
