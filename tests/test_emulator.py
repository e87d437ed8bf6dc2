"""The emulated firmware as a whole: Algorithm 1/2 over I²C, UART timing, EEPROM, recovery, faults.

Everything runs on virtual time (``armbench.fakes.clock.vclock``); each test drives the arm like a
host would,
through ``host_write`` and the reply stream, and checks against ground truth.
"""

from __future__ import annotations

import asyncio
import itertools
import math
import random
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
from build_trace import every_truth
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from armbench.bench.suites.truth_probe import TRUTH_SEARCH
from armbench.drivers.model.protocol import Command, FrameError, Framer, Reply
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.model.twin_parameters import JOINT_PARAMETERS
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.arm_emulator import ArmEmulator, ArmStats
from armbench.fakes.firmware.eeprom import Eeprom, EepromRecord, record_write_times
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.fakes.firmware.faults import Fault, parse_faults
from armbench.fakes.firmware.i2c import REG_STATUS, I2CBus, transaction_bits
from armbench.fakes.firmware.i2c_messages import I2CMessage
from armbench.fakes.twin.physics import END_STOP_MARGIN_RAD, TRUTH_HISTORY

ROBOT = RobotSettings()
LOWER, UPPER = ROBOT.lower_rad, ROBOT.upper_rad


class Host:
    """A minimal host on the emulator's UART: collects replies with their arrival times."""

    def __init__(self, arm: ArmEmulator) -> None:
        self.arm = arm
        self.framer = Framer("reply")
        self.replies: list[tuple[float, Reply]] = []
        self.errors: list[FrameError] = []
        self.chunks = 0
        arm.attach_host(self._sink)

    def _sink(self, data: bytes) -> None:
        self.chunks += 1
        t = asyncio.get_running_loop().time()
        for e in self.framer.feed(data):
            if isinstance(e, Reply):
                self.replies.append((t, e))
            elif isinstance(e, FrameError):
                self.errors.append(e)

    def send(self, q_rad: list[float], duty: int | list[int] = 99) -> None:
        self.arm.host_write(Command.from_rad(q_rad, duty).encode())

    def angles(self) -> tuple[float, ...]:
        return self.replies[-1][1].angles_rad(LOWER, UPPER)


def emulate(body: Callable[[ArmEmulator, Host], Awaitable[Any]], **kwargs: Any) -> Any:
    """Run ``body(arm, host)`` on virtual time with a started emulator, once it has booted and
    replied (as a driver connects), unless ``ready=False``."""
    ready = kwargs.pop("ready", True)
    kwargs.setdefault("profile", "ideal")  # the firmware's exact behaviour; physics: test_physics
    faults = kwargs.pop("faults", ())
    initial = kwargs.pop("initial_q_rad", None)
    robot = kwargs.pop("robot", ROBOT)

    async def main() -> Any:
        arm = ArmEmulator(robot, emulator_settings(robot, **kwargs), faults, initial)
        host = Host(arm)
        await arm.start()
        while ready and not host.replies:
            await asyncio.sleep(0.001)
        try:
            return await body(arm, host)
        finally:
            await arm.close()

    return run_virtual(main)


def loop_period_s(robot: RobotSettings = ROBOT, i2c_hz: int = 100_000) -> float:
    """What the master's loop must take: six I²C transactions plus the CPU overhead."""
    bits = 3 * (1 + 9 * 5 + 1) + 3 * (1 + 9 * 3 + 1)
    return bits / i2c_hz + emulator_settings(robot).loop_overhead_s


def test_bus_timing_matches_transaction_bits() -> None:
    assert transaction_bits((I2CMessage.write(0x10, b"1234"),)) == 1 + 9 * 5 + 1
    assert transaction_bits((I2CMessage.read(0x10, 2),)) == 1 + 9 * 3 + 1


