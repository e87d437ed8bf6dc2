"""The startup-recovery suite's contract: the names it records and the report reads (power cuts,
EEPROM wear).

Plain data and string builders (no numpy, no driver): the suite and its report section both import
it; the record layer finds it by the suite's name, registered as an entry point of
``armbench.suite_contracts`` (:func:`armbench.record.suite_contract.contract`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

from armbench.record.suite_contract import LIFE_WARN_YEARS, Headline

__all__ = ["STARTUP", "StartupNames"]


@dataclass(frozen=True, slots=True)
class StartupNames:
    """The startup-recovery suite (paper §5.2): power cuts and EEPROM wear."""

    suite: str = "startup-recovery"
    #: place in the default run and in the report (lower first)
    order: int = 30
    #: whether the suite records true figures beside the encoders' (the scorecard says which)
    has_true_figures: bool = False
    prefix: str = "startup"
    # trial parameters and their kinds
    kind: str = "kind"
    cut_kind: str = "cut"
    wear_kind: str = "wear"
    condition: str = "condition"
    joints: str = "joints"
    cut: str = "cut"
    duration: str = "duration_s"
    # events (samples with an ``event`` key) and their fields
    ev_fault: str = "fault"
    ev_power_restore: str = "power_restore"
    ev_ready: str = "ready"
    ev_recovered: str = "recovered"
    ev_timeout: str = "timeout"
    ev_outcome: str = "outcome"
    ev_position_check: str = "position_check"
    ev_wear_phase: str = "wear_phase"
    ev_wear: str = "wear"
    ev_rescue: str = "rescue"
    ev_skipped: str = "skipped"
    f_recovered: str = "recovered"
    f_failure: str = "failure"
    f_recovery: str = "recovery_s"
    f_expected: str = "expected_to_recover"
    f_error_mrad: str = "error_mrad"
    f_error_mm: str = "error_mm"
    # the phases of the wear trial (typical use: point-to-point, then streaming)
    ptp_phase: str = "ptp"
    streaming_phase: str = "streaming"

    def metric(self, figure: str) -> str:
        """``startup.<figure>`` (the metrics keep the short prefix of the limits files)."""
        return f"{self.prefix}.{figure}"

    def condition_rate(self, condition: str) -> str:
        """``startup.<condition>.success_rate_pct``."""
        return f"{self.prefix}.{condition}.success_rate_pct"

    def phase_writes(self, phase: str) -> str:
        """``startup.<phase>.eeprom_writes_per_hour``."""
        return f"{self.prefix}.{phase}.eeprom_writes_per_hour"

    # per trial
    @property
    def recovered(self) -> str:
        return self.metric("recovered")

    @property
    def recovery_time(self) -> str:
        return self.metric("recovery_time_s")

    @property
    def first_reply(self) -> str:
        return self.metric("first_reply_s")

    @property
    def position_error_mrad(self) -> str:
        return self.metric("position_error_mrad")

    @property
    def position_error_mm(self) -> str:
        return self.metric("position_error_mm")

    @property
    def eeprom_writes(self) -> str:
        return self.metric("eeprom_writes")

    # per suite
    @property
    def trials_measured(self) -> str:
        return self.metric("trials_measured")

    @property
    def success_rate(self) -> str:
        return self.metric("success_rate_pct")

    @property
    def expected_success_rate(self) -> str:
        return self.metric("expected_success_rate_pct")

    @property
    def recovery_time_max(self) -> str:
        return self.metric("recovery_time_max_s")

    @property
    def recovery_time_mean(self) -> str:
        return self.metric("recovery_time_mean_s")

    @property
    def position_error_max(self) -> str:
        return self.metric("position_error_max_mrad")

    @property
    def recovered_position_error_max(self) -> str:
        return self.metric("recovered_position_error_max_mrad")

    @property
    def eeprom_writes_per_cut(self) -> str:
        return self.metric("eeprom_writes_per_cut")

    @property
    def eeprom_writes_per_hour(self) -> str:
        return self.metric("eeprom_writes_per_hour")

    @property
    def eeprom_cell_wear_per_hour(self) -> str:
        return self.metric("eeprom_cell_wear_per_hour")

    @property
    def eeprom_life_years(self) -> str:
        return self.metric("eeprom_life_years")

    @property
    def eeprom_life_hours(self) -> str:
        return self.metric("eeprom_life_hours")

    @property
    def cut_figures(self) -> tuple[str, ...]:
        """The figures of one power cut (its position error in mm: measured by a tracker)."""
        return (self.recovered, self.recovery_time, self.first_reply, self.position_error_mrad,
                self.position_error_mm, self.eeprom_writes)

    @property
    def summary_figures(self) -> tuple[str, ...]:
        """The figures over every cut, besides the rate per condition."""
        return (self.trials_measured, self.success_rate, self.expected_success_rate,
                self.recovery_time_max, self.recovery_time_mean, self.position_error_max,
                self.recovered_position_error_max, self.eeprom_writes_per_cut)

    @property
    def wear_figures(self) -> tuple[str, ...]:
        """The figures of the wear trial, which the summary repeats."""
        return (*(self.phase_writes(p) for p in (self.ptp_phase, self.streaming_phase)),
                self.eeprom_writes_per_hour, self.eeprom_cell_wear_per_hour,
                self.eeprom_life_years, self.eeprom_life_hours)

    def metric_names(self, conditions: Iterable[str], wear: bool) -> frozenset[str]:
        """Every metric the suite records cutting the power in ``conditions``, with the wear
        trial or (``wear`` False) without."""
        return frozenset({*self.cut_figures, *self.summary_figures,
                          *(self.condition_rate(str(c)) for c in conditions),
                          *(self.wear_figures if wear else ())})

    @property
    def headlines(self) -> tuple[Headline, ...]:
        return (
            Headline("recovered after a power cut", self.success_rate, higher_is_worse=False,
                     no_limit="none: §5.2 can't recover all"),
            Headline("recovered where §5.2 can", self.expected_success_rate,
                     higher_is_worse=False),
            Headline("slowest recovery", self.recovery_time_max),
            Headline("worst error after a recovery", self.recovered_position_error_max),
            Headline("EEPROM life at the configured use", self.eeprom_life_years,
                     higher_is_worse=False,
                     no_limit=f"none: warns < {LIFE_WARN_YEARS:g} y"),
        )


STARTUP: Final = StartupNames()
