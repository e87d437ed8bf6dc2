"""ISO 230-2 style bidirectional positioning of each joint: accuracy, repeatability and reversal
error per joint, on any port.

One trial per joint of ``joints`` (the others hold ``home_rad``). Each of ``cycles`` cycles (ISO
230-2: 5) runs the joint from ``overtravel_rad`` below the lowest target up through every target
of ``targets_frac`` (fractions of the way from the lower to the upper limit; ISO: at least 5),
stopping ``settle_s`` at each (approach ↑), past the highest by the overtravel, and back down
through every target (approach ↓): the linear cycle of ISO 230-2 §4.3. At each stop the reply is
sampled and, with a truth source, the true joint angle beside it.

Figures (:func:`armbench.metrics.iso230.axis_positioning`) in mrad, of the reported angle
(the firmware's encoder: play and deflection do not show) and with a truth source of the true one
(``true_`` names): ``joints.jN.accuracy_mrad`` (A), ``repeatability_mrad`` (R), ``reversal_mrad``
(B), ``mean_reversal_mrad`` (B̄, signed), ``systematic_mrad`` (E).
"""

from __future__ import annotations

import asyncio
from collections.abc import Mapping, Sequence
from typing import Any, Final

from armbench.bench.suites._common import (
    MAX_REPEATS,
    Measurements,
    guarded_trial,
    loop_time,
    settled_state,
)
from armbench.bench.suites.base import Suite, SuiteContext
from armbench.bench.suites.joints_contract import JOINTS
from armbench.bench.suites.truth_probe import TruthProbe
from armbench.drivers.model.bounds import Bound, check, check_whole
from armbench.drivers.model.protocol import MAX_DUTY
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.metrics import MetricsInputError
from armbench.metrics.iso230 import axis_positioning
from armbench.record import Measurement, Trial

__all__ = ["JointsSuite", "joint_figures", "joint_targets"]

MRAD_PER_RAD: Final = 1000.0
_DESCRIPTIONS: Final = dict(zip(JOINTS.all_figures, (
    "ISO 230-2 bidirectional accuracy A",
    "ISO 230-2 bidirectional repeatability R",
    "ISO 230-2 reversal error B (largest over the targets)",
    "ISO 230-2 mean reversal error (signed)",
    "ISO 230-2 bidirectional systematic positioning error E"), strict=True))


def joint_targets(settings: RobotSettings, joint: int, fractions: Sequence[float]) -> list[float]:
    """Target angles (rad) of ``joint`` (1..4): ``fractions`` of the way through its limits."""
    spec = settings.joints[joint - 1]
    return [spec.lower_rad + f * (spec.upper_rad - spec.lower_rad) for f in fractions]


def joint_figures(samples: Sequence[Mapping[str, Any]], key: str = "q_rad"
                  ) -> dict[str, float]:
    """The ISO 230-2 figures (mrad) of one joint's samples (``target_rad``, ``direction``, and the
    attained angle under ``key``); empty when a target lacks two approaches in a direction."""
    targets = sorted({float(s["target_rad"]) for s in samples if key in s})
    up = [[float(s[key]) - t for s in samples if s["target_rad"] == t and s["direction"] > 0
           and key in s] for t in targets]
    down = [[float(s[key]) - t for s in samples if s["target_rad"] == t and s["direction"] < 0
             and key in s] for t in targets]
    try:
        f = axis_positioning(targets, up, down)
    except MetricsInputError:
        return {}
    values = (f.accuracy, f.repeatability, f.reversal, f.mean_reversal, f.systematic)
    return {figure: value * MRAD_PER_RAD
            for figure, value in zip(JOINTS.all_figures, values, strict=True)}


