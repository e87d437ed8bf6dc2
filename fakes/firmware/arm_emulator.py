"""The whole emulated arm: four boards on one I²C bus, the master's UART, power and ground truth.

``ArmEmulator`` is what the fake transport, ``armbench emulate`` and the tests drive. It runs on the
running event loop and reads time only from it, so it works on virtual time (in-process clients)
and in real time (a pty or TCP client) unchanged.
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from armbench.drivers.model.kinematics import tcp_position
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.firmware.boards import Board, SlaveBoard, TruthSample
from armbench.fakes.firmware.eeprom import RATED_CYCLES, Eeprom
from armbench.fakes.firmware.emulator_settings import EmulatorSettings, emulator_settings
from armbench.fakes.firmware.faults import Fault, FaultInjector
from armbench.fakes.firmware.i2c import BusClock, I2CBus
from armbench.fakes.firmware.master_board import MasterBoard
from armbench.fakes.firmware.uart import Uart
from armbench.fakes.twin.physics import TRUTH_HISTORY, Mechanism

__all__ = ["ArmEmulator", "ArmStats"]

log = logging.getLogger("armbench.emulator")


@dataclass(frozen=True, slots=True)
class ArmStats:
    """Counters of one emulator run."""

    loops: int
    commands: int
    rx_bytes: int
    rx_overflow_bytes: int
    tx_bytes: int
    i2c_transactions: int
    i2c_errors: int
    eeprom_record_writes: tuple[int, ...]
    eeprom_max_cell_wear: tuple[int, ...]
    boots: tuple[int, ...]
    recoveries: tuple[int, ...]

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready mapping."""
        return {name: getattr(self, name) for name in self.__slots__}


