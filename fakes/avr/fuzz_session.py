"""One UART session on both sides of the differential fuzzer: the emulator and the firmware.

A :class:`Session` is host writes and power cuts at simulated times. :func:`run_emulator_session`
plays it to the Python emulator on a virtual-time loop, :func:`run_firmware_session` to the
firmware in the simavr harness at full speed (its ``--script``); both give an :class:`Outcome`:
every command the master took (time, command), its replies, when its receive buffer dropped bytes,
and (firmware) the flash addresses it executed. :func:`divergences` compares two outcomes: the
commands taken must be the same, in the same order; the replies must agree within the
differential check's tolerances (``fakes/avr/differential.py``). What is compared, and what is
excused, is in ``docs/fuzzing.md``.

A session's text form is the harness's script (``<seconds> @hex <bytes>``, ``<seconds> @power
off|on``) after a ``# until <seconds>`` line, so a saved session is also a harness script.
"""

from __future__ import annotations

import asyncio
import bisect
import itertools
import subprocess
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from armbench.drivers.model.protocol import Command, Framer, Reply
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.avr.differential import TICKS_HALF_TURN, TICKS_TURN, compare
from armbench.fakes.avr.harness import HARNESS_NAME, board_specs, build, data_symbols, find_images
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.arm_emulator import ArmEmulator
from armbench.fakes.firmware.eeprom import RECORD_BYTES, EepromRecord, decode_record
from armbench.fakes.firmware.emulator_settings import emulator_settings, with_emulator_overrides

__all__ = [
    "BOOT_S",
    "BYTE_S",
    "Event",
    "Outcome",
    "Power",
    "Session",
    "Write",
    "divergences",
    "run_emulator_session",
    "run_firmware_session",
]

#: One byte on the line at 115 200 baud, 8N1 (the robot settings' default serial).
BYTE_S = RobotSettings().serial.byte_time_s
#: From power-up to ``Serial.begin()``: ``emulator.boot_s``, the harness's ``--boot-ms``.
BOOT_S = 0.1
#: The differential check's tolerances (docs/firmware.md): one loop period, 5 encoder counts.
WINDOW_S = 3.2e-3
TOL_COUNTS = 5.0
#: Largest difference between the times the two masters take the same command: a loop each
#: (2.4 and 3.0 ms) plus the longest EEPROM record stall of a loop (16.5 ms), with margin.
TAKE_LAG_S = 0.025
#: Added to that difference: the two masters order their loop's I²C transactions alike but do not
#: time them to the microsecond (one transaction is 0.3–0.5 ms), so a slave gets a command that
#: much earlier or later on one side.
TRANSACTION_S = 0.6e-3
#: A firmware reply this long after the one before followed a stall of the loop (its period is
#: 3.0 ms; an EEPROM record stalls it 3.3 ms a changed byte).
STALL_S = 4.5e-3
#: A joint that moved this shortly before a power cut may have stopped (or started) before it on
#: one side and not on the other (see ``_cuts_compared``).
SETTLE_S = 0.03
#: A reply on one side must have one on the other side within this (the longest stall above).
SILENCE_S = 0.025
#: How far apart the two sides may start writing the same EEPROM cell: each writes a record at its
#: loop's store after the motion change (a master loop apart at most, 3.0 ms, and the two loops'
#: store points differ by a few tenths of a millisecond), then a cell every 3.3 ms on both.
RECORD_PHASE_S = 3.6e-3


@dataclass(frozen=True)
class Write:
    """The host writes ``data`` at ``at_s`` (queued behind bytes still on the line)."""

    at_s: float
    data: bytes


@dataclass(frozen=True)
class Power:
    """All four boards lose (``on`` False) or regain power at ``at_s``."""

    at_s: float
    on: bool


Event = Write | Power


