"""The paper's experiment (§7): a square in the YZ plane, driven the paper's way and armbench's way.

Each lap is driven in two styles, one trial each, alternating within the run so both see the same
arm, emulator seed and drift:

* ``paper`` — corners only, full duty, no path planning: ``move_to`` each corner at ``duty`` (99)
  with one duty for all joints, wait for the arrival, next corner. Each joint runs flat out and
  stops on its own, so the TCP leaves the straight edge in between (the paper reports a mean
  Euclidean error of 12.4 mm for its square).
* ``coordinated`` — armbench's coordinated Cartesian streaming: ``follow_path`` along the edges,
  waypoints ``spacing_m`` apart at ``speed_m_s``, each joint's duty chosen so all joints arrive
  at every waypoint together.

The reply stream is sampled throughout each lap (one sample per ``sample_period_s``): the reported
joints, the reported TCP (forward kinematics of them, as the paper did) and, when the bench has a
reference instrument (``ctx.truth``), the true TCP. Errors are distances to the nearest point of
the reference square (:func:`armbench.metrics.path_errors`); figures in mm. See
``docs/suites.md``.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping, Sequence
from typing import Any, ClassVar, Final, Protocol

import numpy as np

from armbench.bench.suites._common import (
    MAX_REPEATS,
    FloatArray,
    Measurements,
    StateRecorder,
    check_branch,
    check_reachable,
    check_vec3,
    guarded_trial,
    loop_time,
    settled_state,
)
from armbench.bench.suites.accuracy_contract import ACCURACY
from armbench.bench.suites.base import Suite, SuiteContext
from armbench.bench.suites.workspace import DEFAULT_SQUARE_CENTRE_M, DEFAULT_SQUARE_SIDE_M
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.bounds import Bound, check, check_whole
from armbench.drivers.model.protocol import MAX_DUTY
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.metrics import (
    MM_PER_M,
    error_summary,
    path_errors,
    sample_polyline,
    square_yz,
    summarize_errors,
)
from armbench.metrics.path import PathErrorSummary
from armbench.record import PAPER_REFERENCE, Measurement, Trial

__all__ = ["STYLES", "AccuracySuite", "SquareNames", "add_square_figures", "approach_square",
           "check_square", "path_figures", "plan_laps", "pooled_figures", "summarize_styles"]

#: The two ways a lap is driven, in the order they alternate.
STYLES: Final = ACCURACY.styles



def check_square(where: str, settings: RobotSettings, params: Mapping[str, Any],
                 styles_known: Sequence[str]) -> None:
    """The parameters of a lap of the square that every square suite shares (centre, side,
    approach duty, speed, spacing, laps, sampling, settling, branch, roll, styles), each checked
    under ``where``, and the whole square reachable on the branch."""
    centre = check_vec3(f"{where}.{ACCURACY.centre}", params[ACCURACY.centre])
    side = check(f"{where}.{ACCURACY.side}", params[ACCURACY.side], Bound(0.0, 0.5, low_open=True))
    check_whole(f"{where}.approach_duty", params["approach_duty"], Bound(1, MAX_DUTY))
    check(f"{where}.speed_m_s", params["speed_m_s"], Bound(0.0, 1.0, "m/s", low_open=True))
    check(f"{where}.spacing_m", params["spacing_m"], Bound(0.0005, 0.05, "m"))
    check_whole(f"{where}.laps", params["laps"], Bound(1, MAX_REPEATS))
    check(f"{where}.sample_period_s", params["sample_period_s"], Bound(0.0, 1.0, "s"))
    check(f"{where}.settle_s", params["settle_s"], Bound(0.0, 60.0, "s"))
    branch = check_branch(f"{where}.branch", params["branch"])
    roll = check(f"{where}.roll_rad", params["roll_rad"], Bound(unit="rad"))
    styles = params["styles"]
    if (isinstance(styles, (str, bytes)) or not isinstance(styles, Sequence) or not styles
            or any(s not in styles_known for s in styles) or len(set(styles)) != len(styles)):
        raise SettingsError(f"{where}.styles", styles,
                            f"must list some of {', '.join(styles_known)}, each once")
    edge = sample_polyline(square_yz(centre, side), 0.005, closed=True)
    check_reachable(f"{where}.{ACCURACY.centre}", edge, settings, branch=branch, roll_rad=roll)


async def approach_square(arm: Arm, corners: FloatArray, params: Mapping[str, Any]) -> None:
    """Bring the arm to the square's first corner (coordinated, at ``approach_duty``) and let it
    settle for ``settle_s``: where every lap of a square suite starts."""
    await arm.move_to(corners[0], float(params["roll_rad"]), branch=str(params["branch"]),
                      duty=int(params["approach_duty"]), coordinated=True)
    await settled_state(arm, float(params["settle_s"]))


def plan_laps(params: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The trials of a square suite: one per (lap, style), the styles alternating within a lap
    in the order ``params["styles"]`` lists them."""
    return [{ACCURACY.style: style, ACCURACY.lap: lap}
            for lap in range(int(params["laps"])) for style in params["styles"]]