def test_polling_firmware_replies_every_loop_at_the_bus_rate() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        await asyncio.sleep(1.0)

    arm_loops: list[int] = []

    async def counted(arm: ArmEmulator, host: Host) -> None:
        await body(arm, host)
        arm_loops.append(arm.stats().loops)
        # the master's cursor may be a loop ahead of the clock, and a reply takes 2.17 ms
        assert arm.stats().loops - 2 <= len(host.replies) <= arm.stats().loops
        times = [t for t, _ in host.replies]
        gaps = [b - a for a, b in itertools.pairwise(times)]
        assert max(gaps) == pytest.approx(min(gaps), rel=1e-6)
        assert gaps[0] == pytest.approx(loop_period_s(), rel=1e-6)
        assert host.replies[-1][1] == Reply(0, 0, 0, 0)

    emulate(counted, ready=False)
    boot_s = emulator_settings(ROBOT).boot_s
    assert arm_loops[0] == pytest.approx((1.0 - boot_s) / loop_period_s(), abs=2)


def test_400khz_bus_makes_the_loop_uart_bound() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        await asyncio.sleep(1.0)
        times = [t for t, _ in host.replies]
        gap = (times[-1] - times[10]) / (len(times) - 11)
        # 25 bytes of 10 bits at 115200 baud: 2.17 ms per reply, slower than the 400 kHz loop
        assert gap == pytest.approx(25 * 10 / 115200, rel=1e-3)

    emulate(body, i2c_hz=400_000)


def test_command_moves_every_joint_to_its_target() -> None:
    target = [0.8, 0.5, -0.6, 1.2]

    async def body(arm: ArmEmulator, host: Host) -> None:
        host.send(target, 99)
        await asyncio.sleep(15)
        for got, want in zip(host.angles(), target, strict=True):
            assert got == pytest.approx(want, abs=2e-4)
        for true, want in zip(arm.true_angles_rad(), target, strict=True):
            assert true == pytest.approx(want, abs=2e-4)
        assert arm.stats().commands == 1

    emulate(body)


@pytest.mark.parametrize("duty", [1, 50, 99])
def test_speed_law_12_at_system_level(duty: int) -> None:
    j3 = ROBOT.joints[2]
    steps = 600
    distance = steps / j3.steps_per_rad

    async def body(arm: ArmEmulator, host: Host) -> None:
        host.send([0.0, 0.0, distance, 0.0], duty)
        await asyncio.sleep(0.5)
        q0 = arm.true_angles_rad()[2]
        await asyncio.sleep(1.0)
        q1 = arm.true_angles_rad()[2]
        rate = (q1 - q0) * j3.steps_per_rad
        expected = 1e6 / (80 * (101 - duty))
        if q1 < distance - 1e-9:  # still moving through the whole window
            assert rate == pytest.approx(expected, abs=1.01)

    emulate(body)


def test_rx_buffer_overflows_when_the_host_floods() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        await asyncio.sleep(0.05)
        frame = Command.from_rad([0.1, 0.0, 0.0, 0.0], 10).encode()
        arm.host_write(frame * 40)  # 1480 bytes at once: far more than 64 per loop
        await asyncio.sleep(0.5)
        stats = arm.stats()
        assert stats.rx_overflow_bytes > 0
        assert stats.rx_bytes + stats.rx_overflow_bytes == len(frame) * 40
        assert stats.commands < 40

    emulate(body)


def test_blocking_receive_replies_once_per_command() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        await asyncio.sleep(0.5)
        assert host.replies == []
        for k in range(5):
            host.send([0.01 * k, 0.0, 0.0, 0.0], 50)
            await asyncio.sleep(0.05)
        assert len(host.replies) == 5

    emulate(body, uart_receive="blocking", ready=False)  # it never replies unasked


def test_replies_can_end_in_crlf() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        await asyncio.sleep(0.2)
        assert host.replies and not host.errors
        assert host.framer.discarded_bytes == 0

    emulate(body, reply_line_end="\r\n")