@dataclass(frozen=True)
class Session:
    """Host writes and power cuts from a power-up at t = 0 until ``until_s``."""

    events: tuple[Event, ...]
    until_s: float

    def to_text(self) -> str:
        """The harness script of the session, after a ``# until`` line."""
        lines = [f"# until {self.until_s:.6f}"]
        for e in self.events:
            if isinstance(e, Write):
                lines.append(f"{e.at_s:.6f} @hex {e.data.hex()}")
            else:
                lines.append(f"{e.at_s:.6f} @power {'on' if e.on else 'off'}")
        return "\n".join(lines) + "\n"

    @classmethod
    def from_text(cls, text: str) -> Session:
        """Read :meth:`to_text`'s form back."""
        until = 0.0
        events: list[Event] = []
        for line in text.splitlines():
            parts = line.split()
            if parts[:2] == ["#", "until"]:
                until = float(parts[2])
            elif len(parts) == 3 and parts[1] == "@hex":
                events.append(Write(float(parts[0]), bytes.fromhex(parts[2])))
            elif len(parts) == 3 and parts[1] == "@power":
                events.append(Power(float(parts[0]), parts[2] == "on"))
            elif line.strip() and not line.startswith("#"):
                raise ValueError(f"not a session line: {line!r}")
        return cls(tuple(sorted(events, key=lambda e: e.at_s)), until)


@dataclass
class Outcome:
    """What one side did with a session."""

    taken: list[tuple[float, Command]] = field(default_factory=list)
    """Every valid command the master took, with the time it took it."""
    replies: list[tuple[float, Reply]] = field(default_factory=list)
    overflows: list[float] = field(default_factory=list)
    """Times at which the master's receive buffer had dropped bytes."""
    pcs: dict[int, set[int]] = field(default_factory=dict)
    """Firmware only (with coverage): flash byte addresses executed, per joint 1..4."""
    edges: set[int] = field(default_factory=set)
    """Firmware only (with coverage): the master's branch-edge hashes."""
    eeprom_writes: list[list[tuple[float, int, int]]] = field(
        default_factory=lambda: [[] for _ in range(4)])
    """Per joint 1..4, each EEPROM cell write: (start time, address, value); the emulator's as
    planned, also those a power cut then took back."""
    records_at_cuts: list[tuple[float, tuple[bytes, ...]]] = field(default_factory=list)
    """At each power cut, each joint's EEPROM record cells as the cut left them."""


def _ideal_robot() -> RobotSettings:
    """The emulator without physics (the harness's joints have none), as the differential check."""
    return with_emulator_overrides(RobotSettings(), profile="ideal")


def run_emulator_session(session: Session, robot: RobotSettings | None = None) -> Outcome:
    """Play the session to the emulator on virtual time (and :data:`SILENCE_S` beyond its end,
    for the comparison of the firmware's last replies); ``robot``: its settings (default: the
    default arm without physics, as the harness's joints)."""
    robot = robot if robot is not None else _ideal_robot()

    async def main() -> Outcome:
        loop = asyncio.get_running_loop()
        out = Outcome()
        replies = Framer("reply")
        arm = ArmEmulator(robot, emulator_settings(robot))
        arm.attach_host(lambda data: out.replies.extend(
            (loop.time(), r) for r in replies.feed(data) if isinstance(r, Reply)))
        uart = arm.uart
        shadow = [Framer("command")]  # fed what the master's framer is fed: same verdicts
        seen_overflow = [uart.rx_overflow_bytes]

        def taken(t_s: float, data: bytes) -> None:
            if uart.rx_overflow_bytes > seen_overflow[0]:
                out.overflows.append(t_s - t0)
                seen_overflow[0] = uart.rx_overflow_bytes
            out.taken.extend((t_s - t0, c) for c in shadow[0].feed(data)
                             if isinstance(c, Command))

        uart.rx_tap = taken
        for eeprom, writes in zip(arm.eeproms, out.eeprom_writes, strict=True):
            eeprom.write_log = writes
        t0 = loop.time()
        await arm.start()
        for event in session.events:
            await asyncio.sleep(max(0.0, t0 + event.at_s - loop.time()))
            if isinstance(event, Write):
                arm.host_write(event.data)
            elif event.on:
                arm.power_on()
            else:
                arm.power_off()
                out.records_at_cuts.append((event.at_s, tuple(e.read(0, RECORD_BYTES)
                                                              for e in arm.eeproms)))
                shadow[0] = Framer("command")  # the master's framer is new at the next boot
        # on past the end, so the firmware's last replies have the emulator's on both sides
        await asyncio.sleep(max(0.0, t0 + session.until_s + SILENCE_S - loop.time()))
        await arm.close()
        out.replies = [(t - t0, r) for t, r in out.replies]
        out.eeprom_writes = [[(t - t0, a, v) for t, a, v in w] for w in out.eeprom_writes]
        return out

    return run_virtual(main)


