"""The master board (joint 1, Algorithm 1): the UART command, the I²C round of the slaves, the
EEPROM record and the reply, one main loop at a time on the master's own bus clock
(:class:`~armbench.fakes.firmware.i2c.BusClock`). The board's power, EEPROM and joint are
:class:`~armbench.fakes.firmware.boards.Board`'s; the slaves are in
:mod:`armbench.fakes.firmware.boards`.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Generator
from ctypes import create_string_buffer

from armbench.drivers.model.protocol import TICKS_PER_RAD, Command, Framer, encode_reply
from armbench.drivers.model.settings import JointSettings
from armbench.fakes.firmware.boards import NS_PER_CYCLE, Board, SlaveBoard, new_tuple, round_even
from armbench.fakes.firmware.eeprom import Eeprom, RecordWrites
from armbench.fakes.firmware.emulator_settings import EmulatorSettings
from armbench.fakes.firmware.i2c import REG_REFERENCE, BusClock, I2CBus
from armbench.fakes.firmware.i2c_messages import I2C_M_RD, I2CMessage
from armbench.fakes.firmware.uart import Uart
from armbench.fakes.twin.physics import TruthSample

__all__ = ["MAX_LAG_S", "MasterBoard"]

#: A master whose cursor falls this far behind the loop's clock (real time, busy CPU) resynchronises
#: instead of trying to catch up with a burst of loops.
MAX_LAG_S = 0.05


class MasterBoard(Board):
    """Joint 1 (Algorithm 1): UART to the host, I²C master of the slaves."""

    def __init__(self, joint: JointSettings, settings: EmulatorSettings, eeprom: Eeprom,
                 bus: I2CBus, uart: Uart, slaves: list[SlaveBoard], motor_steps: int = 0,
                 on_reply: Callable[[bytes, TruthSample], None] | None = None) -> None:
        super().__init__(1, joint, settings, eeprom, motor_steps)
        self.bus = bus
        self.clock: BusClock = bus.clock
        self.uart = uart
        self.slaves = slaves
        self.on_reply = on_reply
        self.loops = 0
        self.commands = 0
        self.i2c_errors = 0
        self.framer = Framer("command")
        self.unpaid_records = RecordWrites(settings.eeprom_write_s_per_byte, eeprom)
        self._timer: asyncio.TimerHandle | None = None
        self._run_due: Callable[[float], None] | None = None
        self.deferrable = False
        """Whether a main loop may run at the delivery of the previous reply rather than at its
        own start (see :meth:`_run_polling`); the arm sets it when no fault is scheduled, as a
        fault's hooks answer by the time of the call."""

    def _on_power_on(self, t_s: float) -> None:
        self.framer = Framer("command")
        self.unpaid_records = RecordWrites(self.settings.eeprom_write_s_per_byte, self.eeprom)
        self.clock.now = t_s
        self.uart.begin(t_s)

    def _on_power_off(self) -> None:
        self._run_due = self.uart.before_deliver = None
        if self._timer is not None:  # the task's cancellation comes later: a loop may be due now
            self._timer.cancel()
            self._timer = None

    async def _run(self) -> None:
        await self._initialise()
        loop = asyncio.get_running_loop()
        self.clock.now = max(self.clock.now, loop.time())
        if self.settings.uart_receive == "blocking":
            await self._run_blocking(loop)
        else:
            await self._run_polling(loop)

    async def _run_polling(self, loop: asyncio.AbstractEventLoop) -> None:
        """Main loops as timer callbacks, not task wake-ups (a future and a second pass each).

        When :attr:`deferrable`, a loop whose start falls before the delivery of the previous
        reply is run by that delivery instead of a timer of its own (``Uart.before_deliver``), just
        before the reply reaches the host: one event-loop pass per loop. Nothing can tell the
        difference: the loop reads the UART bytes complete at its start, as before, and whoever
        looks at the arm in between (host writes, ground truth, power) goes through
        :meth:`catch_up` first. The task waits here until power-off cancels it, or ends with the
        exception of a failed loop."""
        loops = self._main_loops(loop, None)
        failed: asyncio.Future[None] = loop.create_future()
        boot = self.boots
        uart = self.uart
        due = -math.inf
        timer_at = math.nan

        def run_due(t_s: float) -> None:
            nonlocal due, timer_at
            while due <= t_s:
                try:
                    due = next(loops)
                except Exception as exc:
                    due = math.inf
                    if not failed.done():
                        failed.set_exception(exc)
                    return
                if not self.powered or self.boots != boot:  # a fault cut the power in that loop
                    due = math.inf
                    return
            if self.deferrable and uart.pending_delivery_s >= due:
                return
            if timer_at != due:
                if self._timer is not None:
                    self._timer.cancel()
                timer_at = due
                self._timer = loop.call_at(due, on_timer)

        def on_timer() -> None:
            nonlocal timer_at
            self._timer, timer_at = None, math.nan
            run_due(loop.time())

        self._run_due = run_due
        if self.deferrable:
            uart.before_deliver = run_due
        run_due(loop.time())
        await failed

    def catch_up(self, t_s: float) -> None:
        """Run the main loops due by ``t_s`` that were deferred (see :meth:`_run_polling`)."""
        run_due = self._run_due
        if run_due is not None:
            run_due(t_s)

    async def _run_blocking(self, loop: asyncio.AbstractEventLoop) -> None:
        """Each main loop starts with a blocking read of a whole command."""
        loops = self._main_loops(loop, await self._receive_blocking(self.framer, loop))
        start = next(loops)
        while True:
            resume: asyncio.Future[None] = loop.create_future()
            self._timer = loop.call_at(start, _wake, resume)
            await resume
            start = loops.send(await self._receive_blocking(self.framer, loop))

    def _main_loops(self, loop: asyncio.AbstractEventLoop,
                    received: Command | None) -> Generator[float, Command | None, None]:
        """Algorithm 1, one main loop per step; yields when the next loop starts: when this one
        ends (the master's clock), or now if the master has fallen behind.

        Each step is sent the command a blocking receive got, or None: the loop then polls the
        UART itself and keeps the last complete command.
        """
        clock = self.clock
        uart, bus, slaves, settings = self.uart, self.bus, self.slaves, self.settings
        line_end = settings.reply_line_end.encode()
        writes = self.unpaid_records
        assert writes is not None
        writes.pay(clock.now)  # the start-up recovery's records, written in setup()
        self.in_main_loop = True
        overhead_s = settings.loop_overhead_s
        # messages over buffers of our own (as I2CMessage.write/read build them), read and
        # filled through memoryviews: cheaper than ctypes item access on msg.buf
        ref_bufs = [create_string_buffer(bytes((REG_REFERENCE, 0, 0, 0)), 4) for _ in slaves]
        ref_msgs = [I2CMessage(addr=s.address, flags=0, len=4, buf=b)
                    for s, b in zip(slaves, ref_bufs, strict=True)]
        ref_views = [memoryview(b).cast("B") for b in ref_bufs]
        pos_bufs = [create_string_buffer(2) for _ in slaves]
        pos_msgs = [I2CMessage(addr=s.address, flags=I2C_M_RD, len=2, buf=b)
                    for s, b in zip(slaves, pos_bufs, strict=True)]
        pos_views = [memoryview(b).cast("B") for b in pos_bufs]
        positions = [0] * len(slaves)
        command: Command | None = None
        sent: Command | None = None
        framer = self.framer
        model = self.model
        assert model is not None
        t0, counts_per_rad = self.t0, self._counts_per_rad
        mechanism = self.mechanism
        s2, s3, s4 = slaves
        rdwr, read_available, write = bus.i2c_rdwr, uart.read_available, uart.write
        # the steady loop's traffic (see below), from these very messages: each transaction's
        # bytes as I2CBus.i2c_rdwr adds them up (so both give the same times), and its counts
        bit_s, stats = bus.bit_s, bus.stats
        write_s = (9 * ref_msgs[0].len + 10) * bit_s
        read_s = (9 * pos_msgs[0].len + 10) * bit_s
        steady_transactions = len(ref_msgs) + len(pos_msgs)
        steady_bytes = sum(m.len for m in ref_msgs) + sum(m.len for m in pos_msgs)
        fused = settings.fused_bus
        written = [b.raw for b in ref_bufs]  # what each reference write carries
        last = (-1, -1, -1, -1)  # the positions of the last reply
        reply = b""
        while True:
            # Receive reference poses and velocities from UART
            if received is not None:
                command = received
            else:
                data = read_available(clock.now)
                if data:
                    for event in framer.feed(data):
                        if isinstance(event, Command):
                            command = event
                            self.commands += 1
            new = command is not sent
            if new:
                assert command is not None
                for k, view in enumerate(ref_views):
                    t = command.ticks[k + 1]
                    view[1], view[2], view[3] = t & 0xFF, t >> 8, command.duties[k + 1]
                    written[k] = view.tobytes()
            if (fused and not new and bus.fault is None and s2.on_bus and s3.on_bus
                    and s4.on_bus and s2.last_write == written[0]
                    and s3.last_write == written[1] and s4.last_write == written[2]):
                # A steady loop (``emulator.fused_bus``): no new command, no fault hook on the
                # bus, every slave on it and holding the reference this loop repeats. The six
                # transactions below are then known to do just this: each repeated write puts
                # its slave's pointer back on POSITION, each read returns the POSITION
                # register. So they are run as that, at the very times i2c_rdwr gives them
                # (same sums), without the bus's message decoding and handler dispatch, which
                # were half of a loop's cost. tests/test_emulator.py checks both ways agree.
                stats.transactions += steady_transactions
                stats.bytes += steady_bytes
                now = clock.now + bit_s + write_s + bit_s + write_s + bit_s + write_s + bit_s
                now += read_s
                positions[0] = s2.read_position(now)
                now = now + bit_s + read_s
                positions[1] = s3.read_position(now)
                now = now + bit_s + read_s
                positions[2] = s4.read_position(now)
                clock.now = now
            else:
                # Update reference pose and velocity of joints 2..4 through I2C (every loop;
                # until the first command the references are "hold", duty 00)
                for msg in ref_msgs:
                    try:
                        rdwr(msg)
                    except OSError:
                        self.i2c_errors += 1
                # Update reference pose of joint 1
                if new:
                    assert command is not None
                    self.apply_reference(clock.now, command.ticks[0], command.duties[0])
                    sent = command
                # Request current pose of joints 2..4 through I2C
                for k, msg in enumerate(pos_msgs):
                    try:
                        rdwr(msg)
                    except OSError:
                        self.i2c_errors += 1  # keep the last value, as Wire.requestFrom's 0
                        continue
                    view = pos_views[k]
                    positions[k] = view[0] | view[1] << 8
            # Update current pose of joint 1 (sample_position, inline: hot)
            now = clock.now
            counter, self.last_truth_rad, self.last_motor_rad = model.sample(
                round_even((now - t0) * 1e9) // NS_PER_CYCLE)
            self.last_firmware_rad = q = counter / counts_per_rad
            own = math.floor(q % math.tau * TICKS_PER_RAD + 0.5)
            if model.transitions:
                self.store_transitions()
            if writes.pending:
                now = writes.pay(now)
            now += overhead_s
            # Pack all current poses and send through UART (an unchanged reply: the same bytes)
            p2, p3, p4 = positions[0], positions[1], positions[2]
            if own != last[0] or p2 != last[1] or p3 != last[2] or p4 != last[3]:
                last = (own, p2, p3, p4)
                reply = encode_reply(own, p2, p3, p4)
                if line_end:
                    reply += line_end
            sample = new_tuple(TruthSample, (
                now, (self.last_truth_rad, s2.last_truth_rad, s3.last_truth_rad,
                      s4.last_truth_rad),
                (self.last_firmware_rad, s2.last_firmware_rad, s3.last_firmware_rad,
                 s4.last_firmware_rad),
                (self.last_motor_rad, s2.last_motor_rad, s3.last_motor_rad, s4.last_motor_rad),
                mechanism))
            clock.now = write(reply, now, sample)
            self.loops += 1
            if self.on_reply is not None:
                self.on_reply(reply, sample)
            if clock.now < loop.time() - MAX_LAG_S:  # real time, busy CPU: drop the lag, no burst
                clock.now = loop.time()
            clock.now = t0 + round_even((clock.now - t0) * 1e9) * 1e-9  # see NS_PER_CYCLE
            received = yield clock.now

    async def _receive_blocking(self, framer: Framer, loop: asyncio.AbstractEventLoop) -> Command:
        """Wait for a whole command frame, reading bytes as they arrive (``readBytesUntil``)."""
        clock, uart = self.clock, self.uart
        since = clock.now
        while True:
            for event in framer.feed(uart.read_available(clock.now, continuous_since=since)):
                if isinstance(event, Command):
                    self.commands += 1
                    return event
            t_hash = uart.time_of_next(ord("#"))
            if t_hash is None:
                uart.rx_event.clear()
                await uart.rx_event.wait()
                clock.now = max(clock.now, loop.time())
            else:
                clock.now = max(clock.now, t_hash)
                await asyncio.sleep(max(0.0, t_hash - loop.time()))

def _wake(future: asyncio.Future[None]) -> None:
    """Timer callback ending the master's wait (its task may have been cancelled meanwhile)."""
    if not future.done():
        future.set_result(None)
