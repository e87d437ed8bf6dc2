"""ISO 9283 pose accuracy and repeatability, distance, multi-directional and path characteristics.

Test cube (``cube_centre_m``, ``cube_side_m``) in the reachable workspace; P1 at its centre and
P2..P5 on the diagonal plane ``plane`` at 10 % of the diagonal from its corners
(:func:`armbench.metrics.iso_cube_poses`). At each speed of ``speeds_pct`` (percent of the rated
joint speed; law (12) maps it to a duty, see
:func:`armbench.bench.suites._common.duty_for_speed_pct`):

* ``pose`` trials, one per cycle (``cycles``, ISO: 30): P1 → P5 → P4 → P3 → P2, each pose
  reached through an approach point ``approach_offset_m`` away from it, so every pose is entered
  from the same side (the gear play and the encoder deadband are taken up the same way each time);
  after ``settle_s`` the reply is sampled. Gives AP / RP per pose (§7.2.1, §7.2.2) and AD / RD
  between P2 and P4 (§7.4).
* ``vap`` trials, one per cycle (``vap_cycles``): each pose of ``vap_poses`` approached from three
  directions parallel to the base axes (travelling +x, +y, +z into the pose from ``vap_offset_m``
  away). Gives vAP (§7.3).
* ``path`` trials, one per cycle (``path_cycles``, ISO: 10): the straight line P2 → P4 with
  ``follow_path`` at ``speed_pct`` % of ``path_speed_m_s``, the reply stream sampled every
  ``sample_period_s``. Gives AT / RT (§8.2, normal-plane pairing) on the interior 90 % of the line.

Every figure is computed twice when the bench has a reference instrument: from the forward
kinematics of the reported joints (the paper's way) and from the true position (``true_`` names).
Figures in mm; see ``docs/suites.md`` for names and choices.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar, Final

import numpy as np

from armbench.bench.suites._common import (
    MAX_REPEATS,
    FloatArray,
    Measurements,
    StateRecorder,
    check_branch,
    check_reachable,
    check_vec3,
    duty_for_speed_pct,
    guarded_trial,
    loop_time,
    pos_list,
    settled_state,
)
from armbench.bench.suites.base import Suite, SuiteContext
from armbench.bench.suites.repeatability_contract import REPEATABILITY
from armbench.bench.suites.workspace import (
    CYCLE_ORDER,
    DEFAULT_CUBE_CENTRE_M,
    DEFAULT_CUBE_SIDE_M,
    POSE_NAMES,
)
from armbench.drivers.model.bounds import Bound, check, check_whole
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.metrics import (
    CUBE_PLANES,
    MM_PER_M,
    MetricsInputError,
    distance_characteristics,
    iso_cube_poses,
    multidirectional_variation,
    path_characteristics,
    pose_accuracy,
    pose_repeatability,
)
from armbench.record import Measurement, Trial
from armbench.record.suite_contract import SAMPLE

R: Final = REPEATABILITY

__all__ = [
    "CYCLE_ORDER",
    "POSE_NAMES",
    "RepeatabilitySuite",
    "distance_figures",
    "path_figures",
    "pose_figures",
    "speed_label",
    "vap_figures",
]

#: Directions of travel into a pose for vAP: along +x, +y, +z of the base frame.
VAP_DIRECTIONS: Final = (("+x", (1.0, 0.0, 0.0)), ("+y", (0.0, 1.0, 0.0)),
                         ("+z", (0.0, 0.0, 1.0)))
#: The path of the AT/RT trials runs between these two poses (the distance pair of ISO too).
PATH_POSES: Final = ("P2", "P4")
#: Fraction of the path line at each end where AT/RT are not evaluated (start/stop transients and
#: the normal planes at the very ends, which a path that stops short never crosses).
PATH_END_MARGIN: Final = 0.05


def speed_label(speed_pct: float) -> str:
    """The name part of a speed: ``v100``, ``v50``, ``v10`` (``v12.5`` for fractions)."""
    return REPEATABILITY.speed_label(speed_pct)


def _positions(samples: Sequence[Mapping[str, Any]], key: str) -> FloatArray | None:
    if not samples or any(key not in s for s in samples):
        return None
    return np.array([s[key] for s in samples], dtype=np.float64).reshape(-1, 3)


def pose_figures(samples: Sequence[Mapping[str, Any]], commanded_m: Sequence[float],
                 key: str = "reported_m") -> dict[str, float]:
    """AP (``ap_mm`` = APp, signed ``ap_x_mm`` ...) and, with ≥ 2 samples, RP (``rp_mm``) of the
    attained positions ``samples[i][key]`` (m) of one pose at one speed; mm."""
    pts = _positions(samples, key)
    if pts is None:
        return {}
    ap = pose_accuracy(pts, commanded_m)
    out = dict(zip(R.with_axes(R.ap), (ap.ap_p_mm, ap.ap_x_mm, ap.ap_y_mm, ap.ap_z_mm),
                   strict=True))
    if len(pts) >= 2:
        out[R.rp] = pose_repeatability(pts).rp_mm
    return out


def distance_figures(first: Sequence[Mapping[str, Any]], second: Sequence[Mapping[str, Any]],
                     commanded_first_m: Sequence[float], commanded_second_m: Sequence[float],
                     key: str = "reported_m") -> dict[str, float]:
    """AD (``ad_mm`` signed, ``ad_x_mm`` ...) and RD (``rd_mm`` ...) between two poses, samples
    paired by cycle (≥ 2 cycles); mm."""
    a, b = _positions(first, key), _positions(second, key)
    if a is None or b is None or len(a) != len(b) or len(a) < 2:
        return {}
    d = distance_characteristics(a, b, commanded_first_m, commanded_second_m)
    return dict(zip(R.distance_figures, (d.ad_p_mm, d.ad_x_mm, d.ad_y_mm, d.ad_z_mm, d.rd_p_mm,
                                         d.rd_x_mm, d.rd_y_mm, d.rd_z_mm), strict=True))


def vap_figures(by_direction: Sequence[Sequence[Mapping[str, Any]]],
                key: str = "reported_m") -> dict[str, float]:
    """vAP (``vap_mm``, ``vap_x_mm`` ...) of one pose from the samples of each approach
    direction (≥ 2 directions with samples); mm."""
    groups = [_positions(g, key) for g in by_direction]
    if len(groups) < 2 or any(g is None for g in groups):
        return {}
    v = multidirectional_variation([g for g in groups if g is not None])
    return dict(zip(R.vap_figures, (v.vap_p_mm, v.vap_x_mm, v.vap_y_mm, v.vap_z_mm),
                    strict=True))


def path_reference(start_m: Sequence[float], end_m: Sequence[float],
                   spacing_m: float) -> FloatArray:
    """The evaluation points (m) of AT/RT on the line ``start_m`` → ``end_m``: at most
    ``spacing_m`` apart over its interior (``PATH_END_MARGIN`` left out at each end)."""
    a, b = np.asarray(start_m, dtype=np.float64), np.asarray(end_m, dtype=np.float64)
    length = float(np.linalg.norm(b - a))
    span = (1.0 - 2.0 * PATH_END_MARGIN) * length
    n = max(2, math.ceil(span / spacing_m) + 1)
    t = np.linspace(PATH_END_MARGIN, 1.0 - PATH_END_MARGIN, n)
    out: FloatArray = a[None, :] + t[:, None] * (b - a)[None, :]
    return out


def path_figures(paths: Sequence[Sequence[Mapping[str, Any]]], reference_m: FloatArray,
                 key: str = "reported_m") -> dict[str, float]:
    """AT (``at_mm``) and, with ≥ 2 paths, RT (``rt_mm``) of the recorded paths against the
    evaluation points ``reference_m`` (m), ISO normal-plane pairing; mm. Empty when a path has
    no samples of ``key`` or misses a normal plane."""
    arrays = [_positions(p, key) for p in paths]
    if not arrays or any(a is None or len(a) < 2 for a in arrays):
        return {}
    try:
        pc = path_characteristics([a for a in arrays if a is not None], reference_m,
                                  method="normal_planes")
    except MetricsInputError:
        return {}
    out = {R.at: pc.at_mm}
    if pc.rt_mm is not None:
        out[R.rt] = pc.rt_mm
    return out


class RepeatabilitySuite(Suite):
    """ISO 9283 pose and path characteristics at three speeds (see module doc)."""

    name = REPEATABILITY.suite
    version = "1"
    metric_units: ClassVar[Mapping[str, str]] = {
        "repeatability.*_mm": "mm", "repeatability.*_s": "s", "repeatability.*.cycles": ""}

    def default_params(self, settings: RobotSettings) -> dict[str, Any]:
        """Defaults: a 0.1 m cube at (0.35, 0, 0.82) m, ISO's 30 pose cycles and 10 path cycles
        at 100 / 50 / 10 % speed, 10 vAP cycles."""
        return {
            REPEATABILITY.cube_centre: list(DEFAULT_CUBE_CENTRE_M),
            REPEATABILITY.cube_side: DEFAULT_CUBE_SIDE_M,
            REPEATABILITY.plane: "C1-C2-C7-C8",
            "cycles": 30,
            REPEATABILITY.speeds: [100, 50, 10],
            "settle_s": 0.3,
            "approach_offset_m": [0.0, 0.0, 0.02],
            "vap_cycles": 10,
            "vap_poses": ["P1", "P2", "P4"],
            "vap_offset_m": 0.02,
            "path_cycles": 10,
            "path_speed_m_s": 0.1,
            "path_spacing_m": 0.005,
            "sample_period_s": 0.01,
            "branch": "front-up",
            "roll_rad": 0.0,
        }

    def validate(self, settings: RobotSettings, params: Mapping[str, Any]) -> None:
        """Types and ranges of every parameter; every pose, approach point and the path line
        reachable on ``branch`` within the joint limits."""
        w = f"suites.{self.name}"
        centre = check_vec3(f"{w}.{R.cube_centre}", params[R.cube_centre])
        side = check(f"{w}.{R.cube_side}", params[R.cube_side], Bound(0.0, 0.5, low_open=True))
        plane = params[R.plane]
        if plane not in CUBE_PLANES:
            raise SettingsError(f"{w}.plane", plane, f"is not one of {', '.join(CUBE_PLANES)}")
        check_whole(f"{w}.cycles", params["cycles"], Bound(1, MAX_REPEATS))
        speeds = params[R.speeds]
        if isinstance(speeds, (str, bytes)) or not isinstance(speeds, Sequence) or not speeds:
            raise SettingsError(f"{w}.speeds_pct", speeds, "is not a list of percentages")
        for v in speeds:
            check(f"{w}.speeds_pct", v, Bound(0.0, 100.0, low_open=True))
        if len({speed_label(float(v)) for v in speeds}) != len(speeds):
            raise SettingsError(f"{w}.speeds_pct", speeds, "lists a speed twice")
        check(f"{w}.settle_s", params["settle_s"], Bound(0.0, 60.0, "s"))
        approach = check_vec3(f"{w}.approach_offset_m", params["approach_offset_m"])
        check_whole(f"{w}.vap_cycles", params["vap_cycles"], Bound(0, MAX_REPEATS))
        vap_poses = params["vap_poses"]
        if (isinstance(vap_poses, (str, bytes)) or not isinstance(vap_poses, Sequence)
                or any(p not in POSE_NAMES for p in vap_poses)
                or len(set(vap_poses)) != len(vap_poses)):
            raise SettingsError(f"{w}.vap_poses", vap_poses,
                                f"must list some of {', '.join(POSE_NAMES)}, each once")
        vap_offset = check(f"{w}.vap_offset_m", params["vap_offset_m"],
                           Bound(0.0, 0.1, "m", low_open=True))
        check_whole(f"{w}.path_cycles", params["path_cycles"], Bound(0, MAX_REPEATS))
        check(f"{w}.path_speed_m_s", params["path_speed_m_s"],
              Bound(0.0, 1.0, "m/s", low_open=True))
        check(f"{w}.path_spacing_m", params["path_spacing_m"], Bound(0.0005, 0.05, "m"))
        check(f"{w}.sample_period_s", params["sample_period_s"], Bound(0.0, 1.0, "s"))
        branch = check_branch(f"{w}.branch", params["branch"])
        roll = check(f"{w}.roll_rad", params["roll_rad"], Bound(unit="rad"))
        poses = iso_cube_poses(centre, side, str(plane))
        points = [*poses, *(poses + np.asarray(approach))]
        for name in vap_poses:
            p = poses[POSE_NAMES.index(name)]
            points += [p - vap_offset * np.asarray(e) for _, e in VAP_DIRECTIONS]
        a, b = poses[POSE_NAMES.index(PATH_POSES[0])], poses[POSE_NAMES.index(PATH_POSES[1])]
        points += list(np.linspace(a, b, 21))
        check_reachable(f"{w}.{R.cube_centre}", points, settings, branch=branch, roll_rad=roll)

    def metric_names(self, params: Mapping[str, Any]) -> frozenset[str]:
        """Per speed of ``speeds_pct``: the pose figures of each ISO pose, vAP of each pose of
        ``vap_poses``, distance and path figures; the per-trial figures."""
        return R.metric_names(params[R.speeds], POSE_NAMES, params["vap_poses"])

    def plan(self, params: Mapping[str, Any]) -> list[dict[str, Any]]:
        """Per speed: the pose cycles, then the vAP cycles, then the path cycles; each trial one
        cycle (``{"kind", "speed_pct", "duty", "cycle"}``)."""
        out: list[dict[str, Any]] = []
        for v in params[R.speeds]:
            pct = float(v)
            duty = duty_for_speed_pct(pct)
            for kind, n in ((R.pose_kind, params["cycles"]), (R.vap_kind, params["vap_cycles"]),
                            (R.path_kind, params["path_cycles"])):
                out += [{R.kind: kind, R.speed: v, R.duty: duty, R.cycle: c}
                        for c in range(int(n))]
        return out

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        """One cycle of ``trial_params["kind"]`` at ``trial_params["speed_pct"]``."""
        p = ctx.params
        kind = str(trial_params[R.kind])
        pct = float(trial_params[R.speed])
        duty = duty_for_speed_pct(pct)
        poses = iso_cube_poses(p[R.cube_centre], float(p[R.cube_side]), str(p[R.plane]))
        branch, roll = str(p["branch"]), float(p["roll_rad"])
        settle_s = float(p["settle_s"])
        arm = ctx.arm
        ctx.progress(f"{R.suite}: {kind} cycle {trial_params[R.cycle]} at {pct:g} % "
                     f"(duty {duty})")

        async def reach(target: FloatArray, via: FloatArray) -> None:
            await arm.move_to(via, roll, branch=branch, duty=duty)
            await arm.move_to(target, roll, branch=branch, duty=duty)

        async def pose_body(samples: list[dict[str, Any]]) -> tuple[list[dict[str, Any]],
                                                                    list[Measurement]]:
            t0 = loop_time()
            rec = StateRecorder(ctx, t0, 0.0, into=samples)
            offset = np.asarray(p["approach_offset_m"], dtype=np.float64)
            for name in CYCLE_ORDER:
                target = poses[POSE_NAMES.index(name)]
                await reach(target, target + offset)
                rec.sample(await settled_state(arm, settle_s), kind=R.pose_kind, pose=name,
                           commanded_m=pos_list(target))
            return samples, _pose_error_measurements(ctx, samples)

        async def vap_body(samples: list[dict[str, Any]]) -> tuple[list[dict[str, Any]],
                                                                   list[Measurement]]:
            t0 = loop_time()
            rec = StateRecorder(ctx, t0, 0.0, into=samples)
            d = float(p["vap_offset_m"])
            for name in p["vap_poses"]:
                target = poses[POSE_NAMES.index(name)]
                for direction, e in VAP_DIRECTIONS:
                    await reach(target, target - d * np.asarray(e))
                    rec.sample(await settled_state(arm, settle_s), kind=R.vap_kind, pose=name,
                               direction=direction, commanded_m=pos_list(target))
            return samples, _pose_error_measurements(ctx, samples)

        async def path_body(samples: list[dict[str, Any]]) -> tuple[list[dict[str, Any]],
                                                                    list[Measurement]]:
            a = poses[POSE_NAMES.index(PATH_POSES[0])]
            b = poses[POSE_NAMES.index(PATH_POSES[1])]
            await reach(a, a + np.asarray(p["approach_offset_m"], dtype=np.float64))
            await settled_state(arm, settle_s)
            speed = pct / 100.0 * float(p["path_speed_m_s"])
            t0 = loop_time()
            async with StateRecorder(ctx, t0, float(p["sample_period_s"]),
                                     extra={SAMPLE.kind: R.path_kind}, into=samples):
                run = await arm.follow_path([a, b], speed_m_s=speed,
                                            spacing_m=float(p["path_spacing_m"]), branch=branch,
                                            roll_rad=roll, max_duty=duty)
            ms = Measurements(ctx)
            ref = path_reference(a, b, float(p["path_spacing_m"]))
            for prefix, key in (("", "reported_m"), (R.true, "true_m")):
                f = path_figures([samples], ref, key)
                ms.add(f"{R.trial_path_prefix}.{prefix}{R.at}", f.get(R.at), "mm",
                       description="ISO 9283 path accuracy AT of this one path")
            ms.add(f"{R.trial_path_prefix}.{R.path_duration}", run.duration_s, "s",
                   undirected=True,
                   description="time from the first path command to the arrival at P4")
            return samples, ms.items

        bodies = {R.pose_kind: pose_body, R.vap_kind: vap_body, R.path_kind: path_body}
        if kind not in bodies:
            raise SettingsError("trial.kind", kind, "is not pose, vap or path")
        return await guarded_trial(ctx, index, trial_params, bodies[kind],
                                   timeout_s=self._timeout_s(kind, pct, p))

    @staticmethod
    def _timeout_s(kind: str, pct: float, p: Mapping[str, Any]) -> float:
        """A generous bound (s) on one trial: the driver's own move timeouts fire first."""
        slow = 100.0 / pct
        if kind == R.path_kind:
            side = float(p[R.cube_side])
            return 120.0 + 10.0 * side * math.sqrt(3.0) / (pct / 100.0 * float(p["path_speed_m_s"]))
        moves = 10 if kind == R.pose_kind else 6 * len(p["vap_poses"])
        return 120.0 + moves * (5.0 * slow + float(p["settle_s"]))

    def summarize(self, ctx: SuiteContext, trials: Sequence[Trial]) -> list[Measurement]:
        """Per speed: AP/RP per pose, AD/RD between P2 and P4, vAP per pose, AT/RT of the path,
        from the reported positions and (``true_``) the true ones."""
        p = ctx.params
        poses = iso_cube_poses(p[R.cube_centre], float(p[R.cube_side]), str(p[R.plane]))
        ms = Measurements(ctx)
        done = [t for t in trials if t.status == "done"]
        keys = (("", "reported_m"), (R.true, "true_m"))
        for v in p[R.speeds]:
            label = R.at_speed(float(v))
            at_speed = [t for t in done if float(t.params.get(R.speed, -1)) == float(v)]
            pose_trials = [t for t in at_speed if t.params.get(R.kind) == R.pose_kind]
            by_pose: dict[str, list[Mapping[str, Any]]] = defaultdict(list)
            for t in pose_trials:
                for s in t.samples:
                    by_pose[str(s[SAMPLE.pose])].append(s)
            if pose_trials:
                ms.add(f"{label}.{R.cycles}", float(len(pose_trials)), "",
                       description="pose cycles measured")
            for name in POSE_NAMES:
                cmd = poses[POSE_NAMES.index(name)]
                for prefix, key in keys:
                    f = pose_figures(by_pose.get(name, []), cmd, key)
                    _add(ms, R.pose_metric(float(v), name, prefix), f, "ISO 9283 pose")
            # Distance P2-P4, paired by cycle (trials that sampled both).
            pairs = [(_one(t, "P2"), _one(t, "P4")) for t in pose_trials]
            complete = [(a, b) for a, b in pairs if a is not None and b is not None]
            a_s = [a for a, _ in complete]
            b_s = [b for _, b in complete]
            for prefix, key in keys:
                f = distance_figures(a_s, b_s, poses[1], poses[3], key)
                _add(ms, f"{label}.{prefix}", f, "ISO 9283 distance P2-P4")
            # Multi-directional variation.
            vap = [s for t in at_speed if t.params.get(R.kind) == R.vap_kind for s in t.samples]
            for name in p["vap_poses"]:
                groups = [[s for s in vap
                           if s.get(SAMPLE.pose) == name and s.get(SAMPLE.direction) == d]
                          for d, _ in VAP_DIRECTIONS]
                groups = [g for g in groups if g]
                for prefix, key in keys:
                    f = vap_figures(groups, key)
                    _add(ms, R.pose_metric(float(v), str(name), prefix), f, "ISO 9283 vAP")
            # Path accuracy / repeatability.
            paths = [list(t.samples) for t in at_speed if t.params.get(R.kind) == R.path_kind]
            if paths:
                ref = path_reference(poses[1], poses[3], float(p["path_spacing_m"]))
                for prefix, key in keys:
                    f = path_figures(paths, ref, key)
                    _add(ms, f"{R.path_prefix(float(v))}.{prefix}", f, "ISO 9283 path P2-P4")
        return ms.items