def _harness_args(coverage: Path | None, events: Path, images: list[Path]) -> list[str]:
    args = ["--event-log", str(events)]
    symbols = data_symbols(images[0], ("cmd_ticks", "cmd_duty"))
    if len(symbols) == 2:
        args += ["--command-vars", f"{symbols['cmd_ticks']:#x},{symbols['cmd_duty']:#x}"]
    if coverage is not None:
        args += ["--coverage", str(coverage)]
    return args


def _read_events(text: str, out: Outcome) -> None:
    cells = [bytearray(b"\xff" * RECORD_BYTES) for _ in range(4)]  # the harness starts blank
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 4 and parts[1] == "cmd":
            out.taken.extend((float(parts[0]), c) for c in Framer("command").feed(
                parts[3].encode()) if isinstance(c, Command))
        elif len(parts) == 3 and parts[1] == "overflow":
            out.overflows.append(float(parts[0]))
        elif len(parts) == 5 and parts[1] == "eeprom":
            joint, address, value = int(parts[2]), int(parts[3]), int(parts[4], 16)
            out.eeprom_writes[joint - 1].append((float(parts[0]), address, value))
            if address < RECORD_BYTES:
                cells[joint - 1][address] = value
        elif parts[1:] == ["power", "off"]:
            out.records_at_cuts.append((float(parts[0]), tuple(bytes(c) for c in cells)))


def _read_coverage(text: str, out: Outcome) -> None:
    for line in text.splitlines():
        parts = line.split()
        if parts and parts[0] == "pcs":
            out.pcs[int(parts[1])] = {int(p, 16) for p in parts[2:]}
        elif parts and parts[0] == "edges":
            out.edges = {int(p, 16) for p in parts[1:]}


def run_firmware_session(session: Session, *, coverage: bool = False,
                         firmware: str | None = None,
                         robot: RobotSettings | None = None) -> Outcome:
    """Play the session to the firmware in the harness (full speed, simulated time), the
    reference firmware built with ``robot``'s choices (``firmware_defines``) when given."""
    exe = build() / HARNESS_NAME
    images = find_images(firmware, robot)
    with tempfile.TemporaryDirectory(prefix="armbench-diff-") as tmp:
        script, replies = Path(tmp, "script.txt"), Path(tmp, "replies.txt")
        events, cov = Path(tmp, "events.txt"), Path(tmp, "coverage.txt")
        script.write_text(session.to_text())
        args = [str(exe), "--speed", "max", "--seconds", f"{session.until_s:.6f}",
                "--boot-ms", str(BOOT_S * 1e3), "--script", str(script),
                "--reply-log", str(replies),
                *_harness_args(cov if coverage else None, events, images)]
        for spec in board_specs(RobotSettings(), images):
            args += ["--board", spec]
        subprocess.run(args, stdin=subprocess.DEVNULL, capture_output=True, check=True,
                       timeout=120)
        out = Outcome()
        framer = Framer("reply")
        for line in replies.read_text().splitlines():
            t, _, text = line.partition(" ")
            out.replies.extend((float(t), r) for r in framer.feed(text.encode())
                               if isinstance(r, Reply))
        _read_events(events.read_text(), out)
        if coverage:
            _read_coverage(cov.read_text(), out)
        return out


