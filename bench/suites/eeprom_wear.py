"""EEPROM wear (paper §5.2): the firmware writes each joint's motion state to EEPROM at every
change; a typical duty cycle is run and the writes and the most-worn cell counted (emulator only),
projected to years of life against the ATmega328P's rated write cycles."""

from __future__ import annotations

import asyncio
import math
from typing import Any, Final

import numpy as np

from armbench.bench.suites._common import (
    Measurements,
    TrialSkipped,
    eeprom_counters,
    loop_time,
)
from armbench.bench.suites.base import SuiteContext
from armbench.bench.suites.startup_contract import STARTUP
from armbench.bench.suites.workspace import (
    CYCLE_ORDER,
    DEFAULT_CUBE_CENTRE_M,
    DEFAULT_CUBE_SIDE_M,
    DEFAULT_SQUARE_CENTRE_M,
    DEFAULT_SQUARE_SIDE_M,
    POSE_NAMES,
)
from armbench.metrics import iso_cube_poses, square_yz
from armbench.record import Measurement
from armbench.record.suite_contract import SAMPLE

__all__ = ["ATMEGA328P_EEPROM_CYCLES", "MAX_WEAR_S", "eeprom_life_years", "measure_wear",
           "wear_measurements"]

#: ATmega328P data sheet: rated EEPROM write/erase cycles per cell.
ATMEGA328P_EEPROM_CYCLES: Final = 100_000
#: The longest wear trial (``wear_duration_s``, s of robot time): one day, checked before
#: anything moves; a longer one would only repeat the same duty cycle.
MAX_WEAR_S: Final = 86_400.0


def eeprom_life_years(wear_per_hour: float, hours_per_year: float,
                      rated_cycles: int = ATMEGA328P_EEPROM_CYCLES) -> float:
    """Years until the most-worn EEPROM cell reaches ``rated_cycles``, wearing ``wear_per_hour``
    writes per hour of use and used ``hours_per_year`` hours a year (∞ for no wear)."""
    if wear_per_hour <= 0:
        return math.inf
    return rated_cycles / (wear_per_hour * hours_per_year)



async def measure_wear(ctx: SuiteContext, duration_s: float,
                       samples: list[dict[str, Any]]) -> tuple[list[dict[str, Any]],
                                                               list[Measurement]]:
    """Typical use for ``duration_s`` (s), half in each of two phases (at least one round
    each): ``ptp``, the ISO pose cycle (approach from above, duty 99, 0.3 s dwell) on the
    repeatability suite's default cube; ``streaming``, coordinated laps (0.05 m/s) of the
    accuracy suite's default square. EEPROM counters are read around each phase."""
    arm = ctx.arm
    t0 = loop_time()
    if eeprom_counters(arm) is None:
        reason = "EEPROM writes are not observable on this port"
        samples.append({SAMPLE.t: 0.0, SAMPLE.event: STARTUP.ev_skipped, "reason": reason})
        raise TrialSkipped(reason)
    poses = iso_cube_poses(DEFAULT_CUBE_CENTRE_M, DEFAULT_CUBE_SIDE_M)
    corners = square_yz(DEFAULT_SQUARE_CENTRE_M, DEFAULT_SQUARE_SIDE_M)

    async def ptp() -> None:
        for name in CYCLE_ORDER:
            target = poses[POSE_NAMES.index(name)]
            await arm.move_to(target + np.array([0.0, 0.0, 0.02]), branch="front-up")
            await arm.move_to(target, branch="front-up")
            await asyncio.sleep(0.3)

    async def streaming() -> None:
        await arm.follow_path([*corners, corners[0]], speed_m_s=0.05, branch="front-up")

    hours_per_year = float(ctx.params["use_hours_per_year"])
    ms = Measurements(ctx)
    total_writes = [0, 0, 0, 0]
    total_wear = [0, 0, 0, 0]
    total_s = 0.0
    for phase, body, start in ((STARTUP.ptp_phase, ptp, poses[0]),
                               (STARTUP.streaming_phase, streaming, corners[0])):
        await arm.move_to(start, branch="front-up", coordinated=True)
        before = eeprom_counters(arm)
        t_phase = loop_time()
        rounds = 0
        while rounds == 0 or loop_time() - t_phase < duration_s / 2.0:
            await body()
            rounds += 1
        elapsed = loop_time() - t_phase
        after = eeprom_counters(arm)
        assert before is not None and after is not None
        writes = [b - a for a, b in zip(before[0], after[0], strict=True)]
        wear = [b - a for a, b in zip(before[1], after[1], strict=True)]
        total_writes = [a + b for a, b in zip(total_writes, writes, strict=False)]
        total_wear = [a + b for a, b in zip(total_wear, wear, strict=False)]
        total_s += elapsed
        writes_h = max(writes) * 3600.0 / elapsed
        samples.append({SAMPLE.t: round(loop_time() - t0, 6), SAMPLE.event: STARTUP.ev_wear_phase,
                        "phase": phase, "rounds": rounds, "elapsed_s": round(elapsed, 6),
                        "record_writes": writes, "max_cell_wear": wear,
                        "writes_per_hour": writes_h})
        ms.add(STARTUP.phase_writes(phase), writes_h, "writes/h",
               better="lower", description=f"EEPROM record writes per hour of {phase} "
                                           "motion, busiest joint")
    writes_h = max(total_writes) * 3600.0 / total_s
    wear_h = max(total_wear) * 3600.0 / total_s
    years = eeprom_life_years(wear_h, hours_per_year)
    samples.append({SAMPLE.t: round(loop_time() - t0, 6), SAMPLE.event: STARTUP.ev_wear,
                    "elapsed_s": round(total_s, 6), "record_writes": total_writes,
                    "max_cell_wear": total_wear, "writes_per_hour": writes_h,
                    "cell_wear_per_hour": wear_h,
                    "life_years": None if math.isinf(years) else years})
    wear_measurements(ms, writes_h, wear_h, years, hours_per_year)
    return samples, ms.items


def wear_measurements(ms: Measurements, writes_h: float, wear_h: float, years: float,
                       hours_per_year: float) -> None:
    ms.add(STARTUP.eeprom_writes_per_hour, writes_h, "writes/h", better="lower",
           description="EEPROM record writes per hour of typical use, busiest joint")
    ms.add(STARTUP.eeprom_cell_wear_per_hour, wear_h, "writes/h", better="lower",
           description="writes per hour of typical use to the most-worn EEPROM cell")
    ms.add(STARTUP.eeprom_life_years, years, "years", better="higher",
           description="years until the most-worn cell reaches the ATmega328P's 100 000 "
                       "rated cycles at the configured hours of use per year")
    ms.add(STARTUP.eeprom_life_hours, years * hours_per_year, "h", better="higher",
           description="hours of typical use until the most-worn cell reaches 100 000 cycles")


