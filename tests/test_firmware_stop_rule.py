"""The firmware built with the emulator's stop rule and deadband (``firmware_defines``): where
its joints come to rest is where the emulator's do, for each rule, in the real simavr harness."""

from __future__ import annotations

from collections.abc import Sequence

import pytest
from test_firmware import needs_toolchain

from armbench.drivers.model.protocol import Reply
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.avr.differential import run_emulator, run_firmware
from armbench.fakes.avr.harness import firmware_defines
from armbench.fakes.firmware.emulator_settings import with_emulator_overrides

pytestmark = needs_toolchain

#: Moves at full duty, each given 1.2 s to come to rest: targets on varied counts (some never a
#: value of a counter counting there at 5/4 counts per microstep).
SCRIPT = (
    (0.30, (0.1237, -0.0811, 0.0559, 0.2003), 99),
    (1.50, (-0.0421, 0.1372, -0.1010, 0.0906), 99),
    (2.70, (0.0786, 0.0247, 0.0333, -0.0599), 99),
    (3.90, (0.0005, -0.0007, 0.0011, 0.0003), 99),
)
UNTIL_S = 5.1


def _robot(**emulator: object) -> RobotSettings:
    base = RobotSettings.from_mapping({"emulator": dict(emulator)})
    return with_emulator_overrides(base, profile="ideal")


def _rests(replies: Sequence[tuple[float, Reply]]) -> list[tuple[int, ...]]:
    """The last reply before each next command and at the end: where each move came to rest."""
    ends = [t for t, _, _ in SCRIPT[1:]] + [UNTIL_S]
    out: list[tuple[int, ...]] = []
    for end in ends:
        reply = max((r for r in replies if r[0] < end), key=lambda r: r[0])[1]
        out.append((reply.j1, reply.j2, reply.j3, reply.j4))
    return out


def test_the_defaults_build_the_reference_firmware() -> None:
    assert firmware_defines(RobotSettings()) == ()
    assert firmware_defines(_robot(stop_rule="reach", deadband_counts=2)) == (
        "-DDEADBAND_COUNTS=2", "-DSTOP_RULE_REACH=1")


@pytest.mark.parametrize("emulator", [{}, {"stop_rule": "reach"},
                                      {"stop_rule": "reach", "deadband_counts": 2},
                                      {"deadband_counts": 2}])
def test_the_firmware_rests_where_the_emulator_does(emulator: dict[str, object]) -> None:
    robot = _robot(**emulator)
    firmware = _rests(run_firmware(SCRIPT, UNTIL_S, robot))
    assert firmware == _rests(run_emulator(SCRIPT, UNTIL_S, robot))
    if emulator:  # and the option made a difference: some rest moved
        assert firmware != _rests(run_firmware(SCRIPT, UNTIL_S, _robot()))
