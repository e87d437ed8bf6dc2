"""The names of a campaign's figures (``campaign.<metric>.<statistic>``): what a campaign records
and what the config check knows a limit may name, defined once below both."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

__all__ = ["ALL_LIMITS", "CAMPAIGN", "QUANTILES", "CampaignNames"]

#: The pseudo-metric of a sample passing every limit that judged one of its figures.
ALL_LIMITS = "all_limits"
#: The quantiles recorded, as (statistic name, fraction).
QUANTILES = (("p05", 0.05), ("p50", 0.50), ("p95", 0.95))


@dataclass(frozen=True, slots=True)
class CampaignNames:
    """The names of a campaign's figures: ``campaign.<metric>.<statistic>`` of each metric of
    the samples, and the campaign's own counts ``campaign.samples``, ...; what
    :func:`campaign_measurements` records and the config check knows."""

    prefix: str = "campaign"
    samples: str = "samples"
    samples_in_error: str = "samples_in_error"
    # the distribution of a metric over the samples (the quantiles: QUANTILES)
    n: str = "n"
    mean: str = "mean"
    std: str = "std"
    min: str = "min"
    max: str = "max"
    # a yes/no metric's rate, and a judged metric's pass probability, each with its interval
    rate: str = "rate_pct"
    rate_low: str = "rate_ci_low_pct"
    rate_high: str = "rate_ci_high_pct"
    passed: str = "pass_pct"
    pass_low: str = "pass_ci_low_pct"
    pass_high: str = "pass_ci_high_pct"

    def metric(self, name: str, stat: str | None = None) -> str:
        """``campaign.<name>`` or ``campaign.<name>.<stat>``."""
        return f"{self.prefix}.{name}" if stat is None else f"{self.prefix}.{name}.{stat}"

    @property
    def stats(self) -> tuple[str, ...]:
        """Every statistic of a metric: distribution, rate, pass probability."""
        return (self.n, self.mean, self.std, self.min, *(s for s, _ in QUANTILES), self.max,
                self.rate, self.rate_low, self.rate_high, self.passed, self.pass_low,
                self.pass_high)

    def metric_names(self, sample_names: Iterable[str]) -> frozenset[str]:
        """Every figure a campaign records over samples whose metrics are ``sample_names``."""
        return frozenset({self.metric(self.samples), self.metric(self.samples_in_error),
                          *(self.metric(ALL_LIMITS, s)
                            for s in (self.passed, self.pass_low, self.pass_high)),
                          *(self.metric(name, s) for name in sample_names for s in self.stats)})


#: The names of a campaign's figures.
CAMPAIGN: Final = CampaignNames()