#: The signed figures (a bias, either way): AP along each axis, AD and along each axis.
_SIGNED_KEYS: Final = frozenset({*R.with_axes(R.ap)[1:], *R.with_axes(R.ad)})


def _add(ms: Measurements, prefix: str, figures: Mapping[str, float], what: str) -> None:
    """Add ``figures`` as ``prefix + key`` (mm); signed figures get no regression direction."""
    source = "true position" if prefix.endswith(R.true) else "FK of the reported joints"
    for key, value in figures.items():
        ms.add(f"{prefix}{key}", value, "mm", undirected=key in _SIGNED_KEYS,
               description=f"{what} {key.removesuffix('_mm').upper()}, {source}")


def _one(trial: Trial, pose: str) -> Mapping[str, Any] | None:
    for s in trial.samples:
        if s.get(SAMPLE.pose) == pose:
            return s
    return None


def _pose_error_measurements(ctx: SuiteContext,
                             samples: Sequence[Mapping[str, Any]]) -> list[Measurement]:
    """Per trial: the largest distance (mm) between a sampled pose and its commanded position."""
    ms = Measurements(ctx)
    for prefix, key in (("", "reported_m"), (R.true, "true_m")):
        errs = [float(np.linalg.norm(np.subtract(s[key], s["commanded_m"]))) * MM_PER_M
                for s in samples if key in s]
        if errs and len(errs) == len(samples):
            ms.add(f"{R.cycle_prefix}.{prefix}{R.pose_error_max}", max(errs), "mm",
                   description="largest distance of a sampled pose to its commanded position")
    return ms.items