def test_eeprom_written_on_each_motion_change() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        host.send([0.2, 0.0, 0.0, 0.0], 99)
        await asyncio.sleep(3)
        host.send([-0.2, 0.0, 0.0, 0.0], 99)
        await asyncio.sleep(6)
        # joint 1: stopped->cw, cw->stopped, stopped->ccw, ccw->stopped
        assert arm.eeproms[0].record_writes == 4
        assert arm.eeproms[1].record_writes == 0
        record = arm.eeproms[0].load()
        assert record is not None and record.motion == "stopped"

    emulate(body)


def test_a_power_cut_takes_back_the_cells_not_yet_written() -> None:
    """A record is stored whole and its cells' write times come after (``Eeprom.land``): a cut
    keeps the cells whose write started before it, takes back the others (neither written nor
    worn), in the firmware's order: the state, then the counter from its high byte down."""
    eeprom = Eeprom()
    eeprom.store("cw", 0)
    eeprom.land([0.0, 0.1, 0.2, 0.3, 0.4])
    assert eeprom.store("stopped", -77) == 5  # 0xFFFFFFB3: every cell changes
    starts: list[float] = []
    record_write_times(eeprom.last_written, 1.0, -math.inf, 3.3e-3, starts)
    assert starts == pytest.approx([1.0, 1.0033, 1.0066, 1.0099, 1.0132])
    eeprom.land(starts)
    assert eeprom.cut(1.0100) == 1
    assert eeprom.load() == EepromRecord("stopped", -256)  # the old low byte 0x00
    assert eeprom.cell_writes == 9 and eeprom.max_cell_wear == 2
    eeprom.store("ccw", -256)
    assert eeprom.cut(5.0) == 1  # written after a cut: no time yet, taken back
    assert eeprom.load() == EepromRecord("stopped", -256)


def test_a_slave_record_torn_by_a_power_cut() -> None:
    """Joint 2 starts to move: its first record (blank EEPROM: the state and all four counter
    cells change) is written from the motion change on, 3.3 ms a cell. The power goes 1 ms after
    the second cell's write started: the state and the counter's high byte are new, the other
    three cells still blank; the next boot drives to the Hall as the record says "moving"."""
    async def body(arm: ArmEmulator, host: Host) -> None:
        writes: list[tuple[float, int, int]] = []
        arm.eeproms[1].write_log = writes
        host.send([0.0, 0.2, 0.0, 0.0], 99)
        while len(writes) < 2:
            await asyncio.sleep(0.001)
        await asyncio.sleep(writes[1][0] + 1e-3 - asyncio.get_running_loop().time())
        arm.power_off()
        assert [(a, v) for _, a, v in writes] == [(0, 1), (4, 0), (3, 0), (2, 0), (1, 0)]
        assert arm.eeproms[1].read(0, 5) == bytes((1, 0xFF, 0xFF, 0xFF, 0x00))
        arm.power_on()
        await asyncio.sleep(0.2)
        assert arm.slaves[0].recoveries == 1

    emulate(body)


# --- startup recovery (§5.2) -----------------------------------------------------------------

def _cut_and_restore(target: list[float], cut_after_s: float, settle_s: float,
                     **kwargs: Any) -> tuple[ArmStats, tuple[float, ...], tuple[float, ...],
                                             tuple[float | None, ...]]:
    out: list[Any] = []

    async def body(arm: ArmEmulator, host: Host) -> None:
        host.send(target, 99)
        await asyncio.sleep(cut_after_s)
        arm.power_off()
        truth_at_cut = arm.true_angles_rad()
        await asyncio.sleep(1.0)
        arm.power_on()
        await asyncio.sleep(settle_s)
        out.extend([arm.stats(), truth_at_cut, arm.true_angles_rad(),
                    arm.firmware_angles_rad()])

    emulate(body, **kwargs)
    return out[0], out[1], out[2], out[3]


