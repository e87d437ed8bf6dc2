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
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Final

import numpy as np

from armbench.bench.suites._common import (
    MAX_REPEATS,
    Measurements,
    TrialSkipped,
    check_bool,
    eeprom_counters,
    guarded_trial,
    loop_time,
    rad_list,
    settled_state,
)
from armbench.bench.suites.base import Suite, SuiteContext
from armbench.bench.suites.eeprom_wear import (
    ATMEGA328P_EEPROM_CYCLES,
    MAX_WEAR_S,
    eeprom_life_years,
    measure_wear,
    wear_measurements,
)
from armbench.bench.suites.recovery_judge import RecoveryJudge
from armbench.bench.suites.startup_conditions import (
    CONDITIONS,
    Condition,
    band,
    parse_condition,
    signed_range,
    targets,
)
from armbench.bench.suites.startup_contract import STARTUP
from armbench.bench.suites.startup_watch import (
    await_recovery,
    motion_at,
    rescue,
    stalled_joints,
)
from armbench.bench.suites.truth_probe import TruthProbe
from armbench.drivers.host.motion import coordinated_duties, joint_times_s
from armbench.drivers.model.bounds import Bound, check, check_whole
from armbench.drivers.model.protocol import MAX_DUTY
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.record import Measurement, Trial
from armbench.record.suite_contract import SAMPLE

S: Final = STARTUP
#: The least room a band may leave a joint between its limit and the cut (rad).
MIN_ROOM_RAD: Final = 0.02

__all__ = [
    "ATMEGA328P_EEPROM_CYCLES",
    "CONDITIONS",
    "Condition",
    "StartupRecoverySuite",
    "eeprom_life_years",
    "parse_condition",
]

