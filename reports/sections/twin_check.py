"""The twin-check section (``armbench twin-check --out``): how well the twin predicts an arm's
capture. The overlay (per joint the arm's and the twin's reported angle over the capture, and
their divergence in encoder counts against the allowed RMS), a per-joint table of the RMS and
largest divergence beside the floor (what a perfect twin would score on this capture) and the
allowance, the arrival-time and TCP tables, and the inputs the check read.

Names come from the suite's contract
(:data:`armbench.bench.suites.twin_check_contract.TWIN_CHECK`); every
figure in the tables is one the record holds; the plot draws the series the record kept (a
min/max envelope of each, so a spike survives).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from armbench.bench.suites.twin_check_contract import TWIN_CHECK
from armbench.record import Measurement, RunRecord, SuiteRecord
from armbench.record.suite_contract import SAMPLE
from armbench.reports.render.format import format_value
from armbench.reports.render.plotting import COLOURS, FloatArray, legend, new_figure, plot_style
from armbench.reports.render.views import Figures, SectionView, SuiteView, num, text

__all__ = ["SUITE", "ArrivalRow", "JointRow", "TwinView", "build", "overlay_plot"]

SUITE = TWIN_CHECK.suite
#: Largest arrival differences listed (the record keeps the extremes of every stretch).
TOP_ARRIVALS = 10


@dataclass(frozen=True, slots=True)
class JointRow:
    joint: str
    rms_counts: str
    max_counts: str
    rms_rad: str
    max_rad: str
    floor: str
    allowed: str
    limit: str
    outcome: str


@dataclass(frozen=True, slots=True)
class ArrivalRow:
    t: str
    arm: str
    twin: str
    dt: str


@dataclass(frozen=True, slots=True)
class TwinView:
    joints: list[JointRow]
    arrival_summary: list[tuple[str, str]]
    arrivals: list[ArrivalRow]
    inputs: list[tuple[str, str]]
    tcp: list[tuple[str, str]]


@dataclass(frozen=True, slots=True)
class JointSeries:
    """One joint's kept series: times (s, capture clock), the arm's and the twin's angle (rad),
    the divergence (counts)."""

    joint: int
    t_s: FloatArray
    arm_rad: FloatArray
    twin_rad: FloatArray
    divergence_counts: FloatArray


def _series(samples: Sequence[Mapping[str, Any]]) -> list[JointSeries]:
    n = TWIN_CHECK
    rows: dict[int, list[tuple[float, float, float, float]]] = {}
    for s in samples:
        if s.get(SAMPLE.kind) != n.series_kind:
            continue
        joint, t = num(s.get(n.joint)), num(s.get(SAMPLE.t))
        a, b, d = num(s.get(n.arm)), num(s.get(n.twin)), num(s.get(n.divergence))
        if joint is None or t is None or a is None or b is None or d is None:
            continue
        rows.setdefault(int(joint), []).append((t, a, b, d))
    out = []
    for joint in sorted(rows):
        arr = np.asarray(sorted(rows[joint]), dtype=np.float64)
        out.append(JointSeries(joint, arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3]))
    return out


def overlay_plot(series: Sequence[JointSeries], tolerance_counts: Mapping[int, float]) -> Figure:
    """One row per joint: left the arm's (solid) and the twin's (dashed) reported angle over the
    capture, right their divergence in counts with the joint's allowed RMS (dotted, ±)."""
    with plot_style():
        rows = max(1, len(series))
        fig = new_figure(7.2, 1.35 * rows + 0.6, left=0.1, bottom=0.6 / (1.35 * rows + 0.6),
                         top=1 - 0.35 / (1.35 * rows + 0.6), wspace=0.28, hspace=0.45)
        axes = fig.subplots(rows, 2, squeeze=False, sharex=True)
        for (left, right), s in zip(axes, series, strict=False):
            left.plot(s.t_s, s.arm_rad, color=COLOURS[0], linewidth=1.0, label="arm")
            left.plot(s.t_s, s.twin_rad, color=COLOURS[1], linestyle="--", linewidth=0.9,
                      label="twin")
            left.set_ylabel(f"j{s.joint} (rad)")
            right.plot(s.t_s, s.divergence_counts, color=COLOURS[2], linewidth=0.8,
                       label="arm - twin")
            tolerance = tolerance_counts.get(s.joint)
            if tolerance is not None:
                for sign in (1.0, -1.0):
                    right.axhline(sign * tolerance, color="black", linestyle=":",
                                  linewidth=1.1, label="allowed RMS" if sign > 0 else None)
            right.set_ylabel("counts")
        axes[0][0].set_title("reported angle")
        axes[0][1].set_title("divergence (arm - twin)")
        for ax in axes[-1]:
            ax.set_xlabel("capture time (s)")
        legend(axes[0][0], loc="lower left", bbox_to_anchor=(0.0, 1.12), ncols=2)
        legend(axes[0][1], loc="lower left", bbox_to_anchor=(0.0, 1.12), ncols=2)
    return fig


def _tolerance(ms: Mapping[str, Measurement]) -> tuple[dict[int, float], str]:
    """Per joint, the RMS (counts) the verdict allows: the allowance times the high bound of the
    joint's ``rms_per_allowed`` limit, else the high bound of an absolute ``rms_counts`` limit;
    and a description."""
    n = TWIN_CHECK
    out: dict[int, float] = {}
    text_ = "-"
    for j in range(1, 5):
        ratio = ms.get(n.joint_metric(j, n.per_allowed))
        allowed = ms.get(n.joint_metric(j, n.allowed_counts))
        absolute = ms.get(n.joint_metric(j, n.rms_counts))
        if ratio is not None and allowed is not None and ratio.limit is not None \
                and ratio.limit.high is not None:
            out[j] = allowed.value * ratio.limit.high
            text_ = "k x floor + abs"
        elif absolute is not None and absolute.limit is not None \
                and absolute.limit.high is not None:
            out[j] = absolute.limit.high
            text_ = absolute.limit.describe()
    return out, text_


