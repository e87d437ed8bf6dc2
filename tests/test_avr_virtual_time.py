"""``avr://`` on virtual time: the firmware harness in lockstep with the run's virtual-time loop
(``fakes/avr/lockstep.py``, ``firmware/harness/lockstep.c``). Real toolchain, real harness process,
real driver; every time asserted is virtual (the boards' clock), so a loaded machine only makes
the tests slower."""

from __future__ import annotations

import asyncio
import itertools
import math
import os
import signal
import statistics
import threading
from types import SimpleNamespace
from typing import Any

import pytest
from test_firmware import needs_toolchain
from test_soak import cpu_guard

from armbench.bench.runner.power import HarnessPower, port_power
from armbench.bench.runner.truth import EmulatorTruth
from armbench.bench.suites._common import eeprom_counters
from armbench.drivers.host.arm import Arm
from armbench.drivers.host.motion import joint_times_s
from armbench.drivers.model.errors import ArmbenchError, PortLostError, TransportError
from armbench.drivers.model.protocol import Command, Framer, Reply
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.avr.avr_transport import AvrTransport
from armbench.fakes.avr.differential import DEFAULT_SCRIPT, compare, run_emulator, run_firmware
from armbench.fakes.avr.harness import FirmwareError
from armbench.fakes.avr.lockstep import AvrBoards, AvrVirtualTransport, fresh_boards
from armbench.fakes.clock.vclock import VirtualTimeLoop, run_virtual
from armbench.fakes.firmware.emulator_settings import emulator_settings

pytestmark = needs_toolchain

Timed = list[tuple[float, Reply]]

#: A reply this long after the one before followed a stall of its master's loop (an EEPROM record:
#: 3.3 ms a changed cell; the loop takes 2.4 ms on the emulator, 3.0 ms on the firmware).
STALL_S = 4.5e-3


def dated_as_sampled(replies: Timed) -> tuple[Timed, list[float]]:
    """The replies, each one after a stall dated as if its loop had not stalled (a loop period,
    the median gap, after the reply before), and each stall's length beyond that period.

    Both masters read the positions, then write the EEPROM record of a motion change, then send
    the reply (``role_loop`` in ``firmware/master.c``; the emulator's master alike): the reply
    after a record carries positions read before it, so it is dated where it would have left
    without the record, as every other reply is dated a fixed time after its positions were
    read. The stalls are returned to be compared on their own."""
    period_s = statistics.median(b[0] - a[0] for a, b in itertools.pairwise(replies))
    dated = replies[:1]
    stalls: list[float] = []
    for (t_before, _), (t, reply) in itertools.pairwise(replies):
        if t - t_before > STALL_S:
            stalls.append(t - t_before - period_s)
            t = t_before + period_s
        dated.append((t, reply))
    return dated, stalls


def play_script(until_s: float) -> Timed:
    """DEFAULT_SCRIPT's frames written through the transport at their virtual times, the boards
    powered at t = 0 (as the differential check's two sides are); each reply with the virtual
    time it arrived."""

    async def main() -> Timed:
        loop = asyncio.get_running_loop()
        transport = AvrVirtualTransport("avr://", RobotSettings().serial)
        framer = Framer("reply")
        out: Timed = []
        await transport.open()
        t0 = loop.time()
        transport.set_receiver(lambda data: out.extend(
            (loop.time() - t0, r) for r in framer.feed(data) if isinstance(r, Reply)))
        for t, q, duty in DEFAULT_SCRIPT:
            await asyncio.sleep(t0 + t - loop.time())
            await transport.write(Command.from_rad(list(q), duty).encode())
        await asyncio.sleep(t0 + until_s - loop.time())
        await transport.close()
        return out

    return run_virtual(main)


