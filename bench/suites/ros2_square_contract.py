"""The ros2-square suite's contract: what :mod:`armbench.frontends.ros2_node.square_suite` records
and its report section (``armbench.reports.sections.ros2_square``) reads, registered as an entry
point of ``armbench.suite_contracts`` (found by :func:`armbench.record.suite_contract.contracts`).
Plain data only.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

from armbench.bench.suites.accuracy_contract import ACCURACY
from armbench.record.suite_contract import Headline

__all__ = ["ROS2_SQUARE", "Ros2SquareNames"]


@dataclass(frozen=True, slots=True)
class Ros2SquareNames:
    """The ros2-square suite: the accuracy square through ROS 2 (a ``FollowJointTrajectory`` goal
    from a separate rclpy process) against the driver's own coordinated run, figures named as the
    accuracy suite's."""

    suite: str = "ros2-square"
    #: place in the report (lower first), after the built-in suites of the default run
    order: int = 50
    #: whether the suite records true figures beside the encoders' (the scorecard says which)
    has_true_figures: bool = True
    prefix: str = "ros2"
    styles: tuple[str, ...] = ("coordinated", "trajectory")
    coordinated: str = "coordinated"
    trajectory: str = "trajectory"
    # trial parameters
    style: str = "style"
    lap: str = "lap"
    # suite parameters
    centre: str = "centre_m"
    side: str = "side_m"
    # figures of a style (suffixes of its metric names): the accuracy suite's
    mean: str = ACCURACY.mean
    rms: str = ACCURACY.rms
    max: str = ACCURACY.max
    true_mean: str = ACCURACY.true_mean
    lap_time: str = ACCURACY.lap_time
    laps: str = ACCURACY.laps

    def metric(self, style: str, figure: str) -> str:
        """``ros2.<style>.<figure>``."""
        return f"{self.prefix}.{style}.{figure}"

    def metric_names(self, styles: Iterable[str]) -> frozenset[str]:
        """Every metric the suite records driving ``styles`` (the accuracy suite's figures of a
        lap): the path error ratios need both."""
        return ACCURACY.square_names(self.metric, styles, (self.coordinated, self.trajectory),
                                     (self.ratio, self.true_ratio))

    @property
    def ratio(self) -> str:
        """Mean path error through ROS 2 over the driver's own."""
        return f"{self.prefix}.path_error_ratio"

    @property
    def true_ratio(self) -> str:
        return f"{self.prefix}.true_path_error_ratio"

    @property
    def headlines(self) -> tuple[Headline, ...]:
        return (
            Headline("mean path error through ROS 2", self.metric(self.trajectory, self.mean)),
            Headline("mean path error, the driver's own run",
                     self.metric(self.coordinated, self.mean)),
            Headline("path error ratio (ROS 2 / driver)", self.ratio),
        )


ROS2_SQUARE: Final = Ros2SquareNames()
