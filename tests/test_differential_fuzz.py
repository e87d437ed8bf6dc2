"""The differential fuzzer of the UART (``fakes/avr/fuzzer.py``, ``fakes/avr/fuzz_session.py``): a
few sessions on a fixed seed agree on both sides; the sessions kept in ``fuzz/corpus/differential``
(minimised divergences, fixed or explained) replay without divergence; and the comparison does
catch the firmware bugs it found (the old 16-bit position sum, the slave that waited for its
EEPROM record and the position report of a counter beyond 16 bits, rebuilt here). A power cut
during an EEPROM record tears it alike on both sides, and the records each cut leaves are
compared."""

from __future__ import annotations

import random
import shutil
from pathlib import Path

import pytest
from test_firmware import needs_toolchain

from armbench.drivers.model.protocol import rad_to_ticks
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.avr.fuzz_session import (
    BOOT_S,
    BYTE_S,
    Event,
    Outcome,
    Power,
    Session,
    Write,
    divergences,
    run_emulator_session,
    run_firmware_session,
)
from armbench.fakes.avr.fuzzer import Campaign, generate, minimise, normalise
from armbench.fakes.avr.harness import FIRMWARE_SOURCE, build
from armbench.fakes.firmware.eeprom import EepromRecord, decode_record

pytestmark = needs_toolchain

CORPUS = Path(__file__).resolve().parents[1] / "fuzz" / "corpus" / "differential"
OVERFLOW_FRAME = b"$99999,99,00000,00,00000,00,00000,00#"


def test_sessions_are_replayable_from_their_seed_and_text() -> None:
    a = [generate(random.Random(5)) for _ in range(3)]
    b = [generate(random.Random(5)) for _ in range(3)]
    assert a == b
    for session in a:
        assert Session.from_text(session.to_text()) == session


def test_no_byte_lands_on_a_receiver_edge() -> None:
    """Writes whose bytes would complete within a millisecond of the end of a boot are left out
    (the two sides start their receivers microseconds apart); others stay."""
    near = Write(BOOT_S - 10 * BYTE_S, b"$" * 20)
    clear = Write(BOOT_S + 0.01, b"#")
    cut: list[Event] = [Power(0.2, False), Power(0.21, True), Write(0.2 - 3 * BYTE_S, b"abcdef")]
    kept = normalise(Session((near, clear, *cut), 0.3)).events
    assert near not in kept and clear in kept and cut[2] not in kept
    assert cut[0] in kept and cut[1] in kept


def test_no_frame_ends_just_before_a_power_cut() -> None:
    """A frame completing 2.4 ms before a cut is taken by the emulator's loop (2.4 ms) and not by
    the firmware's (3.0 ms), or the other way round: such writes are left out of sessions."""
    ending = Write(0.180358, b",99#")
    session = Session((Write(0.169287, b"$02268,73,01807,99,02665,00,02"), ending,
                       Power(0.183064, False)), 0.3883)
    kept = normalise(session).events
    assert ending not in kept and len(kept) == 2
    assert Write(0.150, b",99#") in normalise(Session((Write(0.150, b",99#"), *kept[1:]),
                                                      0.3883)).events


@pytest.mark.parametrize(("noise", "taken"), [(26, 2), (27, 1)])
def test_both_receive_buffers_hold_63_bytes(noise: int, taken: int) -> None:
    """While the master recovers after a cut (its loop not reading), 26 bytes of noise and a
    command (63 bytes) all wait in the receive buffer and the command is taken afterwards; with
    27 the command's '#' is the 64th byte and is dropped, on both sides: the Arduino core's ring
    of 64 holds 63 (the emulator once held 64)."""
    frame = b"$00100,10,00000,00,00000,00,00000,00#"
    session = Session((Write(0.11, b"$01500,99,00000,00,00000,00,00000,00#"),
                       Power(0.2, False), Power(0.21, True),
                       Write(0.315, b"x" * noise + frame)), 0.9)
    emu, fw = run_emulator_session(session), run_firmware_session(session)
    assert [c for _, c in emu.taken] == [c for _, c in fw.taken]
    assert len(emu.taken) == taken
    assert bool(emu.overflows) == bool(fw.overflows) == (taken == 1)


def test_a_fixed_seed_campaign_finds_no_divergence() -> None:
    """Eight sessions of seed 2026 (generated, then mutated from the corpus), both sides."""
    campaign = Campaign(2026)
    for _ in range(8):
        assert campaign.run_one(minimise_budget=0) == []
    assert campaign.features  # the harness reported coverage


def test_kept_divergences_replay_clean() -> None:
    """Each minimised divergence the fuzzer found (fixed since) agrees on both sides now."""
    sessions = sorted(CORPUS.glob("*.session"))
    assert sessions
    for path in sessions:
        session = Session.from_text(path.read_text())
        assert divergences(session, run_emulator_session(session),
                           run_firmware_session(session)) == [], path.name