def test_replies_on_virtual_time_agree_with_the_emulator_and_the_free_running_harness() -> None:
    until_s = 4.5
    lockstep = play_script(until_s)
    emulator = run_emulator(DEFAULT_SCRIPT, until_s)
    lockstep_dated, lockstep_stalls = dated_as_sampled(lockstep)
    emulator_dated, emulator_stalls = dated_as_sampled(emulator)
    # the same records stall both masters' loops by the same number of EEPROM cell writes
    write_s = emulator_settings(RobotSettings()).eeprom_write_s_per_byte
    assert len(lockstep_stalls) == 4  # a move's start and end, a reversal, a hold
    assert ([round(s / write_s) for s in lockstep_stalls]
            == [round(s / write_s) for s in emulator_stalls] == [4, 2, 1, 2])
    # the positions within the differential check's tolerances (one loop period, 5 counts),
    # each reply dated as sampled. Dated at its arrival, the reply after a record would leave a
    # gap of the record's length in the other side's window: the two masters take a command up to
    # a loop apart (their loops run 3.0 and 2.4 ms and poll the UART at different moments; here
    # the firmware takes the first move 0.8 ms before the emulator), so a joint runs that far
    # ahead on one side, 4 ticks (6 counts) at duty 99, all through the move. The window absorbs
    # it while the other side's replies go on; at the move's end the emulator's next reply after
    # its last one before the arrival comes a record (6.6 ms) later, and when the firmware's last
    # reply before the arrival leaves after the emulator's (which moves with the firmware's loop
    # period, a few microseconds a loop), only the emulator's position before it is in the window
    against_emulator = compare(lockstep_dated, emulator_dated, window_s=3.2e-3, tol_counts=5.0)
    assert against_emulator.compared > 1000
    assert max(against_emulator.excess_counts) == 0.0, against_emulator
    # the same boards as the harness running the script by itself: a host byte is handed to
    # the UART one quantum (2 us) later in lockstep, nothing more
    free = run_firmware(DEFAULT_SCRIPT, until_s)
    assert abs(len(free) - len(lockstep)) <= 1
    against_free = compare(lockstep, free, window_s=1e-4, tol_counts=1.0)
    assert max(against_free.excess_counts) == 0.0, against_free
    # replies arrive when their last byte left the boards: the master's loop period apart
    gaps = [b[0] - a[0] for a, b in itertools.pairwise(lockstep)]
    assert min(gaps) > 2.5e-3


def test_a_move_takes_law_12s_time_in_virtual_seconds() -> None:
    robot = RobotSettings()
    target = (0.25, -0.2, 0.15, 0.3)
    duty = 60
    tol_rad = 2e-3

    async def main() -> tuple[float, float, Any, tuple[float, ...]]:
        loop = asyncio.get_running_loop()
        boards = AvrBoards(robot)
        transport = AvrVirtualTransport("avr://", robot.serial, boards)
        arm = Arm.connect("avr://", robot, transport=transport)
        try:
            await arm.open()
            start = arm.state.q_rad
            t0 = loop.time()
            state = await arm.move_joints(target, duty, tolerance_rad=tol_rad)
            took = loop.time() - t0
            # arrived: within the tolerance of the target, that much short of the whole way
            short = [t - math.copysign(tol_rad, t - s) for s, t in zip(start, target,
                                                                       strict=True)]
            expected = max(joint_times_s(start, short, [duty] * 4, robot))
            assert state is not None
            return took, expected, state, boards.true_angles_rad()
        finally:
            await arm.close()
            await boards.close()

    took, expected, state, truth = run_virtual(main)
    # law (12), plus the command's bytes on the wire, a loop to take it, the EEPROM record of
    # the move's start (the longest loop, 16.4 ms) and a reply period to see the arrival
    assert expected < took < expected + 0.03, (took, expected)
    assert all(abs(q - t) < 2e-3 for q, t in zip(truth, target, strict=True)), truth
    assert all(abs(q - t) < 2e-3 for q, t in zip(state.q_rad, target, strict=True))


