"""The repeatability suite's contract: the names it records and the report reads (ISO 9283).

Plain data and string builders (no numpy, no driver): the suite and its report section both import
it, and importing it registers the contract (:func:`armbench.record.suite_contract.register`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from armbench.record.suite_contract import Headline, register

__all__ = ["REPEATABILITY", "RepeatabilityNames"]


@dataclass(frozen=True, slots=True)
class RepeatabilityNames:
    """The repeatability suite (ISO 9283)."""

    suite: str = "repeatability"
    #: place in the default run and in the report (lower first)
    order: int = 20
    #: whether the suite records true figures beside the encoders' (the scorecard says which)
    has_true_figures: bool = True
    #: what runs the suite: ``module:Class``, imported only when the suite is loaded
    implementation: str | None = "armbench.bench.suites.repeatability:RepeatabilitySuite"
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
    # figures
    ap: str = "ap_mm"
    rp: str = "rp_mm"
    vap: str = "vap_mm"
    at: str = "at_mm"
    rt: str = "rt_mm"
    rd: str = "rd_mm"
    cycles: str = "cycles"

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

    @property
    def headlines(self) -> tuple[Headline, ...]:
        s = self.suite
        return (
            Headline("worst pose accuracy AP", f"{s}.v*.p?.{self.ap}", worst_of=True),
            Headline("worst pose repeatability RP", f"{s}.v*.p?.{self.rp}", worst_of=True),
            Headline("worst multi-directional vAP", f"{s}.v*.p?.{self.vap}", worst_of=True),
            Headline("worst path accuracy AT", f"{s}.v*.path.{self.at}", worst_of=True),
        )


REPEATABILITY: Final = register(RepeatabilityNames())
