"""A campaign's figures: each metric's distribution over the samples and the probability of
passing its limit, with a Wilson score interval (:func:`campaign_measurements`).

Each done trial of a campaign is one sample; its measurements are the sample's figures, judged
against the limits where the trial ran. :func:`collect` gathers them by metric name (in sample
order); the record keeps the result as suite-level measurements named
``campaign.<metric>.<statistic>``, which the report page and ``armbench compare`` read like any
other figure.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np

from armbench.record import Better, Measurement, Trial, judge
from armbench.record.campaign_names import ALL_LIMITS, CAMPAIGN, QUANTILES, CampaignNames
from armbench.record.limits import LimitsConfig

__all__ = ["ALL_LIMITS", "CAMPAIGN", "CAMPAIGN_KEY", "Z95", "CampaignNames", "MetricDistribution",
           "campaign_measurements", "collect", "wilson_interval"]

#: The key of the suite parameters that holds the campaign's own (samples, seed, uncertainties).
CAMPAIGN_KEY: Final = "campaign"
#: z of the 95 % two-sided interval.
Z95: Final = 1.959963984540054


def wilson_interval(passed: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval (95 % by default) of a proportion ``passed`` of ``n``, as
    fractions; (0, 1) for no trial."""
    if n <= 0:
        return 0.0, 1.0
    p = passed / n
    z2 = z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / (1 + z2 / n)
    # the bounds hold p (rounding aside: at p = 1 the formula's upper bound is 1 - 1e-16)
    return max(0.0, min(p, centre - half)), min(1.0, max(p, centre + half))

@dataclass(slots=True)
class MetricDistribution:
    """The values of one metric over the samples that have it, and how many passed its limit.

    ``judged`` is the denominator of the pass probability: every sample of the campaign once a
    limit judged the metric in any of them. A sample in error, or one without the figure (a power
    cut the arm did not recover from has no recovery time), counts as not passing: leaving it
    out would report 100 % of the samples that happened to succeed.
    """

    name: str
    unit: str
    values: list[float] = field(default_factory=list)
    passed: int = 0
    judged: int = 0
    limit: str | None = None
    """The limit as text (``<= 10 s``), when one judged the metric."""

    def pass_interval(self) -> tuple[float, float]:
        """The 95 % Wilson interval of the pass probability (fractions)."""
        return wilson_interval(self.passed, self.judged)


def collect(trials: Iterable[Trial]) -> dict[str, MetricDistribution]:
    """Each metric's distribution over the done trials (samples), plus :data:`ALL_LIMITS`: the
    samples measured whose every judged figure is there and passed. Pass counts are over every
    sample, those in error included (see :class:`MetricDistribution`)."""
    out: dict[str, MetricDistribution] = {}
    overall = MetricDistribution(ALL_LIMITS, "")
    ordered = sorted(trials, key=lambda t: t.index)
    clean: list[set[str]] = []  # per measured sample without a failure: its judged figures
    for trial in ordered:
        if trial.status != "done":
            continue
        failed = False
        judged: set[str] = set()
        for m in trial.measurements:
            d = out.get(m.name)
            if d is None:
                d = out[m.name] = MetricDistribution(m.name, m.unit)
            d.values.append(m.value)
            if m.outcome in ("pass", "fail"):
                judged.add(m.name)
                d.passed += m.outcome == "pass"
                failed |= m.outcome == "fail"
                if d.limit is None and m.limit is not None:
                    d.limit = m.limit.describe()
        if not failed:
            clean.append(judged)
    limited = {name for name, d in out.items() if d.limit is not None}
    for name in limited:
        out[name].judged = len(ordered)
    if limited:
        overall.judged = len(ordered)
        overall.passed = sum(limited <= judged for judged in clean)
        out[ALL_LIMITS] = overall
    return out


def campaign_measurements(trials: Sequence[Trial],
                          limits: LimitsConfig | None = None) -> list[Measurement]:
    """The campaign's suite-level figures: samples measured and in error, and for each metric
    its count, mean, standard deviation, extremes and quantiles, and for a judged metric the
    pass probability (%) over every sample with its 95 % Wilson interval.

    Each figure is judged against ``limits`` by its name (``[limits."campaign.all_limits.
    pass_ci_low_pct"] low = 95``: the campaign fails unless the pass probability is above 95 %
    with 95 % confidence); these are the campaign's verdict (the samples' own limits are its
    findings, summarised by the pass probabilities).
    """
    def _stat(name: str, value: float, unit: str, description: str, *,
              better: Better | None = None) -> Measurement:
        # directions as before the figures were judged: only a pass probability has one
        return dataclasses.replace(judge(name, value, unit, limits, description=description),
                                   better=better)

    c = CAMPAIGN
    done = [t for t in trials if t.status == "done"]
    ms = [_stat(c.metric(c.samples), float(len(done)), "", "samples measured"),
          _stat(c.metric(c.samples_in_error), float(len(trials) - len(done)), "",
                "samples that could not be measured")]
    for name, d in collect(trials).items():
        if d.values:
            v = np.asarray(d.values, dtype=np.float64)
            ms.append(_stat(c.metric(name, c.n), float(v.size), "", f"samples with {name}"))
            ms.append(_stat(c.metric(name, c.mean), float(v.mean()), d.unit, f"mean of {name}"))
            ms.append(_stat(c.metric(name, c.std), float(v.std(ddof=1)) if v.size > 1 else 0.0,
                            d.unit, f"standard deviation of {name} (n − 1)"))
            ms.append(_stat(c.metric(name, c.min), float(v.min()), d.unit, f"smallest {name}"))
            for stat, q in QUANTILES:
                ms.append(_stat(c.metric(name, stat), float(np.quantile(v, q)), d.unit,
                                f"{round(q * 100)} % quantile of {name}"))
            ms.append(_stat(c.metric(name, c.max), float(v.max()), d.unit, f"largest {name}"))
            if d.unit == "bool":  # a yes/no figure: its rate, with the same interval
                yes = int(np.count_nonzero(v))
                low, high = wilson_interval(yes, int(v.size))
                ms.append(_stat(c.metric(name, c.rate), 100.0 * yes / v.size, "%",
                                f"samples in which {name} is true ({yes} of {v.size})"))
                ms.append(_stat(c.metric(name, c.rate_low), 100.0 * low, "%",
                                "95 % Wilson interval of the rate, lower end"))
                ms.append(_stat(c.metric(name, c.rate_high), 100.0 * high, "%",
                                "95 % Wilson interval of the rate, upper end"))
        if d.judged:
            low, high = d.pass_interval()
            what = ("samples passing every limit" if name == ALL_LIMITS
                    else f"samples whose {name} passes {d.limit}")
            ms.append(_stat(c.metric(name, c.passed), 100.0 * d.passed / d.judged, "%",
                            f"{what} ({d.passed} of {d.judged} samples; a sample in error or "
                            "without the figure does not pass)", better="higher"))
            ms.append(_stat(c.metric(name, c.pass_low), 100.0 * low, "%",
                            "95 % Wilson interval of the pass probability, lower end"))
            ms.append(_stat(c.metric(name, c.pass_high), 100.0 * high, "%",
                            "95 % Wilson interval of the pass probability, upper end"))
    return ms