def test_truth_power_cut_and_re_referencing_on_virtual_time() -> None:
    robot = RobotSettings()

    async def main() -> None:
        loop = asyncio.get_running_loop()
        boards = fresh_boards(robot)
        transport = AvrVirtualTransport("avr://", robot.serial, boards)
        arm = Arm.connect("avr://", robot, transport=transport)
        await arm.open()
        try:
            power = port_power(boards)
            assert isinstance(power, HarnessPower)
            # the suites' emulator counters: none here, as on hardware (not the harness figures)
            assert eeprom_counters(arm) is None
            truth = EmulatorTruth(boards, robot)
            await arm.move_joints((0.1, 0.1, 0.1, 0.1), 90)
            joints = truth.true_joints_rad()
            assert joints is not None and all(abs(q - 0.1) < 2e-3 for q in joints)
            assert truth.true_position_m() is not None
            # one ground-truth sample per reply, at its time, beside what the firmware said
            sample = boards.truth[-1]
            assert abs(sample.t_s - loop.time()) < 4e-3
            assert all(abs(a - b) < 2e-3
                       for a, b in zip(sample.firmware_rad, sample.link_rad, strict=True))
            # a cut mid-move: silence in virtual time, the joints stop where they are
            await arm.move_joints((-0.2, 0.1, 0.1, 0.1), 99, wait=False)
            await asyncio.sleep(0.02)
            await power.power_off()
            cut_at = boards.true_angles_rad()
            received = arm.frames_received
            await asyncio.sleep(1.0)
            assert arm.frames_received == received  # no replies without power
            assert boards.true_angles_rad() == cut_at
            assert not boards.powered
            # re-referenced and powered: the firmware counts from zero where the joints stand
            await power.re_reference()
            assert boards.true_angles_rad() == (0.0, 0.0, 0.0, 0.0)
            await power.power_on()
            await asyncio.sleep(0.5)
            assert arm.frames_received > received
            stats = boards.figures()
            assert stats["uart"]["rx_lost_power"] == 0
            assert stats["boards"][0]["powered"] == 1
        finally:
            await arm.close()
            await boards.close()
        assert boards.last_stats is not None and boards.last_stats["sim_s"] > 1.5
        await boards.close()  # idempotent

    run_virtual(main)


def test_avr_transport_gives_fresh_boards_per_trial_on_virtual_time() -> None:
    robot = RobotSettings()
    arm_spec = SimpleNamespace(robot=robot, seed=7, faults=[])

    async def trial() -> tuple[int, AvrBoards]:
        transport = AvrTransport.fresh("avr://", robot.serial, arm_spec)
        assert isinstance(transport, AvrTransport)
        arm = Arm.connect("avr://", robot, transport=transport)
        async with arm:
            boards = transport.emulator
            assert isinstance(boards, AvrBoards)
            assert transport.harness is boards
            assert port_power(arm.emulator).__class__ is HarnessPower
            await arm.move_joints((0.05, 0.0, 0.0, 0.0), 99)
            steps = boards.harness.motor_steps[0]
        # the transport built the boards, so it closed them (the runner's close is idempotent)
        assert boards.last_stats is not None
        assert transport.last_stats is boards.last_stats and not transport.is_open
        await boards.close()
        return steps, boards

    first_steps, first = run_virtual(trial)
    second_steps, second = run_virtual(trial)
    assert first is not second
    # each trial from the same fresh start: the same steps, at the target within the deadband
    assert first_steps == second_steps
    assert abs(first_steps - 0.05 * robot.joints[0].steps_per_rad) <= 2
    with pytest.raises(TransportError, match="no faults"):
        AvrTransport.fresh("avr://", robot.serial, SimpleNamespace(robot=robot, faults=[1]))


