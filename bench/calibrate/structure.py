"""The drive's speed model of each joint, chosen by held-out prediction: how it loses steps (the
step-loss law of ``docs/robot-model.md``) and whether its speed is scaled (a gear ratio other than
the nominal one).

Every speed run of the ladder (or of a capture) gives the ratio ``r`` of its effective speed to
law (12) (the candidates' fits and predictions: ``bench/calibrate/speed_laws.py``), with a
standard error from the scatter of its own replies about the fitted slope (the
link's and the host's timing jitter included) and the rounding of one pulse in its steps: the
arm's own noise in this session. Each candidate structure predicts ``r`` for a run:

* ``prior`` — the base settings' twin as it is (nothing fitted);
* ``none`` — no step lost: ``r = s``;
* ``torque`` — the torque deficit's share is lost: ``r = s · clip(P / f, 0.1, 1)`` with ``f`` the
  torque the run needs (the prior's masses, worm gear, friction, spin-up) times
  ``1 + rate / corner``: one parameter, the pull-out torque ``P``;
* ``stall`` — the rotor stops where the need exceeds the pull-out torque at the rate: ``r = s``
  or 0 (only when a run stalled), with the prior's pull-out curve and with the other shape
  (``bench/calibrate/stall.py``: hyperbolic or linear in the rate), each a candidate;
* ``duty`` — a fixed share is lost above a duty, per direction: ``r = s (1 − share±)`` above the
  threshold, ``s`` below it;

each with ``s = 1`` or with ``s`` fitted (the speed scale: the gear ratio is the nominal over
``s``). Every candidate is fitted leaving one run out and scored on that run (leave-one-out
cross-validation, the squared error over the run's standard error, summed, each run's at most
:data:`MISS_Z2`): the held-out χ².
Starting from the simplest, a candidate with more parameters is taken only when its held-out χ²
is lower by more than :data:`MARGIN` (about two standard errors of evidence), and the prior is
replaced only when the candidate taken beats it by as much. Each candidate's weight
(``exp(−χ²/2)`` normalised, an Akaike-style weight of held-out evidence) says how sure the choice
is.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Final

import numpy as np
import numpy.typing as npt

from armbench.bench.calibrate.model import Fitted, Observations, session_scatter
from armbench.bench.calibrate.speed_laws import (
    NEED_REL,
    STEPS,
    Candidate,
    JointSpeeds,
    at_bound,
    fit_law,
    param_sigma,
    predict,
    prior_prediction,
    run_table,
    stall_bracket,
    subset,
)
from armbench.bench.calibrate.stall import STALLED_RATIO
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.model.twin_parameters import TWIN
from armbench.fakes.twin.physics import ArmPhysics, JointPhysics

__all__ = ["MARGIN", "MAX_OPTIONS", "PARSIMONY", "Candidate", "JointSpeeds", "SpeedOption",
           "choose_joint", "fit_speed_models", "kept_speed", "run_table", "session_scatter",
           "speed_keys"]

FloatArray = npt.NDArray[np.float64]

#: Held-out χ² the best structure must gain over the prior's to replace it.
MARGIN: Final = 4.0
#: Candidates within this held-out χ² of the best count as equally good: the simplest is taken.
PARSIMONY: Final = 2.0
#: Largest share of the held-out χ² one run can take (a miss by five standard errors or more).
MISS_Z2: Final = 25.0

def _robust(z2: FloatArray) -> float:
    """Sum of squared standardised errors, each at most :data:`MISS_Z2`: a run predicted wrong
    by far (a stall on the wrong side of its boundary, a run the link's hiccup slowed) counts
    as one miss, not as its distance in standard errors."""
    return float(np.minimum(z2, MISS_Z2).sum())


def held_out_chi2(d: JointSpeeds, law: str, scaled: bool) -> float:
    """Leave-one-out χ² of ``law``: each run predicted by the fit to all the others (infinite
    when a fit runs into its bounds: :func:`at_bound`)."""
    n = len(d.ratio)
    total = 0.0
    if at_bound(fit_law(d, law, scaled)):
        return math.inf
    for i in range(n):
        keep = np.ones(n, dtype=bool)
        keep[i] = False
        c = fit_law(subset(d, keep), law, scaled)
        one = subset(d, ~keep)
        pred = predict(c, one)
        total += _robust(((one.ratio - pred) / one.sigma) ** 2)
    return total


def fit_speed_models(obs: Observations, base: RobotSettings, prior: ArmPhysics,
                     link_of: Callable[[Sequence[float]], list[float]],
                     fixed: Mapping[int, tuple[str, bool] | None] | None = None,
                     options: dict[int, list[SpeedOption]] | None = None) -> list[Fitted]:
    """Per joint: the step-loss law and its parameters, and the gear ratio, as :class:`Fitted`
    values (the law as ``choice``); a joint whose runs do not show a better structure than the
    prior's beyond the noise keeps the prior, and says why. ``fixed``: the structure per joint
    (0-based; None: the prior) taken as chosen instead of choosing it (a refit on another base:
    the sensitivity table). ``options`` receives, per joint, the candidates the held-out
    blocks judge (:func:`choose_joint`)."""
    out: list[Fitted] = []
    scatter, pairs = session_scatter(obs)
    noise = (f"; runs' errors × {scatter:.3g} (the scatter of {pairs} repeated runs)" if pairs
             else "; no repeated run: the runs' own errors")
    for j, spec in enumerate(base.joints):
        p = prior.joints[j]
        d = run_table(obs, base, prior, j, link_of, scatter)
        structure = None if fixed is None else (fixed.get(j) or ("prior", False))
        found: list[SpeedOption] | None = None if options is None else options.setdefault(j, [])
        out.extend(replace(f, reason=f.reason + noise) if f.key == TWIN["loss_law"].path(j) else f
                   for f in choose_joint(j, spec.gear_ratio, p, d, structure, found))
    return out


def speed_keys(j: int) -> frozenset[str]:
    """The settings keys of joint ``j``'s (0-based) speed model: its loss law and what the law
    reads, its pull-out curve, its gear ratio."""
    params = (TWIN["loss_law"], TWIN["pullout_curve"], *(p for p, _ in STEPS))
    return frozenset({*(p.path(j) for p in params), f"joints.j{j + 1}.gear_ratio"})


def kept_speed(j: int, gear: float, p: JointPhysics, reason: str) -> list[Fitted]:
    """Joint ``j``'s (0-based) speed model kept at the prior ``p`` (nominal gear ratio
    ``gear``), for ``reason``: nothing of it written."""
    law, pullout = TWIN["loss_law"], TWIN["pullout_nm"]
    return [Fitted(law.path(j), math.nan, None, law.unit, False, reason, choice=p.loss_law),
            Fitted(pullout.path(j), p.pullout_nm, None, pullout.unit, False, reason,
                   p.pullout_nm),
            Fitted(f"joints.j{j + 1}.gear_ratio", gear, None, "", False, reason, gear)]


@dataclass(frozen=True, slots=True)
class SpeedOption:
    """One candidate speed model of a joint for the held-out blocks to judge: its name
    (``duty+scale``), its number of parameters, its held-out χ² on the ladder's runs and its
    :class:`Fitted` values (fitted to all runs)."""

    name: str
    n_params: int
    ladder_chi2: float
    fitted: list[Fitted]


#: Candidate speed models per joint the held-out blocks judge beside the prior.
MAX_OPTIONS: Final = 3


def _ladder_scores(d: JointSpeeds, p: JointPhysics
                   ) -> tuple[dict[tuple[str, bool], float], dict[tuple[str, bool], int], float]:
    """Every candidate's held-out χ² on the runs ``d`` and its number of parameters, and the
    prior's χ²."""
    prior_chi2 = _robust(((d.ratio - prior_prediction(p, d)) / d.sigma) ** 2)
    laws = ["none", "torque", "duty"] + ([f"stall:{c}" for c in d.curves]
                                         if (d.ratio < STALLED_RATIO).any() else [])
    scores: dict[tuple[str, bool], float] = {}
    sizes: dict[tuple[str, bool], int] = {}
    for law in laws:
        for scaled in (False, True):
            scores[(law, scaled)] = held_out_chi2(d, law, scaled)
            sizes[(law, scaled)] = {"none": 0, "torque": 1, "duty": 3}.get(law, 1) + scaled
    return scores, sizes, prior_chi2


