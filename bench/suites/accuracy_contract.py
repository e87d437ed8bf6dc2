"""The accuracy suite's contract: the names it records and the report reads (the paper's square).

Plain data and string builders (no numpy, no driver): the suite and its report section both import
it; the record layer finds it by the suite's name, registered as an entry point of
``armbench.suite_contracts`` (:func:`armbench.record.suite_contract.contract`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Final

from armbench.record.suite_contract import Headline

__all__ = ["ACCURACY", "AccuracyNames"]


@dataclass(frozen=True, slots=True)
class AccuracyNames:
    """The accuracy suite (the paper's square, §7)."""

    suite: str = "accuracy"
    #: place in the default run and in the report (lower first)
    order: int = 10
    #: whether the suite records true figures beside the encoders' (the scorecard says which)
    has_true_figures: bool = True
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
    # figures of a style (suffixes of its metric names): statistics of the distance to the
    # square, overall and along each axis, of the reported TCP and (``true_``) of the true one;
    # of the distance between the two (``belief_``)
    mean: str = "mean_mm"
    rms: str = "rms_mm"
    max: str = "max_mm"
    axes: tuple[str, ...] = ("x", "y", "z")
    true: str = "true_"
    belief: str = "belief_"
    lap_time: str = "lap_time_s"
    laps: str = "laps"

    def metric(self, style: str, figure: str) -> str:
        """``accuracy.<style>.<figure>``."""
        return f"{self.suite}.{style}.{figure}"

    def square_figure(self, stat: str, prefix: str = "", axis: str = "") -> str:
        """A figure of a lap of the square: ``[true_|belief_][<axis>_]<stat>`` (``mean_mm``,
        ``true_x_rms_mm``, ``belief_max_mm``)."""
        return f"{prefix}{axis}{'_' if axis else ''}{stat}"

    @property
    def stats(self) -> tuple[str, ...]:
        """The statistics of a distance: mean, RMS, largest."""
        return (self.mean, self.rms, self.max)

    def square_figures(self) -> tuple[str, ...]:
        """Every figure of a lap of the square, in the order the suites record them: of the
        reported TCP and of the true one (overall, then per axis), then the belief figures."""
        return (*(self.square_figure(stat, prefix, axis) for prefix in ("", self.true)
                  for axis in ("", *self.axes) for stat in self.stats),
                *(self.square_figure(stat, self.belief) for stat in self.stats))

    @property
    def true_mean(self) -> str:
        return self.square_figure(self.mean, self.true)

    @property
    def belief_mean(self) -> str:
        return self.square_figure(self.mean, self.belief)

    @property
    def belief_max(self) -> str:
        return self.square_figure(self.max, self.belief)

    def square_names(self, metric: Callable[[str, str], str], styles: Iterable[str],
                     pair: tuple[str, str], ratios: tuple[str, ...]) -> frozenset[str]:
        """What a square suite records driving ``styles``: the figures of a lap of each (named
        ``metric(style, figure)``), and ``ratios`` of the two styles of ``pair`` when both are
        driven (the true and belief figures of a bench with a reference instrument included)."""
        driven = set(styles)
        per_style = (*self.square_figures(), self.lap_time, self.laps)
        both = set(pair) <= driven
        return frozenset({metric(style, figure) for style in driven for figure in per_style}
                         | (set(ratios) if both else set()))

    def metric_names(self, styles: Iterable[str]) -> frozenset[str]:
        """Every metric the suite records driving ``styles``: the improvement ratios need both."""
        return self.square_names(self.metric, styles, (self.paper, self.coordinated),
                                 (self.improvement, self.true_improvement))

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


ACCURACY: Final = AccuracyNames()