def path_figures(samples: Sequence[Mapping[str, Any]], corners_m: FloatArray) -> dict[str, float]:
    """The path figures (mm) of ``samples`` against the closed polyline ``corners_m`` (m).

    Keys (suffixes of the measurement names): ``mean_mm``, ``rms_mm``, ``max_mm`` and per axis
    ``{x,y,z}_mean_mm`` (signed bias), ``{x,y,z}_rms_mm``, ``{x,y,z}_max_mm`` (largest |error|)
    of the reported TCP (``reported_m``: FK of the reported joints); the same with a ``true_``
    prefix for the true TCP (``true_m``) when every sample has one, and ``belief_mean_mm`` /
    ``belief_rms_mm`` / ``belief_max_mm``: the distance between the firmware's belief (reported
    TCP) and the truth. Empty for no samples.
    """
    if not samples:
        return {}
    return _figures(*_positions(samples), corners_m)


def _positions(samples: Sequence[Mapping[str, Any]]) -> tuple[FloatArray, FloatArray | None]:
    """The reported TCP positions ``(N, 3)`` (m) of ``samples`` and the true ones when every
    sample has one, else None."""
    reported = np.array([s["reported_m"] for s in samples], dtype=np.float64).reshape(-1, 3)
    if not all("true_m" in s for s in samples):
        return reported, None
    return reported, np.array([s["true_m"] for s in samples], dtype=np.float64).reshape(-1, 3)


def pooled_figures(trials: Sequence[Trial], corners_m: FloatArray) -> dict[str, float]:
    """:func:`path_figures` of the samples of ``trials`` pooled, read one trial at a time and
    kept as error series only (a long run's samples are on disk, not in memory)."""
    true_ = ACCURACY.true
    series: dict[str, tuple[list[FloatArray], list[FloatArray]]] = {"": ([], []), true_: ([], [])}
    belief: list[FloatArray] = []
    with_truth = True
    for t in trials:
        if not t.samples:
            continue
        reported, true = _positions(t.samples)
        with_truth = with_truth and true is not None
        for prefix, points in (("", reported), (true_, true if with_truth else None)):
            if points is not None:
                e = path_errors(points, corners_m, closed=True)
                series[prefix][0].append(e.error_mm)
                series[prefix][1].append(e.euclidean_mm)
        if with_truth and true is not None:
            belief.append(np.linalg.norm(reported - true, axis=1) * MM_PER_M)
    out: dict[str, float] = {}
    if not series[""][0]:
        return out
    for prefix in ("", true_) if with_truth else ("",):
        error_mm, euclidean_mm = series[prefix]
        _summary(out, prefix, summarize_errors(np.concatenate(error_mm),
                                               np.concatenate(euclidean_mm)))
    if with_truth:
        _belief(out, np.concatenate(belief))
    return out


def _figures(reported: FloatArray, true: FloatArray | None,
             corners_m: FloatArray) -> dict[str, float]:
    out: dict[str, float] = {}
    _summary(out, "", error_summary(path_errors(reported, corners_m, closed=True)))
    if true is not None:
        _summary(out, ACCURACY.true, error_summary(path_errors(true, corners_m, closed=True)))
        _belief(out, np.linalg.norm(reported - true, axis=1) * MM_PER_M)
    return out


def _belief(out: dict[str, float], belief: FloatArray) -> None:
    values = (belief.mean(), np.sqrt(np.mean(belief * belief)), belief.max())
    for stat, value in zip(ACCURACY.stats, values, strict=True):
        out[ACCURACY.square_figure(stat, ACCURACY.belief)] = float(value)