class JointsSuite(Suite):
    """ISO 230-2 bidirectional positioning per joint (see module doc)."""

    name = JOINTS.suite
    version = "1"

    def default_params(self, settings: RobotSettings) -> dict[str, Any]:
        """Defaults: all four joints, 5 targets over the middle 60 % of each range, 5 cycles."""
        return {"joints": [1, 2, 3, 4], "targets_frac": [0.2, 0.35, 0.5, 0.65, 0.8],
                "cycles": 5, "overtravel_rad": 0.05, "duty": MAX_DUTY, "settle_s": 0.25,
                "home_rad": [0.0, 0.0, 0.0, 0.0]}

    def validate(self, settings: RobotSettings, params: Mapping[str, Any]) -> None:
        """Types and ranges; every target and overtravel point within the joint limits."""
        where = f"suites.{self.name}"
        joints = params["joints"]
        if (not isinstance(joints, list) or not joints
                or any(isinstance(j, bool) or j not in (1, 2, 3, 4) for j in joints)
                or len(set(joints)) != len(joints)):
            raise SettingsError(f"{where}.joints", joints, "must list some of 1, 2, 3, 4 once each")
        fracs = params["targets_frac"]
        if not isinstance(fracs, list) or not 2 <= len(fracs) <= MAX_REPEATS:
            raise SettingsError(f"{where}.targets_frac", fracs,
                                f"must list 2 to {MAX_REPEATS} fractions")
        for f in fracs:
            check(f"{where}.targets_frac", f, Bound(0.0, 1.0))
        if len(set(fracs)) != len(fracs):
            raise SettingsError(f"{where}.targets_frac", fracs, "has repeated targets")
        check_whole(f"{where}.cycles", params["cycles"], Bound(2, MAX_REPEATS))
        over = check(f"{where}.overtravel_rad", params["overtravel_rad"],
                     Bound(0.0, 0.5, "rad", low_open=True))
        check_whole(f"{where}.duty", params["duty"], Bound(1, MAX_DUTY))
        check(f"{where}.settle_s", params["settle_s"], Bound(0.0, 60.0, "s"))
        home = params["home_rad"]
        if not isinstance(home, list) or len(home) != 4:
            raise SettingsError(f"{where}.home_rad", home, "is not a list of 4 angles")
        for q, spec in zip(home, settings.joints, strict=True):
            check(f"{where}.home_rad", q, Bound(spec.lower_rad, spec.upper_rad, "rad",
                                                why=f"{spec.name}'s limits"))
        for j in joints:
            spec = settings.joints[j - 1]
            targets = joint_targets(settings, j, fracs)
            room = min(min(targets) - spec.lower_rad, spec.upper_rad - max(targets))
            check(f"{where}.overtravel_rad", over, Bound(
                high=room, unit="rad", why=f"the room joint {j}'s targets leave to its limits"))

    def metric_names(self, params: Mapping[str, Any]) -> frozenset[str]:
        """The figures of each joint of ``joints``, reported and true."""
        return JOINTS.metric_names(params["joints"])

    def plan(self, params: Mapping[str, Any]) -> list[dict[str, Any]]:
        """One trial per joint."""
        return [{JOINTS.joint: j} for j in params["joints"]]

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        """All cycles of one joint."""
        p = ctx.params
        joint = int(trial_params[JOINTS.joint])
        j = joint - 1
        targets = sorted(joint_targets(ctx.settings, joint, p["targets_frac"]))
        over, duty, settle = float(p["overtravel_rad"]), int(p["duty"]), float(p["settle_s"])
        probe = TruthProbe(ctx)
        ctx.progress(f"joints: joint {joint}")

        async def body(samples: list[dict[str, Any]]) -> tuple[list[dict[str, Any]],
                                                               list[Measurement]]:
            arm = ctx.arm
            pose = [float(v) for v in p["home_rad"]]
            t0 = loop_time()

            async def go(q: float) -> None:
                pose[j] = q
                await arm.move_joints(pose, duty)

            for cycle in range(int(p["cycles"])):
                await go(targets[0] - over)
                for direction, order in ((1, targets), (-1, targets[::-1])):
                    for target in order:
                        await go(target)
                        state = await settled_state(arm, settle)
                        sample: dict[str, Any] = {
                            "t_s": round(state.t_s - t0, 6), "cycle": cycle,
                            "target_rad": target, "direction": direction,
                            "q_rad": round(state.q_rad[j], 6)}
                        true = probe.joints(state)
                        if true is not None:
                            sample[JOINTS.true_angle] = round(true[j], 7)
                        samples.append(sample)
                    if direction > 0:
                        await go(targets[-1] + over)
                await asyncio.sleep(0)
            ms = Measurements(ctx)
            _add(ms, joint, "", joint_figures(samples))
            _add(ms, joint, JOINTS.true, joint_figures(samples, JOINTS.true_angle))
            return samples, ms.items

        timeout_s = 60.0 + 20.0 * int(p["cycles"]) * len(targets)
        return await guarded_trial(ctx, index, trial_params, body, timeout_s=timeout_s)

    def summarize(self, ctx: SuiteContext, trials: Sequence[Trial]) -> list[Measurement]:
        """The per-joint figures again, one set per joint measured."""
        ms = Measurements(ctx)
        for t in trials:
            if t.status != "done":
                continue
            joint = int(t.params[JOINTS.joint])
            _add(ms, joint, "", joint_figures(t.samples))
            _add(ms, joint, JOINTS.true, joint_figures(t.samples, JOINTS.true_angle))
        return ms.items


def _add(ms: Measurements, joint: int, prefix: str, figures: Mapping[str, float]) -> None:
    for key, value in figures.items():
        what = "true" if prefix else "reported"
        ms.add(JOINTS.metric(joint, key, true=bool(prefix)), value, "mrad",
               undirected=key == JOINTS.mean_reversal,
               description=f"{_DESCRIPTIONS[key]}, {what} angle")
