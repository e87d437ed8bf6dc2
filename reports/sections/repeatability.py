"""The repeatability section: the ISO 9283 test cube and its poses, the attained positions around
their barycentre, then AP / RP per pose and speed and the figures per speed.

Names come from the suite's contract
(:data:`armbench.bench.suites.repeatability_contract.REPEATABILITY`). The
figures are the recorded ones; a pose whose figure the suite's summary lacks (an interrupted
suite) shows the interim figure the record layer gives (:mod:`armbench.record.interim`), marked
so. The section computes no figure.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from armbench.bench.suites.repeatability_contract import REPEATABILITY
from armbench.metrics import cube_corners
from armbench.record import Measurement, RunRecord, SuiteRecord
from armbench.record.interim import Vec3, interim_pose_figures, pose_samples
from armbench.reports.render import plots
from armbench.reports.render.format import format_duration, format_number, format_value
from armbench.reports.render.views import (
    Figures,
    FigureView,
    FloatArray,
    SectionView,
    SuiteView,
    num,
    vec3,
)

__all__ = ["SUITE", "RepCell", "RepRow", "RepeatabilityView", "SpeedRow", "build"]

SUITE = REPEATABILITY.suite
R = REPEATABILITY
_SAFE_POSE = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,11}")


@dataclass(frozen=True, slots=True)
class RepCell:
    """AP and RP of one pose at one speed."""

    ap: str
    ap_outcome: str
    rp: str
    rp_outcome: str
    true_rp: str
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
    cycles: str
    cycle_time: str
    worst_ap: str
    worst_rp: str
    worst_true_rp: str
    rd: str
    at: str


@dataclass(frozen=True, slots=True)
class RepeatabilityView:
    speeds: list[str]
    rows: list[RepRow]
    speed_rows: list[SpeedRow]
    cube: str
    has_true: bool


def _pose_key(name: str) -> tuple[int, str]:
    digits = re.sub(r"\D", "", name)
    return (int(digits) if digits and len(digits) < 6 else 10**6, name)


def build(record: RunRecord, suite: SuiteRecord, view: SuiteView, figs: Figures) -> SectionView:
    """The repeatability section of ``record``."""
    samples = pose_samples(suite)
    points, commanded, times = samples.attained, samples.commanded, samples.cycle_s
    interim = interim_pose_figures(suite, samples)
    speeds = sorted({sp for sp, _ in points}, reverse=True)
    poses = sorted({p for _, p in points}, key=_pose_key)
    recorded: dict[str, Measurement] = {m.name: m for m in suite.measurements}
    notes: list[str] = []
    centre, side = vec3(suite.params.get(R.cube_centre)), num(suite.params.get(R.cube_side))
    corners = None
    cube = "-"
    if centre is not None and side is not None and side > 0:
        corners = cube_corners(centre, side)
        cube = (f"centre ({', '.join(f'{v * 1000:g}' for v in centre)}) mm, "
                f"side {side * 1000:g} mm")

    def label(i: int, name: str) -> str:
        return name if _SAFE_POSE.fullmatch(name) else f"pose {i + 1}"

    rows: list[RepRow] = []
    scatter: list[plots.PoseScatter] = []
    computed_any = False
    for i, pose in enumerate(poses):
        cells, groups = [], []
        for speed in speeds:
            pts = np.array(points.get((speed, pose), []), dtype=np.float64).reshape(-1, 3)
            ap_m = recorded.get(R.pose_metric(speed, pose, R.ap))
            rp_m = recorded.get(R.pose_metric(speed, pose, R.rp))
            true_rp_m = recorded.get(R.pose_metric(speed, pose, f"true_{R.rp}"))
            ap = None if ap_m is None else ap_m.value
            rp = None if rp_m is None else rp_m.value
            computed = False
            late = interim.get((speed, pose))
            if ap is None and late is not None and late.ap_mm is not None:
                ap, computed = late.ap_mm, True
            if rp is None and late is not None and late.rp_mm is not None:
                rp, computed = late.rp_mm, True
            computed_any |= computed
            cells.append(RepCell(
                ap=format_number(ap, unit="mm"),
                ap_outcome="unjudged" if ap_m is None else ap_m.outcome,
                rp=format_number(rp, unit="mm"),
                rp_outcome="unjudged" if rp_m is None else rp_m.outcome,
                true_rp="-" if true_rp_m is None else format_number(true_rp_m.value, unit="mm"),
                n=len(pts), computed=computed))
            if len(pts):
                dev = (pts - pts.mean(axis=0))[:, 1:] * 1000.0
                groups.append(plots.ScatterGroup(f"{format_number(speed)} %", dev, rp))
        c = commanded.get(pose)
        rows.append(RepRow(pose=pose, cells=cells, commanded="-" if c is None else
                           "(" + ", ".join(f"{v * 1000:.1f}" for v in c) + ") mm"))
        scatter.append(plots.PoseScatter(label(i, pose), groups))
    if computed_any:
        notes.append("† interim: the suite was interrupted before its summary, so the figure is "
                     "computed from the samples recorded so far.")

    def worst(speed: float, figure: str) -> str:
        ms = [recorded.get(R.pose_metric(speed, p, figure)) for p in poses]
        values = [m for m in ms if m is not None]
        if not values:
            return "-"
        return format_value(max(m.value for m in values), "mm")

    def one(name: str) -> str:
        m = recorded.get(name)
        return "-" if m is None else format_value(m.value, m.unit)

    speed_rows = [SpeedRow(
        speed=f"{format_number(sp)} %", cycles=one(f"{R.at_speed(sp)}.{R.cycles}"),
        cycle_time=format_duration(sum(times[sp]) / len(times[sp])) if times.get(sp) else "-",
        worst_ap=worst(sp, R.ap), worst_rp=worst(sp, R.rp),
        worst_true_rp=worst(sp, f"true_{R.rp}"),
        rd=one(f"{R.at_speed(sp)}.{R.rd}"), at=one(f"{R.path_prefix(sp)}.{R.at}"))
        for sp in speeds]
    has_true = any(r.worst_true_rp != "-" for r in speed_rows)
    if has_true:
        notes.append("RP is computed twice: from the reported joints (encoder counts on the motor "
                     "shafts, as the paper measured) and from the true position (a tracker, or "
                     "the emulator's truth). A closed loop that rests on the same counts every "
                     "cycle reports RP 0 while the links, past the gears' play and friction, "
                     "scatter: the true RP is the arm's repeatability (docs/robot-model.md).")
    figures: list[FigureView] = []
    if poses:
        figures.append(_cube_figure(figs, corners, poses, commanded, points, speeds, label))
        rp_text = "; ".join(f"{r.speed}: worst RP {r.worst_rp}" for r in speed_rows)
        figures.append(figs.make(
            plots.pose_scatter, (scatter,),
            "ISO 9283: attained positions around their barycentre",
            "Attained positions of each pose around their barycentre, projected on the YZ plane, "
            "one marker shape per speed; each circle is that speed's RP (ISO 9283: mean distance "
            "to the barycentre + 3 standard deviations). A spread below the samples' resolution "
            "(0.1 µm) is a point at the origin.", rp_text))
    return SectionView(
        key=SUITE, template="repeatability", title="Repeatability: ISO 9283 poses",
        suite=view, figures=figures, notes=notes,
        body=RepeatabilityView(speeds=[f"{format_number(s)} %" for s in speeds], rows=rows,
                               speed_rows=speed_rows, cube=cube, has_true=has_true))


def _cube_figure(figs: Figures, corners: FloatArray | None, poses: list[str],
                 commanded: dict[str, Vec3], points: dict[tuple[float, str], list[Vec3]],
                 speeds: list[float], label: Callable[[int, str], str]) -> FigureView:
    pose_pts = [(label(i, p), np.array(commanded[p]) * 1000.0)
                for i, p in enumerate(poses) if p in commanded]
    bary = []
    for p in poses:
        every = [x for sp in speeds for x in points.get((sp, p), [])]
        if every:
            bary.append(np.array(every, dtype=np.float64).mean(axis=0) * 1000.0)
    return figs.make(
        plots.cube_projections, (None if corners is None else corners * 1000.0, pose_pts, bary),
        "ISO 9283: test cube and poses",
        "The ISO 9283 test cube and the commanded poses in three projections, with the "
        "barycentre of the attained positions of each pose (all speeds).",
        f"{len(pose_pts)} poses; largest distance of a barycentre from its pose "
        + format_value(max((float(np.linalg.norm(b - c)) for (_, c), b
                            in zip(pose_pts, bary, strict=False)), default=None), "mm"))