def _taken_differences(emu: Outcome, fw: Outcome, until_s: float) -> list[str]:
    """The commands taken, compared exactly: each one a side took must be the other's command
    of the same rank. Not those taken in the session's last :data:`TAKE_LAG_S` (the other side
    may take them after the end), nor once either side's receive buffer has dropped bytes (at a
    moment each side's loop timing decides)."""
    cut = min([*emu.overflows, *fw.overflows, until_s]) - TAKE_LAG_S
    found = []
    for name, a, b in (("emulator", emu.taken, fw.taken), ("firmware", fw.taken, emu.taken)):
        other = "firmware" if name == "emulator" else "emulator"
        for k, (t, command) in enumerate(a):
            if t >= cut:
                break
            if k >= len(b):
                found.append(f"the {name} took {command.encode().decode()} at {t:.4f} s, "
                             f"the {other} took only {len(b)} commands")
                return found
            t_b, command_b = b[k]
            if command_b != command:
                found.append(f"command {k + 1}: the {name} took {command.encode().decode()} at "
                             f"{t:.4f} s, the {other} {command_b.encode().decode()} at "
                             f"{t_b:.4f} s")
                return found
            if abs(t_b - t) > TAKE_LAG_S:
                found.append(f"command {k + 1} {command.encode().decode()}: taken at {t:.4f} s "
                             f"by the {name}, {t_b:.4f} s by the {other}")
                return found
    return found


def _silences(a: list[tuple[float, Reply]], b: list[tuple[float, Reply]], name: str,
              until_s: float) -> list[str]:
    """Replies of one side with none of the other within :data:`SILENCE_S` (the session's last
    :data:`SILENCE_S` aside: the other side's reply may fall after the end)."""
    times = [t for t, _ in b]
    k = 0
    for t, reply in a:
        if t > until_s - SILENCE_S:
            break
        while k < len(times) and times[k] < t - SILENCE_S:
            k += 1
        if k == len(times) or times[k] > t + SILENCE_S:
            return [f"the {name} replied {reply.encode().decode()} at {t:.4f} s, the other side "
                    f"not within {SILENCE_S * 1e3:.0f} ms"]
    return []


def _take_lag(emu: Outcome, fw: Outcome) -> Callable[[float], float]:
    """At time t, how far apart in time the two sides' joints may be: the sum, over the commands
    taken by t, of how far apart the two masters took each (and :data:`TRANSACTION_S`). A move
    set off that much later on one side runs that far behind; a hold or a reversal taken that
    much later or earlier adds its own difference, and the joint stops that much further on
    until a later move reaches its target."""
    matched = itertools.takewhile(lambda pair: pair[0][1] == pair[1][1],
                                  zip(emu.taken, fw.taken, strict=False))
    pairs = sorted((min(a, b), abs(a - b) + TRANSACTION_S) for (a, _), (b, _) in matched)
    starts = [p[0] for p in pairs]
    total = list(itertools.accumulate(p[1] for p in pairs))

    def lag(t: float) -> float:
        k = bisect.bisect_right(starts, t)
        return total[k - 1] if k else 0.0

    return lag


def _speeds(replies: list[tuple[float, Reply]]) -> list[float]:
    """Each joint's fastest motion between two successive replies, counts per second."""
    robot = RobotSettings()
    fastest = [0.0] * 4
    for (t0, a), (t1, b) in itertools.pairwise(replies):
        if t1 > t0:
            for j, joint in enumerate(robot.joints):
                ticks = abs((b[j] - a[j] + TICKS_HALF_TURN) % TICKS_TURN - TICKS_HALF_TURN)
                fastest[j] = max(fastest[j], ticks * joint.counts_per_rad / 1e4 / (t1 - t0))
    return fastest


def _agree_until(emu: Outcome, fw: Outcome, until_s: float) -> float:
    """Until when the two masters had taken the same commands (the end of the session if they
    always had): the replies are compared up to then. Commands taken differently after an
    overflow are excused (:func:`_taken_differences`), and so are the motions that follow."""
    for k in range(max(len(emu.taken), len(fw.taken))):
        a = emu.taken[k] if k < len(emu.taken) else None
        b = fw.taken[k] if k < len(fw.taken) else None
        if a is None or b is None or a[1] != b[1]:
            return min(pair[0] for pair in (a, b) if pair is not None)
    return until_s


