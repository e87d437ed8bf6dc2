"""The accuracy suite's contract: the names it records and the report reads (the paper's square).

Plain data and string builders (no numpy, no driver): the suite and its report section both import
it, and importing it registers the contract (:func:`armbench.record.suite_contract.register`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from armbench.record.suite_contract import Headline, register

__all__ = ["ACCURACY", "AccuracyNames"]


@dataclass(frozen=True, slots=True)
class AccuracyNames:
    """The accuracy suite (the paper's square, §7)."""

    suite: str = "accuracy"
    #: place in the default run and in the report (lower first)
    order: int = 10
    #: whether the suite records true figures beside the encoders' (the scorecard says which)
    has_true_figures: bool = True
    #: what runs the suite: ``module:Class``, imported only when the suite is loaded
    implementation: str | None = "armbench.bench.suites.accuracy:AccuracySuite"
    styles: tuple[str, ...] = ("paper", "coordinated")
    paper: str = "paper"
    coordinated: str = "coordinated"
    # trial parameters
    style: str = "style"
    lap: str = "lap"
    # suite parameters; ``paper_mean`` is also the key of the paper's figure in a record's
    # ``reference`` table
    centre: str = "centre_m"
    side: str = "side_m"
    paper_mean: str = "paper_mean_error_mm"
    # figures of a style (suffixes of its metric names)
    mean: str = "mean_mm"
    rms: str = "rms_mm"
    max: str = "max_mm"
    true_mean: str = "true_mean_mm"
    belief_mean: str = "belief_mean_mm"
    belief_max: str = "belief_max_mm"
    lap_time: str = "lap_time_s"
    laps: str = "laps"

    def metric(self, style: str, figure: str) -> str:
        """``accuracy.<style>.<figure>``."""
        return f"{self.suite}.{style}.{figure}"

    @property
    def improvement(self) -> str:
        """Paper-style mean over coordinated mean."""
        return f"{self.suite}.improvement_ratio"

    @property
    def true_improvement(self) -> str:
        return f"{self.suite}.true_improvement_ratio"

    @property
    def headlines(self) -> tuple[Headline, ...]:
        return (
            Headline("paper-style mean path error", self.metric(self.paper, self.mean),
                     paper=self.paper_mean),
            Headline("coordinated mean path error", self.metric(self.coordinated, self.mean)),
            Headline("coordinated max path error", self.metric(self.coordinated, self.max)),
            Headline("improvement (paper-style / coordinated)", self.improvement,
                     higher_is_worse=False),
            Headline("worst firmware belief vs truth", f"{self.suite}.*.{self.belief_max}",
                     worst_of=True),
        )


ACCURACY: Final = register(AccuracyNames())