def _outcome(ms: Mapping[str, Measurement], joint: int) -> str:
    """The joint's outcome: fail when any of its judged figures fails, pass when one is judged."""
    outcomes = [m.outcome for name, m in ms.items()
                if name.startswith(TWIN_CHECK.joint_metric(joint, ""))]
    if "fail" in outcomes:
        return "fail"
    return "pass" if "pass" in outcomes else "unjudged"


def _value(ms: Mapping[str, Measurement], name: str) -> str:
    m = ms.get(name)
    return "-" if m is None else format_value(m.value, m.unit)


def build(record: RunRecord, suite: SuiteRecord, view: SuiteView, figs: Figures) -> SectionView:
    """The twin-check section of ``record``."""
    n = TWIN_CHECK
    ms = {m.name: m for m in suite.measurements}
    joints = []
    for j in range(1, 5):
        rms = ms.get(n.joint_metric(j, n.rms_counts))
        if rms is None:
            continue
        judged = [m for m in (ms.get(n.joint_metric(j, n.per_allowed)), rms)
                  if m is not None and m.limit is not None]
        joints.append(JointRow(
            f"j{j}", format_value(rms.value, rms.unit),
            _value(ms, n.joint_metric(j, n.max_counts)), _value(ms, n.joint_metric(j, n.rms_rad)),
            _value(ms, n.joint_metric(j, n.max_rad)),
            _value(ms, n.joint_metric(j, n.floor_counts)),
            _value(ms, n.joint_metric(j, n.allowed_counts)),
            "; ".join(f"{m.name.rsplit('.', 1)[-1]} {m.limit.describe()}" for m in judged
                      if m.limit is not None) or "-", _outcome(ms, j)))
    samples = [s for t in suite.trials for s in t.samples]
    series = _series(samples)
    tolerance, tolerance_text = _tolerance(ms)
    figures = []
    if series:
        worst = max(series, key=lambda s: float(np.max(np.abs(s.divergence_counts))))
        figures.append(figs.make(
            overlay_plot, (series, tolerance),
            "Arm against twin: reported angle and divergence per joint",
            "Left, per joint, the angle the arm reported (solid) and the one the twin reported "
            "when the same commands were replayed into it (dashed); right, their difference in "
            f"encoder counts, the allowed RMS dotted ({tolerance_text}). The series are the "
            "record's: a min/max envelope of each, so no spike is lost.",
            f"largest divergence {float(np.max(np.abs(worst.divergence_counts))):.3g} counts "
            f"on j{worst.joint}"))
    arrivals = sorted((s for s in samples if s.get(SAMPLE.kind) == n.arrival_kind
                       and num(s.get(n.arrival_dt)) is not None),
                      key=lambda s: -abs(num(s.get(n.arrival_dt)) or 0.0))[:TOP_ARRIVALS]
    summary = [(label, _value(ms, n.metric(figure))) for label, figure in (
        ("commands replayed", n.moves), ("moves both arrived at", n.compared),
        ("only the arm arrived", n.arm_only), ("only the twin arrived", n.twin_only),
        ("mean difference, twin - arm", n.mean_dt), ("largest |difference|", n.max_abs_dt),
        ("RMS difference, twin - arm", n.rms_dt), ("floor (a perfect twin's RMS)", n.floor_dt),
        ("RMS over allowed RMS", n.arrival_per_allowed),
        ("timing scatter of the replies", n.scatter),
        ("scatter of the arm's reaction to commands", n.reaction),
        ("mean start shift, arm - twin", n.shift_mean), ("largest |start shift|", n.shift_max),
        ("replies compared", n.replies), ("replies left out (read in a burst)", n.untimed),
        ("sessions", n.sessions))]
    tcp = [(label, _value(ms, n.metric(figure))) for label, figure in (
        ("RMS divergence", n.tcp_rms), ("largest divergence", n.tcp_max),
        ("floor (a perfect twin's RMS)", n.tcp_floor), ("RMS over allowed RMS", n.tcp_per_allowed),
        ("RMS divergence where the twin rests", n.tcp_rest),
        ("at rest, over its allowance", n.tcp_rest_per_allowed),
        ("truth samples compared", n.tcp_samples)) if n.metric(figure) in ms]
    p = suite.params
    inputs = [(label, text(p.get(key), 300)) for label, key in (
        ("capture", n.capture), ("capture SHA-256", n.capture_sha256),
        ("twin settings", n.settings), ("settings SHA-256", n.settings_sha256),
        ("limits", n.config), ("limits SHA-256", n.config_sha256))]
    return SectionView(
        key=SUITE, template="twin_check", title="Twin check: the twin against the arm's capture",
        suite=view, figures=figures,
        body=TwinView(joints, summary, [
            ArrivalRow(format_value(num(s.get(SAMPLE.t)), "s"),
                       format_value(num(s.get(n.arm_arrival)), "s"),
                       format_value(num(s.get(n.twin_arrival)), "s"),
                       format_value(num(s.get(n.arrival_dt)), "s")) for s in arrivals], inputs,
            tcp))