def _moving(replies: list[tuple[float, Reply]], cut_s: float,
            target: Command | None) -> list[tuple[bool, bool]]:
    """Per joint, whether it moved in the :data:`SETTLE_S` before a cut, and whether it surely
    moved through the cut: its last two replies differ and, at the speed between them, it was
    more than :data:`SETTLE_S` / 3 from its target."""
    before = [(t, r) for t, r in replies if cut_s - SETTLE_S - 0.005 <= t <= cut_s]
    out = []
    for j in range(4):
        values = [r[j] for _, r in before]
        moved = len(set(values)) > 1
        through = moved and values[-1] != values[-2]
        if through and target is not None:
            (t0, r0), (t1, r1) = before[-2], before[-1]
            speed = abs(_ticks_apart(r1[j], r0[j])) / max(t1 - t0, 1e-6)
            left = abs(_ticks_apart(target.ticks[j], r1[j]))
            through = left > speed * (cut_s - t1 + SETTLE_S / 3)
        out.append((moved, through))
    return out


def _ticks_apart(a: int, b: int) -> int:
    """a - b on the circle of wire ticks."""
    return (a - b + TICKS_HALF_TURN) % TICKS_TURN - TICKS_HALF_TURN


def _in_force(side: Outcome, t_s: float) -> Command | None:
    """The last command a side took by ``t_s``."""
    taken = [c for t, c in side.taken if t <= t_s]
    return taken[-1] if taken else None


def _same_record(a: EepromRecord | None, b: EepromRecord | None, tol_counts: float) -> bool:
    """Whether two records make the same start-up: both blank, both "moving" the same way (the
    drive to the Hall sensor), or both "stopped" at counters within ``tol_counts``."""
    if a is None or b is None:
        return a is b
    return a.motion == b.motion and (a.motion != "stopped"
                                     or abs(a.counter - b.counter) <= tol_counts)


def _record_at(side: Outcome, cut_s: float) -> tuple[bytes, ...] | None:
    return next((cells for t, cells in side.records_at_cuts if abs(t - cut_s) < 1e-4), None)


def _records_near(session: Session, emu: Outcome, joint: int, cut_s: float) -> list[bytes]:
    """The emulator's record cells of ``joint`` (0..3) at every moment within
    :data:`RECORD_PHASE_S` of the cut at ``cut_s`` at which it wrote a cell, had the cut not
    come, and just before the first such write (none: no write that near): the cells the last
    cut left (blank at first), then the writes planned since the boards' last boot."""
    earlier = [e for e in session.events if isinstance(e, Power) and e.at_s < cut_s]
    last_cut = max((e.at_s for e in earlier if not e.on), default=None)
    booted_s = max((e.at_s for e in earlier if e.on), default=0.0) + BOOT_S
    base = _record_at(emu, last_cut) if last_cut is not None else None
    cells = bytearray(base[joint] if base is not None else b"\xff" * RECORD_BYTES)
    seen: list[bytes] = []
    for t, address, value in emu.eeprom_writes[joint]:
        if t < booted_s - 1e-6 or address >= RECORD_BYTES:
            continue
        if t > cut_s + RECORD_PHASE_S:
            break
        if t >= cut_s - RECORD_PHASE_S and not seen:
            seen.append(bytes(cells))
        cells[address] = value
        if t >= cut_s - RECORD_PHASE_S:
            seen.append(bytes(cells))
    return seen


