"""The four Arduino boards: the master (joint 1, Algorithm 1) and three slaves (Algorithm 2).

Each board is one asyncio task while it has power. RAM (encoder counter, references, the PWM state
machine) is lost on a power cut; the EEPROM and the mechanics (motor position) are not. At power-up
each board runs the start-up procedure of §5.2 before its main loop: a record saying "stopped"
restores the counter; "moving CW/CCW" drives the joint the opposite way until the Hall sensor
resets the counter (and a joint driven into its hard limit instead stays there: a visible failure).

Time: the master keeps its own cursor (``BusClock``) advanced by its I²C traffic, EEPROM writes,
CPU time and blocking prints. Each main loop (with the default polling receive) is one timer
callback at the loop's start, so a loop costs one event-loop pass however many transactions it
makes, plus one for the delivery of its reply. Slaves answer the bus from its handlers (Arduino's
Wire ISRs) at the transaction's time; their tasks only run the start-up procedure.
"""

from __future__ import annotations

import asyncio
import logging
import math
from typing import Final

from armbench.drivers.model.protocol import TICKS_PER_RAD, ticks_to_rad
from armbench.drivers.model.settings import JointSettings
from armbench.fakes.firmware.eeprom import Eeprom, RecordWrites, record_write_times
from armbench.fakes.firmware.emulator_settings import EmulatorSettings
from armbench.fakes.firmware.i2c import (
    REG_POSITION,
    REG_REFERENCE,
    REG_STATUS,
    REG_WHO_AM_I,
    I2CBus,
)
from armbench.fakes.twin.joint import CYCLE_S, JointModel
from armbench.fakes.twin.physics import Mechanism, TruthSample

__all__ = ["NS_PER_CYCLE", "Board", "SlaveBoard", "TruthSample", "new_tuple", "round_even"]

log = logging.getLogger("armbench.emulator")

#: The 80 µs control cycle in nanoseconds. Cycle counts are taken from times since a board's
#: power-up rounded to the nanosecond, and the master's clock is put back on that nanosecond grid
#: after every loop: sums of bit times on an absolute float clock drift by ulps (~5e-13 s per
#: simulated second at 4..32 s of loop time), which made reads that fall exactly on a cycle edge
#: (every I²C time is whole 10 µs bits) count one cycle less at some absolute times than at
#: others. So a run measures the same whatever loop time it starts at.
NS_PER_CYCLE: Final = round(CYCLE_S * 1e9)


def round_even(x: float) -> int:
    """``round(x)`` (ties to even), in arithmetic compiled code does natively: the builtin is
    called through Python from compiled code, and every main loop rounds five times. ``x``
    minus its floor is exact in binary floating point, so the comparisons with 0.5 are too."""
    whole = math.floor(x)
    frac = x - whole
    if frac > 0.5 or (frac == 0.5 and whole % 2 == 1):
        return whole + 1
    return whole

new_tuple = tuple.__new__  # builds a NamedTuple without its Python-level __new__ (hot path)