def test_a_harness_that_dies_is_a_lost_port_not_a_dead_loop() -> None:
    robot = RobotSettings()

    async def main() -> None:
        loop = asyncio.get_running_loop()
        assert isinstance(loop, VirtualTimeLoop)
        transport = AvrVirtualTransport("avr://", robot.serial)
        arm = Arm.connect("avr://", robot, transport=transport)
        await arm.open()
        boards = transport.emulator
        assert boards is not None
        os.kill(boards.harness.pid, signal.SIGKILL)
        with pytest.raises(ArmbenchError):
            await arm.move_joints((0.2, 0.0, 0.0, 0.0), 99)
        assert boards.failure is not None and boards not in loop.peers
        t = loop.time()
        await asyncio.sleep(1.0)  # the clock goes on without the boards
        assert loop.time() == pytest.approx(t + 1.0)
        # the boards stay where the harness died: every side channel and the port say so
        with cpu_guard(30.0):
            with pytest.raises(FirmwareError, match="harness exited"):
                boards.true_angles_rad()
            with pytest.raises(FirmwareError, match="harness exited"):
                await boards.power(False)
            with pytest.raises(PortLostError, match="harness exited"):
                await transport.write(Command.from_rad([0.0] * 4, 0).encode())
            with pytest.raises(PortLostError, match="harness exited"):
                await transport.read()
        assert not transport.is_open
        await arm.close()
        await boards.close()

    run_virtual(main)


def test_fresh_boards_refuse_faults_and_a_real_loop() -> None:
    with pytest.raises(FirmwareError, match="no faults"):
        fresh_boards(RobotSettings(), faults=[object()])

    async def on_a_real_loop() -> None:
        await AvrBoards().start()

    with pytest.raises(FirmwareError, match="virtual-time loop"):
        asyncio.run(on_a_real_loop())


class StepPeer:
    """A clock peer with events at fixed times: it stops at each one it passes."""

    def __init__(self, events: list[float]) -> None:
        self.events = events
        self.now = 0.0
        self.asked: list[float] = []
        self.stops: list[float] = []

    def run_until(self, t_s: float) -> float:
        self.asked.append(t_s)
        due = [e for e in self.events if self.now < e < t_s]
        self.now = min(due) if due else t_s
        self.stops.append(self.now)
        return self.now


def test_the_virtual_clock_jumps_only_as_far_as_its_peer_ran() -> None:
    peer = StepPeer([0.25, 0.7])
    seen: list[float] = []

    async def main() -> None:
        loop = asyncio.get_running_loop()
        assert isinstance(loop, VirtualTimeLoop)
        loop.peers.append(peer)
        for _ in range(3):
            await asyncio.sleep(0.4)
            seen.append(loop.time())
        loop.peers.remove(peer)

    run_virtual(main)
    # each jump stops at the peer's events on the way (0.25, 0.7), then goes on to the timer
    assert peer.asked == pytest.approx([0.4, 0.4, 0.8, 0.8, 1.2])
    assert peer.stops == pytest.approx([0.25, 0.4, 0.7, 0.8, 1.2])
    assert seen == pytest.approx([0.4, 0.8, 1.2])


def test_with_no_timer_the_clock_still_moves_while_a_peer_runs() -> None:
    """A host that only waits for the boards (no timeout) still sees them: the clock moves in
    idle steps while a peer is there, instead of the selector waiting for real I/O forever."""
    done: list[float] = []

    class EventPeer(StepPeer):
        def __init__(self, events: list[float], arrived: asyncio.Future[float]) -> None:
            super().__init__(events)
            self.arrived = arrived

        def run_until(self, t_s: float) -> float:
            reached = super().run_until(t_s)
            if reached in self.events:
                asyncio.get_running_loop().call_soon(self.arrived.set_result, reached)
            return reached

    async def main() -> None:
        loop = asyncio.get_running_loop()
        assert isinstance(loop, VirtualTimeLoop)
        arrived: asyncio.Future[float] = loop.create_future()
        loop.peers.append(EventPeer([0.25], arrived))
        await arrived  # no timer anywhere
        done.append(loop.time())

    worker = threading.Thread(target=run_virtual, args=(main,), daemon=True)
    worker.start()
    worker.join(30.0)
    assert done == [0.25]