def _summary(out: dict[str, float], prefix: str, s: PathErrorSummary) -> None:
    """The figures of one TCP (``prefix``: "" reported, ``true_`` true), named by the contract:
    mean, RMS and largest distance, then per axis the signed bias, RMS and largest |error|."""
    per_axis = ((st.mean_mm, st.rms_mm, st.max_abs_mm) for st in (s.x, s.y, s.z))
    for axis, values in zip(("", *ACCURACY.axes), ((s.mean_mm, s.rms_mm, s.max_mm), *per_axis),
                            strict=True):
        for stat, value in zip(ACCURACY.stats, values, strict=True):
            out[ACCURACY.square_figure(stat, prefix, axis)] = value


_DESCRIPTIONS: Final = {
    "mean_mm": "mean Euclidean distance of the reported TCP (FK) to the square (paper's figure)",
    "rms_mm": "RMS distance of the reported TCP to the square",
    "max_mm": "largest distance of the reported TCP to the square",
    "true_mean_mm": "mean distance of the true TCP to the square",
    "true_rms_mm": "RMS distance of the true TCP to the square",
    "true_max_mm": "largest distance of the true TCP to the square",
    "belief_mean_mm": "mean distance between the reported (firmware) and the true TCP",
    "belief_rms_mm": "RMS distance between the reported (firmware) and the true TCP",
    "belief_max_mm": "largest distance between the reported (firmware) and the true TCP",
}


_SIGNED: Final = re.compile(r"(true_)?[xyz]_mean_mm")


def add_square_figures(ms: Measurements, metric: Callable[[str, str], str], style: str,
                       figures: Mapping[str, float]) -> None:
    """Add a lap's square figures (:func:`path_figures`, :func:`pooled_figures`) to ``ms``,
    each named by ``metric(style, key)`` (the suite's contract), with its unit and meaning."""
    for key, value in figures.items():
        signed = _SIGNED.fullmatch(key) is not None
        ms.add(metric(style, key), value, "mm", undirected=signed,
               description=_DESCRIPTIONS.get(key) or _axis_description(key))


def _axis_description(key: str) -> str:
    true = key.startswith("true_")
    axis = key.removeprefix("true_")[0]
    what = {"mean": "mean signed error (bias)", "rms": "RMS error",
            "max": "largest |error|"}[key.removeprefix("true_")[2:-3]]
    return f"{what} along {axis} of the {'true' if true else 'reported'} TCP"


class SquareNames(Protocol):
    """What a square suite's contract names: the trials' style parameter, the lap figures and
    each figure's metric."""

    @property
    def style(self) -> str: ...
    @property
    def lap_time(self) -> str: ...
    @property
    def laps(self) -> str: ...

    def metric(self, style: str, figure: str) -> str: ...


def summarize_styles(ms: Measurements, names: SquareNames, styles: Sequence[str],
                     trials: Sequence[Trial], corners_m: FloatArray) -> dict[str, dict[str, float]]:
    """Per style, into ``ms``: the square figures over the samples of its done laps pooled, the
    mean lap time and the laps measured. Returns the pooled figures of each style that has any
    (for the suite's ratio of two styles)."""
    figures: dict[str, dict[str, float]] = {}
    for style in styles:
        done = [t for t in trials if t.status == "done" and t.params.get(names.style) == style]
        f = pooled_figures(done, corners_m)
        if not f:
            continue
        figures[style] = f
        add_square_figures(ms, names.metric, style, f)
        laps = [m.value for t in done for m in t.measurements
                if m.name == names.metric(style, names.lap_time)]
        if laps:
            ms.add(names.metric(style, names.lap_time), float(np.mean(laps)), "s",
                   undirected=True, description="mean lap time")
        ms.add(names.metric(style, names.laps), float(len(done)), "",
               description="laps measured")
    return figures