def test_the_corpus_agrees_under_the_reach_rule() -> None:
    """The fuzzer's corpus of sessions (power cuts, noise, overruns, reversals) on the firmware
    built with ``-DSTOP_RULE_REACH=1`` and on the emulator with ``stop_rule = "reach"``: no
    divergence beyond the check's tolerances (a count at rest is within them: where each rule
    rests, exactly, is ``tests/test_firmware_stop_rule.py``'s)."""
    robot = RobotSettings.from_mapping({"emulator": {"profile": "ideal", "stop_rule": "reach"}})
    sessions = sorted(CORPUS.glob("*.session"))
    assert len(sessions) >= 10
    for path in sessions:
        session = Session.from_text(path.read_text())
        assert divergences(session, run_emulator_session(session, robot),
                           run_firmware_session(session, robot=robot)) == [], path.name


@pytest.fixture(scope="module")
def old_firmware(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The firmware as it was: the five digits of a position summed in 16 bits, a slave that
    took a new reference only after its EEPROM record, and a position report that took a counter
    beyond 16 bits modulo 2^16 counts."""
    src = tmp_path_factory.mktemp("old-firmware")
    for path in FIRMWARE_SOURCE.rglob("*"):
        if path.is_file() and path.suffix in (".c", ".h"):
            (src / path.relative_to(FIRMWARE_SOURCE)).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(path, src / path.relative_to(FIRMWARE_SOURCE))
    master = src / "master.c"
    text = master.read_text()
    assert "uint32_t t = 0;" in text
    master.write_text(text.replace("uint32_t t = 0;", "uint16_t t = 0;"))
    slave = src / "slave.c"
    text = slave.read_text()
    waits = "    refresh_position();\n    take_reference();\n}"
    assert waits in text
    slave.write_text(text.replace(waits, "    refresh_position();\n}"))
    joint = src / "joint.c"
    text = joint.read_text()
    reduce = text[text.index("    if (c >= 65536L"):text.index("    uint16_t ac = ")]
    joint.write_text(text.replace(reduce, ""))
    return build(src, src / "build")


def test_the_comparison_catches_a_frame_only_the_firmware_takes(old_firmware: Path) -> None:
    """The issue's frame on the old firmware: taken there, rejected by the emulator; the
    divergence survives minimisation down to that one write."""
    session = Session((Write(0.15, b"\r\n" + OVERFLOW_FRAME + b"##"),
                       Write(0.2, b"$00100,99,00000,00,00000,00,00000,00#")), 0.3)

    def check(s: Session) -> list[str]:
        return divergences(s, run_emulator_session(s),
                           run_firmware_session(s, firmware=str(old_firmware)))

    found = check(session)
    assert any("34463" in line for line in found), found
    small = minimise(session, check, budget=10)
    assert len(small.events) == 1 and OVERFLOW_FRAME in small.events[0].data  # type: ignore[union-attr]
    assert not divergences(session, run_emulator_session(session), run_firmware_session(session))


def test_the_comparison_catches_a_slave_that_waits_for_its_record(old_firmware: Path) -> None:
    """The kept session of the slave that took a command only after its EEPROM record diverges
    on the old firmware (joint 3 ran on at the old duty) and agrees on the current one."""
    session = Session.from_text((CORPUS / "slave-reference-during-eeprom-record.session")
                                .read_text())
    emu = run_emulator_session(session)
    found = divergences(session, emu, run_firmware_session(session, firmware=str(old_firmware)))
    assert any(line.startswith("joint 3") for line in found), found
    assert divergences(session, emu, run_firmware_session(session)) == []


def _joint1_records(side: Outcome) -> list[EepromRecord | None]:
    return [decode_record(cells[0]) for _, cells in side.records_at_cuts]


def test_a_record_torn_by_a_power_cut() -> None:
    """Joint 1 stops at -77 counts; its record (state and four counter cells, 3.3 ms a cell) is
    being written when the power goes, after the state and three counter cells: on both sides
    the record says "stopped at -256" (the new high bytes, the old low byte 0x00), and after the
    power-up joint 1 reports that on both. An emulator storing the record whole said -77."""
    session = Session.from_text((CORPUS / "record-torn-by-a-power-cut.session").read_text())
    emu, fw = run_emulator_session(session), run_firmware_session(session)
    torn = EepromRecord("stopped", -256)
    assert _joint1_records(emu) == _joint1_records(fw) == [torn]
    after = [r[0] for t, r in emu.replies if t > 0.33], [r[0] for t, r in fw.replies if t > 0.33]
    assert after[0][0] == after[1][0] == rad_to_ticks(-256 / RobotSettings().joints[0]
                                                       .counts_per_rad)
    assert divergences(session, emu, fw) == []


def test_a_cut_at_a_cell_write_is_the_sides_timing() -> None:
    """The same record, the cut 10 µs before the firmware starts its last cell, some tenths of a
    millisecond after the emulator started it (the two loops store at points that far apart):
    the firmware's record is torn, the emulator's whole. The emulator's record was the
    firmware's a moment before the cut, so the comparison stops there rather than reporting it.
    (The cut is placed from the firmware's own write times: microseconds of its code move it.)"""
    kept = Session.from_text((CORPUS / "record-torn-at-a-cell-write-edge.session").read_text())
    writes = tuple(e for e in kept.events if isinstance(e, Write))
    uncut = Session(writes, kept.until_s)
    last_fw = run_firmware_session(uncut).eeprom_writes[0][9][0]
    last_emu = run_emulator_session(uncut).eeprom_writes[0][9][0]
    cut = last_fw - 10e-6
    assert last_emu < cut - 1e-4
    session = Session((*writes, Power(cut, False), Power(0.225174, True)), kept.until_s)
    emu, fw = run_emulator_session(session), run_firmware_session(session)
    assert _joint1_records(fw) == [EepromRecord("stopped", -256)]
    assert _joint1_records(emu) == [EepromRecord("stopped", -77)]
    assert divergences(session, emu, fw) == []


def test_a_record_differing_away_from_any_write_is_reported() -> None:
    """Records that differ at a cut with no cell written near it on either side, the joint at
    rest, are a divergence: joint 1 has rested 70 ms when the power goes, its record written
    50 ms before; the emulator's record, changed behind its back, is reported."""
    torn = Session.from_text((CORPUS / "record-torn-by-a-power-cut.session").read_text())
    writes = tuple(e for e in torn.events if isinstance(e, Write))
    session = Session((*writes, Power(0.26, False), Power(0.28, True)), 0.45)
    emu, fw = run_emulator_session(session), run_firmware_session(session)
    assert divergences(session, emu, fw) == []
    t, cells = emu.records_at_cuts[0]
    emu.records_at_cuts[0] = (t, (bytes.fromhex("0100000000"), *cells[1:]))
    found = divergences(session, emu, fw)
    assert found and found[0].startswith("joint 1: the power cut at 0.2600 s"), found


def test_a_torn_counter_beyond_16_bits(old_firmware: Path) -> None:
    """The record of joint 1 cut after the state and the counter's high byte: "stopped at
    -16 777 216" on both sides. The old firmware's position report took |counter| modulo 2^16
    (62 832 ticks); now it reports the counter's angle, as the emulator."""
    session = Session.from_text((CORPUS / "torn-counter-beyond-16-bits.session").read_text())
    emu, fw = run_emulator_session(session), run_firmware_session(session)
    assert _joint1_records(emu) == _joint1_records(fw) == [EepromRecord("stopped", -2**24)]
    angle = -2**24 / RobotSettings().joints[0].counts_per_rad
    after = [r[0] for t, r in emu.replies if t > 0.33], [r[0] for t, r in fw.replies if t > 0.33]
    assert after[0][0] == after[1][0] == rad_to_ticks(angle)
    assert divergences(session, emu, fw) == []
    old = run_firmware_session(session, firmware=str(old_firmware))
    assert next(r[0] for t, r in old.replies if t > 0.33) == 62832
    assert any(line.startswith("joint 1") for line in divergences(session, emu, old))


def test_records_after_a_command_lost_to_an_overflow_are_not_compared() -> None:
    """Joint 1 moves, stops (a record stalling both loops 3.3 ms a cell) while two commands
    arrive, the second a reversal; the emulator's loop last read its receive buffer just before
    their first byte, the firmware's just after, so the emulator's buffer overflows and loses the
    reversal's end, the firmware's takes it. At the power cut the firmware's record says "moving
    CCW", the emulator's "moving CW": both right for what each took, so not compared, as the
    replies after the first command taken differently are not. Without the overflow the command
    only one side took is the divergence reported."""
    session = Session.from_text((CORPUS / "reversal-lost-to-an-overflow-before-a-cut.session")
                                .read_text())
    emu, fw = run_emulator_session(session), run_firmware_session(session)
    assert emu.overflows and not fw.overflows, (emu.overflows, fw.overflows)
    assert [c for _, c in emu.taken] == [c for _, c in fw.taken][:2] and len(fw.taken) == 3
    assert _joint1_records(fw) == [EepromRecord("ccw", 106)]
    assert _joint1_records(emu) == [EepromRecord("cw", 106)]
    assert divergences(session, emu, fw) == []
    emu.overflows.clear()
    found = divergences(session, emu, fw)
    assert len(found) == 1 and "the emulator took only 2 commands" in found[0], found