def choose_joint(j: int, gear: float, p: JointPhysics, d: JointSpeeds,
                 fixed: tuple[str, bool] | None = None,
                 options: list[SpeedOption] | None = None) -> list[Fitted]:
    """Joint ``j``'s (0-based) speed model from its runs ``d`` against the prior ``p`` (nominal
    gear ratio ``gear``): the chosen law, its parameters and the gear ratio as :class:`Fitted`.
    ``fixed``: take this ``(law, scaled)`` as chosen (``("prior", False)``: keep the prior).
    ``options`` receives the candidates the held-out blocks judge (:class:`SpeedOption`): the
    one chosen here first, then the others no worse than the prior on the runs beyond the
    noise, by their held-out χ², at most :data:`MAX_OPTIONS`, each whose values are
    identified."""
    n = len(d.ratio)
    if n < 3:
        return kept_speed(j, gear, p, f"{n} speed runs: too few to hold any out")
    if fixed is not None:
        if fixed[0] == "prior":
            return kept_speed(j, gear, p, "the prior (structure fixed)")
        return _emit(j, gear, p, d, fit_law(d, *fixed), "structure fixed", n)
    scores, sizes, prior_chi2 = _ladder_scores(d, p)
    simple = _step_up(scores, sizes)
    everything = {"prior": prior_chi2, **{_name(k): v for k, v in scores.items()}}
    low = min(everything.values())
    weights = {k: math.exp(-0.5 * (v - low)) for k, v in everything.items()}
    total_w = sum(weights.values())
    table = ", ".join(f"{k} {v:.3g}" for k, v in sorted(everything.items(), key=lambda kv: kv[1]))
    if options is not None:
        ranked = sorted((k for k, v in scores.items() if v <= prior_chi2 + MARGIN),
                        key=lambda k: (k != simple, scores[k]))
        for k in ranked:
            fitted = _emit(j, gear, p, d, fit_law(d, *k), f"{_name(k)} (ladder held-out χ² "
                                                       f"{scores[k]:.3g}; {table})", n)
            if any(f.identified for f in fitted) and len(options) < MAX_OPTIONS:
                options.append(SpeedOption(_name(k), sizes[k], scores[k], fitted))
    if prior_chi2 - scores[simple] <= MARGIN:
        return kept_speed(j, gear, p, f"no structure predicts the {n} held-out runs better than "
                                      f"the prior beyond the noise (held-out χ²: {table})")
    c = fit_law(d, *simple)
    sure = weights[_name(simple)] / total_w
    why = (f"{c.name} chosen by held-out prediction of {n} speed runs (weight {sure:.2f}; "
           f"held-out χ²: {table})")
    return _emit(j, gear, p, d, c, why, n)


