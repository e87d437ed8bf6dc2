"""The twin-check record's contract: the names ``armbench twin-check --out`` records and the report
reads (how well the twin predicts an arm's capture).

Plain data and string builders (no numpy, no driver): the suite and its report section both import
it; the record layer finds it by the suite's name, registered as an entry point of
``armbench.suite_contracts`` (:func:`armbench.record.suite_contract.contract`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from armbench.record.suite_contract import Headline

__all__ = ["TWIN_CHECK", "TwinCheckNames"]


@dataclass(frozen=True, slots=True)
class TwinCheckNames:
    """``armbench twin-check --out``: how well the twin predicts an arm's capture (the record of
    :mod:`armbench.bench.twin_check.twin_record`; the report's twin-check section)."""

    suite: str = "twin-check"
    #: place in the default run and in the report (lower first)
    order: int = 90
    #: whether the suite records true figures beside the encoders' (the scorecard says which)
    has_true_figures: bool = False
    prefix: str = "twin"
    # suite parameters: the inputs and how the series were kept
    capture: str = "capture"
    capture_sha256: str = "capture_sha256"
    settings: str = "settings"
    settings_sha256: str = "settings_sha256"
    config: str = "config"
    config_sha256: str = "config_sha256"
    buckets: str = "series_buckets"
    # samples: ``kind`` (SAMPLE.kind) is one of these
    series_kind: str = "series"
    arrival_kind: str = "arrival"
    # keys of a series sample (one joint at one reply of the capture)
    joint: str = "joint"
    arm: str = "arm_rad"
    twin: str = "twin_rad"
    divergence: str = "divergence_counts"
    # keys of an arrival sample (one command both streams arrived at; SAMPLE.t is its time)
    arm_arrival: str = "arm_s"
    twin_arrival: str = "twin_s"
    arrival_dt: str = "dt_s"
    # figures per joint (twin.j<N>.<figure>)
    rms_counts: str = "rms_counts"
    max_counts: str = "max_counts"
    rms_rad: str = "rms_rad"
    max_rad: str = "max_rad"
    # figures of the whole check (twin.<figure>)
    mean_dt: str = "arrival.mean_dt_s"
    max_abs_dt: str = "arrival.max_abs_dt_s"
    moves: str = "arrival.moves"
    compared: str = "arrival.compared"
    arm_only: str = "arrival.arm_only"
    twin_only: str = "arrival.twin_only"
    replies: str = "replies_compared"
    untimed: str = "replies_untimed"
    sessions: str = "sessions"
    # the floor and the verdict relative to it (twin.j<N>.<figure>, twin.<figure>)
    floor_counts: str = "floor_counts"
    allowed_counts: str = "allowed_counts"
    per_allowed: str = "rms_per_allowed"
    settled_counts: str = "settled_counts"
    settled_per_allowed: str = "settled_per_allowed"
    worst_part_counts: str = "worst_part_counts"
    worst_part_per_allowed: str = "worst_part_per_allowed"
    parts: str = "parts"
    rms_dt: str = "arrival.rms_dt_s"
    floor_dt: str = "arrival.floor_s"
    arrival_per_allowed: str = "arrival.rms_per_allowed"
    scatter: str = "timing_scatter_s"
    reaction: str = "reaction_scatter_s"
    shift_mean: str = "start_shift.mean_s"
    shift_max: str = "start_shift.max_abs_s"
    tcp_floor: str = "tcp.floor_mm"
    tcp_per_allowed: str = "tcp.rms_per_allowed"
    tcp_samples: str = "tcp.samples"
    tcp_rest: str = "tcp.rest_rms_mm"
    tcp_rest_per_allowed: str = "tcp.rest_rms_per_allowed"
    tcp_rms: str = "tcp.rms_mm"
    tcp_max: str = "tcp.max_mm"

    joints: tuple[int, ...] = (1, 2, 3, 4)

    def metric_names(self) -> frozenset[str]:
        """Every figure the check records: per joint, of the arrival times, of the TCP (where
        the capture has truth) and of the whole check."""
        per_joint = (self.rms_counts, self.max_counts, self.rms_rad, self.max_rad,
                     self.floor_counts, self.allowed_counts, self.per_allowed,
                     self.settled_counts, self.settled_per_allowed, self.worst_part_counts,
                     self.worst_part_per_allowed)
        whole = (self.mean_dt, self.max_abs_dt, self.rms_dt, self.floor_dt,
                 self.arrival_per_allowed, self.moves, self.compared, self.arm_only,
                 self.twin_only, self.replies, self.untimed, self.sessions, self.parts,
                 self.scatter,
                 self.reaction, self.shift_mean, self.shift_max, self.tcp_floor,
                 self.tcp_per_allowed, self.tcp_samples, self.tcp_rest,
                 self.tcp_rest_per_allowed, self.tcp_rms, self.tcp_max)
        return frozenset({*(self.joint_metric(j, f) for j in self.joints for f in per_joint),
                          *(self.metric(f) for f in whole)})

    def joint_metric(self, joint: int, figure: str) -> str:
        """``twin.j<N>.<figure>``."""
        return f"{self.prefix}.j{joint}.{figure}"

    def metric(self, figure: str) -> str:
        """``twin.<figure>``."""
        return f"{self.prefix}.{figure}"

    @property
    def headlines(self) -> tuple[Headline, ...]:
        p = self.prefix
        return (
            Headline("worst joint RMS divergence", f"{p}.j*.{self.rms_counts}", worst_of=True),
            Headline("worst joint RMS over its allowance", f"{p}.j*.{self.per_allowed}",
                     worst_of=True),
            Headline("worst joint largest divergence", f"{p}.j*.{self.max_counts}",
                     worst_of=True),
            Headline("largest arrival-time difference", self.metric(self.max_abs_dt)),
            Headline("TCP RMS divergence", self.metric(self.tcp_rms)),
        )


TWIN_CHECK: Final = TwinCheckNames()
