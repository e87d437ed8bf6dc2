"""Campaigns: many trials of one suite over drawn conditions (arm parameters from a
calibration's uncertainties, the state of each power cut), their distributions and pass
probabilities (``armbench campaign``); and shards of a run joined into one record
(``armbench merge``). See ``docs/campaigns.md``."""

from armbench.bench.campaign.campaign_run import CampaignOptions, prepare_campaign, run_campaign
from armbench.bench.campaign.draws import Uncertain, draw_arm, read_uncertainties
from armbench.bench.campaign.shards import MergeError, merge_shards
from armbench.bench.campaign.stats import (
    CAMPAIGN_KEY,
    MetricDistribution,
    campaign_measurements,
    collect,
    wilson_interval,
)
from armbench.bench.campaign.suite import CampaignSuite

__all__ = [
    "CAMPAIGN_KEY",
    "CampaignOptions",
    "CampaignSuite",
    "MergeError",
    "MetricDistribution",
    "Uncertain",
    "campaign_measurements",
    "collect",
    "draw_arm",
    "merge_shards",
    "prepare_campaign",
    "read_uncertainties",
    "run_campaign",
    "wilson_interval",
]
