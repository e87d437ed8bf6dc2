"""Least-squares fits of the robot model to a calibration's observations, each with its standard
error (``docs/calibration.md`` derives every estimator).

Each fit returns :class:`~armbench.bench.calibrate.model.Fitted` values keyed by their path in the
settings file; a parameter the data cannot determine keeps its prior and says why. Priors are the
base settings' (``--settings``, else the default arm): the link masses, the payload, efficiency,
friction and inertia are *not* identified (the traffic and a joint truth only show torque over
stiffness, or over pull-out torque) and the fits that need a torque take it from them.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Final

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from armbench.bench.calibrate.model import Fitted, Observations
from armbench.bench.calibrate.reference import fit_reference
from armbench.bench.calibrate.stop_rule import choose_stop_rule
from armbench.bench.calibrate.structure import SpeedOption, fit_speed_models
from armbench.drivers.model.kinematics import tcp_position
from armbench.drivers.model.protocol import TICKS_PER_RAD
from armbench.drivers.model.settings import RobotSettings
from armbench.drivers.model.twin_parameters import GEOMETRY_ERRORS, TWIN
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.fakes.twin.physics import DEFAULT_ARM, ArmPhysics, Mechanism

__all__ = [
    "INSTRUMENT_SIGMA_M",
    "LOADED_NM",
    "base_physics",
    "chosen_structures",
    "fit_all",
    "fit_hall",
    "fit_kinematics",
    "fit_play",
    "fit_stiffness",
    "fit_timing",
    "link_estimate",
    "with_kinematics",
    "with_references",
]

FloatArray = npt.NDArray[np.float64]

#: Standard error assumed for one coordinate of the true TCP (m): a laser tracker's class; the
#: fit's own residuals scale it up when they are larger.
INSTRUMENT_SIGMA_M: Final = 1e-5
#: A hold counts as loaded on a joint when the model's gravity torque there exceeds this (N·m):
#: above the largest hold torque of the documented range, so the play sits on gravity's side.
LOADED_NM: Final = 2.5
#: Floor of an angle's standard error (rad): what float arithmetic of the truth can resolve.
SIGMA_FLOOR_RAD: Final = 1e-7
#: The DH length errors the true TCP shows (the tool offset's is kept: ``GEOMETRY_ERRORS``).
_LENGTHS: Final = tuple(p for p in GEOMETRY_ERRORS if p.fitted)
_KINEMATIC_KEYS: Final = tuple(p.name for p in _LENGTHS)
_D4: Final = next(p for p in GEOMETRY_ERRORS if not p.fitted)
_PLAY, _STICK, _HALL = TWIN["backlash_rad"], TWIN["stick_rad"], TWIN["hall_error_rad"]
_OFFSET, _STIFFNESS = TWIN["offset_error_rad"], TWIN["stiffness_nm_per_rad"]


def base_physics(base: RobotSettings) -> ArmPhysics:
    """The prior arm: the base settings' physics, the default arm's when they are ideal."""
    physics = emulator_settings(base).physics
    return physics if physics is not None else DEFAULT_ARM


def fit_timing(obs: Observations) -> list[Fitted]:
    """Reply period and command latency: means with their standard errors."""
    out = []
    for key, values in (("timing.reply_period_s", obs.reply_dt_s),
                        ("timing.latency_s", obs.latency_s)):
        if len(values) >= 2:
            a = np.asarray(values, dtype=np.float64)
            out.append(Fitted(key, float(a.mean()), float(a.std(ddof=1) / math.sqrt(len(a))), "s",
                              True, f"{len(a)} intervals"))
        else:
            out.append(Fitted(key, math.nan, None, "s", False, "not measured"))
    return out


def _play_channel(obs: Observations, j: int, counts_per_rad: float
                  ) -> tuple[list[float], list[int], float] | None:
    """Per approach of joint ``j``: link minus motor (exact) or true minus reported (then with
    the quantisation variance of the reply and the counter), the approach direction, and that
    variance."""
    ys, ds = [], []
    quant = 0.0
    for a in obs.approaches:
        if a.joint != j + 1:
            continue
        if a.link_rad is not None and a.motor_rad is not None:
            ys.append(a.link_rad[j] - a.motor_rad[j])
        elif a.true_rad is not None:
            ys.append(a.true_rad[j] - a.reported_rad[j])
            quant = (1.0 / TICKS_PER_RAD) ** 2 / 12 + (1.0 / counts_per_rad) ** 2 / 12
        else:
            return None
        ds.append(a.direction)
    return ys, ds, quant


def fit_play(obs: Observations, base: RobotSettings, prior: ArmPhysics) -> list[Fitted]:
    """Gear play and stick-slip band per joint from the bidirectional approaches.

    After an approach moving ``d`` the link trails the motor by half the play and overshoots by
    ``band · U`` (U uniform in 0..1): ``y = c + d (band U − play/2)``. The difference of the two
    directions' means is ``band − play``; the pooled variance within a direction is
    ``band² / 12`` (plus the quantisation of the channel).
    """
    out: list[Fitted] = []
    for j, spec in enumerate(base.joints):
        p = prior.joints[j]
        channel = _play_channel(obs, j, spec.counts_per_rad) if obs.truth else None
        reason = "no truth source: the play is on the link side, behind the encoder"
        groups = None
        if channel is not None:
            ys, ds, quant = channel
            up = np.asarray([y for y, d in zip(ys, ds, strict=True) if d > 0])
            down = np.asarray([y for y, d in zip(ys, ds, strict=True) if d < 0])
            groups = (up, down, quant) if len(up) >= 2 and len(down) >= 2 else None
            reason = "fewer than 2 approaches from each side"
        play_prior, stick_prior = _PLAY.from_twin(p.backlash_rad), _STICK.from_twin(p.stick_rad)
        if groups is None:
            out.append(Fitted(_PLAY.path(j), play_prior, None, _PLAY.unit, False, reason,
                              play_prior))
            out.append(Fitted(_STICK.path(j), stick_prior, None, _STICK.unit, False, reason,
                              stick_prior))
            continue
        up, down, quant = groups
        if quant == 0.0:
            band, sigma_band, diff, var_diff = _uniform_exact(up, down)
        else:
            band, sigma_band, diff, var_diff = _uniform_noisy(up, down, quant)
        play = band - diff
        sigma_play = math.sqrt(sigma_band ** 2 + var_diff)
        why = f"{len(up)} + {len(down)} approaches at the Hall position (reversal and scatter)"
        out.append(Fitted(_PLAY.path(j), _PLAY.from_twin(play),
                          _PLAY.from_twin(max(sigma_play, SIGMA_FLOOR_RAD)), _PLAY.unit, True,
                          why, play_prior))
        out.append(Fitted(_STICK.path(j), _STICK.from_twin(band),
                          _STICK.from_twin(max(sigma_band, SIGMA_FLOOR_RAD)), _STICK.unit, True,
                          why + ", at full duty", stick_prior))
    return out


def _uniform_exact(up: FloatArray, down: FloatArray) -> tuple[float, float, float, float]:
    """Band, its standard error, the difference of the two groups' centres and its variance,
    for exact samples of ``centre ± band·U``: ranges and mid-ranges (the efficient estimators of
    a uniform variable's width and centre). The range's distribution is skewed (a Beta), so the
    standard error is half the wider side of the exact 95 % interval of the band
    (:func:`_band_interval`): two of them bracket the band as a 95 % interval does."""
    mids, mid_vars = [], []
    for g in (up, down):
        n = len(g)
        mids.append(0.5 * float(g.max() + g.min()))
        mid_vars.append(1.0 / (2.0 * (n + 1) * (n + 2)))
    ranges = (float(up.max() - up.min()), float(down.max() - down.min()))
    lo_q, hi_q = _band_interval(len(up), len(down))
    estimate = 0.5 * (ranges[0] * (len(up) + 1) / (len(up) - 1)
                      + ranges[1] * (len(down) + 1) / (len(down) - 1))
    band = max(estimate, *ranges)
    sigma_band = 0.5 * max(estimate / lo_q - estimate, estimate - estimate / hi_q)
    return band, sigma_band, mids[0] - mids[1], band * band * sum(mid_vars)


@functools.lru_cache(maxsize=16)
def _band_interval(n_up: int, n_down: int) -> tuple[float, float]:
    """The 2.5 % and 97.5 % quantiles of the band estimate over the true band (mean of the two
    groups' unbiased ranges of uniform samples), by a seeded Monte Carlo of 20 000 draws."""
    rng = np.random.default_rng(0)
    est = np.zeros(20_000)
    for n in (n_up, n_down):
        u = rng.random((20_000, n))
        est += 0.5 * (u.max(axis=1) - u.min(axis=1)) * (n + 1) / (n - 1)
    lo, hi = np.quantile(est, [0.025, 0.975])
    return float(lo), float(hi)


def _uniform_noisy(up: FloatArray, down: FloatArray,
                   quant: float) -> tuple[float, float, float, float]:
    """As :func:`_uniform_exact` for samples with a quantisation variance ``quant``: the pooled
    variance is ``band² / 12 + quant``."""
    n = len(up) + len(down)
    s2 = (float(((up - up.mean()) ** 2).sum() + ((down - down.mean()) ** 2).sum()) / (n - 2))
    band = math.sqrt(12.0 * max(0.0, s2 - quant))
    var_s2 = s2 * s2 * (1.8 - (n - 3) / (n - 1)) / n  # a uniform variable's kurtosis is 1.8
    sigma_band = math.sqrt(12.0 * var_s2) / (2.0 * math.sqrt(s2)) if s2 > 0 else 0.0
    return band, sigma_band, float(up.mean() - down.mean()), s2 * (1 / len(up) + 1 / len(down))


def fit_hall(obs: Observations, base: RobotSettings, prior: ArmPhysics) -> list[Fitted]:
    """Hall position error per joint: after a crossing the counter is set to the nominal Hall
    count where the sensor really is, so the counter minus the motor is minus the error (the
    emulator's motor-side truth; a fixed quantisation of ~0.54 count remains)."""
    out: list[Fitted] = []
    for j, spec in enumerate(base.joints):
        prior_deg = _HALL.from_twin(prior.joints[j].hall_error_rad)
        values = [-(a.firmware_rad[j] - a.motor_rad[j]) for a in obs.approaches
                  if a.joint == j + 1 and a.cycle >= 1 and a.firmware_rad is not None
                  and a.motor_rad is not None]
        if len(values) < 2:
            reason = ("needs the motor-side truth of the emulator (a counter reset is invisible "
                      "in the traffic)" if not obs.motor_truth else "no Hall crossing measured")
            out.append(Fitted(_HALL.path(j), prior_deg, None, _HALL.unit, False, reason,
                              prior_deg))
            continue
        a = np.asarray(values)
        se = float(a.std(ddof=1) / math.sqrt(len(a)))
        fixed = 0.54 / spec.counts_per_rad
        out.append(Fitted(_HALL.path(j), _HALL.from_twin(float(a.mean())),
                          _HALL.from_twin(math.hypot(se, fixed)), _HALL.unit, True,
                          f"counter against motor after {len(a)} Hall crossings", prior_deg))
    return out


def link_estimate(q_rad: Sequence[float], fitted: Sequence[Fitted], prior: ArmPhysics,
                  mech: Mechanism) -> list[float]:
    """The link angles behind reported ones: the motor is the counter plus the Hall error, the
    link sits half the play towards gravity where it is loaded (identified values, else the
    prior's)."""
    values = {f.key: f.value for f in fitted if f.identified}
    tau = mech.gravity_nm(q_rad)
    out = []
    for j, q in enumerate(q_rad):
        p = prior.joints[j]
        hall = _HALL.to_twin(values.get(_HALL.path(j), _HALL.from_twin(p.hall_error_rad)))
        half = _PLAY.to_twin(values.get(_PLAY.path(j), _PLAY.from_twin(p.backlash_rad))) / 2
        side = 1 if tau[j] > p.hold_nm else -1 if tau[j] < -p.hold_nm else 0
        out.append(q + hall + side * half)
    return out


def fit_stiffness(obs: Observations, base: RobotSettings, prior: ArmPhysics,
                  play: Sequence[Fitted], fitted_before: Sequence[Fitted] = ()) -> list[Fitted]:
    """Torsional stiffness of the joints gravity loads: at loaded holds the link's offset from
    the motor is ``c + side · play/2 + τ(q)/k`` (τ from the prior's masses and payload); linear
    least squares in ``(c, play/2, 1/k)``, the play fixed from the approaches when the torque has
    one sign only."""
    mech = Mechanism(prior, base, lambda: [0.0] * 4)
    out: list[Fitted] = []
    for j in range(4):
        p = prior.joints[j]
        key = _STIFFNESS.path(j)
        rows: list[tuple[float, float]] = []
        for h in obs.holds:
            if h.true_rad is None:
                continue
            at = h.link_rad if h.link_rad is not None else link_estimate(
                h.reported_rad, fitted_before, prior, mech)
            tau = mech.gravity_nm(at)[j]
            ref = h.motor_rad[j] if h.motor_rad is not None else h.reported_rad[j]
            if abs(tau) >= LOADED_NM:
                rows.append((tau, h.true_rad[j] - ref))
        if len(rows) < 4:
            reason = ("no truth source: the deflection is on the link side" if not obs.truth
                      else f"only {len(rows)} holds with |gravity torque| ≥ {LOADED_NM} N·m "
                           "(joint 1 turns about the vertical; joint 4 carries no lever)")
            out.append(Fitted(key, p.stiffness_nm_per_rad, None, _STIFFNESS.unit, False, reason,
                              p.stiffness_nm_per_rad))
            continue
        tau_a = np.asarray([r[0] for r in rows])
        y = np.asarray([r[1] for r in rows])
        side = np.sign(tau_a)
        play_fit = next((f for f in play if f.key == _PLAY.path(j) and f.identified), None)
        x = np.column_stack([np.ones_like(tau_a), tau_a])
        extra_var = 0.0
        if play_fit is not None and play_fit.sigma is not None:  # the approaches' play: better
            half = _PLAY.to_twin(play_fit.value) / 2
            sigma_half = _PLAY.to_twin(play_fit.sigma) / 2
            y = y - side * half
            b = np.linalg.lstsq(x, side, rcond=None)[0][-1]
            extra_var = float(b * sigma_half) ** 2
        elif min(int((side > 0).sum()), int((side < 0).sum())) >= 2:
            x = np.column_stack([np.ones_like(tau_a), side, tau_a])
        else:
            y = y - side * p.backlash_rad / 2
        coef, cov = _linear_lsq(x, y)
        s, sigma_s = coef[-1], math.sqrt(cov[-1, -1] + extra_var)
        if s <= 0 or sigma_s >= 0.5 * s:
            out.append(Fitted(key, p.stiffness_nm_per_rad, None, _STIFFNESS.unit, False,
                              f"deflection not resolved (1/k = {s:.3g} ± {sigma_s:.2g} rad/N·m)",
                              p.stiffness_nm_per_rad))
            continue
        out.append(Fitted(key, 1.0 / s, sigma_s / (s * s), _STIFFNESS.unit, True,
                          f"deflection at {len(rows)} loaded holds against the model's gravity "
                          "torque (masses and payload of the prior)", p.stiffness_nm_per_rad))
    return out


def _linear_lsq(x: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Ordinary least squares: coefficients and their covariance (residual variance scaled)."""
    coef = np.asarray(np.linalg.lstsq(x, y, rcond=None)[0], dtype=np.float64)
    resid = y - x @ coef
    dof = max(1, len(y) - x.shape[1])
    s2 = max(float(resid @ resid) / dof, SIGMA_FLOOR_RAD ** 2)
    cov = np.asarray(s2 * np.linalg.pinv(x.T @ x), dtype=np.float64)
    return coef, cov


def _kinematic_model(base: RobotSettings, theta: FloatArray) -> RobotSettings:
    g = base.geometry
    geometry = replace(g, **{k: getattr(g, k) + float(theta[i])
                             for i, k in enumerate(_KINEMATIC_KEYS)})
    joints = tuple(replace(spec, offset_rad=spec.offset_rad + float(theta[4 + i]))
                   if i < 3 else spec for i, spec in enumerate(base.joints))
    return replace(base, geometry=geometry, joints=joints)


def instrument_offsets(obs: Observations, prior: ArmPhysics,
                       hall: Sequence[Fitted] = ()) -> dict[int, tuple[float, float]]:
    """Per joint (0-based): the zero offset error (rad) and its standard error that a reference
    instrument's joint angles show. A tracker (true joints, no motor side) measures the load
    side's angles, its zero offsets included; at the approaches, made from both sides at the
    upright Hall pose where gravity loads no joint, the play's two sides average out, and the
    true minus the reported angle is the offset error plus the Hall error (the counter's
    reference). Empty with the emulator's truth (its true joints exclude the offsets, which
    only the TCP shows) or without truth."""
    if not obs.truth or obs.motor_truth:
        return {}
    values = {f.key: f.value for f in hall if f.identified}
    out: dict[int, tuple[float, float]] = {}
    for j in range(4):
        sides = [[a.true_rad[j] - a.reported_rad[j] for a in obs.approaches
                  if a.joint == j + 1 and a.direction == d and a.true_rad is not None]
                 for d in (1, -1)]
        if min(len(x) for x in sides) < 2:
            continue
        mean = 0.5 * sum(float(np.mean(x)) for x in sides)
        sigma = 0.5 * math.sqrt(sum(float(np.var(x, ddof=1)) / len(x) for x in sides))
        hall_rad = _HALL.to_twin(values.get(_HALL.path(j),
                                            _HALL.from_twin(prior.joints[j].hall_error_rad)))
        out[j] = (mean - hall_rad, max(sigma, SIGMA_FLOOR_RAD))
    return out


def fit_kinematics(obs: Observations, base: RobotSettings, prior: ArmPhysics,
                   hall: Sequence[Fitted] = ()) -> list[Fitted]:
    """DH length errors and joint offset errors from the true TCP at the holds against the true
    joints (nonlinear least squares, ``scipy.optimize.least_squares``; covariance from the
    Jacobian, the TCP's standard error :data:`INSTRUMENT_SIGMA_M` or the residuals' if larger).
    Joint 4's offset turns the tool about its own axis and cannot move the TCP. A reference
    instrument's true joints include the zero offsets: the fit's offsets are then relative to
    them, and :func:`instrument_offsets` adds what they hold."""
    ge = prior.geometry_error
    theta0 = np.array([getattr(ge, k) for k in _KINEMATIC_KEYS]
                      + [prior.joints[i].offset_error_rad for i in range(3)], dtype=np.float64)
    keys = [p.path() for p in _LENGTHS] + [_OFFSET.path(i) for i in range(3)]
    scale = np.array([1.0] * 4 + [180.0 / math.pi] * 3)
    units = [p.unit for p in _LENGTHS] + [_OFFSET.unit] * 3
    j4_prior = _OFFSET.from_twin(prior.joints[3].offset_error_rad)
    kept = [Fitted(_OFFSET.path(3), j4_prior, None, _OFFSET.unit, False,
                   "turns the tool about its own axis: does not move the TCP", j4_prior),
            Fitted(_D4.path(), ge.d4_m, None, _D4.unit, False,
                   "the tool offset and joint 3's offset turn the TCP about joint 3 alike "
                   "(only their combination is seen); joint 3's offset is fitted", ge.d4_m)]
    data = [(h.true_rad, h.tcp_true_m) for h in obs.holds
            if h.true_rad is not None and h.tcp_true_m is not None]
    if len(data) < 4:
        reason = ("no truth source for the TCP" if not obs.truth
                  else f"only {len(data)} holds with a true TCP")
        return [Fitted(k, float(v * sc), None, u, False, reason, float(v * sc))
                for k, v, sc, u in zip(keys, theta0, scale, units, strict=True)] + kept
    q = np.asarray([d[0] for d in data], dtype=np.float64)
    p = np.asarray([d[1] for d in data], dtype=np.float64)

    def residuals(theta: FloatArray) -> FloatArray:
        model = _kinematic_model(base, theta)
        pred = np.asarray([tcp_position(qi, model) for qi in q])
        r: FloatArray = ((pred - p) / INSTRUMENT_SIGMA_M).reshape(-1)
        return r

    result = least_squares(residuals, theta0, method="lm", x_scale=np.full(len(theta0), 1e-3))
    jac = result.jac
    dof = max(1, jac.shape[0] - jac.shape[1])
    chi2 = float(result.fun @ result.fun) / dof
    cov = np.linalg.pinv(jac.T @ jac) * max(1.0, chi2)
    out = []
    limits = [p.high for p in _LENGTHS] + [_OFFSET.to_twin(_OFFSET.high)] * 3
    seen = instrument_offsets(obs, prior, hall)
    if 3 in seen:
        kept[0] = Fitted(_OFFSET.path(3), _OFFSET.from_twin(seen[3][0]),
                         _OFFSET.from_twin(seen[3][1]), _OFFSET.unit, True,
                         "the reference instrument's joint angle at the approaches", j4_prior)
    for i, key in enumerate(keys):
        sigma = math.sqrt(max(0.0, float(cov[i, i])))
        value = float(result.x[i])
        if i >= 4 and i - 4 in seen:  # relative to the instrument's joints: add their offset
            value += seen[i - 4][0]
            sigma = math.hypot(sigma, seen[i - 4][1])
        if sigma > 0.5 * limits[i]:
            out.append(Fitted(key, float(theta0[i] * scale[i]), None, units[i], False,
                              f"not resolved by {len(data)} poses (σ {sigma * scale[i]:.2g})",
                              float(theta0[i] * scale[i])))
            continue
        out.append(Fitted(key, value * scale[i], max(sigma, SIGMA_FLOOR_RAD) * scale[i],
                          units[i], True, f"true TCP at {len(data)} holds (χ²/dof {chi2:.3g})",
                          float(theta0[i] * scale[i])))
    return [*out, *kept]


def chosen_structures(fitted: Sequence[Fitted]) -> dict[int, tuple[str, bool] | None]:
    """Each joint's speed model as :func:`fit_all` chose it (None: the prior kept)."""
    out: dict[int, tuple[str, bool] | None] = {}
    values = {f.key: f for f in fitted}
    for j in range(4):
        law = values.get(TWIN["loss_law"].path(j))
        gear = values.get(f"joints.j{j + 1}.gear_ratio")
        if law is None or not law.identified or law.choice is None:
            out[j] = None
        else:
            curve = values.get(TWIN["pullout_curve"].path(j))
            choice = law.choice if curve is None or curve.choice is None else (
                f"{law.choice}:{curve.choice}")
            out[j] = (choice, gear is not None and gear.identified)
    return out


def with_kinematics(prior: ArmPhysics, fitted: Sequence[Fitted]) -> ArmPhysics:
    """``prior`` with the identified DH length and joint offset errors: the gravity torques the
    stiffness and pull-out fits divide by are then those of the real arm's geometry."""
    values = {f.key: f.value for f in fitted if f.identified}
    ge = replace(prior.geometry_error, **{
        p.name: values[p.path()] for p in _LENGTHS if p.path() in values})
    joints = tuple(replace(p, offset_error_rad=_OFFSET.to_twin(values[_OFFSET.path(i)]))
                   if _OFFSET.path(i) in values else p
                   for i, p in enumerate(prior.joints))
    return replace(prior, geometry_error=ge, joints=joints)


def with_references(obs: Observations, base: RobotSettings, prior: ArmPhysics,
                    kinematics: list[Fitted], play: list[Fitted]
                    ) -> tuple[list[Fitted], list[Fitted]]:
    """The kinematic and play fits with what the reference poses (``--reference``,
    ``--touch-off``) identify put in place of what the instrument's truth did not: each value
    the reference fit identified replaces one the truth left at the prior
    (:func:`~armbench.bench.calibrate.reference.fit_reference`)."""
    if not obs.references:
        return kinematics, play
    what = ("touched plate points" if any(r.history_rad for r in obs.references)
            else "reference poses")
    measured = {f.key: f for f in play if f.identified}
    known = {j: _PLAY.to_twin(measured[_PLAY.path(j)].value) for j in range(3)
             if _PLAY.path(j) in measured}
    found = {f.key: f for f in fit_reference(obs.references, base, prior, what, known)
             if f.identified}

    def merged(fits: list[Fitted]) -> list[Fitted]:
        return [found.get(f.key, f) if not f.identified else f for f in fits]
    return merged(kinematics), merged(play)


def fit_all(obs: Observations, base: RobotSettings,
            structures: Mapping[int, tuple[str, bool] | None] | None = None,
            options: dict[int, list[SpeedOption]] | None = None) -> list[Fitted]:
    """Every fit, in the order of the settings file (the kinematics first: the torque models of
    the others use it). ``structures``: each joint's speed model taken as chosen; ``options``
    receives each joint's candidate speed models for the held-out blocks (see
    :func:`~armbench.bench.calibrate.structure.fit_speed_models`)."""
    prior = base_physics(base)
    hall = fit_hall(obs, base, prior)
    kinematics = fit_kinematics(obs, base, prior, hall)
    play = fit_play(obs, base, prior)
    kinematics, play = with_references(obs, base, prior, kinematics, play)
    model = with_kinematics(prior, kinematics)
    before = [*play, *hall]
    mech = Mechanism(model, base, lambda: [0.0] * 4)
    speeds = fit_speed_models(obs, base, model,
                              lambda q: link_estimate(q, before, model, mech), structures,
                              options)
    return [*fit_timing(obs), choose_stop_rule(obs, base, hall), *play, *hall,
            *fit_stiffness(obs, base, model, play, before), *speeds, *kinematics]