def test_recovery_after_a_cut_while_stopped_restores_the_position() -> None:
    stats, at_cut, true, firmware = _cut_and_restore([0.3, 0.2, -0.1, 0.5], 10, 1)
    assert stats.recoveries == (0, 0, 0, 0)
    for t, f, c in zip(true, firmware, at_cut, strict=True):
        assert f is not None
        assert f == pytest.approx(t, abs=1e-4)
        assert t == pytest.approx(c, abs=1e-12)


def test_recovery_after_a_cut_moving_cw_drives_ccw_to_the_hall() -> None:
    stats, at_cut, true, firmware = _cut_and_restore([0.6, 0.0, 0.0, 0.0], 0.5, 8)
    assert stats.recoveries[0] == 1
    assert 0.0 < at_cut[0] < 0.6
    # back at the Hall sensor (0 rad), counter reset there: belief equals truth again
    assert true[0] == pytest.approx(0.0, abs=2e-4)
    assert firmware[0] == pytest.approx(true[0], abs=2e-4)


def test_recovery_after_a_cut_moving_ccw_drives_cw_to_the_hall() -> None:
    stats, at_cut, true, firmware = _cut_and_restore([-0.6, 0.0, 0.0, 0.0], 0.5, 8)
    assert stats.recoveries[0] == 1
    assert -0.6 < at_cut[0] < 0.0
    assert true[0] == pytest.approx(0.0, abs=2e-4)
    assert firmware[0] == pytest.approx(true[0], abs=2e-4)


def test_recovery_driving_away_from_the_hall_fails_at_the_limit() -> None:
    # Start past the Hall sensor: moving CCW from +1.0 towards +0.5 never crosses 0, so the
    # recovery (drive CW) runs away from the Hall sensor into the upper hard limit.
    out: list[Any] = []

    async def body(arm: ArmEmulator, host: Host) -> None:
        host.send([0.5, 0.0, 0.0, 0.0], 99)
        await asyncio.sleep(0.3)
        arm.power_off()
        await asyncio.sleep(0.1)
        arm.power_on()
        await asyncio.sleep(60)
        out.append((arm.true_angles_rad()[0], arm.master.model, len(host.replies)))

    emulate(body, initial_q_rad=[1.0, 0.0, 0.0, 0.0])
    true_q1, model, _ = out[0]
    assert model is not None and model.homing and model.at_limit
    assert true_q1 == pytest.approx(UPPER[0] + END_STOP_MARGIN_RAD, abs=1e-3)  # the end stop


# --- faults ----------------------------------------------------------------------------------

def _faults(*items: dict[str, Any]) -> list[Fault]:
    return parse_faults(items)


def test_uart_corruption_to_host_is_seen_as_frame_errors() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        await asyncio.sleep(1)
        assert host.errors
        assert host.replies

    emulate(body, faults=_faults({"kind": "uart_corrupt", "at_s": 0.2, "duration_s": 0.5,
                                  "probability": 0.05}))


def test_uart_drop_and_insert_to_robot_lose_commands_not_the_firmware() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        for k in range(50):
            host.send([0.001 * k, 0.0, 0.0, 0.0], 10)
            await asyncio.sleep(0.01)
        await asyncio.sleep(0.2)
        assert 0 < arm.stats().commands < 50
        assert arm.master.framer.errors > 0

    emulate(body, faults=_faults(
        {"kind": "uart_drop", "at_s": 0.0, "probability": 0.01, "direction": "to_robot"},
        {"kind": "uart_insert", "at_s": 0.0, "probability": 0.3, "count": 3,
         "direction": "to_robot"}))


def test_split_and_delayed_writes_reach_the_host_intact() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        await asyncio.sleep(0.5)
        assert not host.errors
        assert host.chunks > 2 * len(host.replies) > 0

    emulate(body, faults=_faults(
        {"kind": "split_write", "at_s": 0.0, "count": 2, "delay_s": 0.0002},
        {"kind": "delay_write", "at_s": 0.0, "delay_s": 0.01}))


