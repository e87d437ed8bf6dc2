"""The joints suite's contract: the names it records and the report reads (ISO 230-2).

Plain data and string builders (no numpy, no driver): the suite and its report section both import
it; the record layer finds it by the suite's name, registered as an entry point of
``armbench.suite_contracts`` (:func:`armbench.record.suite_contract.contract`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

from armbench.record.suite_contract import Headline

__all__ = ["JOINTS", "JointsNames"]


@dataclass(frozen=True, slots=True)
class JointsNames:
    """The joints suite (ISO 230-2 bidirectional positioning of each joint)."""

    suite: str = "joints"
    #: place in the default run and in the report (lower first)
    order: int = 40
    #: whether the suite records true figures beside the encoders' (the scorecard says which)
    has_true_figures: bool = True
    prefix: str = "joints"
    # trial parameter and the sample key of the true angle
    joint: str = "joint"
    true_angle: str = "true_rad"
    # figures per joint (mrad), of the reported angle, and with ``true_`` of the true one
    accuracy: str = "accuracy_mrad"
    repeatability: str = "repeatability_mrad"
    reversal: str = "reversal_mrad"
    mean_reversal: str = "mean_reversal_mrad"
    systematic: str = "systematic_mrad"
    true: str = "true_"

    def metric(self, joint: int, figure: str, true: bool = False) -> str:
        """``joints.j<N>.[true_]<figure>``."""
        return f"{self.prefix}.j{joint}.{self.true if true else ''}{figure}"

    @property
    def figures(self) -> tuple[str, ...]:
        """The figures shown per joint, in order."""
        return (self.accuracy, self.repeatability, self.reversal, self.systematic)

    @property
    def all_figures(self) -> tuple[str, ...]:
        """Every figure of a joint, in the order the suite records them."""
        return (self.accuracy, self.repeatability, self.reversal, self.mean_reversal,
                self.systematic)

    def metric_names(self, joints: Iterable[int]) -> frozenset[str]:
        """Every metric the suite records measuring ``joints``: each figure of the reported
        angle and of the true one."""
        return frozenset(self.metric(int(j), figure, true) for j in joints
                         for figure in self.all_figures for true in (False, True))

    @property
    def headlines(self) -> tuple[Headline, ...]:
        p = self.prefix
        return (
            Headline("worst joint accuracy A", f"{p}.j*.{self.accuracy}", worst_of=True),
            Headline("worst joint repeatability R", f"{p}.j*.{self.repeatability}",
                     worst_of=True),
            Headline("worst joint reversal B", f"{p}.j*.{self.reversal}", worst_of=True),
            Headline("worst true joint accuracy A", f"{p}.j*.{self.true}{self.accuracy}",
                     worst_of=True),
        )


JOINTS: Final = JointsNames()
