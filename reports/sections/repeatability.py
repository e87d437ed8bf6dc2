"""The repeatability section: ISO 9283 poses, their AP / RP and their scatter."""

from __future__ import annotations

import math
import re
import statistics
from dataclasses import dataclass

import numpy as np

from armbench.bench.metrics import (
    cube_corners,
    iso_cube_poses,
    pose_accuracy,
    pose_repeatability,
)
from armbench.bench.record import (
    SuiteRecord,
)
from armbench.reports import plots
from armbench.reports.format import (
    format_duration,
    format_number,
)
from armbench.reports.views import (
    Figures,
    FigureView,
    SuiteView,
    num,
    vec3,
)

_SAFE_POSE = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,11}")


@dataclass(frozen=True, slots=True)
class RepCell:
    """AP and RP of one pose at one speed."""

    ap: str
    ap_outcome: str
    rp: str
    rp_outcome: str
    n: int
    computed: bool


@dataclass(frozen=True, slots=True)
class RepRow:
    pose: str
    commanded: str
    cells: list[RepCell]


@dataclass(frozen=True, slots=True)
class SpeedRow:
    speed: str
    cycles: int
    cycle_time: str
    worst_ap: str
    worst_rp: str


@dataclass(frozen=True, slots=True)
class RepeatabilityView:
    suite: SuiteView
    figures: list[FigureView]
    speeds: list[str]
    rows: list[RepRow]
    speed_rows: list[SpeedRow]
    cube: str
    notes: list[str]



# --------------------------------------------------------------------------------------------
# Repeatability
# --------------------------------------------------------------------------------------------


def _pose_key(name: str) -> tuple[int, str]:
    digits = re.sub(r"\D", "", name)
    return (int(digits) if digits and len(digits) < 6 else 10**6, name)


def _speed_token(speed: float | None) -> str:
    if speed is None:
        return "?"
    return str(int(speed)) if float(speed).is_integer() else format_number(speed)