class StartupRecoverySuite(Suite):
    """Power cuts in every condition of §5.2, and the EEPROM wear (see module doc)."""

    name = S.suite
    version = "1"
    metric_units: ClassVar[Mapping[str, str]] = {
        S.metric("*_pct"): "%", S.metric("*_s"): "s", S.metric("*_mrad"): "mrad",
        S.metric("*_mm"): "mm", S.recovered: "bool", S.trials_measured: "",
        S.metric("*_per_hour"): "writes/h", S.eeprom_writes: "writes",
        S.eeprom_writes_per_cut: "writes", S.eeprom_life_years: "years",
        S.eeprom_life_hours: "h"}

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
        check_whole(f"{w}.trials", params["trials"], Bound(0, MAX_REPEATS))
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
                joints.add(check_whole(f"{w}.joint_sets", j, Bound(1, len(settings.joints))))
        check_whole(f"{w}.duty", params["duty"], Bound(1, MAX_DUTY))
        for key, low, high in (("near_band_rad", 0.0, 3.0), ("far_band_rad", 0.0, 3.0),
                               ("cut_fraction", 0.0, 1.0), ("stopped_dwell_s", 0.0, 60.0)):
            pair = params[key]
            if isinstance(pair, (str, bytes)) or not isinstance(pair, Sequence) or len(pair) != 2:
                raise SettingsError(f"{w}.{key}", pair, "is not a pair [low, high]")
            a = check(f"{w}.{key}", pair[0], Bound(low, high))
            check(f"{w}.{key}", pair[1], Bound(a, high, low_open=True, why="the pair's high: "
                                                                          "above its low"))
        check(f"{w}.off_s", params["off_s"], Bound(0.0, 60.0, "s"))
        check(f"{w}.recovery_timeout_s", params["recovery_timeout_s"],
              Bound(0.0, 3600.0, "s", low_open=True))
        check(f"{w}.tolerance_rad", params["tolerance_rad"], Bound(0.0, low_open=True, unit="rad"))
        check(f"{w}.tolerance_mm", params["tolerance_mm"], Bound(0.0, low_open=True, unit="mm"))
        check(f"{w}.still_s", params["still_s"], Bound(0.0, 10.0, "s"))
        check_bool(f"{w}.rescue", params["rescue"])
        check(f"{w}.wear_duration_s", params["wear_duration_s"], Bound(0.0, MAX_WEAR_S, "s"))
        check(f"{w}.use_hours_per_year", params["use_hours_per_year"],
              Bound(0.0, 8784.0, "h", low_open=True))
        for zone in ("near", "far"):
            for j in sorted(joints):
                for side in (1, -1):
                    a, b = signed_range(settings, int(j) - 1, *band(params, zone), side)
                    check(f"{w}.{zone}_band_rad", abs(b - a), Bound(
                        MIN_ROOM_RAD, unit="rad", why=f"the room it leaves joint {j} on its "
                                                      f"{'+' if side > 0 else '-'} side"))

    def metric_names(self, params: Mapping[str, Any]) -> frozenset[str]:
        """The figures of a cut and over all cuts, the rate of each of ``conditions``, and the
        wear figures when ``wear_duration_s`` > 0."""
        return S.metric_names(params["conditions"], float(params["wear_duration_s"]) > 0)

    def plan(self, params: Mapping[str, Any]) -> list[dict[str, Any]]:
        """``trials`` cuts cycling through ``conditions`` (inner) and ``joint_sets`` (outer: the
        first round of conditions moves the first set, ...), then the wear trial (if any)."""
        conditions = list(params["conditions"])
        sets = [list(g) for g in params["joint_sets"]]
        out: list[dict[str, Any]] = [
            {S.kind: S.cut_kind, S.condition: conditions[i % len(conditions)],
             S.joints: sets[(i // len(conditions)) % len(sets)], S.cut: i}
            for i in range(int(params["trials"]))]
        if float(params["wear_duration_s"]) > 0:
            out.append({S.kind: S.wear_kind, S.duration: float(params["wear_duration_s"])})
        return out

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        """One power cut (``kind="cut"``) or the wear measurement (``kind="wear"``)."""
        p = ctx.params
        if trial_params.get(S.kind) == S.wear_kind:
            duration = float(trial_params[S.duration])
            ctx.progress(f"{S.suite}: EEPROM wear over {duration:g} s of typical use")
            return await guarded_trial(ctx, index, trial_params,
                                       lambda samples: measure_wear(ctx, duration, samples),
                                       timeout_s=3.0 * duration + 300.0)
        condition = parse_condition(str(trial_params[S.condition]))
        ctx.progress(f"{S.suite}: cut {trial_params.get(S.cut, index)} "
                     f"({condition.name})")
        # Generous: a manual power switch waits for the operator twice per cut.
        timeout_s = 600.0 + 3.0 * float(p["recovery_timeout_s"]) + float(p["off_s"])
        return await guarded_trial(ctx, index, trial_params,
                                   lambda samples: self._cut(ctx, condition,
                                                             trial_params[S.joints], samples),
                                   timeout_s=timeout_s)

    # --- one power cut --------------------------------------------------------------------------

    async def _cut(self, ctx: SuiteContext, condition: Condition, joints: Sequence[int],
                   samples: list[dict[str, Any]]) -> tuple[list[dict[str, Any]],
                                                           list[Measurement]]:
        p = ctx.params
        arm = ctx.arm
        rng = ctx.rng
        t0 = loop_time()

        def log(event: str, **data: Any) -> dict[str, Any]:
            s = {SAMPLE.t: round(loop_time() - t0, 6), SAMPLE.event: event, **data}
            samples.append(s)
            return s

        if ctx.power is None:
            reason = ("no power switch configured (give --power-command or --power-manual, or "
                      "a labgrid place's power)")
            log(S.ev_skipped, reason=reason)
            raise TrialSkipped(reason)
        probe = TruthProbe(ctx)
        duty = int(p["duty"])
        start, end = targets(ctx, condition, joints)
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
            motion = motion_at(list(recent), before)
        cut_true = probe.joints()
        await ctx.power.power_off()
        t_cut = loop_time()
        log(S.ev_fault, kind="power_cut", condition=condition.name,
            reported_q_rad=rad_list(before.q_rad),
            true_q_rad=None if cut_true is None else rad_list(cut_true), motion=motion,
            cut_fraction=None if cut_fraction is None else round(cut_fraction, 4))
        await asyncio.sleep(float(p["off_s"]))
        await ctx.power.power_on()
        t_on = loop_time()
        log(S.ev_power_restore, off_s=round(t_on - t_cut, 6))

        # What the reported joints should say once recovered.
        hall = [j.hall_rad for j in ctx.settings.joints]
        fixed = [hall[i] if motion[i] != "stopped" else before.q_rad[i]
                 for i in range(len(hall))]
        judge = RecoveryJudge(probe, fixed, float(p["tolerance_rad"]),
                              float(p["tolerance_mm"]) / 1000.0, ctx.settings, t_on,
                              float(p["still_s"]), arm.state.seq, log)
        result = await await_recovery(arm, judge, float(p["recovery_timeout_s"]), log)
        counters1 = eeprom_counters(arm)
        stalled = stalled_joints(arm)
        recovered = result.recovered_s is not None
        failure = None if recovered else ("no_reply" if result.first_reply_s is None
                                          else "position")
        log(S.ev_outcome, **{S.f_recovered: recovered, S.f_failure: failure,
                             S.condition: condition.name, S.f_expected:
                             condition.expected_to_recover, S.f_recovery: result.recovered_s},
            joints=list(joints),
            motion=motion, toward_hall=condition.relation == "toward", zone=condition.zone,
            cut_true_q_rad=None if cut_true is None else rad_list(cut_true),
            cut_reported_q_rad=rad_list(before.q_rad),
            final_q_rad=None if result.last is None else rad_list(result.last.q_rad),
            compared_with=result.compared_with,
            **{S.f_error_mm if result.compared_with == "truth_m" else S.f_error_mrad:
               None if result.error_rad is None else round(result.error_rad * 1e3, 4)},
            first_reply_s=result.first_reply_s,
            stalled_joints=stalled)
        ms = Measurements(ctx)
        ms.add(S.recovered, 1.0 if recovered else 0.0, "bool", better="higher",
               description="the arm replied with its true position after the power cut")
        ms.add(S.recovery_time, result.recovered_s, "s",
               description="power-on to the first reply of the final within-tolerance window")
        ms.add(S.first_reply, result.first_reply_s, "s",
               description="power-on to the first reply")
        if result.error_rad is not None and result.compared_with != "truth_m":
            ms.add(S.position_error_mrad, result.error_rad * 1e3, "mrad",
                   description="largest joint error of the final reply against the reference")
        if result.error_rad is not None and result.compared_with == "truth_m":
            ms.add(S.position_error_mm, result.error_rad * 1e3, "mm",
                   description="TCP error of the final reply against the tracker")
        if counters0 is not None and counters1 is not None:
            ms.add(S.eeprom_writes, float(sum(counters1[0]) - sum(counters0[0])),
                   "writes", better="lower",
                   description="EEPROM record writes of all joints during the trial")
        if not recovered and bool(p["rescue"]):
            await rescue(ctx, log)
        return samples, ms.items

    # --- summary --------------------------------------------------------------------------------

    def summarize(self, ctx: SuiteContext, trials: Sequence[Trial]) -> list[Measurement]:
        """Success rate (overall and per condition), worst recovery time and position error,
        EEPROM writes per cut and the wear projection."""
        ms = Measurements(ctx)
        outcomes = [(t, _outcome(t)) for t in trials
                    if t.status == "done" and t.params.get(S.kind) == S.cut_kind]
        measured = [(t, o) for t, o in outcomes if o is not None]
        ms.add(S.trials_measured, float(len(measured)), "",
               description="power cuts carried out and judged")
        if measured:
            ok = [o for _, o in measured if o[S.f_recovered]]
            ms.add(S.success_rate, 100.0 * len(ok) / len(measured), "%",
                   better="higher", description="power cuts after which the arm recovered")
            expected = [o for _, o in measured if o[S.f_expected]]
            if expected:
                good = [o for o in expected if o[S.f_recovered]]
                ms.add(S.expected_success_rate, 100.0 * len(good) / len(expected),
                       "%", better="higher",
                       description="recoveries among the cuts §5.2 can handle (not towards the "
                                   "Hall sensor)")
            times = [float(o[S.f_recovery]) for o in ok if o[S.f_recovery] is not None]
            if times:
                ms.add(S.recovery_time_max, max(times), "s",
                       description="slowest recovery")
                ms.add(S.recovery_time_mean, float(np.mean(times)), "s",
                       description="mean recovery time")
            errors = [float(o[S.f_error_mrad]) for _, o in measured
                      if o.get(S.f_error_mrad) is not None]
            if errors:
                ms.add(S.position_error_max, max(errors), "mrad",
                       description="largest joint error after a cut (failed recoveries too)")
            ok_errors = [float(o[S.f_error_mrad]) for o in ok if o.get(S.f_error_mrad) is not None]
            if ok_errors:
                ms.add(S.recovered_position_error_max, max(ok_errors), "mrad",
                       description="largest joint error after a successful recovery")
            for name in dict.fromkeys(str(o[S.condition]) for _, o in measured):
                group = [o for _, o in measured if o[S.condition] == name]
                rate = 100.0 * sum(1 for o in group if o[S.f_recovered]) / len(group)
                ms.add(S.condition_rate(name), rate, "%", better="higher",
                       description=f"recoveries after cuts in condition {name}")
            writes = [m.value for t, _ in measured for m in t.measurements
                      if m.name == S.eeprom_writes]
            if writes:
                ms.add(S.eeprom_writes_per_cut, float(np.mean(writes)), "writes",
                       better="lower", description="mean EEPROM record writes per cut trial")
        hours_per_year = float(ctx.params["use_hours_per_year"])
        for t in trials:
            if t.status != "done" or t.params.get(S.kind) != S.wear_kind:
                continue
            for s in t.samples:
                if s.get(SAMPLE.event) == S.ev_wear_phase:
                    ms.add(S.phase_writes(s["phase"]),
                           float(s["writes_per_hour"]), "writes/h", better="lower",
                           description=f"EEPROM record writes per hour of {s['phase']} motion, "
                                       "busiest joint")
                elif s.get(SAMPLE.event) == S.ev_wear:
                    years = s["life_years"]
                    wear_measurements(ms, float(s["writes_per_hour"]),
                                       float(s["cell_wear_per_hour"]),
                                       math.inf if years is None else float(years),
                                       hours_per_year)
        return ms.items




def _outcome(trial: Trial) -> Mapping[str, Any] | None:
    for s in trial.samples:
        if s.get(SAMPLE.event) == S.ev_outcome:
            return s
    return None


