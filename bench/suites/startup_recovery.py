"""Start-up recovery (paper §5.2): power cuts at random moments, and what the EEPROM costs.

The firmware stores each joint's motion state (stopped / moving CW / moving CCW) and encoder
counter in EEPROM at every change of state. At power-up a joint whose record says "stopped"
restores its counter; one whose record says "moving" drives the *opposite* way until its Hall
sensor (at ``hall_deg``, 0 by default) resets the counter. That is right when the joint was moving
away from the Hall sensor; moving towards it, the recovery drives away from the sensor and ends
stalled at a hard limit (a visible failure the bench must record, not hide).

Each ``cut`` trial puts the arm in one condition, cuts the power through ``ctx.power`` at a random
moment (``ctx.rng``), restores it after ``off_s`` and watches the reply stream. The test joints of a
trial are one set of ``joint_sets`` (all four, then 2-4 so that slave failures are seen while the
master still replies); the others stand at their Hall angle (0 rad: the arm's zero pose).

* ``stopped-near`` / ``stopped-far``: the test joints stand still ``near`` / ``far`` from the
  Hall sensor (random side) for a random dwell, then the cut;
* ``cw|ccw``-``away|toward``-``near|far``: the test joints move together (coordinated, ``duty``)
  CW (counting up) or CCW, away from or towards the Hall sensor, through the ``near`` or ``far``
  band of angles; the cut falls at a random fraction (``cut_fraction``) of the planned motion.

Recovered = replies are back and the reported joints are within ``tolerance_rad`` of the truth
(``ctx.truth``; without it: of the known physical position, the Hall angle for a joint that was
moving at the cut and the last reported angle for one that stood still) and stay there, unchanged,
for ``still_s``. The recovery time runs from power-on to the first reply of that final window.

A ``wear`` trial (``wear_duration_s`` > 0) runs a typical duty cycle (the ISO pose cycle at full
speed and a coordinated square lap, alternating) and counts the EEPROM record writes and cell wear
(emulator only), projected to writes per hour and years of life at ``use_hours_per_year`` against
the ATmega328P's 100 000 rated write cycles per cell. See ``docs/suites.md``.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final

import numpy as np

from armbench.bench.metrics import iso_cube_poses, square_yz
from armbench.bench.record import Measurement, Trial
from armbench.bench.suites._common import (
    Measurements,
    TruthProbe,
    check_bool,
    check_int,
    check_number,
    eeprom_counters,
    emulator_of,
    guarded_trial,
    loop_time,
    rad_list,
    settled_state,
)
from armbench.bench.suites.accuracy import DEFAULT_CENTRE_M, DEFAULT_SIDE_M
from armbench.bench.suites.base import Suite, SuiteContext
from armbench.bench.suites.repeatability import (
    CYCLE_ORDER,
    DEFAULT_CUBE_CENTRE_M,
    DEFAULT_CUBE_SIDE_M,
)
from armbench.drivers.arm import ReplyTimeoutError, WaitTimeoutError
from armbench.drivers.motion import coordinated_duties, joint_times_s
from armbench.drivers.protocol import MAX_DUTY
from armbench.drivers.settings import RobotSettings, SettingsError

if TYPE_CHECKING:
    from armbench.drivers.arm import JointState

__all__ = [
    "ATMEGA328P_EEPROM_CYCLES",
    "CONDITIONS",
    "Condition",
    "StartupRecoverySuite",
    "eeprom_life_years",
    "parse_condition",
]

#: ATmega328P data sheet: rated EEPROM write/erase cycles per cell.
ATMEGA328P_EEPROM_CYCLES: Final = 100_000

#: Every condition, in the default order (each occurs twice in the default 20 trials).
CONDITIONS: Final = (
    "stopped-near", "stopped-far",
    "cw-away-near", "cw-away-far", "cw-toward-near", "cw-toward-far",
    "ccw-away-near", "ccw-away-far", "ccw-toward-near", "ccw-toward-far",
)

#: Two replies whose joints differ by no more than this (rad, 1.5 wire ticks) show a still arm.
STILL_RAD: Final = 1.5e-4
#: Keep a joint this far (rad) inside its limits when placing it.
LIMIT_MARGIN_RAD: Final = 0.02
#: Interval (s) of the recovery trace kept in the samples.
TRACE_PERIOD_S: Final = 0.1
#: Motion at the cut is read over this window of replies (s): at duty ≥ 10 a moving joint
#: covers more than ``STILL_RAD`` in it.
MOTION_WINDOW_S: Final = 0.05


@dataclass(frozen=True, slots=True)
class Condition:
    """A parsed condition: ``motion`` (``stopped``, ``cw``, ``ccw``), ``relation`` to the Hall
    sensor (``away``, ``toward``, or None when stopped) and ``zone`` (``near``, ``far``)."""

    name: str
    motion: str
    relation: str | None
    zone: str

    @property
    def moving(self) -> bool:
        """Whether the cut happens during a motion."""
        return self.motion != "stopped"

    @property
    def expected_to_recover(self) -> bool:
        """What §5.2's procedure predicts: every case but a motion towards the Hall sensor."""
        return self.relation != "toward"


