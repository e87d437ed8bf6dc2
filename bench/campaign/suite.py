"""A campaign as a suite the runner runs like any other: :class:`CampaignSuite` wraps a bench
suite; each of its trials is one *sample*.

A sample draws its conditions from the campaign seed and its index alone (so the record is the
same however the samples are spread over workers or shards):

* the arm (``"arm"``): each setting a calibration fitted, drawn from its uncertainty
  (:func:`~armbench.bench.campaign.draws.draw_arm`). The emulator plays the drawn arm
  (:meth:`CampaignSuite.emulated_settings`); the driver and the suite keep the fitted settings,
  as a bench does with a real arm it knows only through its calibration;
* the trials it runs (``"trials"``): for ``startup-recovery`` one power cut in a drawn state
  (condition: stopped, moving CW or CCW, away from or towards the Hall sensor, near or far; and a
  drawn joint set; the moment of the cut within the motion, or the dwell before it, is drawn by
  the suite from the trial's own seed); for any other suite its whole plan.

The sample's trials run in turn on one connection (a fresh emulator per sample), then the
suite's own ``summarize`` reduces them: the sample's figures are those suite-level figures plus,
for a one-trial sample, that trial's own. Long sample series (the accuracy suite's 100 Hz
states) are left out of the record: the figures keep what they say.
"""

from __future__ import annotations

import dataclasses
import random
from collections.abc import Mapping, Sequence
from typing import Any, Final

from armbench.bench.campaign.draws import Uncertain, apply_arm, draw_arm
from armbench.bench.campaign.stats import CAMPAIGN, CAMPAIGN_KEY, campaign_measurements
from armbench.bench.runner.options import derive_seed
from armbench.bench.suites.base import Suite, SuiteContext
from armbench.drivers.model.settings import RobotSettings
from armbench.record import Measurement, Trial

__all__ = ["MAX_KEPT_SAMPLES", "CampaignSuite", "campaign_params"]

#: A sample keeps a trial's samples (events) only when it has at most this many.
MAX_KEPT_SAMPLES: Final = 100


def campaign_params(inner_params: Mapping[str, Any], samples: int, seed: int,
                    uncertain: Sequence[Uncertain]) -> dict[str, Any]:
    """The parameters of a campaign over a suite with ``inner_params``."""
    return {**inner_params, CAMPAIGN_KEY: {
        "samples": samples, "seed": seed, "uncertain": [u.to_json() for u in uncertain]}}


def _inner(params: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in params.items() if k != CAMPAIGN_KEY}


class CampaignSuite(Suite):
    """``inner`` over drawn conditions (see the module doc). ``settings``: the fitted arm the
    draws start from."""

    def __init__(self, inner: Suite, settings: RobotSettings) -> None:
        self.inner = inner
        self.settings = settings
        self.name = inner.name
        self.version = inner.version

    def default_params(self, settings: RobotSettings) -> dict[str, Any]:
        """The wrapped suite's."""
        return self.inner.default_params(settings)

    def metric_names(self, params: Mapping[str, Any]) -> frozenset[str]:
        """A sample's figures (the wrapped suite's) and the campaign's over them."""
        inner = self.inner.metric_names(_inner(params))
        return inner | CAMPAIGN.metric_names(inner)

    def plan(self, params: Mapping[str, Any]) -> list[dict[str, Any]]:
        """One trial per sample: ``{"sample": i, "arm": {key: value}, "trials": [...]}``."""
        c = params[CAMPAIGN_KEY]
        uncertain = [Uncertain(u["key"], u["value"], u["sigma"], u["unit"])
                     for u in c["uncertain"]]
        inner = _inner(params)
        out = []
        for i in range(int(c["samples"])):
            rng = random.Random(derive_seed(int(c["seed"]), "campaign", self.name, i))
            arm = draw_arm(self.settings, uncertain, rng)
            out.append({"sample": i, "arm": arm, "trials": self._sample_trials(inner, rng, i)})
        return out

    def _sample_trials(self, inner: Mapping[str, Any], rng: random.Random,
                       i: int) -> list[dict[str, Any]]:
        if self.inner.name == "startup-recovery":
            condition = rng.choice(list(inner["conditions"]))
            joints = rng.choice([list(g) for g in inner["joint_sets"]])
            return [{"kind": "cut", "condition": condition, "joints": joints, "cut": i}]
        return [dict(t) for t in self.inner.plan(inner)]

    def emulated_settings(self, settings: RobotSettings,
                          trial_params: Mapping[str, Any]) -> RobotSettings:
        """The drawn arm of the sample."""
        return apply_arm(self.settings, trial_params.get("arm", {}))

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        """The sample's trials in turn, then their summary (see the module doc); the first trial
        in error makes the sample an error."""
        sub = dataclasses.replace(ctx, params=_inner(ctx.params))
        trials: list[Trial] = []
        events: list[dict[str, Any]] = []
        for j, tp in enumerate(trial_params["trials"]):
            t = await self.inner.run_trial(
                dataclasses.replace(sub, rng=random.Random(ctx.rng.getrandbits(64))), j, tp)
            if t.status == "error":
                return Trial(index, 0.0, 0.0, params=trial_params, status="error",
                             error=f"{self.inner.name} trial {j}: {t.error}")
            trials.append(t)
            if len(t.samples) <= MAX_KEPT_SAMPLES:
                events += [{"trial": j, **s} for s in t.samples]
            else:
                events.append({"trial": j, "event": "samples_left_out", "count": len(t.samples)})
        return Trial(index, 0.0, 0.0, params=trial_params, samples=events,
                     measurements=sample_figures(self.inner, sub, trials))

    def summarize(self, ctx: SuiteContext, trials: Sequence[Trial]) -> list[Measurement]:
        """Distributions and pass probabilities over the samples (``campaign.*``)."""
        return campaign_measurements(trials, ctx.limits)


def sample_figures(inner: Suite, ctx: SuiteContext, trials: Sequence[Trial]) -> list[Measurement]:
    """A sample's figures: ``inner``'s summary of its trials and, for one trial, that trial's
    figures the summary does not have."""
    summary = inner.summarize(ctx, trials)
    names = {m.name for m in summary}
    own = [m for m in trials[0].measurements if m.name not in names] if len(trials) == 1 else []
    return own + summary
