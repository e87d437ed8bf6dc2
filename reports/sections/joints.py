"""The joints section: ISO 230-2 bidirectional positioning of each joint, the accuracy A,
repeatability R, reversal B and systematic error E of the reported angle (the encoder on the
motor) beside the true one (the link, with play and deflection) where the bench had truth.

Names come from the suite's contract
(:data:`armbench.bench.suites.joints_contract.JOINTS`); every figure
shown is one the suite recorded.
"""

from __future__ import annotations

from dataclasses import dataclass

from armbench.bench.suites.joints_contract import JOINTS
from armbench.record import Measurement, RunRecord, SuiteRecord
from armbench.reports.render import plots
from armbench.reports.render.format import format_value
from armbench.reports.render.views import Figures, SectionView, SuiteView

__all__ = ["SUITE", "JointRow", "build"]

SUITE = JOINTS.suite
#: Column titles of the figures, in the order of ``JOINTS.figures``.
_TITLES = {JOINTS.accuracy: "accuracy A", JOINTS.repeatability: "repeatability R",
           JOINTS.reversal: "reversal B", JOINTS.systematic: "systematic E"}


@dataclass(frozen=True, slots=True)
class JointRow:
    joint: str
    reported: list[str]
    true: list[str]


def _by_name(suite: SuiteRecord) -> dict[str, Measurement]:
    return {m.name: m for m in suite.measurements}


def build(record: RunRecord, suite: SuiteRecord, view: SuiteView, figs: Figures) -> SectionView:
    """The joints section of ``record``."""
    ms = _by_name(suite)
    joints = sorted({int(t.params[JOINTS.joint]) for t in suite.trials
                     if JOINTS.joint in t.params})
    rows: list[JointRow] = []
    reported: dict[str, list[float | None]] = {f: [] for f in JOINTS.figures}
    true: dict[str, list[float | None]] = {f: [] for f in JOINTS.figures}
    for j in joints:
        cells_r, cells_t = [], []
        for f in JOINTS.figures:
            r, t = ms.get(JOINTS.metric(j, f)), ms.get(JOINTS.metric(j, f, true=True))
            reported[f].append(None if r is None else r.value)
            true[f].append(None if t is None else t.value)
            cells_r.append("-" if r is None else format_value(r.value, r.unit))
            cells_t.append("-" if t is None else format_value(t.value, t.unit))
        rows.append(JointRow(f"j{j}", cells_r, cells_t))
    figures = []
    if rows:
        panels = [plots.JointBars(_TITLES[f], reported[f], true[f]) for f in JOINTS.figures]
        worst = max((v for f in JOINTS.figures for v in reported[f] if v is not None),
                    default=None)
        alt = "" if worst is None else f"largest reported figure {worst:.3g} mrad"
        figures.append(figs.make(
            plots.joint_bars, ([r.joint for r in rows], panels, "mrad"),
            "Bidirectional positioning of each joint (ISO 230-2)",
            "Per joint, the reported angle (solid) and the true one (hatched): the encoder sits "
            "on the motor, so play and deflection show only in the true figures.", alt))
    return SectionView(key=SUITE, template="joints", title="Joints: ISO 230-2 positioning",
                       suite=view, figures=figures,
                       body={"rows": rows, "titles": [_TITLES[f] for f in JOINTS.figures]})