def parse_condition(name: str) -> Condition:
    """``"cw-away-near"`` → Condition; raises ValueError for an unknown name."""
    parts = name.split("-")
    if len(parts) == 2 and parts[0] == "stopped" and parts[1] in ("near", "far"):
        return Condition(name, "stopped", None, parts[1])
    if (len(parts) == 3 and parts[0] in ("cw", "ccw") and parts[1] in ("away", "toward")
            and parts[2] in ("near", "far")):
        return Condition(name, parts[0], parts[1], parts[2])
    raise ValueError(f"unknown condition {name!r} (known: {', '.join(CONDITIONS)})")


def eeprom_life_years(wear_per_hour: float, hours_per_year: float,
                      rated_cycles: int = ATMEGA328P_EEPROM_CYCLES) -> float:
    """Years until the most-worn EEPROM cell reaches ``rated_cycles``, wearing ``wear_per_hour``
    writes per hour of use and used ``hours_per_year`` hours a year (∞ for no wear)."""
    if wear_per_hour <= 0:
        return math.inf
    return rated_cycles / (wear_per_hour * hours_per_year)


def _band(params: Mapping[str, Any], zone: str) -> tuple[float, float]:
    lo, hi = params[f"{zone}_band_rad"]
    return float(lo), float(hi)


def _signed_range(settings: RobotSettings, joint: int, lo: float, hi: float,
                  side: int) -> tuple[float, float]:
    """The band ``[lo, hi]`` (rad, distance from the Hall angle) on ``side`` (+1/−1) of joint
    ``joint`` (0-based), clipped inside its limits; returned as (near end, far end)."""
    j = settings.joints[joint]
    hall = j.hall_rad
    limit = (j.upper_rad if side > 0 else j.lower_rad) - side * LIMIT_MARGIN_RAD
    room = abs(limit - hall)
    near, far = min(lo, room), min(hi, room)
    return hall + side * near, hall + side * far


