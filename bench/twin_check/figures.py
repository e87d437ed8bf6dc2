"""The figures of ``armbench twin-check`` judged: per joint, for the arrival times and for the
TCP, each against its limit and against what the capture's floor allows (``k × floor + abs``,
:class:`Allowance`; see :mod:`armbench.bench.twin_check.check`), and the verdict they give."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from armbench.bench.suites.twin_check_contract import TWIN_CHECK
from armbench.drivers.model.bounds import Bound, check
from armbench.drivers.model.settings import SettingsError
from armbench.record import Measurement, judge
from armbench.record.limits import LimitsConfig

if TYPE_CHECKING:
    from armbench.bench.twin_check.parts import Part

__all__ = ["Allowance", "arrival_measurements", "joint_measurements", "part_measurements",
           "tcp_measurements", "verdict_of"]

FloatArray = npt.NDArray[np.float64]


#: Each factor and slack of an :class:`Allowance`: any finite number, not negative.
_TOLERANCE = Bound(0.0)


@dataclass(frozen=True, slots=True)
class Allowance:
    """How far above its floor a twin may score: ``k × floor + abs`` per joint (counts), on each
    part of the capture (``part_factor``: a part holds a few moves, where a timing artifact of
    one move that the whole dilutes weighs in full), for the arrival times (s) and the TCP
    (mm). Read from the config's ``[suites."twin-check"]``."""

    floor_factor: float = 3.0
    abs_counts: float = 2.0
    part_factor: float = 5.0
    arrival_factor: float = 3.0
    arrival_abs_s: float = 0.01
    tcp_factor: float = 3.0
    tcp_abs_mm: float = 1.5

    @classmethod
    def of(cls, table: Mapping[str, Any]) -> Allowance:
        """From a config table; unknown keys and values that are not numbers >= 0 raise
        :class:`SettingsError` naming the key."""
        known = {f.name for f in fields(cls)}
        out: dict[str, float] = {}
        for key, value in table.items():
            where = f'suites."twin-check".{key}'
            if key not in known:
                raise SettingsError(where, value, "is not a known setting")
            out[key] = check(where, value, _TOLERANCE)
        return cls(**out)



def verdict_of(measurements: Sequence[Measurement]) -> str:
    """``fail`` when a figure is outside its limit, else ``pass``."""
    return "fail" if any(m.outcome == "fail" for m in measurements) else "pass"


def joint_measurements(rms: FloatArray, peak: FloatArray, counts: FloatArray,
                       floor: FloatArray, allowed: FloatArray, settled: FloatArray,
                       settled_allowed: FloatArray | None,
                       limits: LimitsConfig | None) -> list[Measurement]:
    """Per joint: the RMS and largest divergence (counts, rad), the floor and the allowance
    (counts), the RMS over its allowance (the judged figure), where moves settled (counts)."""
    n = TWIN_CHECK
    out = []
    for j, joint in enumerate(n.joints):
        for figure, value, unit, what in (
                (n.rms_counts, rms[j] * counts[j], "counts", "RMS divergence"),
                (n.max_counts, peak[j] * counts[j], "counts", "largest divergence"),
                (n.rms_rad, rms[j], "rad", "RMS divergence"),
                (n.max_rad, peak[j], "rad", "largest divergence"),
                (n.floor_counts, floor[j] * counts[j], "counts", "floor (a perfect twin's RMS)"),
                (n.allowed_counts, allowed[j], "counts", "allowed RMS: k x floor + abs"),
                (n.per_allowed, rms[j] * counts[j] / allowed[j], "", "RMS over allowed RMS"),
                (n.settled_counts, settled[j] * counts[j], "counts",
                 "RMS divergence where the moves settled")):
            out.append(judge(n.joint_metric(joint, figure), float(value), unit, limits,
                             better="lower", description=f"{what} of the reported angle"))
        if settled_allowed is not None:
            out.append(judge(n.joint_metric(joint, n.settled_per_allowed),
                             float(settled[j] * counts[j] / settled_allowed[j]), "", limits,
                             better="lower", description="RMS divergence where the moves "
                             "settled over k x quantisation + abs"))
    return out


