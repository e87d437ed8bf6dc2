"""The firmware's command framer against the protocol (docs/protocol.md, "Malformed input"):
malformed frames sent on the simulated UART are rejected as the emulator's framer rejects them,
so no joint moves; the valid frames next to them are taken. Real toolchain, real harness."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from test_firmware import needs_toolchain, run_harness

from armbench.drivers.model.protocol import Command, Framer
from armbench.drivers.model.settings import RobotSettings

pytestmark = needs_toolchain

HOLD = "$00000,00,00000,00,00000,00,00000,00#"

#: Position fields of five digits above 62832: each wraps in 16 bits to a value the old
#: firmware took (99999 -> 34463, 65537 -> 1, 70000 -> 4464) or is just out of range.
OUT_OF_RANGE = ["99999", "65537", "70000", "62833", "65535"]


def _frame(field: str, joint: int = 1) -> str:
    fields = ["00000,00"] * 4
    fields[joint - 1] = f"{field},99"
    return "$" + ",".join(fields) + "#"


def _counts(ticks: int, joint: int) -> float:
    """Wire ticks as signed encoder counts of ``joint`` (1..4)."""
    rad = (ticks / 1e4 + math.pi) % (2 * math.pi) - math.pi
    return rad * RobotSettings().joints[joint - 1].counts_per_rad


def test_the_emulator_rejects_every_out_of_range_position() -> None:
    """The specification side: the emulator's framer rejects each of these frames."""
    for field in OUT_OF_RANGE:
        for joint in range(1, 5):
            events = Framer("command").feed(_frame(field, joint).encode())
            assert len(events) == 1 and not isinstance(events[0], Command), (field, joint)


@pytest.mark.parametrize("joint", [1, 2, 4])
def test_a_position_above_62832_moves_no_joint(joint: int, tmp_path: Path) -> None:
    """Each out-of-range frame, sent after the boot, is rejected: every joint stays at 0 (the
    firmware once summed the five digits in 16 bits, so 99999 became 34463 and joint 1 drove
    towards it). A valid frame to 0.05 rad afterwards is still taken."""
    script = [(0.12 + 0.01 * k, _frame(field, joint)) for k, field in enumerate(OUT_OF_RANGE)]
    script.append((0.3, _frame("00500", joint)))
    replies, stats = run_harness(script, 0.45, tmp_path)
    before = [r for t, r in replies if t < 0.3]
    assert len(before) > 20
    for reply in before:
        assert all(abs(_counts(reply[j], j + 1)) <= 1 for j in range(4)), reply
    assert stats["boards"][0]["fw"]["bad_frames"] >= len(OUT_OF_RANGE)
    moved = _counts(replies[-1][1][joint - 1], joint)
    assert moved > 5  # the valid frame afterwards was taken: the joint set off towards 0.05 rad