@pytest.mark.parametrize("kind", ["i2c_nak", "i2c_bus_error"])
def test_i2c_fault_on_a_slave_freezes_its_reported_position(kind: str) -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        host.send([0.0, 0.3, 0.0, 0.0], 99)
        await asyncio.sleep(3)
        frozen = host.angles()[1]
        assert arm.bus.stats.naks + arm.bus.stats.bus_errors > 0
        assert frozen < 0.05  # fault began at 0.1 s: the master never saw the move
        await asyncio.sleep(3)
        assert host.angles()[1] == pytest.approx(0.3, abs=2e-4)

    emulate(body, faults=_faults({"kind": kind, "at_s": 0.1, "duration_s": 4.0, "joint": 2}))


def test_slave_reset_reboots_one_board_and_recovers() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        host.send([0.0, 0.0, 0.4, 0.0], 99)
        await asyncio.sleep(12)
        stats = arm.stats()
        assert stats.boots == (1, 1, 2, 1)
        assert stats.recoveries == (0, 0, 1, 0)

    emulate(body, faults=_faults({"kind": "slave_reset", "at_s": 0.3, "joint": 3}))


def test_stalled_joint_does_not_move_until_freed() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        host.send([0.0, 0.0, 0.0, 0.3], 99)
        await asyncio.sleep(1.5)
        assert arm.true_angles_rad()[3] == pytest.approx(0.0, abs=1e-9)
        await asyncio.sleep(6)
        assert arm.true_angles_rad()[3] == pytest.approx(0.3, abs=2e-4)

    emulate(body, faults=_faults({"kind": "stall", "at_s": 0.0, "duration_s": 2.0,
                                  "joint": 4}))


def test_power_cut_and_restore_by_schedule() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        await asyncio.sleep(1.0)
        assert not arm.powered
        n = len(host.replies)
        await asyncio.sleep(1.0)
        assert arm.powered and len(host.replies) > n

    emulate(body, faults=_faults({"kind": "power_cut", "at_s": 0.5},
                                 {"kind": "power_restore", "at_s": 1.5}))


def test_boards_boot_before_they_answer() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        host.send([0.01, 0.0, 0.0, 0.0], 99)  # lost: the receiver is off until Serial.begin()
        await asyncio.sleep(0.29)
        assert host.replies == []
        assert arm.bus.scan() == []  # the slaves join the bus in setup()
        await asyncio.sleep(0.02)
        assert host.replies and arm.stats().commands == 0
        assert arm.uart.rx_lost_bytes == 37

    emulate(body, boot_s=0.3, ready=False)


@pytest.mark.parametrize("kind", ["power_cut", "uart_drop"])
def test_a_fault_at_time_zero_acts_before_the_first_loop(kind: str) -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        await asyncio.sleep(0.5)
        assert host.replies == [] and host.chunks == 0

    emulate(body, faults=_faults({"kind": kind, "at_s": 0}), ready=False)


def test_replies_on_the_wire_at_a_power_cut_never_arrive() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        await asyncio.sleep(0.1)
        n = len(host.replies)
        arm.power_off()
        await asyncio.sleep(0.1)
        assert len(host.replies) == n
        assert not host.errors

    emulate(body)


def test_event_scheduled_fault_after_frames() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        for _k in range(5):
            host.send([0.0, 0.0, 0.0, 0.0], 0)
            await asyncio.sleep(0.05)
        await asyncio.sleep(0.2)
        assert not arm.powered
        assert arm.injector.activations[0][1].startswith("power_cut")

    emulate(body, faults=_faults({"kind": "power_cut", "after_frames": 3}))


def test_same_faults_and_seed_reproduce_the_same_run() -> None:
    faults = _faults({"kind": "uart_corrupt", "at_s": 0.0, "probability": 0.02},
                     {"kind": "split_write", "at_s": 0.0, "count": 3, "probability": 0.5})

    async def body(arm: ArmEmulator, host: Host) -> list[object]:
        host.send([0.2, 0.1, 0.1, 0.1], 99)
        await asyncio.sleep(1.0)
        return [*host.replies, *host.errors]

    a = emulate(body, faults=faults, seed=7)
    b = emulate(body, faults=faults, seed=7)
    c = emulate(body, faults=faults, seed=8)
    assert a == b
    assert a != c


