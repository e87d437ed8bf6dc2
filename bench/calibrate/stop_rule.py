"""Which rule stops the arm's joints (``emulator.stop_rule``), chosen by where its approaches came
to rest.

The paper's state machine stops a joint when its "position error is null" (§5.1, Fig. 7); an
encoder of 5/4 counts per microstep skips counts, so a firmware must say what it does there
(``docs/emulator.md``): stop inside a deadband (``window``) or once the target is met or
passed (``reach``). Each ISO 230-2 approach ends at rest on its target with a reply whose
difference from the target (wire ticks) the rule decides: the twin's joint, replayed from the
approach's start at every phase of its microsteps against its encoder counts, gives each rule's
distribution of that difference. The approaches' log-likelihood under each rule (a share
:data:`OUTSIDE` of replies allowed to differ for reasons outside the rule, a spurious count or
a reply in flight) compares them: no parameter is fitted, so every approach is held out. The
prior's rule is replaced only when the other's ``−2 log L`` is lower by :data:`MARGIN`; the
weight ``exp(−(−2 log L)/2)``, normalised, says how sure the choice is.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Final

from armbench.bench.calibrate.model import APPROACH_OFFSET_RAD, Approach, Fitted, Observations
from armbench.drivers.protocol import MAX_DUTY, MAX_TICKS, rad_to_ticks, ticks_to_rad
from armbench.drivers.settings import JointSettings, RobotSettings
from armbench.fakes.emulator_settings import emulator_settings
from armbench.fakes.joint import JointModel
from armbench.fakes.physics import JointPhysics
from armbench.fakes.stepper import STOP_RULES, StopRule

__all__ = ["MARGIN", "OUTSIDE", "STOP_RULE_KEY", "choose_stop_rule", "rest_offsets_ticks"]

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


def rest_offsets_ticks(joint: JointSettings, physics: JointPhysics | None, rule: StopRule,
                       deadband_counts: int, target_rad: float, direction: int) -> Counter[int]:
    """Where the twin's joint rests after an approach to ``target_rad`` moving ``direction`` at
    full duty, as reply minus target (ticks), counted over every phase of its microsteps against
    its encoder counts (its counter as the Hall sensor sets it)."""
    target_ticks = rad_to_ticks(target_rad)
    q = ticks_to_rad(target_ticks, joint.lower_rad, joint.upper_rad)
    target_counts = round(q * joint.counts_per_rad)
    start = round((target_rad - direction * APPROACH_OFFSET_RAD) * joint.steps_per_rad)
    hall = JointModel(joint, physics=physics)
    out: Counter[int] = Counter()
    for k in range(joint.counts_per_step.denominator):
        # the counter as the Hall sensor left it: hall_count at the Hall's motor position
        counter = hall.hall_count + math.floor((start + k - hall.hall_step)
                                               * joint.counts_per_step)
        model = JointModel(joint, physics=physics, deadband_counts=deadband_counts,
                           stop_rule=rule, motor_steps=start + k, counter=counter)
        model.set_reference(0, target_counts, MAX_DUTY)
        model.advance(_HORIZON_TICKS)
        reply = rad_to_ticks(model.counter / joint.counts_per_rad)
        out[_wrap_ticks(reply - target_ticks)] += 1
    return out


def _log_p(offsets: Counter[int], seen: int) -> float:
    n = sum(offsets.values())
    return math.log((1.0 - OUTSIDE) * offsets.get(seen, 0) / n
                    + OUTSIDE * 0.5 ** abs(seen) / 3.0)


def choose_stop_rule(obs: Observations, base: RobotSettings) -> Fitted:
    """The stop rule the approaches of ``obs`` favour over the base settings' (see the module
    doc); the prior's, with the reason, when they do not by :data:`MARGIN` or there are none."""
    emu = emulator_settings(base)
    prior: StopRule = emu.stop_rule
    physics = emu.physics
    rests: list[tuple[Approach, int]] = []
    for a in obs.approaches:
        if not 1 <= a.joint <= len(base.joints) or a.direction not in (1, -1):
            continue
        seen = rad_to_ticks(a.reported_rad[a.joint - 1]) - rad_to_ticks(a.target_rad)
        rests.append((a, _wrap_ticks(seen)))
    if not rests:
        return Fitted(STOP_RULE_KEY, math.nan, None, "", False, "no approaches measured",
                      choice=prior)
    score: dict[StopRule, float] = {}
    cache: dict[tuple[StopRule, int, float, int], Counter[int]] = {}
    for rule in STOP_RULES:
        total = 0.0
        for a, seen in rests:
            key = (rule, a.joint, a.target_rad, a.direction)
            if key not in cache:
                j = a.joint - 1
                cache[key] = rest_offsets_ticks(
                    base.joints[j], None if physics is None else physics.joints[j], rule,
                    emu.deadband_counts, a.target_rad, a.direction)
            total += _log_p(cache[key], seen)
        score[rule] = -2.0 * total
    best = min(STOP_RULES, key=lambda r: score[r])
    low = min(score.values())
    weights = {r: math.exp(-(s - low) / 2.0) for r, s in score.items()}
    weight = weights[best] / math.fsum(weights.values())
    shown = ", ".join(f"{r} {score[r]:.3g}" for r in STOP_RULES)
    rested = Counter(seen for _, seen in rests)
    where = ", ".join(f"{n} at {d:+d}" for d, n in sorted(rested.items()))
    text = (f"{len(rests)} approaches rested ({where} ticks from the target); −2 log L: "
            f"{shown}")
    if best != prior and score[prior] - score[best] > MARGIN:
        return Fitted(STOP_RULE_KEY, weight, None, "", True,
                      f"{best} (weight {weight:.2f}): {text}", choice=best)
    return Fitted(STOP_RULE_KEY, math.nan, None, "", False,
                  f"the approaches do not favour another rule beyond the margin ({text})",
                  choice=prior)