def _cuts_compared(session: Session, emu: Outcome,
                   fw: Outcome) -> tuple[float, list[str]]:
    """Until when the comparison runs past power cuts, and how the two sides' EEPROM records
    differed at a cut where nothing excuses it.

    At each cut each joint's record (as the cut left it, torn if it came in the middle of a
    write) must make the same start-up on both sides: a "stopped" record's counter within the
    replies' tolerance (:data:`TOL_COUNTS`, widened by the take lags at the joint's fastest
    speed, as :func:`divergences` compares positions). Records that differ are excused, and the
    comparison stops at the cut, where the emulator's record was the firmware's at some moment
    within :data:`RECORD_PHASE_S` of the cut (the two sides write the same cells that far apart,
    so a cell written just before the cut on one side may come just after it on the other), or
    where the joint moved shortly before the cut and was not moving at the cut on both sides (it
    may have stopped or started on one side and not yet on the other: the records then differ
    in their state). Records that differ otherwise are a divergence.

    Records that agree and say joint 1 was moving also end the comparison at the cut: at the
    power-up the master drives its joint to the Hall sensor before its loop starts, each side from
    where the joint stood at the cut, which the two know only within the take lags, and the
    drive at the recovery duty stretches that difference into the time of the master's first
    reply (a reversal taken some milliseconds apart, tens of milliseconds between the first
    replies). A slave's drive goes on while the master replies, its position within the replies'
    tolerance, so it is compared.

    Cuts after the first command the two masters took differently are not compared, as the
    replies are not (:func:`_agree_until`): the records then follow different commands. Only a
    receive-buffer overflow excuses such a command (:func:`_taken_differences` reports it
    otherwise), and whether a buffer overflows depends on when each loop last read it before a
    stall (an EEPROM record stalls a loop up to 16.5 ms)."""
    agree_s = _agree_until(emu, fw, session.until_s)
    lag = _take_lag(emu, fw)
    speeds = [max(a, b) for a, b in zip(_speeds(emu.replies), _speeds(fw.replies), strict=True)]
    for event in session.events:
        if not isinstance(event, Power) or event.on:
            continue
        cut = event.at_s
        if cut >= agree_s:
            break
        cells_emu, cells_fw = _record_at(emu, cut), _record_at(fw, cut)
        if cells_emu is None or cells_fw is None:
            return cut, []  # one side had no power to lose
        a = _moving(emu.replies, cut, _in_force(emu, cut))
        b = _moving(fw.replies, cut, _in_force(fw, cut))
        for j in range(4):
            rec_emu, rec_fw = decode_record(cells_emu[j]), decode_record(cells_fw[j])
            tol = TOL_COUNTS + lag(cut) * speeds[j]
            if _same_record(rec_emu, rec_fw, tol):
                continue
            if any(_same_record(decode_record(near), rec_fw, tol)
                   for near in _records_near(session, emu, j, cut)):
                return cut, []  # a cell written on one side of the cut here, the other there
            (moved_a, at_cut_a), (moved_b, at_cut_b) = a[j], b[j]
            if (moved_a or moved_b) and not (at_cut_a and at_cut_b):
                return cut, []
            return cut, [f"joint {j + 1}: the power cut at {cut:.4f} s left the firmware's "
                         f"EEPROM record {rec_fw} ({cells_fw[j].hex()}), the emulator's "
                         f"{rec_emu} ({cells_emu[j].hex()})"]
        master = decode_record(cells_fw[0])
        if master is not None and master.motion != "stopped":
            return cut, []  # the master's loop waits for its drive to the Hall: not compared
    return session.until_s, []


def divergences(session: Session, emu: Outcome, fw: Outcome) -> list[str]:
    """Where the firmware and the emulator differ on ``session``: an empty list when they agree
    (commands taken exactly, replies within the differential check's tolerances)."""
    compared_until, found = _cuts_compared(session, emu, fw)
    found += _taken_differences(emu, fw, min(session.until_s, compared_until))
    end = min(session.until_s, _agree_until(emu, fw, session.until_s), compared_until)
    found += _silences(fw.replies, emu.replies, "firmware", end)
    found += _silences([(t, r) for t, r in emu.replies if t <= end], fw.replies, "emulator", end)
    cuts = [e.at_s for e in session.events if isinstance(e, Power) and not e.on]
    # a firmware reply just before a cut has no emulator reply after it (none comes in the cut)
    shown = [(t, r) for t, r in fw.replies
             if t <= end and not any(0 <= cut - t < SILENCE_S for cut in cuts)]
    diff = compare(shown, emu.replies, window_s=WINDOW_S, tol_counts=TOL_COUNTS,
                   widen_s=_take_lag(emu, fw),
                   speed_counts_per_s=[max(a, b) for a, b in zip(_speeds(emu.replies),
                                                                 _speeds(fw.replies),
                                                                 strict=True)],
                   stall_s=STALL_S)
    for j, (excess, at) in enumerate(zip(diff.excess_counts, diff.at_s, strict=True)):
        if excess > 0:
            found.append(f"joint {j + 1}: the firmware's position at {at:.4f} s is {excess:.1f} "
                         f"counts outside the emulator's (tolerance {TOL_COUNTS:.0f} counts over "
                         f"±{WINDOW_S * 1e3:.1f} ms, widened by the take lags)")
    return found