def test_faults_in_the_robot_settings_file_reach_fake_ports(tmp_path: Path) -> None:
    from armbench.fakes.links.fake_transport import parse_fake_url

    robot = tmp_path / "robot.toml"
    robot.write_text('[[faults]]\nkind = "power_cut"\nat_s = 2.0\n')
    extra = tmp_path / "faults.toml"
    extra.write_text('[[faults]]\nkind = "stall"\njoint = 2\nat_s = 1.0\n')
    _, seed, faults = parse_fake_url(f"fake://?settings={robot}&seed=4")
    assert seed == 4
    assert [f.kind for f in faults] == ["power_cut"]
    # one source per setting: the query's fault list replaces the file's, it is not added to it
    _, _, faults = parse_fake_url(f"fake://?settings={robot}&faults={extra}")
    assert [f.kind for f in faults] == ["stall"]


@pytest.mark.parametrize(("item", "field"), [
    ({"kind": "meteor", "at_s": 1}, "faults[0].kind"),
    ({"kind": "stall", "at_s": 1}, "faults[0].joint"),
    ({"kind": "power_cut"}, "faults[0]"),
    ({"kind": "i2c_nak", "at_s": 1, "joint": 1}, "faults[0].joint"),
    ({"kind": "uart_drop", "at_s": 1, "probability": 2}, "faults[0].probability"),
    ({"kind": "uart_drop", "at_s": -1}, "faults[0].at_s"),
    ({"kind": "uart_drop", "at_s": 1, "colour": "red"}, "faults[0].colour"),
])
def test_bad_fault_entries_name_the_field(item: dict[str, Any], field: str) -> None:
    from armbench.drivers.model.settings import SettingsError

    with pytest.raises(SettingsError) as info:
        parse_faults([item])
    assert info.value.field == field


# --- robustness ------------------------------------------------------------------------------

@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.binary(max_size=120), max_size=25))
def test_the_firmware_never_dies_on_random_bytes(chunks: list[bytes]) -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        for c in chunks:
            arm.host_write(c)
            await asyncio.sleep(0.003)
        host.send([0.05, 0.0, 0.0, 0.0], 99)
        await asyncio.sleep(1.0)
        assert arm.master._task is not None and not arm.master._task.done()
        assert host.angles()[0] == pytest.approx(0.05, abs=2e-4)

    emulate(body)


def test_i2c_scan_finds_the_three_slaves() -> None:
    async def body(arm: ArmEmulator, host: Host) -> list[int]:
        await asyncio.sleep(0.2)  # after the boot delay
        return arm.bus.scan()

    assert emulate(body) == [0x10, 0x11, 0x12]


def test_the_newest_truth_sample_belongs_to_the_newest_delivered_reply() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        host.send([0.5, 0.4, -0.3, 0.6], 99)
        for _ in range(200):
            await asyncio.sleep(0.0011)
            if host.replies:
                reply = host.replies[-1][1]
                sample = arm.truth[-1]
                assert reply == Reply.from_rad(sample.firmware_rad)
                assert sample.t_s <= host.replies[-1][0]
        assert len(arm.truth) == len(host.replies)

    emulate(body)


def test_the_truth_history_keeps_the_newest_samples_the_bench_searches() -> None:
    """The history is bounded (a longer one only feeds the garbage collector) and holds more
    than the newest samples a reply's truth is looked for among; every sample still passes
    ``uart.on_delivered``, in the order of the replies."""
    assert TRUTH_SEARCH < TRUTH_HISTORY

    async def body(arm: ArmEmulator, host: Host) -> None:
        every = every_truth(arm)
        host.send([0.5, 0.4, -0.3, 0.6], 99)
        while len(every) < 2 * TRUTH_HISTORY + 5:
            await asyncio.sleep(0.01)
        assert len(arm.truth) == TRUTH_HISTORY
        assert list(arm.truth) == every[-TRUTH_HISTORY:]
        assert [s.t_s for s in every] == sorted(s.t_s for s in every)

    emulate(body)


