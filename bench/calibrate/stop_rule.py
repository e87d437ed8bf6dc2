"""Which rule stops the arm's joints (``emulator.stop_rule``), chosen by where its approaches came
to rest.

The paper's state machine stops a joint when its "position error is null" (§5.1, Fig. 7); an
encoder of 5/4 counts per microstep skips counts, so a firmware must say what it does there
(``docs/emulator.md``): stop inside a deadband (``window``) or once the target is met or
passed (``reach``). Each ISO 230-2 approach ends at rest on its target (the Hall position) with
a reply whose difference from the target (wire ticks) the rule decides, together with where the
Hall sensor, which resets the counter, really is: the twin's joint is replayed from the
approach's start under each rule, its counter as the sensor sets it. The sensor's position error
is the fitted one where the calibration identified it; elsewhere it is unknown, one per joint,
and each of its possible positions (every microstep within the documented range) is replayed:
the joint's likelihood is their mean (the error marginalised). The approaches' log-likelihood
under each rule (a share :data:`OUTSIDE` of replies allowed to differ for reasons outside the
rule, a spurious count or a reply in flight) compares them: no parameter is fitted to the rests,
so every approach is held out. The prior's rule is replaced only when the other's ``−2 log L``
is lower by :data:`MARGIN`; the weight ``exp(−(−2 log L)/2)``, normalised, says how sure the
choice is.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from typing import Final

from armbench.bench.calibrate.model import APPROACH_OFFSET_RAD, Approach, Fitted, Observations
from armbench.drivers.model.protocol import MAX_DUTY, MAX_TICKS, rad_to_ticks, ticks_to_rad
from armbench.drivers.model.settings import JointSettings, RobotSettings
from armbench.drivers.model.twin_parameters import TWIN
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.fakes.twin.joint import JointModel
from armbench.fakes.twin.physics import ideal_joint
from armbench.fakes.twin.stepper import STOP_RULES, StopRule

__all__ = ["MARGIN", "OUTSIDE", "STOP_RULE_KEY", "choose_stop_rule", "hall_errors_rad",
           "rest_offset_ticks"]

#: The settings key the choice is written to.
STOP_RULE_KEY: Final = "emulator.stop_rule"
#: ``−2 log L`` the other rule must gain over the prior's to replace it (as a χ² margin).
MARGIN: Final = 4.0
#: Share of approaches whose rest may differ for a reason outside the stop rule; such a reply
#: has probability ``OUTSIDE · 2^−|d| / 3`` at ``d`` ticks.
OUTSIDE: Final = 0.05
#: Control cycles an approach may take in the replay (far more than 0.04 rad at full speed).
_HORIZON_TICKS: Final = 10_000_000


def _wrap_ticks(d: int) -> int:
    """A tick difference within half a turn of 0."""
    return (d + MAX_TICKS // 2) % MAX_TICKS - MAX_TICKS // 2


def rest_offset_ticks(joint: JointSettings, hall_error_rad: float, rule: StopRule,
                      deadband_counts: int, target_rad: float, direction: int) -> int:
    """Where the twin's joint rests after an approach to ``target_rad`` moving ``direction`` at
    full duty, as reply minus target (ticks), with its Hall sensor ``hall_error_rad`` off and
    its counter as the sensor sets it."""
    target_ticks = rad_to_ticks(target_rad)
    q = ticks_to_rad(target_ticks, joint.lower_rad, joint.upper_rad)
    target_counts = round(q * joint.counts_per_rad)
    start = round((target_rad - direction * APPROACH_OFFSET_RAD) * joint.steps_per_rad)
    physics = ideal_joint(hall_error_rad=hall_error_rad)
    hall = JointModel(joint, physics=physics, motor_steps=start)
    c = joint.counts_per_step
    counter = hall.hall_count - math.floor(hall.hall_step * c) + math.floor(start * c)
    model = JointModel(joint, physics=physics, deadband_counts=deadband_counts, stop_rule=rule,
                       motor_steps=start, counter=counter)
    model.set_reference(0, target_counts, MAX_DUTY)
    model.advance(_HORIZON_TICKS)
    return _wrap_ticks(rad_to_ticks(model.counter / joint.counts_per_rad) - target_ticks)


def hall_errors_rad(joint: JointSettings, fitted: Fitted | None) -> list[float]:
    """The Hall position errors a joint's rests are replayed with: the fitted one where
    identified, else one per microstep position within the documented range."""
    if fitted is not None and fitted.identified:
        return [math.radians(fitted.value)]
    hall = TWIN["hall_error_rad"]
    low, high = hall.to_twin(hall.low), hall.to_twin(hall.high)
    spr = joint.steps_per_rad
    first = math.ceil((joint.hall_rad + low) * spr)
    last = math.floor((joint.hall_rad + high) * spr)
    return [h / spr - joint.hall_rad for h in range(first, last + 1)]


def _log_p(predicted: int, seen: int) -> float:
    return math.log((1.0 - OUTSIDE) * (predicted == seen) + OUTSIDE * 0.5 ** abs(seen) / 3.0)


def _log_mean_exp(values: Sequence[float]) -> float:
    top = max(values)
    return top + math.log(math.fsum(math.exp(v - top) for v in values) / len(values))


def choose_stop_rule(obs: Observations, base: RobotSettings,
                     hall: Sequence[Fitted] = ()) -> Fitted:
    """The stop rule the approaches of ``obs`` favour over the base settings' (see the module
    doc); ``hall``: the calibration's Hall position errors (``hall_error_deg``). The prior's
    rule, with the reason, when they do not by :data:`MARGIN` or there are none."""
    emu = emulator_settings(base)
    prior: StopRule = emu.stop_rule
    by_joint: dict[int, list[tuple[Approach, int]]] = {}
    for a in obs.approaches:
        if not 1 <= a.joint <= len(base.joints) or a.direction not in (1, -1):
            continue
        seen = rad_to_ticks(a.reported_rad[a.joint - 1]) - rad_to_ticks(a.target_rad)
        by_joint.setdefault(a.joint - 1, []).append((a, _wrap_ticks(seen)))
    if not by_joint:
        return Fitted(STOP_RULE_KEY, math.nan, None, "", False, "no approaches measured",
                      choice=prior)
    fitted_hall = {f.key: f for f in hall}
    score: dict[StopRule, float] = {}
    for rule in STOP_RULES:
        total = 0.0
        for j, rests in by_joint.items():
            joint = base.joints[j]
            errors = hall_errors_rad(joint, fitted_hall.get(TWIN["hall_error_rad"].path(j)))
            memo: dict[tuple[float, float, int], int] = {}
            per_error = []
            for e in errors:
                ll = 0.0
                for a, seen in rests:
                    key = (e, a.target_rad, a.direction)
                    if key not in memo:
                        memo[key] = rest_offset_ticks(joint, e, rule, emu.deadband_counts,
                                                      a.target_rad, a.direction)
                    ll += _log_p(memo[key], seen)
                per_error.append(ll)
            total += _log_mean_exp(per_error)
        score[rule] = -2.0 * total
    best = min(STOP_RULES, key=lambda r: score[r])
    low = min(score.values())
    weights = {r: math.exp(-(s - low) / 2.0) for r, s in score.items()}
    weight = weights[best] / math.fsum(weights.values())
    shown = ", ".join(f"{r} {score[r]:.3g}" for r in STOP_RULES)
    rested = Counter(seen for rests in by_joint.values() for _, seen in rests)
    where = ", ".join(f"{n} at {d:+d}" for d, n in sorted(rested.items()))
    text = (f"{rested.total()} approaches rested ({where} ticks from the target); −2 log L: "
            f"{shown}")
    if best != prior and score[prior] - score[best] > MARGIN:
        return Fitted(STOP_RULE_KEY, weight, None, "", True,
                      f"{best} (weight {weight:.2f}): {text}", choice=best)
    return Fitted(STOP_RULE_KEY, math.nan, None, "", False,
                  f"the approaches do not favour another rule beyond the margin ({text})",
                  choice=prior)