def part_measurements(parts: Sequence[Part], limits: LimitsConfig | None) -> list[Measurement]:
    """Per joint, the part of the capture where its RMS is furthest over its allowance: that RMS
    (counts) and its ratio (the judged figure: a twin within its allowance on the whole may not
    be on every part), and how many parts the capture was cut into."""
    if not parts:
        return []
    n = TWIN_CHECK
    out = []
    for j, joint in enumerate(n.joints):
        worst = max(parts, key=lambda p: p.per_allowed(j))
        out.append(judge(n.joint_metric(joint, n.worst_part_counts), worst.rms_counts[j],
                         "counts", limits, better="lower",
                         description=f"RMS divergence of the reported angle on the part "
                                     f"{worst.start_s:.2f}..{worst.end_s:.2f} s furthest over "
                                     "its allowance"))
        out.append(judge(n.joint_metric(joint, n.worst_part_per_allowed), worst.per_allowed(j),
                         "", limits, better="lower",
                         description="RMS over allowed RMS on the part of the capture furthest "
                                     "over it"))
    out.append(judge(n.metric(n.parts), float(len(parts)), "", limits,
                     description="parts of the capture judged one by one"))
    return out


def arrival_measurements(dts: Sequence[float], floor_s: float, allow: Allowance,
                         limits: LimitsConfig | None) -> list[Measurement]:
    """The arrival-time differences: mean, largest, RMS, its floor and RMS over allowance."""
    if not dts:
        return []
    n = TWIN_CHECK
    dt = np.asarray(dts)
    rms = float(np.sqrt(np.mean(dt * dt)))
    allowed = allow.arrival_factor * floor_s + allow.arrival_abs_s
    return [
        replace(judge(n.metric(n.mean_dt), float(dt.mean()), "s", limits,
                      description="mean arrival-time difference, twin - arm"), better=None),
        judge(n.metric(n.max_abs_dt), float(np.abs(dt).max()), "s", limits,
              description="largest arrival-time difference, |twin - arm|"),
        judge(n.metric(n.rms_dt), rms, "s", limits, better="lower",
              description="RMS arrival-time difference"),
        judge(n.metric(n.floor_dt), floor_s, "s", limits,
              description="floor of the arrival-time difference (a perfect twin's RMS)"),
        judge(n.metric(n.arrival_per_allowed), rms / allowed, "", limits, better="lower",
              description="RMS arrival-time difference over its allowance"),
    ]


def tcp_measurements(tcp: dict[str, float] | None, allow: Allowance,
                     limits: LimitsConfig) -> list[Measurement]:
    """The TCP divergence as measurements, where the capture had truth."""
    if not tcp:
        return []
    n = TWIN_CHECK
    allowed = allow.tcp_factor * tcp["floor_mm"] + allow.tcp_abs_mm
    out = [judge(n.metric(name), tcp[key], "mm", limits, better="lower",
                 description=f"{what} of the TCP, arm against twin")
           for name, key, what in ((n.tcp_rms, "rms_mm", "RMS divergence"),
                                   (n.tcp_max, "max_mm", "largest divergence"),
                                   (n.tcp_floor, "floor_mm", "floor of the RMS divergence"))]
    out.append(judge(n.metric(n.tcp_per_allowed), tcp["rms_mm"] / allowed, "", limits,
                     better="lower", description="RMS TCP divergence over its allowance"))
    if "rest_rms_mm" in tcp:
        out.append(judge(n.metric(n.tcp_rest), tcp["rest_rms_mm"], "mm", limits,
                         better="lower", description="RMS TCP divergence where the twin rests"))
        out.append(judge(n.metric(n.tcp_rest_per_allowed), tcp["rest_rms_mm"] / allow.tcp_abs_mm,
                         "", limits, better="lower",
                         description="RMS TCP divergence at rest over its allowance (abs)"))
    out.append(judge(n.metric(n.tcp_samples), tcp["samples"], "", limits,
                     description="truth samples compared"))
    return out
