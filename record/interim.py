"""Figures of a suite whose summary the record does not hold yet.

A run killed or interrupted inside a suite keeps that suite's finished trials (``results.json``
and the journal replayed by :func:`~armbench.record.run_record.load_record`) but not the summary
the suite computes at its end. What those trials measured is still worth showing: for the
repeatability suite, the ISO 9283 pose figures AP and RP of every pose and speed that has
samples, computed here with the suite's own metric code (:mod:`armbench.metrics`) from the
recorded samples, so the report reads them and computes no figure itself. The record itself is
left as it is: the figures are interim, and the suite's summary replaces them once the suite is
run to its end (``--resume``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from armbench.metrics import pose_accuracy, pose_repeatability
from armbench.record.measurement import SuiteRecord
from armbench.record.suite_contract import SAMPLE, contract, lacks

__all__ = ["InterimPose", "PoseSamples", "PoseTrialNames", "Vec3", "interim_pose_figures",
           "pose_samples"]

Vec3 = tuple[float, float, float]


@runtime_checkable
class PoseTrialNames(Protocol):
    """The names of a suite's contract these figures are read with (the repeatability suite's,
    found in the registry by the suite record's name)."""

    @property
    def speed(self) -> str: ...
    @property
    def kind(self) -> str: ...
    @property
    def pose_kind(self) -> str: ...
    @property
    def ap(self) -> str: ...
    @property
    def rp(self) -> str: ...
    def pose_metric(self, speed_pct: float, pose: str, figure: str) -> str: ...


def _names(suite: SuiteRecord) -> PoseTrialNames:
    names = contract(suite.name)
    if not isinstance(names, PoseTrialNames):
        raise lacks(suite.name, PoseTrialNames)
    return names


def _num(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    v = float(value)
    return v if math.isfinite(v) else None


def _vec3(value: object) -> Vec3 | None:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        return None
    x, y, z = (_num(v) for v in value)
    return None if x is None or y is None or z is None else (x, y, z)


@dataclass(frozen=True, slots=True)
class PoseSamples:
    """The repeatability suite's pose trials as recorded: the attained (reported) positions per
    (speed %, pose), the commanded position per pose (m) and the cycles' durations per speed
    (s). Trials not done and malformed samples are left out."""

    attained: dict[tuple[float, str], list[Vec3]]
    commanded: dict[str, Vec3]
    cycle_s: dict[float, list[float]]


def pose_samples(suite: SuiteRecord) -> PoseSamples:
    """The pose samples of a repeatability suite's record."""
    R = _names(suite)
    attained: dict[tuple[float, str], list[Vec3]] = {}
    commanded: dict[str, Vec3] = {}
    cycle_s: dict[float, list[float]] = {}
    for trial in suite.trials:
        speed = _num(trial.params.get(R.speed))
        if speed is None or trial.params.get(R.kind) != R.pose_kind or trial.status != "done":
            continue
        cycle_s.setdefault(speed, []).append(trial.duration_s)
        for s in trial.samples:
            pose, r = s.get(SAMPLE.pose), _vec3(s.get(SAMPLE.reported))
            if not isinstance(pose, str) or r is None:
                continue
            attained.setdefault((speed, pose), []).append(r)
            c = _vec3(s.get(SAMPLE.commanded))
            if c is not None:
                commanded.setdefault(pose, c)
    return PoseSamples(attained, commanded, cycle_s)


@dataclass(frozen=True, slots=True)
class InterimPose:
    """AP and RP (mm) of one pose at one speed that the suite's summary lacks; None where the
    samples do not determine it (AP needs the commanded pose, RP two cycles)."""

    ap_mm: float | None
    rp_mm: float | None


def interim_pose_figures(suite: SuiteRecord, samples: PoseSamples | None = None,
                         ) -> dict[tuple[float, str], InterimPose]:
    """For every (speed %, pose) with samples whose AP or RP the suite's measurements lack, the
    missing figures computed from the samples (an interrupted suite); empty for a suite that
    ran to its end."""
    R = _names(suite)
    samples = pose_samples(suite) if samples is None else samples
    recorded = {m.name for m in suite.measurements}
    out: dict[tuple[float, str], InterimPose] = {}
    for (speed, pose), attained in samples.attained.items():
        pts = np.array(attained, dtype=np.float64).reshape(-1, 3)
        ap = rp = None
        if R.pose_metric(speed, pose, R.ap) not in recorded and pose in samples.commanded:
            ap = pose_accuracy(pts, samples.commanded[pose]).ap_p_mm
        if R.pose_metric(speed, pose, R.rp) not in recorded and len(pts) >= 2:
            rp = pose_repeatability(pts).rp_mm
        if ap is not None or rp is not None:
            out[(speed, pose)] = InterimPose(ap, rp)
    return out