class Board:
    """One board: its joint, EEPROM and power. Subclasses add the main loop."""

    def __init__(self, number: int, joint: JointSettings, settings: EmulatorSettings,
                 eeprom: Eeprom, motor_steps: int = 0) -> None:
        self.number = number
        self.joint = joint
        self.settings = settings
        self.eeprom = eeprom
        self.t0 = 0.0
        self.powered = False
        self.model: JointModel | None = None
        self._motor_steps = motor_steps
        self._task: asyncio.Task[None] | None = None
        self.boots = 0
        self.recoveries = 0
        self.reference: tuple[int, int] | None = None  # (wire ticks, duty) last applied
        self.last_truth_rad = motor_steps / joint.steps_per_rad
        self.last_firmware_rad = 0.0
        self.last_motor_rad = self.last_truth_rad
        self.mechanism: Mechanism | None = None
        """The arm's physics (gravity, deflection, play side); None: the ideal mechanism."""
        self.stalled = False
        self._counts_per_rad = joint.counts_per_rad
        self.unpaid_records: RecordWrites | None = None
        """The records whose write time the main loop still has to pay (the master's); None where
        nothing waits for them."""
        self.in_main_loop = False
        """Whether the main loop runs: it then writes the records at its store (the master);
        before it (start-up recovery), and always on a slave, a record is written as the motion
        changes."""
        self._eeprom_busy_s = -math.inf
        """Until when the EEPROM writes the records written as the motion changed."""

    # time ----------------------------------------------------------------------------------------
    def tick(self, t_s: float) -> int:
        """The board's control cycle count at ``t_s`` (cycles since its power-up)."""
        return round_even((t_s - self.t0) * 1e9) // NS_PER_CYCLE

    def sync(self, t_s: float) -> JointModel:
        """Bring the joint to ``t_s`` (never backwards) and store EEPROM records it produced."""
        model = self.model
        assert model is not None
        tick = self.tick(t_s)
        if tick > model.tick:
            model.advance(tick)
        if model.transitions:
            self.store_transitions()
        return model

    def store_transitions(self) -> int:
        """Write the EEPROM record for each motion change since the last call; cells written.

        Each cell's write gets the time the firmware starts it (a power cut before then leaves
        the cell as it was, :meth:`Eeprom.cut`): the master's main loop gives them when it pays
        the record at its store; otherwise the record is written from the motion change on, a
        cell after the other as the EEPROM frees (``record_write_times``)."""
        assert self.model is not None
        cells = 0
        eeprom, writes = self.eeprom, self.unpaid_records
        looping = self.in_main_loop
        for tick, motion, counter in self.model.drain_transitions():
            cells += eeprom.store(motion, counter)
            written = eeprom.last_written
            if writes is not None:
                writes.add(written, landed=not looping)
            if writes is None or not looping:
                starts: list[float] = []
                _, self._eeprom_busy_s = record_write_times(
                    written, self.t0 + tick * CYCLE_S, self._eeprom_busy_s,
                    self.settings.eeprom_write_s_per_byte, starts)
                eeprom.land(starts)
        return cells

    # conversions ---------------------------------------------------------------------------------
    def counter_rad(self) -> float:
        """The firmware's position belief, radians (protocol convention)."""
        assert self.model is not None
        return self.model.counter / self._counts_per_rad

    def sample_position(self, t_s: float) -> int:
        """The firmware reads its counter for a position report at ``t_s``: the joint is brought
        there, the truth and the belief beside the report are recorded; wire ticks."""
        model = self.model
        assert model is not None
        counter, self.last_truth_rad, self.last_motor_rad = model.sample(
            round_even((t_s - self.t0) * 1e9) // NS_PER_CYCLE)
        self.last_firmware_rad = q = counter / self._counts_per_rad
        return math.floor(q % math.tau * TICKS_PER_RAD + 0.5)  # rad_to_ticks(q), inline: hot

    def true_rad(self) -> float:
        """The joint angle after the gear play and stick-slip, radians (protocol convention;
        the arm adds the deflection under load)."""
        if self.model is None:
            return self.last_truth_rad
        return self.model.true_angle_rad()

    def apply_reference(self, t_s: float, ticks: int, duty: int) -> None:
        """Take a reference (wire ticks, duty) into the controller at ``t_s``."""
        if self.reference == (ticks, duty):
            return
        self.reference = (ticks, duty)
        model = self.sync(t_s)
        if model.homing:
            return  # held until start-up recovery ends (see _initialise)
        q = ticks_to_rad(ticks, self.joint.lower_rad, self.joint.upper_rad)
        model.set_reference(model.tick, round(q * self.joint.counts_per_rad), duty)

    # power ---------------------------------------------------------------------------------------
    def power_on(self, t_s: float) -> None:
        """Power the board: after the boot delay RAM starts blank, the start-up procedure runs,
        then the main loop."""
        if self.powered:
            return
        self.powered = True
        self.boots += 1
        self.in_main_loop = False
        self._eeprom_busy_s = -math.inf  # a cut ends the write under way
        self._task = asyncio.get_running_loop().create_task(self._boot(),
                                                            name=f"board-{self.number}")

    async def _boot(self) -> None:
        """Boot loader and clock start-up (``emulator.boot_s``), then ``setup()`` and the loop."""
        if self.settings.boot_s > 0:
            await asyncio.sleep(self.settings.boot_s)
        self._setup(asyncio.get_running_loop().time())
        await self._run()

    def _setup(self, t_s: float) -> None:
        """``setup()``: read the EEPROM record, restore the counter or start the drive to the
        Hall sensor (§5.2), start the 80 µs control cycle at ``t_s``."""
        self.t0 = t_s
        record = self.eeprom.load()
        counter = record.counter if record is not None else round(
            self._motor_steps * self.joint.counts_per_step)
        mechanism = self.mechanism
        physics = None if mechanism is None else mechanism.physics
        self.model = JointModel(
            self.joint, effects=self.settings.effects, seed=self.settings.seed * 31 + self.number
            + 1000 * self.boots, deadband_counts=self.settings.deadband_counts,
            stop_rule=self.settings.stop_rule,
            motor_steps=self._motor_steps, counter=counter, tick=0,
            physics=None if physics is None else physics.joints[self.number - 1],
            load=None if mechanism is None else mechanism.load_of(self.number - 1),
            noise_per_count=0.0 if physics is None else physics.noise_per_count)
        if self.stalled:
            self.model.stall(0, True)
        self.reference = None
        if record is not None and record.motion != "stopped":
            direction = -1 if record.motion == "cw" else 1
            self.model.home(0, direction, self.settings.recovery_duty)
            self.recoveries += 1
            log.info("joint %d: powered up after moving %s, driving %s to the Hall sensor",
                     self.number, record.motion, "CCW" if direction < 0 else "CW")
        self._on_power_on(t_s)

    def power_off(self, t_s: float) -> None:
        """Cut power at ``t_s``: the joint stops where it is, RAM is lost, EEPROM stays."""
        if not self.powered:
            return
        self.powered = False
        if self.model is not None:  # else still booting: nothing ran yet
            self.sync(t_s)
            self._motor_steps = self.model.motor_steps
            self.last_truth_rad = self.model.true_angle_rad()
            self._on_power_off()
        self.eeprom.cut(t_s)  # the record cells not yet written keep their old values
        if self._task is not None:
            self._task.cancel()
            self._task = None
        self.model = None

    def set_stalled(self, t_s: float, stalled: bool) -> None:
        """Fault: the joint is mechanically blocked (or freed)."""
        self.stalled = stalled
        if self.model is not None:
            self.sync(t_s)
            self.model.stall(self.model.tick, stalled)

    async def _initialise(self) -> None:
        """§5.2: wait for the drive to the Hall sensor (if any), then apply a held reference."""
        loop = asyncio.get_running_loop()
        model = self.model
        assert model is not None
        while model.homing:
            nxt = model.next_event_tick()
            if nxt is None:  # stalled against a hard limit: the firmware keeps trying forever
                await asyncio.Event().wait()
                return
            await asyncio.sleep(max(0.0, self.t0 + (nxt + 1) * CYCLE_S - loop.time()))
            self.sync(loop.time())
        held, self.reference = self.reference, None
        if held is not None:
            self.apply_reference(loop.time(), *held)

    async def _run(self) -> None:
        raise NotImplementedError

    def _on_power_on(self, t_s: float) -> None:
        """Hook: attach to the bus (slaves)."""

    def _on_power_off(self) -> None:
        """Hook: detach from the bus (slaves)."""

    def status_byte(self) -> int:
        """The STATUS register: moving, CW, recovering, stalled at a limit, initialised."""
        model = self.model
        if model is None:
            return 0
        motion = model.motion
        return ((motion != "stopped") | (motion == "cw") << 1 | model.homing << 2
                | (model.homing and model.at_limit) << 3 | (not model.homing) << 4)


class SlaveBoard(Board):
    """Joints 2–4 (Algorithm 2): answer the master on I²C, run the joint."""

    def __init__(self, number: int, joint: JointSettings, settings: EmulatorSettings,
                 eeprom: Eeprom, bus: I2CBus, motor_steps: int = 0) -> None:
        super().__init__(number, joint, settings, eeprom, motor_steps)
        assert joint.i2c_address is not None
        self.address = joint.i2c_address
        self.bus = bus
        self._pointer = REG_POSITION
        self.last_write = b""
        """The last reference write the board took (the master repeats it every loop)."""
        self.on_bus = False
        """Whether the board answers on the bus (after ``Wire.begin``, until power-off)."""
        self.bad_writes = 0

    def _on_power_on(self, t_s: float) -> None:
        self._pointer = REG_POSITION
        self.last_write = b""
        self.bus.attach(self.address, self)  # Wire.begin(address) comes first in setup()
        self.on_bus = True

    def _on_power_off(self) -> None:
        self.bus.detach(self.address)
        self.on_bus = False

    async def _run(self) -> None:
        await self._initialise()
        await asyncio.Event().wait()  # the rest happens in the Wire handlers

    # Wire handlers -------------------------------------------------------------------------------
    def on_receive(self, data: bytes, t_s: float) -> None:
        """onReceive: a register pointer, optionally followed by a reference."""
        if data == self.last_write:  # the master repeats its reference every loop
            self._pointer = REG_POSITION
            return
        if not data:
            return
        register = data[0]
        if register == REG_REFERENCE and len(data) == 4:
            ticks = data[1] | data[2] << 8
            duty = data[3]
            if ticks > 62_832 or duty > 99:
                self.bad_writes += 1
            else:
                self.apply_reference(t_s, ticks, duty)
                self.last_write = data
            self._pointer = REG_POSITION
        elif len(data) == 1 and register in (REG_POSITION, REG_STATUS, REG_WHO_AM_I):
            self._pointer = register
        else:
            self.bad_writes += 1

    def on_request(self, length: int, t_s: float) -> bytes:
        """onRequest: the register the pointer names; the pointer returns to POSITION."""
        register = self._pointer
        if register != REG_POSITION:
            self._pointer = REG_POSITION
            self.sync(t_s)
            return bytes((self.status_byte() if register == REG_STATUS else 0xA0 | self.number,))
        return self.read_position(t_s).to_bytes(2, "little")

    def read_position(self, t_s: float) -> int:
        """The POSITION register read at ``t_s`` (the pointer left on POSITION): the counter in
        wire ticks, the truth and the belief beside it recorded (:meth:`sample_position`,
        inline: three calls per main loop)."""
        self._pointer = REG_POSITION
        model = self.model
        assert model is not None
        counter, self.last_truth_rad, self.last_motor_rad = model.sample(
            round_even((t_s - self.t0) * 1e9) // NS_PER_CYCLE)
        self.last_firmware_rad = q = counter / self._counts_per_rad
        if model.transitions:
            self.store_transitions()
        return math.floor(q % math.tau * TICKS_PER_RAD + 0.5)