class AccuracySuite(Suite):
    """The square in the YZ plane: paper style against coordinated streaming (see module doc)."""

    name = ACCURACY.suite
    version = "1"
    metric_units: ClassVar[Mapping[str, str]] = {
        "accuracy.*_mm": "mm", "accuracy.*.lap_time_s": "s", "accuracy.*.laps": "",
        "accuracy.*_ratio": ""}

    def default_params(self, settings: RobotSettings) -> dict[str, Any]:
        """Defaults: a 0.15 m square centred at (0.38, 0, 0.80) m, 3 laps per style."""
        return {
            ACCURACY.centre: list(DEFAULT_SQUARE_CENTRE_M),
            ACCURACY.side: DEFAULT_SQUARE_SIDE_M,
            "duty": MAX_DUTY,
            "speed_m_s": 0.05,
            "spacing_m": 0.005,
            "laps": 3,
            "sample_period_s": 0.01,
            "settle_s": 0.2,
            "approach_duty": MAX_DUTY,
            "branch": "front-up",
            "roll_rad": 0.0,
            "styles": list(STYLES),
            ACCURACY.paper_mean: PAPER_REFERENCE[ACCURACY.paper_mean],
        }

    def validate(self, settings: RobotSettings, params: Mapping[str, Any]) -> None:
        """Types and ranges of every parameter, and the whole square reachable on ``branch``."""
        where = f"suites.{self.name}"
        check_whole(f"{where}.duty", params["duty"], Bound(1, MAX_DUTY))
        check(f"{where}.{ACCURACY.paper_mean}", params[ACCURACY.paper_mean], Bound(0.0))
        check_square(where, settings, params, STYLES)

    def metric_names(self, params: Mapping[str, Any]) -> frozenset[str]:
        """The figures of each style driven, and the improvement ratios when both are."""
        return ACCURACY.metric_names(params["styles"])

    def plan(self, params: Mapping[str, Any]) -> list[dict[str, Any]]:
        """One trial per (lap, style): lap 0 paper, lap 0 coordinated, lap 1 paper, ..."""
        return plan_laps(params)

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        """Drive one lap in ``trial_params["style"]`` and measure its path errors."""
        p = ctx.params
        style = str(trial_params[ACCURACY.style])
        corners = square_yz(p[ACCURACY.centre], float(p[ACCURACY.side]))
        perimeter = 4.0 * float(p[ACCURACY.side])
        timeout_s = 120.0 + 4.0 * perimeter / float(p["speed_m_s"])
        ctx.progress(f"{ACCURACY.suite}: lap {trial_params[ACCURACY.lap]} ({style})")

        async def body(samples: list[dict[str, Any]]) -> tuple[list[dict[str, Any]],
                                                               list[Measurement]]:
            arm = ctx.arm
            branch, roll = str(p["branch"]), float(p["roll_rad"])
            await approach_square(arm, corners, p)
            t0 = loop_time()
            async with StateRecorder(ctx, t0, float(p["sample_period_s"]), into=samples):
                if style == ACCURACY.paper:
                    for k in (1, 2, 3, 0):
                        await arm.move_to(corners[k], roll, branch=branch, duty=int(p["duty"]))
                else:
                    await arm.follow_path([*corners, corners[0]], speed_m_s=float(p["speed_m_s"]),
                                          spacing_m=float(p["spacing_m"]), branch=branch,
                                          roll_rad=roll)
                lap_s = loop_time() - t0
            ms = Measurements(ctx)
            add_square_figures(ms, ACCURACY.metric, style, path_figures(samples, corners))
            ms.add(ACCURACY.metric(style, ACCURACY.lap_time), lap_s, "s", undirected=True,
                   description="time from the first command to the arrival back at the start")
            return samples, ms.items

        return await guarded_trial(ctx, index, trial_params, body, timeout_s=timeout_s)

    def summarize(self, ctx: SuiteContext, trials: Sequence[Trial]) -> list[Measurement]:
        """Per style, the figures over the samples of all its done laps pooled; the improvement
        ratio paper mean / coordinated mean (reported and true)."""
        p = ctx.params
        corners = square_yz(p[ACCURACY.centre], float(p[ACCURACY.side]))
        ms = Measurements(ctx)
        figures = summarize_styles(ms, ACCURACY, STYLES, trials, corners)
        paper = figures.get(ACCURACY.paper, {})
        coord = figures.get(ACCURACY.coordinated, {})
        for key, name in ((ACCURACY.mean, ACCURACY.improvement),
                          (ACCURACY.true_mean, ACCURACY.true_improvement)):
            if key in paper and coord.get(key, 0.0) > 0.0:
                ms.add(name, paper[key] / coord[key], "", better="higher",
                       description=f"paper-style {key} / coordinated {key}")
        return ms.items