def repeatability_section(suite: SuiteRecord, view: SuiteView, figs: Figures) -> RepeatabilityView:
    points: dict[tuple[float | None, str], list[tuple[float, float, float]]] = {}
    commanded: dict[str, tuple[float, float, float]] = {}
    cycles: dict[float | None, int] = {}
    cycle_times: dict[float | None, list[float]] = {}
    for trial in suite.trials:
        speed = num(trial.params.get("speed_pct"))
        used = False
        for s in trial.samples:
            pose, r = s.get("pose"), vec3(s.get("reported_m"))
            if not isinstance(pose, str) or r is None:
                continue
            points.setdefault((speed, pose), []).append(r)
            c = vec3(s.get("commanded_m"))
            if c is not None:
                commanded.setdefault(pose, c)
            used = True
        if used:
            cycles[speed] = cycles.get(speed, 0) + 1
            ct = next((m.value for m in trial.measurements if m.name.endswith("cycle_time_s")),
                      trial.duration_s)
            cycle_times.setdefault(speed, []).append(ct)
    speeds = sorted({sp for sp, _ in points}, key=lambda v: (v is None, v or 0.0))
    poses = sorted({p for _, p in points}, key=_pose_key)
    recorded = {m.name: m for m in suite.measurements}
    notes: list[str] = []

    centre = vec3(suite.params.get("cube_centre_m"))
    side = num(suite.params.get("cube_side_m"))
    corners = None
    cube = "-"
    if centre is not None and side is not None and side > 0:
        corners = cube_corners(centre, side)
        cube = (f"centre ({', '.join(f'{v * 1000:g}' for v in centre)}) mm, "
                f"side {side * 1000:g} mm")
        if not commanded and len(poses) <= 5:
            for i, p in enumerate(iso_cube_poses(centre, side)):
                commanded[f"P{i + 1}"] = (float(p[0]), float(p[1]), float(p[2]))

    def plot_label(i: int, name: str) -> str:
        return name if _SAFE_POSE.fullmatch(name) else f"pose {i + 1}"

    rows: list[RepRow] = []
    scatter: list[plots.PoseScatter] = []
    worst: dict[float | None, tuple[float, float]] = {}
    computed_any = False
    for i, pose in enumerate(poses):
        cells = []
        groups = []
        for speed in speeds:
            pts = np.array(points.get((speed, pose), []), dtype=np.float64).reshape(-1, 3)
            base = f"repeatability.v{_speed_token(speed)}.{pose.lower()}"
            ap_m, rp_m = recorded.get(f"{base}.ap_mm"), recorded.get(f"{base}.rp_mm")
            ap = None if ap_m is None else ap_m.value
            rp = None if rp_m is None else rp_m.value
            computed = False
            if ap is None and len(pts) >= 1 and pose in commanded:
                ap, computed = pose_accuracy(pts, commanded[pose]).ap_p_mm, True
            if rp is None and len(pts) >= 2:
                rp, computed = pose_repeatability(pts).rp_mm, True
            computed_any |= computed
            cells.append(RepCell(
                ap=format_number(ap), ap_outcome="unjudged" if ap_m is None else ap_m.outcome,
                rp=format_number(rp), rp_outcome="unjudged" if rp_m is None else rp_m.outcome,
                n=len(pts), computed=computed))
            w_ap, w_rp = worst.get(speed, (-math.inf, -math.inf))
            worst[speed] = (max(w_ap, ap if ap is not None else -math.inf),
                            max(w_rp, rp if rp is not None else -math.inf))
            if len(pts):
                dev = (pts - pts.mean(axis=0))[:, 1:] * 1000.0
                groups.append(plots.ScatterGroup(f"{format_number(speed)} %", dev, rp))
        c = commanded.get(pose)
        rows.append(RepRow(pose=pose, cells=cells, commanded="-" if c is None else
                           "(" + ", ".join(f"{v * 1000:.1f}" for v in c) + ") mm"))
        scatter.append(plots.PoseScatter(plot_label(i, pose), groups))
    if computed_any:
        notes.append("† computed by the report from the samples (no recorded, judged "
                     "measurement of that name, e.g. an interrupted suite).")

    figures: list[FigureView] = []
    if poses:
        pose_pts = [(plot_label(i, p), np.array(commanded[p]) * 1000.0)
                    for i, p in enumerate(poses) if p in commanded]
        bary = []
        for p in poses:
            every = [x for sp in speeds for x in points.get((sp, p), [])]
            if every:
                bary.append(np.array(every, dtype=np.float64).mean(axis=0) * 1000.0)
        figures.append(figs.make(
            plots.cube_projections(None if corners is None else corners * 1000.0, pose_pts,
                                   bary),
            "ISO 9283 test cube and poses",
            "The ISO 9283 test cube and the five commanded poses in three projections, with the "
            "barycentre of every attained position of each pose (all speeds)."))
        figures.append(figs.make(
            plots.pose_scatter(scatter),
            "Attained positions around their barycentre",
            "Attained positions of each pose around their barycentre, projected on the YZ plane, "
            "one marker shape per speed; each circle is the outline of that speed's RP sphere "
            "(ISO 9283: mean distance to the barycentre + 3 standard deviations)."))
    speed_rows = []
    for speed in speeds:
        w_ap, w_rp = worst.get(speed, (-math.inf, -math.inf))
        times = cycle_times.get(speed, [])
        speed_rows.append(SpeedRow(
            speed=f"{format_number(speed)} %", cycles=cycles.get(speed, 0),
            cycle_time=format_duration(statistics.fmean(times)) if times else "-",
            worst_ap=format_number(w_ap if math.isfinite(w_ap) else None),
            worst_rp=format_number(w_rp if math.isfinite(w_rp) else None)))
    return RepeatabilityView(suite=view, figures=figures,
                             speeds=[f"{format_number(s)} %" for s in speeds], rows=rows,
                             speed_rows=speed_rows, cube=cube, notes=notes)


