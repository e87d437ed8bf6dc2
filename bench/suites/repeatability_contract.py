"""The repeatability suite's contract: the names it records and the report reads (ISO 9283).

Plain data and string builders (no numpy, no driver): the suite and its report section both import
it; the record layer finds it by the suite's name, registered as an entry point of
``armbench.suite_contracts`` (:func:`armbench.record.suite_contract.contract`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

from armbench.record.suite_contract import Headline

__all__ = ["REPEATABILITY", "RepeatabilityNames"]


@dataclass(frozen=True, slots=True)
class RepeatabilityNames:
    """The repeatability suite (ISO 9283)."""

    suite: str = "repeatability"
    #: place in the default run and in the report (lower first)
    order: int = 20
    #: whether the suite records true figures beside the encoders' (the scorecard says which)
    has_true_figures: bool = True
    # trial parameters and their kinds
    kind: str = "kind"
    speed: str = "speed_pct"
    duty: str = "duty"
    cycle: str = "cycle"
    pose_kind: str = "pose"
    vap_kind: str = "vap"
    path_kind: str = "path"
    # suite parameters
    cube_centre: str = "cube_centre_m"
    cube_side: str = "cube_side_m"
    plane: str = "plane"
    speeds: str = "speeds_pct"
    # figures: of the reported TCP, and with ``true_`` of the true one; AP, AD, RD and vAP also
    # along each axis (``ap_x_mm``)
    ap: str = "ap_mm"
    rp: str = "rp_mm"
    vap: str = "vap_mm"
    at: str = "at_mm"
    rt: str = "rt_mm"
    ad: str = "ad_mm"
    rd: str = "rd_mm"
    cycles: str = "cycles"
    true: str = "true_"
    axes: tuple[str, ...] = ("x", "y", "z")
    # per-trial figures: a cycle's worst pose, a path's duration
    pose_error_max: str = "pose_error_max_mm"
    path_duration: str = "duration_s"

    def with_axes(self, figure: str) -> tuple[str, ...]:
        """``figure`` and its components along each axis: ``ap_mm``, ``ap_x_mm``, ..."""
        stem = figure.removesuffix("_mm")
        return (figure, *(f"{stem}_{axis}_mm" for axis in self.axes))

    @property
    def pose_figures(self) -> tuple[str, ...]:
        """AP (and along each axis) and RP of one pose."""
        return (*self.with_axes(self.ap), self.rp)

    @property
    def distance_figures(self) -> tuple[str, ...]:
        """AD and RD between P2 and P4, each also along each axis."""
        return (*self.with_axes(self.ad), *self.with_axes(self.rd))

    @property
    def vap_figures(self) -> tuple[str, ...]:
        """vAP of one pose, and along each axis."""
        return self.with_axes(self.vap)

    @property
    def path_figures(self) -> tuple[str, ...]:
        """AT and RT of the path."""
        return (self.at, self.rt)

    def speed_label(self, speed_pct: float) -> str:
        """The name part of a speed: ``v100``, ``v50``, ``v10`` (``v12.5`` for fractions)."""
        return f"v{speed_pct:g}"

    def at_speed(self, speed_pct: float) -> str:
        """``repeatability.v100``: the prefix of every figure at that speed."""
        return f"{self.suite}.{self.speed_label(speed_pct)}"

    def pose_metric(self, speed_pct: float, pose: str, figure: str) -> str:
        """``repeatability.v100.p1.rp_mm``."""
        return f"{self.at_speed(speed_pct)}.{pose.lower()}.{figure}"

    def path_prefix(self, speed_pct: float) -> str:
        return f"{self.at_speed(speed_pct)}.path"

    @property
    def cycle_prefix(self) -> str:
        """Per-trial figures of one cycle: ``repeatability.cycle``."""
        return f"{self.suite}.cycle"

    @property
    def trial_path_prefix(self) -> str:
        """Per-trial figures of one path: ``repeatability.path``."""
        return f"{self.suite}.path"

    def metric_names(self, speeds_pct: Iterable[float], poses: Iterable[str],
                     vap_poses: Iterable[str]) -> frozenset[str]:
        """Every metric the suite records at ``speeds_pct`` with ISO poses ``poses`` and vAP
        measured at ``vap_poses`` (the per-trial figures and the true ones included)."""
        speeds = [float(v) for v in speeds_pct]
        figures = [(pose, figure) for pose in poses for figure in self.pose_figures]
        figures += [(pose, figure) for pose in vap_poses for figure in self.vap_figures]
        names = {f"{self.at_speed(v)}.{self.cycles}" for v in speeds}
        for true in ("", self.true):
            for v in speeds:
                names.update(self.pose_metric(v, pose, true + figure) for pose, figure in figures)
                names.update(f"{self.at_speed(v)}.{true}{figure}"
                             for figure in self.distance_figures)
                names.update(f"{self.path_prefix(v)}.{true}{figure}"
                             for figure in self.path_figures)
            names.add(f"{self.cycle_prefix}.{true}{self.pose_error_max}")
            names.add(f"{self.trial_path_prefix}.{true}{self.at}")
        names.add(f"{self.trial_path_prefix}.{self.path_duration}")
        return frozenset(names)

    @property
    def headlines(self) -> tuple[Headline, ...]:
        s = self.suite
        return (
            Headline("worst pose accuracy AP", f"{s}.v*.p?.{self.ap}", worst_of=True),
            Headline("worst pose repeatability RP", f"{s}.v*.p?.{self.rp}", worst_of=True),
            Headline("worst multi-directional vAP", f"{s}.v*.p?.{self.vap}", worst_of=True),
            Headline("worst path accuracy AT", f"{s}.v*.path.{self.at}", worst_of=True),
        )


REPEATABILITY: Final = RepeatabilityNames()