class ArmEmulator:
    """The Igus RoboLink firmware of the paper, emulated; see ``docs/emulator.md``."""

    def __init__(self, robot: RobotSettings | None = None,
                 settings: EmulatorSettings | None = None, faults: Sequence[Fault] = (),
                 initial_q_rad: Sequence[float] | None = None,
                 resumed: bool | Sequence[bool] = False) -> None:
        """``initial_q_rad``: the joints' angles at power-up (rad; default 0: a new arm,
        assembled at its zero pose, its counters at 0 there and EEPROM blank). ``resumed``: an
        arm that ran before, stopped at that pose: each EEPROM holds a "stopped" record of it
        and each counter agrees with its Hall sensor, which has set it (the motor stands the
        Hall's position error away from the pose the counter says); per joint when a sequence
        (each joint's sensor sets its own counter, once the joint has passed it)."""
        self.robot = robot or RobotSettings()
        self.settings = settings or emulator_settings(self.robot)
        self.eeproms = [Eeprom(self.settings.eeprom_cells) for _ in self.robot.joints]
        q0 = list(initial_q_rad) if initial_q_rad is not None else [0.0] * len(self.robot.joints)
        ran = ([bool(resumed)] * len(q0) if isinstance(resumed, bool)
               else [bool(r) for r in resumed])
        if len(ran) != len(q0):
            raise ValueError(f"resumed names {len(ran)} joints; the arm has {len(q0)}")
        physics = self.settings.physics
        hall_error_rad = [0.0] * len(q0) if physics is None else [
            p.hall_error_rad if r else 0.0 for p, r in zip(physics.joints, ran, strict=True)]
        steps = [round((q + e) * j.steps_per_rad)
                 for q, e, j in zip(q0, hall_error_rad, self.robot.joints, strict=True)]
        for eeprom, q, j, r in zip(self.eeproms, q0, self.robot.joints, ran, strict=True):
            if r:
                eeprom.store("stopped", round(q * j.counts_per_rad))
                eeprom.land([0.0] * len(eeprom.last_written))
        self.clock = BusClock()
        self.bus = I2CBus(self.clock, self.settings.i2c_bit_s)
        # The Arduino core's receive buffer is a ring of rx_buffer_bytes that holds one byte
        # fewer (head == tail means empty): 63 of 64, as the reference firmware's.
        self.uart = Uart(self.robot.serial.byte_time_s, self.settings.rx_buffer_bytes - 1,
                         self.settings.tx_buffer_bytes)
        self.slaves = [SlaveBoard(k + 1, j, self.settings, self.eeproms[k], self.bus, steps[k])
                       for k, j in enumerate(self.robot.joints) if k > 0]
        self.master = MasterBoard(self.robot.joints[0], self.settings, self.eeproms[0], self.bus,
                                  self.uart, self.slaves, steps[0])
        self.boards: list[Board] = [self.master, *self.slaves]
        self.mechanism = None if physics is None else Mechanism(physics, self.robot,
                                                                self._link_angles_rad)
        """The arm's physics (gravity, deflection; ``fakes/twin/physics.py``); None when ideal."""
        self.actual_settings = self.robot if self.mechanism is None else self.mechanism.actual
        """The real arm's robot model (actual DH lengths and joint offsets): forward kinematics
        of :meth:`true_angles_rad` with it is the true TCP; the firmware and the host use the
        nominal ``robot``."""
        for b in self.boards:
            b.mechanism = self.mechanism
        self.truth: deque[TruthSample] = deque(maxlen=TRUTH_HISTORY)
        """Ground truth of each reply that reached the host (the newest last): ``truth[-1]``
        belongs to the newest reply the host has received."""
        self.uart.on_delivered = self.truth.append  # each reply's sample, the master's tag
        self.injector = FaultInjector(faults, self.settings.seed, self)
        self.bus.fault = self.injector.i2c_fault if faults else None
        self.uart.rx_filter = self.injector.to_robot if faults else None
        self.uart.tx_filter = self.injector.to_host if faults else None
        self.master.deferrable = not faults
        if any(f.after_frames is not None for f in faults):
            self.master.on_reply = self._on_reply  # counts the commands for their schedule
        self._commands_seen = 0
        self.started = False

    # lifecycle ---------------------------------------------------------------------------------
    async def start(self) -> None:
        """Power the arm up on the running loop and start the fault schedule."""
        if self.started:
            return
        self.started = True
        self.power_on()
        self.injector.start(self._now())
        await asyncio.sleep(0)

    async def close(self) -> None:
        """Power down and cancel everything (idempotent)."""
        self.injector.stop()
        self.power_off()
        self.started = False
        await asyncio.sleep(0)

    async def __aenter__(self) -> ArmEmulator:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # power -------------------------------------------------------------------------------------
    @property
    def powered(self) -> bool:
        """Whether the arm has power."""
        return self.master.powered

    def power_on(self) -> None:
        """Restore power to all four boards at the loop's now."""
        t = self._now()
        for b in self.boards:
            b.power_on(t)

    def power_off(self) -> None:
        """Cut power to all four boards at the loop's now."""
        t = self._now()
        for b in self.boards:
            b.power_off(t)
        self.uart.cut()

    def reset_board(self, joint: int) -> None:
        """Reboot one board (a brown-out or watchdog reset)."""
        board = self.boards[joint - 1]
        if board.powered:
            t = self._now()
            board.power_off(t)
            board.power_on(t)

    def set_stalled(self, joint: int, stalled: bool) -> None:
        """Block (or free) a joint mechanically."""
        self.boards[joint - 1].set_stalled(self._now(), stalled)

    def slave_address(self, joint: int) -> int:
        """The I²C address of joint 2..4."""
        address = self.robot.joints[joint - 1].i2c_address
        assert address is not None
        return address

    # host side ---------------------------------------------------------------------------------
    def attach_host(self, sink: Callable[[bytes], None]) -> None:
        """Connect a host: ``sink`` receives every chunk the master sends, at its arrival time."""
        self.uart.host_sink = sink

    def detach_host(self) -> None:
        """Disconnect the host; the master's prints go nowhere."""
        self.uart.host_sink = None

    def host_write(self, data: bytes) -> None:
        """The host sends bytes now."""
        self.uart.host_write(data, self._now())

    # ground truth --------------------------------------------------------------------------------
    def true_angles_rad(self) -> tuple[float, ...]:
        """The real joint angles now (protocol convention), as a laser tracker would see them.

        A board's joint is never moved backwards in time: while the master is inside a loop its
        joints may already stand up to one loop (~2.4 ms) ahead of the loop's clock.
        """
        t = self._now()
        out = []
        for b in self.boards:
            if b.model is not None:
                b.sync(t)
            out.append(b.true_rad())
        if self.mechanism is not None:
            return self.mechanism.true_rad(out)
        return tuple(out)

    def true_position_m(self) -> tuple[float, float, float]:
        """The real TCP position now (m, base frame): the true joints through the actual
        kinematics."""
        p = tcp_position(self.true_angles_rad(), self.actual_settings)
        return float(p[0]), float(p[1]), float(p[2])

    def _link_angles_rad(self) -> list[float]:
        """The joints' link angles where they stand, before the stick-slip (no syncing: called
        from inside a joint's event, gravity needs the others' angles as they are)."""
        return [b.true_rad() if b.model is None else b.model.loaded_angle_rad()
                for b in self.boards]

    def firmware_angles_rad(self) -> tuple[float | None, ...]:
        """What each board's encoder counter says now (``None`` without power)."""
        t = self._now()
        out: list[float | None] = []
        for b in self.boards:
            if b.model is None:
                out.append(None)
                continue
            b.sync(t)
            out.append(b.counter_rad())
        return tuple(out)

    def _on_reply(self, reply: bytes, sample: TruthSample) -> None:
        while self._commands_seen < self.master.commands:
            self._commands_seen += 1
            self.injector.on_command(self._commands_seen)

    # statistics ----------------------------------------------------------------------------------
    def stats(self) -> ArmStats:
        """Counters so far."""
        if self.started:
            self._now()
        return ArmStats(
            loops=self.master.loops, commands=self.master.commands,
            rx_bytes=self.uart.rx_bytes, rx_overflow_bytes=self.uart.rx_overflow_bytes,
            tx_bytes=self.uart.tx_bytes, i2c_transactions=self.bus.stats.transactions,
            i2c_errors=self.master.i2c_errors,
            eeprom_record_writes=tuple(e.record_writes for e in self.eeproms),
            eeprom_max_cell_wear=tuple(e.max_cell_wear for e in self.eeproms),
            boots=tuple(b.boots for b in self.boards),
            recoveries=tuple(b.recoveries for b in self.boards),
        )

    @staticmethod
    def eeprom_rated_cycles() -> int:
        """Rated write cycles per cell (ATmega328P)."""
        return RATED_CYCLES

    def _now(self) -> float:
        """The loop's time, with every main loop due by then run (see ``MasterBoard.catch_up``):
        whatever the caller looks at or changes happens after them, as in the firmware."""
        t = asyncio.get_running_loop().time()
        self.master.catch_up(t)
        return t
