"""The candidate speed models of a joint (``bench/calibrate/structure.py`` chooses among them):
each fitted to a joint's speed runs, and what each predicts for a run.

A run's ratio (its effective speed over law (12)) is predicted by ``none`` (``s``), ``torque``
(``s · clip(P / f, 0.1, 1)``, ``f`` the torque the run needs on the pull-out curve), ``stall``
(``s`` or 0: the rotor stands where ``f`` exceeds ``P``, on either pull-out curve) and ``duty``
(``s (1 − share±)`` above a threshold duty, ``s`` at and below it), each with the speed scale
``s`` fitted or 1; the prior is the base settings' twin as it is.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Final

import numpy as np
import numpy.typing as npt
from scipy.optimize import minimize_scalar

from armbench.bench.calibrate.model import Observations, run_sigma
from armbench.bench.calibrate.stall import STALLED_RATIO, curve_factor, stall_interval, stall_pred
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.model.twin_parameters import TWIN
from armbench.fakes.twin.physics import PULLOUT_CURVES, ArmPhysics, JointPhysics, Mechanism

__all__ = ["NEED_REL", "P_GRID", "SCALE_RANGE", "STEPS", "Candidate", "JointSpeeds", "at_bound",
           "fit_law", "param_sigma", "predict", "prior_prediction", "run_table", "stall_bracket",
           "subset"]

FloatArray = npt.NDArray[np.float64]

#: Relative standard error of a run's needed torque (masses and angles of the prior): the torque
#: fit adds it to each lossy run's ratio error in its weights, and to the pull-out torque's; the
#: held-out scores use the runs' own errors only (a model cannot excuse its misses).
NEED_REL: Final = 0.01
_PULLOUT, _ABOVE = TWIN["pullout_nm"], TWIN["loss_above_duty"]
_PLUS, _MINUS = TWIN["loss_plus"], TWIN["loss_minus"]
#: Pull-out torques the profile fits search (N·m, log-spaced): the band the settings file
#: accepts around the documented range.
P_GRID: Final = np.geomspace(*_PULLOUT.accepted(), 481)
#: The parameters a speed model fits, each with the step of its numerical derivative (its unit).
STEPS: Final = ((_PULLOUT, 0.01), (_ABOVE, 0.5), (_PLUS, 1e-4), (_MINUS, 1e-4))
#: The duty law losing nothing anywhere (the parameters' ideal values).
_NO_DUTY_LOSS: Final = {p.name: float(p.ideal_value()) for p in (_ABOVE, _PLUS, _MINUS)}
#: Speed scales a fit may return: another gear set of the same arm (a quarter off the nominal
#: ratio at most); beyond that a scale would stand in for any step loss.
SCALE_RANGE: Final = (0.75, 1.33)


@dataclass(frozen=True, slots=True)
class JointSpeeds:
    """One joint's speed runs as the fits need them: the ratio, its standard error, duty,
    direction and the torque factor ``f`` (N·m) of each run on the prior's pull-out curve
    ``curve``; ``factors``: the factor on every curve (None: the prior's only)."""

    ratio: FloatArray
    sigma: FloatArray
    duty: FloatArray
    direction: FloatArray
    factor: FloatArray
    factors: Mapping[str, FloatArray] | None = None
    curve: str = "hyperbolic"

    @property
    def curves(self) -> list[str]:
        """The pull-out curves the runs have factors on, the prior's first."""
        return [self.curve] + [c for c in (self.factors or {}) if c != self.curve]

    def on_curve(self, curve: str) -> JointSpeeds:
        """The runs with the factors of the pull-out curve ``curve``."""
        if curve == self.curve or not curve:
            return self
        return replace(self, factor=(self.factors or {})[curve], curve=curve)


def run_table(obs: Observations, base: RobotSettings, prior: ArmPhysics, j: int,
              link_of: Callable[[Sequence[float]], list[float]],
              scatter: float = 1.0) -> JointSpeeds:
    """Joint ``j``'s (0-based) runs; ``link_of`` estimates the link angles at a run's start;
    each run's standard error is multiplied by the session's ``scatter``."""
    spec = base.joints[j]
    p = prior.joints[j]
    mech = Mechanism(prior, base, lambda: [0.0] * 4)
    rows = []
    for run in obs.speeds:
        if run.joint != j + 1 or run.law_rad_s <= 0:
            continue
        rate = run.law_rad_s * spec.steps_per_rad
        tau = mech.gravity_nm(link_of(run.start_rad))[j]
        need = p.required_nm(tau, run.direction, spec.gear_ratio, rate, spec.steps_per_motor_rev)
        rows.append((run.ratio, scatter * run_sigma(run), run.duty, run.direction, need,
                     rate))
    a = np.asarray(rows, dtype=np.float64).reshape(-1, 6)
    factors = {c: curve_factor(a[:, 4], a[:, 5], p.corner_steps_per_s, c)
               for c in PULLOUT_CURVES}
    return JointSpeeds(a[:, 0], a[:, 1], a[:, 2], a[:, 3], factors[p.pullout_curve], factors,
                       p.pullout_curve)


@dataclass(frozen=True, slots=True)
class Candidate:
    """A fitted structure: its name, whether ``s`` is fitted, the parameters and the
    predictions of the runs it was fitted on."""

    law: str
    scaled: bool
    params: dict[str, float]
    n_params: int
    curve: str = ""

    @property
    def name(self) -> str:
        """``law`` (``stall:linear``: with its pull-out curve) with ``+scale`` when the speed
        scale is fitted."""
        return self.law + (f":{self.curve}" if self.curve else "") + (
            "+scale" if self.scaled else "")


def _wmean(x: FloatArray, w: FloatArray) -> float:
    return float((x * w).sum() / w.sum()) if len(x) and w.sum() > 0 else math.nan


def _clip_scale(s: float) -> float:
    return min(SCALE_RANGE[1], max(SCALE_RANGE[0], s))


def _torque_pred(p_nm: float | FloatArray, factor: FloatArray) -> FloatArray:
    out: FloatArray = np.clip(p_nm / factor, 0.1, 1.0)
    return out


_stall_pred = stall_pred


def _model_error(shape: FloatArray) -> FloatArray:
    """The ratio error a 1 % error of the needed torque makes: ``NEED_REL · r`` on a run that
    loses steps, but never more than its loss (a run barely losing is as near to losing none:
    the error cannot excuse a model that makes every run lose a hair)."""
    out: FloatArray = np.minimum(NEED_REL * shape, 1.0 - shape) * (shape < 1.0)
    return out


def _sigma_total(d: JointSpeeds, shape: FloatArray) -> FloatArray:
    """Each run's ratio error plus the needed torque's relative error where it loses steps."""
    out: FloatArray = np.sqrt(d.sigma ** 2 + _model_error(shape) ** 2)
    return out


def _profile(d: JointSpeeds, pred: Callable[[float | FloatArray, FloatArray], FloatArray],
             scaled: bool) -> tuple[float, float]:
    """Best ``P`` (and ``s``) of a one-parameter shape ``s · pred(P, f)``: a grid over log P,
    ``s`` in closed form at each."""
    def at(p_nm: float) -> tuple[float, float]:
        g = pred(p_nm, d.factor)
        w = 1.0 / _sigma_total(d, g) ** 2
        s = (_clip_scale(float((d.ratio * g * w).sum() / (g * g * w).sum()))
             if scaled and (g > 0).any() else 1.0)
        return float((((d.ratio - s * g) ** 2) * w).sum()), s

    # the whole grid at once (rows: P, columns: runs)
    g = pred(P_GRID[:, None], d.factor[None, :])
    w = 1.0 / (d.sigma[None, :] ** 2 + _model_error(g) ** 2)
    if scaled:
        den = (g * g * w).sum(axis=1)
        s_all = np.clip((d.ratio * g * w).sum(axis=1) / np.where(den > 0, den, 1.0),
                        *SCALE_RANGE)
        s_all = np.where(den > 0, s_all, 1.0)
    else:
        s_all = np.ones(len(P_GRID))
    chi2_all = (((d.ratio[None, :] - s_all[:, None] * g) ** 2) * w).sum(axis=1)
    k = int(np.argmin(chi2_all))  # the first of equal minima: the lowest P
    best = (float(chi2_all[k]), float(P_GRID[k]), float(k))
    if 0 < k < len(P_GRID) - 1 and pred is _torque_pred:  # between grid points: refine
        lo, hi = math.log(float(P_GRID[k - 1])), math.log(float(P_GRID[k + 1]))
        r = minimize_scalar(lambda x: at(math.exp(x))[0], bounds=(lo, hi), method="bounded",
                            options={"xatol": 1e-7})
        if float(r.fun) < best[0]:
            return math.exp(float(r.x)), at(math.exp(float(r.x)))[1]
    return best[1], at(best[1])[1]


def fit_law(d: JointSpeeds, law: str, scaled: bool) -> Candidate:
    """Fit ``law`` (with or without the scale) to the runs of ``d``."""
    if law == "none":
        s = _clip_scale(_wmean(d.ratio, 1.0 / d.sigma ** 2)) if scaled else 1.0
        return Candidate(law, scaled, {"s": s}, int(scaled))
    if law == "torque":
        p_nm, s = _profile(d, _torque_pred, scaled)
        return Candidate(law, scaled, {"s": s, "pullout_nm": p_nm}, 1 + int(scaled))
    if law.startswith("stall"):  # the middle of the interval between the runs that moved and
        curve = _curve_of(law, d)   # stalled, on the law's pull-out curve
        d = d.on_curve(curve)
        p_nm, sigma = stall_bracket(d)
        moved = d.ratio >= STALLED_RATIO
        s = 1.0
        if math.isinf(sigma):
            p_nm, s = _profile(d, _stall_pred, scaled)
        elif scaled and moved.any():
            s = _clip_scale(_wmean(d.ratio[moved], 1.0 / d.sigma[moved] ** 2))
        return Candidate("stall", scaled, {"s": s, "pullout_nm": p_nm}, 1 + int(scaled),
                         curve)
    # duty: the threshold that fits best, the shares above it per direction
    best: tuple[float, Candidate] | None = None
    duties = {float(x) for x in d.duty}
    for thr in sorted(duties | {99.0, min(duties) - 1.0}):
        below = d.duty <= thr
        w = 1.0 / d.sigma ** 2
        s = _clip_scale(_wmean(d.ratio[below], w[below])) if scaled and below.any() else 1.0
        params = {"s": s, "loss_above_duty": thr}
        pred = np.full_like(d.ratio, s)
        for share_of, sign in ((_PLUS, 1.0), (_MINUS, -1.0)):
            above = (~below) & (d.direction == sign)
            share = 1.0 - _wmean(d.ratio[above] / s, w[above]) if above.any() else 0.0
            share = min(0.9, max(0.0, share))
            params[share_of.name] = share
            pred[above] = s * (1.0 - share)
        if not below.any() and _same_both_ways(d, w):
            continue  # one share at every duty, both ways: a speed scale, not a duty threshold
        chi2 = float((((d.ratio - pred) ** 2) * w).sum())
        if best is None or chi2 < best[0] - 1e-12:
            best = (chi2, Candidate(law, scaled, params, 3 + int(scaled)))
    if best is None:  # no threshold left: loss nowhere
        return Candidate(law, scaled, {"s": 1.0, **_NO_DUTY_LOSS}, 3 + int(scaled))
    return best[1]


def _same_both_ways(d: JointSpeeds, w: FloatArray) -> bool:
    """Whether the runs towards + and towards − have the same mean ratio within three standard
    errors of the difference (or one direction has no run)."""
    plus, minus = d.direction > 0, d.direction < 0
    if not plus.any() or not minus.any():
        return True
    diff = _wmean(d.ratio[plus], w[plus]) - _wmean(d.ratio[minus], w[minus])
    return abs(diff) <= 3.0 * math.sqrt(1.0 / w[plus].sum() + 1.0 / w[minus].sum())


def predict(c: Candidate, d: JointSpeeds) -> FloatArray:
    """The ratio ``c`` predicts for every run of ``d``."""
    s = c.params["s"]
    if c.law == "none":
        return np.full_like(d.ratio, s)
    if c.law == "torque":
        return s * _torque_pred(c.params["pullout_nm"], d.factor)
    if c.law == "stall":
        return s * _stall_pred(c.params["pullout_nm"], d.on_curve(c.curve).factor)
    pred = np.full_like(d.ratio, s)
    above = d.duty > c.params["loss_above_duty"]
    pred[above & (d.direction > 0)] *= 1.0 - c.params["loss_plus"]
    pred[above & (d.direction < 0)] *= 1.0 - c.params["loss_minus"]
    return pred


def prior_prediction(p: JointPhysics, d: JointSpeeds) -> FloatArray:
    """The prior twin's ratio for every run (its own law and pull-out torque, no scale)."""
    if p.loss_law == "torque":
        return _torque_pred(p.pullout_nm, d.factor)
    if p.loss_law == "stall":
        return _stall_pred(p.pullout_nm, d.factor)
    if p.loss_law == "none":
        return np.ones_like(d.ratio)
    c = Candidate("duty", False, {"s": 1.0, "loss_above_duty": p.loss_above_duty,
                                  "loss_plus": p.loss_plus, "loss_minus": p.loss_minus}, 0)
    return predict(c, d)


def subset(d: JointSpeeds, keep: npt.NDArray[np.bool_]) -> JointSpeeds:
    factors = None if d.factors is None else {c: f[keep] for c, f in d.factors.items()}
    return JointSpeeds(d.ratio[keep], d.sigma[keep], d.duty[keep], d.direction[keep],
                       d.factor[keep], factors, d.curve)


def at_bound(c: Candidate) -> bool:
    """Whether a fit ran into the edge of what it may return (a scale a quarter off, a pull-out
    torque at the settings' band): it then stands in for something else and predicts nothing."""
    s = c.params["s"]
    p_nm = c.params.get("pullout_nm")
    return (c.scaled and s in SCALE_RANGE) or (
        p_nm is not None and p_nm in (float(P_GRID[0]), float(P_GRID[-1])))


def param_sigma(d: JointSpeeds, c: Candidate, key: str, step: float) -> float:
    """Standard error of ``c.params[key]`` from the χ² curvature (central differences),
    scaled by the reduced χ² when the fit is worse than the runs' errors."""

    def chi2(v: float) -> float:
        params = dict(c.params)
        params[key] = v
        pred = predict(Candidate(c.law, c.scaled, params, c.n_params, c.curve), d)
        return float((((d.ratio - pred) / _sigma_total(d, pred / params["s"])) ** 2).sum())

    v0 = c.params[key]
    curv = (chi2(v0 + step) - 2.0 * chi2(v0) + chi2(v0 - step)) / step ** 2
    if curv <= 0:
        return math.inf
    dof = max(1, len(d.ratio) - c.n_params)
    return math.sqrt(2.0 / curv * max(1.0, chi2(v0) / dof))


def stall_bracket(d: JointSpeeds) -> tuple[float, float]:
    """:func:`~armbench.bench.calibrate.stall.stall_interval` of ``d``'s runs on its curve."""
    return stall_interval(d.ratio, d.factor, (float(P_GRID[0]), float(P_GRID[-1])))


def _curve_of(law: str, d: JointSpeeds) -> str:
    """The pull-out curve of a stall law (``stall:linear``; plain ``stall``: the prior's)."""
    return law.partition(":")[2] or d.curve