def test_ground_truth_beside_each_reply_includes_backlash() -> None:
    async def body(arm: ArmEmulator, host: Host) -> None:
        host.send([0.0, 0.2, 0.0, 0.0], 99)
        await asyncio.sleep(4)
        host.send([0.0, 0.1, 0.0, 0.0], 99)
        await asyncio.sleep(4)
        sample = arm.truth[-1]
        assert sample.firmware_rad[1] == pytest.approx(0.1, abs=2e-4)
        # the link sits half the gear play behind the motor's nominal angle (the play is centred
        # on it: docs/robot-model.md), on the side it last came from
        assert sample.true_rad[1] - sample.firmware_rad[1] == pytest.approx(0.001, abs=2e-4)
        assert math.isfinite(sample.t_s)

    # a play of 0.002 rad on joint 2, every other effect of it off (the declared ideal values:
    # no stick-slip, friction or Hall error), no weight beyond it to bend it, no encoder noise
    ideal = {p.key: p.ideal_value() for p in JOINT_PARAMETERS
             if isinstance(p.ideal_value(), float) and math.isfinite(float(p.ideal_value()))}
    emulate(body, profile="physical", physics={
        "noise_per_count": 0.0, "j2": {**ideal, "backlash_deg": math.degrees(0.002)},
        "j3": {"mass_kg": 0.0}, "j4": {"mass_kg": 0.0}})


