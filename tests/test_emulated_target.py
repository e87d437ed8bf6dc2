"""The emulator behind a port is typed, not guessed: a transport's ``emulator`` (None for hardware,
the simulator on ``fake://`` and on ``avr://`` on virtual time) and :func:`emulated`, which reads
it from a transport or an arm. Real transports throughout: the in-process emulator, a real pty
served by ``armbench emulate --pty``, the simavr harness where the toolchain is installed."""

from __future__ import annotations

import ast
import asyncio
from pathlib import Path

import pytest
from far_end import emulator_maker
from test_firmware import needs_toolchain

import armbench
from armbench.bench.runner.power import port_power
from armbench.bench.runner.truth import EmulatorTruth
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.transports import open_transport
from armbench.drivers.transports.base import EmulatedTarget, Emulator, emulated
from armbench.drivers.transports.serial_port import SerialTransport
from armbench.fakes.avr.avr_transport import AvrTransport
from armbench.fakes.avr.lockstep import AvrBoards
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.links.fake_transport import FakeTransport

#: Names of the side channel no module may reach for by a string.
SIDE_CHANNEL = {"emulator", "truth"}


def _reaching_by_name(path: Path) -> list[str]:
    """Every ``getattr``/``hasattr`` of ``path`` that names the emulator or its truth by a
    string, as ``file:line``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                and node.func.id in ("getattr", "hasattr") and len(node.args) >= 2
                and isinstance(node.args[1], ast.Constant) and node.args[1].value in SIDE_CHANNEL):
            found.append(f"{path}:{node.lineno}")
    return found


def test_no_module_of_the_package_reaches_for_the_emulator_by_name(tmp_path: Path) -> None:
    """The typed accessor is the only way to the emulator: no ``getattr(x, "emulator", None)``
    or ``getattr(x, "truth", None)`` anywhere in the installed package."""
    package = Path(armbench.__file__).parent
    modules = sorted(package.rglob("*.py"))
    assert len(modules) > 200, package  # the whole package, not an empty folder
    assert [hit for path in modules for hit in _reaching_by_name(path)] == []
    # the check finds what it looks for
    sample = tmp_path / "sample.py"
    sample.write_text("a = getattr(t, 'emulator', None)\nb = hasattr(e, \"truth\")\n"
                      "c = getattr(t, 'port', None)\n", encoding="utf-8")
    assert _reaching_by_name(sample) == [f"{sample}:1", f"{sample}:2"]


def test_fake_transport_declares_its_emulator() -> None:
    """``fake://``: no emulator before it is opened (it makes one), the one it made after, the
    one given from the start; its truth grows with the replies the arm reads."""

    async def main() -> None:
        made = open_transport("fake://?seed=1")
        assert isinstance(made, FakeTransport) and emulated(made) is None
        robot = RobotSettings()
        arm = Arm.connect("fake://?seed=1", robot, transport=made)
        await arm.open()
        try:
            emulator = emulated(made)
            assert isinstance(emulator, ArmEmulator) and isinstance(emulator, Emulator)
            assert emulated(arm) is emulator and arm.emulator is emulator
            await arm.move_joints((0.05, 0.0, 0.0, 0.0), 90)
            assert emulator.truth and arm.ground_truth() is emulator.truth[-1]
            truth = EmulatorTruth(arm, robot)
            assert truth.true_joints_rad() == pytest.approx(emulator.true_angles_rad())
            assert port_power(arm) is not None  # its own switch, through the emulator
        finally:
            await arm.close()
        given = ArmEmulator()
        fresh = FakeTransport("fake://", robot.serial, given)
        assert emulated(fresh) is given  # before open: the caller's emulator
        await given.close()

    run_virtual(main)


def test_hardware_and_no_target_have_no_emulator() -> None:
    """Every transport answers (the base's None), and no target is no emulator."""
    for port in ("socket://127.0.0.1:9", "rfc2217://127.0.0.1:9", "/dev/ttyUSB9"):
        transport = open_transport(port)
        assert isinstance(transport, EmulatedTarget)
        assert emulated(transport) is None
    assert emulated(None) is None


def test_a_real_pty_has_no_emulator_and_no_ground_truth(tmp_path: Path) -> None:
    """``armbench emulate --pty`` in another process: only bytes cross the pty, so the arm on it
    reads replies but has no emulator, no ground truth and no switch of its own."""

    async def main(port: str) -> None:
        async with asyncio.timeout(60), Arm.connect(port, reply_timeout_s=5.0) as arm:
            assert isinstance(arm.transport, SerialTransport)
            await arm.wait_state(lambda s: s.seq >= 3, timeout_s=10.0)
            assert emulated(arm.transport) is None and arm.emulator is None
            assert arm.ground_truth() is None
            assert EmulatorTruth(arm).true_joints_rad() is None
            assert port_power(arm) is None

    with emulator_maker(tmp_path) as make:
        asyncio.run(main(make("pty").port))


@needs_toolchain
def test_avr_declares_its_boards_on_virtual_time() -> None:
    """``avr://`` on virtual time: no boards before it is opened, the lockstep boards after,
    their truth one sample per reply."""

    async def main() -> None:
        transport = open_transport("avr://")
        assert isinstance(transport, AvrTransport) and emulated(transport) is None
        arm = Arm.connect("avr://", RobotSettings(), transport=transport)
        async with arm:
            boards = emulated(transport)
            assert isinstance(boards, AvrBoards) and isinstance(boards, Emulator)
            assert arm.emulator is boards
            await arm.move_joints((0.05, 0.0, 0.0, 0.0), 99)
            assert boards.truth and arm.ground_truth() is boards.truth[-1]

    run_virtual(main)