class StartupRecoverySuite(Suite):
    """Power cuts in every condition of §5.2, and the EEPROM wear (see module doc)."""

    name = "startup-recovery"
    version = "1"

    def default_params(self, settings: RobotSettings) -> dict[str, Any]:
        """Defaults: 20 cuts (each condition once with all four joints moving, once with joints
        2-4 only, so slave failures are seen with the master replying), 2 min of wear."""
        return {
            "trials": 20,
            "conditions": list(CONDITIONS),
            "joint_sets": [[1, 2, 3, 4], [2, 3, 4]],
            "duty": MAX_DUTY,
            "near_band_rad": [0.05, 0.2],
            "far_band_rad": [0.3, 0.5],
            "cut_fraction": [0.2, 0.8],
            "stopped_dwell_s": [0.2, 1.0],
            "off_s": 0.5,
            "recovery_timeout_s": 15.0,
            "tolerance_rad": 0.001,
            "tolerance_mm": 1.0,
            "still_s": 0.1,
            "rescue": True,
            "wear_duration_s": 120.0,
            "use_hours_per_year": 2000.0,
        }

    def validate(self, settings: RobotSettings, params: Mapping[str, Any]) -> None:
        """Types and ranges; every condition known; bands within the joints' room."""
        w = f"suites.{self.name}"
        check_int(f"{w}.trials", params["trials"], low=0)
        conditions = params["conditions"]
        if (isinstance(conditions, (str, bytes)) or not isinstance(conditions, Sequence)
                or not conditions):
            raise SettingsError(f"{w}.conditions", conditions, "is not a list of conditions")
        for c in conditions:
            try:
                parse_condition(str(c))
            except ValueError as exc:
                raise SettingsError(f"{w}.conditions", c, str(exc)) from None
        sets = params["joint_sets"]
        if isinstance(sets, (str, bytes)) or not isinstance(sets, Sequence) or not sets:
            raise SettingsError(f"{w}.joint_sets", sets, "is not a list of joint lists")
        joints: set[int] = set()
        for group in sets:
            if (isinstance(group, (str, bytes)) or not isinstance(group, Sequence) or not group
                    or len(set(group)) != len(group)):
                raise SettingsError(f"{w}.joint_sets", group, "is not a list of distinct joints")
            for j in group:
                joints.add(check_int(f"{w}.joint_sets", j, low=1, high=len(settings.joints)))
        check_int(f"{w}.duty", params["duty"], low=1, high=MAX_DUTY)
        for key, low, high in (("near_band_rad", 0.0, 3.0), ("far_band_rad", 0.0, 3.0),
                               ("cut_fraction", 0.0, 1.0), ("stopped_dwell_s", 0.0, 60.0)):
            pair = params[key]
            if isinstance(pair, (str, bytes)) or not isinstance(pair, Sequence) or len(pair) != 2:
                raise SettingsError(f"{w}.{key}", pair, "is not a pair [low, high]")
            a = check_number(f"{w}.{key}", pair[0], low=low, high=high)
            b = check_number(f"{w}.{key}", pair[1], low=low, high=high)
            if not a < b:
                raise SettingsError(f"{w}.{key}", pair, "needs low < high")
        check_number(f"{w}.off_s", params["off_s"], low=0.0, high=60.0)
        check_number(f"{w}.recovery_timeout_s", params["recovery_timeout_s"], low=0.0,
                     low_open=True, high=3600.0)
        check_number(f"{w}.tolerance_rad", params["tolerance_rad"], low=0.0, low_open=True)
        check_number(f"{w}.tolerance_mm", params["tolerance_mm"], low=0.0, low_open=True)
        check_number(f"{w}.still_s", params["still_s"], low=0.0, high=10.0)
        check_bool(f"{w}.rescue", params["rescue"])
        check_number(f"{w}.wear_duration_s", params["wear_duration_s"], low=0.0)
        check_number(f"{w}.use_hours_per_year", params["use_hours_per_year"], low=0.0,
                     low_open=True, high=8784.0)
        for zone in ("near", "far"):
            for j in sorted(joints):
                for side in (1, -1):
                    a, b = _signed_range(settings, int(j) - 1, *_band(params, zone), side)
                    if abs(b - a) < 0.02:
                        raise SettingsError(f"{w}.{zone}_band_rad", params[f"{zone}_band_rad"],
                                            f"leaves joint {j} less than 0.02 rad of room on "
                                            f"its {'+' if side > 0 else '-'} side")

    def plan(self, params: Mapping[str, Any]) -> list[dict[str, Any]]:
        """``trials`` cuts cycling through ``conditions`` (inner) and ``joint_sets`` (outer: the
        first round of conditions moves the first set, ...), then the wear trial (if any)."""
        conditions = list(params["conditions"])
        sets = [list(g) for g in params["joint_sets"]]
        out: list[dict[str, Any]] = [
            {"kind": "cut", "condition": conditions[i % len(conditions)],
             "joints": sets[(i // len(conditions)) % len(sets)], "cut": i}
            for i in range(int(params["trials"]))]
        if float(params["wear_duration_s"]) > 0:
            out.append({"kind": "wear", "duration_s": float(params["wear_duration_s"])})
        return out

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        """One power cut (``kind="cut"``) or the wear measurement (``kind="wear"``)."""
        p = ctx.params
        if trial_params.get("kind") == "wear":
            duration = float(trial_params["duration_s"])
            ctx.progress(f"startup-recovery: EEPROM wear over {duration:g} s of typical use")
            return await guarded_trial(ctx, index, trial_params,
                                       lambda samples: self._wear(ctx, duration, samples),
                                       timeout_s=3.0 * duration + 300.0)
        condition = parse_condition(str(trial_params["condition"]))
        ctx.progress(f"startup-recovery: cut {trial_params.get('cut', index)} "
                     f"({condition.name})")
        # Generous: a manual power switch waits for the operator twice per cut.
        timeout_s = 600.0 + 3.0 * float(p["recovery_timeout_s"]) + float(p["off_s"])
        return await guarded_trial(ctx, index, trial_params,
                                   lambda samples: self._cut(ctx, condition,
                                                             trial_params["joints"], samples),
                                   timeout_s=timeout_s)

    # --- one power cut --------------------------------------------------------------------------

    def _targets(self, ctx: SuiteContext, condition: Condition,
                 joints: Sequence[int]) -> tuple[list[float], list[float]]:
        """Start and end joint angles (rad) of the condition's motion (equal when stopped):
        the test joints in the condition's band and side, the others at their Hall angle."""
        p = ctx.params
        rng = ctx.rng
        start = [j.hall_rad for j in ctx.settings.joints]
        end = list(start)
        lo, hi = _band(p, condition.zone)
        for j in (int(v) - 1 for v in joints):
            if not condition.moving:
                side = rng.choice((1, -1))
                a, b = _signed_range(ctx.settings, j, lo, hi, side)
                start[j] = end[j] = rng.uniform(min(a, b), max(a, b))
                continue
            # CW counts up. Away from the Hall sensor: CW on the + side, CCW on the − side.
            up = condition.motion == "cw"
            side = 1 if up == (condition.relation == "away") else -1
            near, far = _signed_range(ctx.settings, j, lo, hi, side)
            going_out = condition.relation == "away"
            start[j], end[j] = (near, far) if going_out else (far, near)
        return start, end

    async def _cut(self, ctx: SuiteContext, condition: Condition, joints: Sequence[int],
                   samples: list[dict[str, Any]]) -> tuple[list[dict[str, Any]],
                                                           list[Measurement]]:
        p = ctx.params
        arm = ctx.arm
        rng = ctx.rng
        t0 = loop_time()

        def log(event: str, **data: Any) -> dict[str, Any]:
            s = {"t_s": round(loop_time() - t0, 6), "event": event, **data}
            samples.append(s)
            return s

        if ctx.power is None:
            log("skipped", reason="no power switch configured (ctx.power is None)")
            return samples, []
        probe = TruthProbe(ctx)
        duty = int(p["duty"])
        start, end = self._targets(ctx, condition, joints)
        await arm.move_joints(start, duty, coordinated=True)
        await settled_state(arm, 0.2)
        counters0 = eeprom_counters(arm)
        cut_fraction: float | None = None
        with arm.record_states() as recent:
            if condition.moving:
                duties = coordinated_duties(arm.state.q_rad, end, duty, ctx.settings)
                planned_s = max(joint_times_s(arm.state.q_rad, end, duties, ctx.settings))
                cut_fraction = rng.uniform(*(float(v) for v in p["cut_fraction"]))
                log("move", start_rad=rad_list(start), target_rad=rad_list(end),
                    duties=list(duties), planned_s=round(planned_s, 4))
                await arm.move_joints(end, duty, coordinated=True, wait=False)
                await asyncio.sleep(cut_fraction * planned_s)
            else:
                dwell = rng.uniform(*(float(v) for v in p["stopped_dwell_s"]))
                log("dwell", position_rad=rad_list(start), dwell_s=round(dwell, 4))
                await asyncio.sleep(dwell)
            before = arm.state
            motion = _motion_at(list(recent), before)
        cut_true = probe.joints()
        await ctx.power.power_off()
        t_cut = loop_time()
        log("fault", kind="power_cut", condition=condition.name,
            reported_q_rad=rad_list(before.q_rad),
            true_q_rad=None if cut_true is None else rad_list(cut_true), motion=motion,
            cut_fraction=None if cut_fraction is None else round(cut_fraction, 4))
        await asyncio.sleep(float(p["off_s"]))
        await ctx.power.power_on()
        t_on = loop_time()
        log("power_restore", off_s=round(t_on - t_cut, 6))

        # What the reported joints should say once recovered.
        hall = [j.hall_rad for j in ctx.settings.joints]
        fixed = [hall[i] if motion[i] != "stopped" else before.q_rad[i]
                 for i in range(len(hall))]
        tol_rad = float(p["tolerance_rad"])
        tol_m = float(p["tolerance_mm"]) / 1000.0

        def error(state: JointState) -> tuple[float, bool, str]:
            """(error, within tolerance, what it was compared with) of ``state``."""
            if probe.available:
                q = probe.joints(state, motor=True)
                if q is not None:
                    e = max(abs(a - b) for a, b in zip(state.q_rad, q, strict=True))
                    return e, e <= tol_rad, "truth_rad"
                pos = probe.position(state)
                if pos is not None:
                    e = float(np.linalg.norm(np.subtract(state.tcp_m(ctx.settings), pos)))
                    return e, e <= tol_m, "truth_m"
            e = max(abs(a - b) for a, b in zip(state.q_rad, fixed, strict=True))
            return e, e <= tol_rad, "expected_rad"

        result = await _await_recovery(arm, t_on, error, float(p["recovery_timeout_s"]),
                                       float(p["still_s"]), log)
        counters1 = eeprom_counters(arm)
        stalled = _stalled_joints(arm)
        recovered = result.recovered_s is not None
        failure = None if recovered else ("no_reply" if result.first_reply_s is None
                                          else "position")
        log("outcome", recovered=recovered, failure=failure, condition=condition.name,
            joints=list(joints),
            motion=motion, toward_hall=condition.relation == "toward", zone=condition.zone,
            expected_to_recover=condition.expected_to_recover,
            cut_true_q_rad=None if cut_true is None else rad_list(cut_true),
            cut_reported_q_rad=rad_list(before.q_rad),
            final_q_rad=None if result.last is None else rad_list(result.last.q_rad),
            compared_with=result.compared_with,
            **{"error_mm" if result.compared_with == "truth_m" else "error_mrad":
               None if result.error_rad is None else round(result.error_rad * 1e3, 4)},
            recovery_s=result.recovered_s, first_reply_s=result.first_reply_s,
            stalled_joints=stalled)
        ms = Measurements(ctx)
        ms.add("startup.recovered", 1.0 if recovered else 0.0, "bool", better="higher",
               description="the arm replied with its true position after the power cut")
        ms.add("startup.recovery_time_s", result.recovered_s, "s",
               description="power-on to the first reply of the final within-tolerance window")
        ms.add("startup.first_reply_s", result.first_reply_s, "s",
               description="power-on to the first reply")
        if result.error_rad is not None and result.compared_with != "truth_m":
            ms.add("startup.position_error_mrad", result.error_rad * 1e3, "mrad",
                   description="largest joint error of the final reply against the reference")
        if result.error_rad is not None and result.compared_with == "truth_m":
            ms.add("startup.position_error_mm", result.error_rad * 1e3, "mm",
                   description="TCP error of the final reply against the tracker")
        if counters0 is not None and counters1 is not None:
            ms.add("startup.eeprom_writes", float(sum(counters1[0]) - sum(counters0[0])),
                   "writes", better="lower",
                   description="EEPROM record writes of all joints during the trial")
        if not recovered and bool(p["rescue"]):
            await self._rescue(ctx, log)
        return samples, ms.items

    async def _rescue(self, ctx: SuiteContext, log: Callable[..., Any]) -> None:
        """After a failed recovery: re-reference the arm so the campaign can go on. On the
        emulator: power off, blank EEPROMs (the firmware then takes the motor position as its
        counter, what an operator re-referencing the joints by hand achieves), power on. On
        hardware: nothing can be done from here; the next trial errors if the arm is unusable."""
        emu = emulator_of(ctx.arm)
        if emu is None or ctx.power is None:
            log("rescue", done=False, reason="operator must re-reference the arm")
            return
        await ctx.power.power_off()
        for eeprom in getattr(emu, "eeproms", ()):
            eeprom.erase()
        await asyncio.sleep(float(ctx.params["off_s"]))
        await ctx.power.power_on()
        t = loop_time()
        try:
            await ctx.arm.wait_state(lambda s: s.t_s >= t, timeout_s=5.0)
            await settled_state(ctx.arm, 0.1)
        except (ReplyTimeoutError, WaitTimeoutError) as exc:
            # The failure was measured; the next trial will find the arm unusable and error.
            log("rescue", done=False, reason=f"the arm did not come back: {exc}")
            return
        log("rescue", done=True, q_rad=rad_list(ctx.arm.state.q_rad))

    # --- EEPROM wear ----------------------------------------------------------------------------

    async def _wear(self, ctx: SuiteContext, duration_s: float,
                    samples: list[dict[str, Any]]) -> tuple[list[dict[str, Any]],
                                                            list[Measurement]]:
        """Typical use for ``duration_s`` (s), half in each of two phases (at least one round
        each): ``ptp``, the ISO pose cycle (approach from above, duty 99, 0.3 s dwell) on the
        repeatability suite's default cube; ``streaming``, coordinated laps (0.05 m/s) of the
        accuracy suite's default square. EEPROM counters are read around each phase."""
        arm = ctx.arm
        t0 = loop_time()
        if eeprom_counters(arm) is None:
            samples.append({"t_s": 0.0, "event": "skipped",
                            "reason": "EEPROM writes are not observable on this port"})
            return samples, []
        poses = iso_cube_poses(DEFAULT_CUBE_CENTRE_M, DEFAULT_CUBE_SIDE_M)
        corners = square_yz(DEFAULT_CENTRE_M, DEFAULT_SIDE_M)
        names = ("P1", "P2", "P3", "P4", "P5")

        async def ptp() -> None:
            for name in CYCLE_ORDER:
                target = poses[names.index(name)]
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
        for phase, body, start in (("ptp", ptp, poses[0]), ("streaming", streaming, corners[0])):
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
            samples.append({"t_s": round(loop_time() - t0, 6), "event": "wear_phase",
                            "phase": phase, "rounds": rounds, "elapsed_s": round(elapsed, 6),
                            "record_writes": writes, "max_cell_wear": wear,
                            "writes_per_hour": writes_h})
            ms.add(f"startup.{phase}.eeprom_writes_per_hour", writes_h, "writes/h",
                   better="lower", description=f"EEPROM record writes per hour of {phase} "
                                               "motion, busiest joint")
        writes_h = max(total_writes) * 3600.0 / total_s
        wear_h = max(total_wear) * 3600.0 / total_s
        years = eeprom_life_years(wear_h, hours_per_year)
        samples.append({"t_s": round(loop_time() - t0, 6), "event": "wear",
                        "elapsed_s": round(total_s, 6), "record_writes": total_writes,
                        "max_cell_wear": total_wear, "writes_per_hour": writes_h,
                        "cell_wear_per_hour": wear_h,
                        "life_years": None if math.isinf(years) else years})
        _wear_measurements(ms, writes_h, wear_h, years, hours_per_year)
        return samples, ms.items

    # --- summary --------------------------------------------------------------------------------

    def summarize(self, ctx: SuiteContext, trials: Sequence[Trial]) -> list[Measurement]:
        """Success rate (overall and per condition), worst recovery time and position error,
        EEPROM writes per cut and the wear projection."""
        ms = Measurements(ctx)
        outcomes = [(t, _outcome(t)) for t in trials
                    if t.status == "done" and t.params.get("kind") == "cut"]
        measured = [(t, o) for t, o in outcomes if o is not None]
        ms.add("startup.trials_measured", float(len(measured)), "",
               description="power cuts carried out and judged")
        if measured:
            ok = [o for _, o in measured if o["recovered"]]
            ms.add("startup.success_rate_pct", 100.0 * len(ok) / len(measured), "%",
                   better="higher", description="power cuts after which the arm recovered")
            expected = [o for _, o in measured if o["expected_to_recover"]]
            if expected:
                good = [o for o in expected if o["recovered"]]
                ms.add("startup.expected_success_rate_pct", 100.0 * len(good) / len(expected),
                       "%", better="higher",
                       description="recoveries among the cuts §5.2 can handle (not towards the "
                                   "Hall sensor)")
            times = [float(o["recovery_s"]) for o in ok if o["recovery_s"] is not None]
            if times:
                ms.add("startup.recovery_time_max_s", max(times), "s",
                       description="slowest recovery")
                ms.add("startup.recovery_time_mean_s", float(np.mean(times)), "s",
                       description="mean recovery time")
            errors = [float(o["error_mrad"]) for _, o in measured
                      if o.get("error_mrad") is not None]
            if errors:
                ms.add("startup.position_error_max_mrad", max(errors), "mrad",
                       description="largest joint error after a cut (failed recoveries too)")
            ok_errors = [float(o["error_mrad"]) for o in ok if o.get("error_mrad") is not None]
            if ok_errors:
                ms.add("startup.recovered_position_error_max_mrad", max(ok_errors), "mrad",
                       description="largest joint error after a successful recovery")
            for name in dict.fromkeys(str(o["condition"]) for _, o in measured):
                group = [o for _, o in measured if o["condition"] == name]
                rate = 100.0 * sum(1 for o in group if o["recovered"]) / len(group)
                ms.add(f"startup.{name}.success_rate_pct", rate, "%", better="higher",
                       description=f"recoveries after cuts in condition {name}")
            writes = [m.value for t, _ in measured for m in t.measurements
                      if m.name == "startup.eeprom_writes"]
            if writes:
                ms.add("startup.eeprom_writes_per_cut", float(np.mean(writes)), "writes",
                       better="lower", description="mean EEPROM record writes per cut trial")
        hours_per_year = float(ctx.params["use_hours_per_year"])
        for t in trials:
            if t.status != "done" or t.params.get("kind") != "wear":
                continue
            for s in t.samples:
                if s.get("event") == "wear_phase":
                    ms.add(f"startup.{s['phase']}.eeprom_writes_per_hour",
                           float(s["writes_per_hour"]), "writes/h", better="lower",
                           description=f"EEPROM record writes per hour of {s['phase']} motion, "
                                       "busiest joint")
                elif s.get("event") == "wear":
                    years = s["life_years"]
                    _wear_measurements(ms, float(s["writes_per_hour"]),
                                       float(s["cell_wear_per_hour"]),
                                       math.inf if years is None else float(years),
                                       hours_per_year)
        return ms.items


def _wear_measurements(ms: Measurements, writes_h: float, wear_h: float, years: float,
                       hours_per_year: float) -> None:
    ms.add("startup.eeprom_writes_per_hour", writes_h, "writes/h", better="lower",
           description="EEPROM record writes per hour of typical use, busiest joint")
    ms.add("startup.eeprom_cell_wear_per_hour", wear_h, "writes/h", better="lower",
           description="writes per hour of typical use to the most-worn EEPROM cell")
    ms.add("startup.eeprom_life_years", years, "years", better="higher",
           description="years until the most-worn cell reaches the ATmega328P's 100 000 "
                       "rated cycles at the configured hours of use per year")
    ms.add("startup.eeprom_life_hours", years * hours_per_year, "h", better="higher",
           description="hours of typical use until the most-worn cell reaches 100 000 cycles")


def _outcome(trial: Trial) -> Mapping[str, Any] | None:
    for s in trial.samples:
        if s.get("event") == "outcome":
            return s
    return None


def _motion_at(recent: Sequence[JointState], last: JointState) -> list[str]:
    """Each joint's motion (``stopped``, ``cw``, ``ccw``) over the last ``MOTION_WINDOW_S`` of
    replies before ``last``."""
    earlier = [s for s in recent if s.t_s <= last.t_s - MOTION_WINDOW_S]
    if not earlier:
        return ["stopped"] * len(last.q_rad)
    ref = earlier[-1]
    out = []
    for a, b in zip(ref.q_rad, last.q_rad, strict=True):
        d = b - a
        out.append("stopped" if abs(d) <= STILL_RAD else "cw" if d > 0 else "ccw")
    return out


def _stalled_joints(arm: Any) -> list[int] | None:
    """Joints (1-based) whose start-up recovery is stuck at a hard limit (emulator only)."""
    emu = emulator_of(arm)
    if emu is None:
        return None
    out = []
    for k, board in enumerate(getattr(emu, "boards", ())):
        model = getattr(board, "model", None)
        if model is not None and getattr(model, "homing_failed", False):
            out.append(k + 1)
    return out


@dataclass(slots=True)
class _Recovery:
    first_reply_s: float | None = None
    recovered_s: float | None = None
    error_rad: float | None = None
    compared_with: str | None = None
    last: JointState | None = None


async def _await_recovery(arm: Any, t_on: float,
                          error: Callable[[JointState], tuple[float, bool, str]],
                          timeout_s: float, still_s: float,
                          log: Callable[..., Any]) -> _Recovery:
    """Watch the replies after power-on (loop time ``t_on``) until the arm has been within
    tolerance and still for ``still_s`` or ``timeout_s`` has passed. Silence is expected while a
    joint 1 recovery runs (the master starts its loop afterwards), so reply timeouts are waited
    through; a lost port raises."""
    loop = asyncio.get_running_loop()
    deadline = t_on + timeout_s
    out = _Recovery()
    seen = arm.state.seq
    window: JointState | None = None
    last_trace = -math.inf
    while True:
        remaining = deadline - loop.time()
        if remaining <= 0:
            break
        try:
            state = await arm.wait_state(lambda s, seen=seen: s.seq > seen, timeout_s=remaining)
        except WaitTimeoutError:
            break
        except ReplyTimeoutError:
            continue
        seen = state.seq
        if state.t_s < t_on:
            continue
        e, within, what = error(state)
        out.last, out.error_rad, out.compared_with = state, e, what
        if out.first_reply_s is None:
            out.first_reply_s = round(state.t_s - t_on, 6)
            log(event="ready", first_reply_s=out.first_reply_s, q_rad=rad_list(state.q_rad))
        if state.t_s - last_trace >= TRACE_PERIOD_S:
            last_trace = state.t_s
            log(event="position_check", q_rad=rad_list(state.q_rad),
                error_mrad=round(e * 1e3, 4), within=within)
        if not within:
            window = None
            continue
        if window is None or max(abs(a - b) for a, b in zip(state.q_rad, window.q_rad,
                                                            strict=True)) > STILL_RAD:
            window = state
        if state.t_s - window.t_s >= still_s:
            out.recovered_s = round(window.t_s - t_on, 6)
            log(event="recovered", recovery_s=out.recovered_s, error_mrad=round(e * 1e3, 4))
            return out
    log(event="timeout", after_s=round(loop.time() - t_on, 6))
    return out