def _fused_trace(fused: bool, seed: int, **settings: Any) -> dict[str, Any]:
    """Everything observable of a random session (commands at random duties, board resets, power
    cuts, stalls, STATUS reads by a second bus master), with ``emulator.fused_bus`` on or off."""
    rng = random.Random(seed)
    calls = [0]

    async def body(arm: ArmEmulator, host: Host) -> dict[str, Any]:
        stalled = [False] * 4
        seen: list[bytes] = []
        for _ in range(30):
            action = rng.random()
            if action < 0.55:
                q = [rng.uniform(lo, up) for lo, up in zip(LOWER, UPPER, strict=True)]
                host.send(q, [rng.randint(0, 99) for _ in range(4)] if rng.random() < 0.3
                          else rng.choice((99, 90, 50, 1)))
            elif action < 0.65:
                arm.reset_board(rng.randint(1, 4))
            elif action < 0.72:
                arm.power_off()
                await asyncio.sleep(rng.uniform(0.0, 0.3))
                arm.power_on()
            elif action < 0.85:
                j = rng.randint(1, 4)
                stalled[j - 1] = not stalled[j - 1]
                arm.set_stalled(j, stalled[j - 1])
            else:  # a second master points a slave at STATUS, later reads where it points
                address = arm.slave_address(rng.randint(2, 4))
                read = I2CMessage.read(address, 2)
                try:
                    arm.bus.i2c_rdwr(I2CMessage.write(address, [REG_STATUS]))
                    await asyncio.sleep(rng.uniform(0.0, 0.05))
                    arm.bus.i2c_rdwr(read)
                except OSError:
                    continue
                seen.append(bytes(read))
            await asyncio.sleep(rng.uniform(0.0, 0.5))
        models = [None if b.model is None else (
            b.model.counter, b.model.motor_steps, b.model.pulses, b.model.steps_taken,
            b.model.steps_missed, b.model.steps_blocked, b.model.spurious_counts)
            for b in arm.boards]
        return {
            "replies": list(host.replies), "errors": [e.raw for e in host.errors],
            "truth": list(arm.truth), "stats": arm.stats(), "bus": arm.bus.stats,
            "eeprom": [(bytes(e._cells), list(e._wear), e.record_writes) for e in arm.eeproms],
            "models": models, "bad_writes": [s.bad_writes for s in arm.slaves],
            "truth_now": arm.true_angles_rad(), "seen": seen, "rdwr_calls": calls[0],
        }

    rdwr = I2CBus.i2c_rdwr

    def counted(bus: I2CBus, *msgs: I2CMessage) -> None:
        calls[0] += 1
        rdwr(bus, *msgs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(I2CBus, "i2c_rdwr", counted)
        # a blocking firmware says nothing before its first command
        result: dict[str, Any] = emulate(
            body, fused_bus=fused, ready=settings.get("uart_receive") != "blocking", **settings)
        return result


@pytest.mark.parametrize(("seed", "settings"), [
    (1, {}), (2, {}), (3, {}), (4, {"i2c_hz": 400_000}),
    (21, {"uart_receive": "blocking"}),  # a seed whose power cuts leave no recovery stuck
    # physical: a seed whose session keeps the arm moving (6 leaves it recovering from a cut)
    (7, {"effects": {"miss_probability": 0.05, "miss_above_duty": 40}, "profile": "physical",
         "physics": {"noise_per_count": 1e-3, "j2": {"backlash_deg": 0.17}}}),
    (8, {"profile": "physical", "physics": {"payload_kg": 2.0}}),
])
def test_fused_bus_loops_are_the_bus_loops(seed: int, settings: dict[str, Any]) -> None:
    """``emulator.fused_bus`` runs a steady loop's six transactions as their known outcome: the
    replies (bytes and times), ground truth, counters, EEPROM and joints must be the same as with
    every transaction going through ``I2CBus.i2c_rdwr``, and the fast path must have been taken."""
    fused = _fused_trace(True, seed, **settings)
    plain = _fused_trace(False, seed, **settings)
    fused_calls, plain_calls = fused.pop("rdwr_calls"), plain.pop("rdwr_calls")
    assert plain_calls == plain["bus"].transactions
    if settings.get("uart_receive") == "blocking":  # every loop has a new command: none fused
        assert len(plain["replies"]) > 10
        assert fused_calls == plain_calls
    else:
        assert len(plain["replies"]) > 1000
        assert fused_calls < plain_calls / 3  # most loops were steady: the fused path was taken
    for key in plain:
        assert fused[key] == plain[key], key


def test_perf_workloads_and_figures() -> None:
    """``armbench perf --only emulator``'s plumbing on its quick run, and the behaviour behind
    its figures: at 9600 baud each print waits for the line, so there are about 11× fewer loops
    (cost follows events), at the rate the line sets."""
    from armbench.cli.perf import PerfOptions
    from armbench.cli.perf import emulator_perf as perf_emulator

    _, fast_loops = run_virtual(perf_emulator.emulate(5.0, moving=True))
    _, slow_loops = run_virtual(perf_emulator.emulate(5.0, moving=True,
                                                       baudrate=perf_emulator.SLOW_BAUD))
    assert fast_loops == pytest.approx(5.0 / loop_period_s(), rel=0.02)
    slow_period_s = 25 * 10 / perf_emulator.SLOW_BAUD  # each print waits for the line
    assert slow_loops == pytest.approx(5.0 / slow_period_s, rel=0.02)
    figures = {f.name: f for f in perf_emulator.run(PerfOptions(quick=True, repeats=1))}
    assert set(figures) == {"emulator.realtime_factor", "emulator.bus_realtime_factor",
                            "emulator.cpu_realtime_factor", "emulator.loop_cost",
                            "emulator.idle_realtime_factor", "emulator.slow_line_realtime_factor",
                            "emulator.cycle_loop_factor"}
    cost = figures["emulator.loop_cost"]
    assert cost.bound is not None and cost.ratio == pytest.approx(cost.value / cost.bound)
    assert all(f.value > 0 for f in figures.values())
    # a thread's CPU time never exceeds the wall time it passed in
    assert figures["emulator.cpu_realtime_factor"].value >= \
        figures["emulator.realtime_factor"].value * 0.99