def _emit(j: int, gear: float, p: JointPhysics, d: JointSpeeds, c: Candidate, why: str,
          n: int) -> list[Fitted]:
    """The :class:`Fitted` values of the structure ``c`` fitted to all ``n`` runs ``d``."""
    law, curve = TWIN["loss_law"], TWIN["pullout_curve"]
    out = [Fitted(law.path(j), math.nan, None, law.unit, True, why, choice=c.law)]
    if c.curve:
        d = d.on_curve(c.curve)
        out.append(Fitted(curve.path(j), math.nan, None, curve.unit, True,
                          f"{c.curve}: the pull-out curve of the law chosen (corner "
                          f"{p.corner_steps_per_s:g} microsteps/s, the prior's)", choice=c.curve))
    for param, step in STEPS:
        key = param.name
        if key not in c.params:
            continue
        path, unit = param.path(j), param.unit
        value = c.params[key]
        prior_value = float(getattr(p, param.name))
        if key == "loss_above_duty":
            duties = sorted({float(x) for x in d.duty})
            above = [x for x in duties if x > value]
            reason = (f"no loss at duty {value:g} and below" + (
                f", loss from {above[0]:g} on" if above else ""))
            out.append(Fitted(path, value, None, unit, True, reason, prior_value))
            continue
        if key == "pullout_nm" and c.law == "stall":
            value, sigma = stall_bracket(d)
        else:
            sigma = param_sigma(d, c, key, step * max(1.0, abs(value)))
        if key == "pullout_nm":  # the masses' error is common to every run: it does not average
            sigma = math.hypot(sigma, NEED_REL * value)
        if key == "pullout_nm" and not (d.factor > value).any():
            out.append(Fitted(path, max(value, prior_value), None, unit, False,
                              "no run needed more than the pull-out torque: only a lower bound",
                              prior_value, float(d.factor.max())))
            continue
        ok = math.isfinite(sigma) and (sigma <= 0.5 * abs(value) if key == "pullout_nm"
                                       else sigma <= 0.05)
        if not ok:
            out.append(Fitted(path, prior_value, None, unit, False,
                              f"not identified: {value:.3g} ± {sigma:.2g} (the interval is wider "
                              "than the value)", prior_value))
            return kept_speed(j, gear, p, f"{c.name} was best but its {key} is not identified "
                                     f"({value:.3g} ± {sigma:.2g})")
        low_r, high_r = param.low, param.high
        note = ("" if low_r <= value <= high_r else
                f"; OUTSIDE the documented range {low_r:g}..{high_r:g}")
        out.append(Fitted(path, value, sigma, unit, True, why + note, prior_value))
    if c.scaled:
        s = c.params["s"]
        sigma_s = param_sigma(d, c, "s", 1e-5)
        out.append(Fitted(f"joints.j{j + 1}.gear_ratio", gear / s, gear * sigma_s / s ** 2, "",
                          True, f"speed scale {s:.5g} ± {sigma_s:.2g} against law (12) with the "
                                f"nominal ratio {gear:g}", gear))
    else:
        out.append(Fitted(f"joints.j{j + 1}.gear_ratio", gear, None, "", False,
                          "no speed scale beyond the noise", gear))
    return out


def _step_up(scores: Mapping[tuple[str, bool], float],
             sizes: Mapping[tuple[str, bool], int]) -> tuple[str, bool]:
    """From the simplest candidate (fewest parameters, then the best score among those within
    :data:`PARSIMONY` of the best of that size), step to one with more parameters only when it
    predicts the held-out runs better by more than :data:`MARGIN`."""
    order = sorted(scores, key=lambda k: (sizes[k], scores[k]))
    current = order[0]
    for k in order[1:]:
        need = MARGIN if sizes[k] > sizes[current] else PARSIMONY
        if scores[k] < scores[current] - need:
            current = k
    return current


def _name(k: tuple[str, bool]) -> str:
    return k[0] + ("+scale" if k[1] else "")
