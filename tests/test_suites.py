"""The bench suites end to end: accuracy, repeatability and start-up recovery.

Each suite runs against the emulator over ``fake://`` on virtual time
(``armbench.fakes.clock.vclock``) with small
parameters, through the same calls the runner makes (``params`` → ``plan`` → ``run_trial`` per
trial → ``summarize``). Checks: every trial is measured, the figures are present and plausible,
and each suite-level figure equals what the metric functions of ``armbench.metrics`` give on the
trial samples stored in the record. One accuracy run goes over a real pty to
``armbench emulate --pty`` in real time.
"""

from __future__ import annotations

import asyncio
import itertools
import math
import os
import random
import select
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from armbench.bench.runner.power import EmulatorPower
from armbench.bench.runner.truth import EmulatorTruth
from armbench.bench.suites._common import (
    StateRecorder,
    duty_for_speed_pct,
    fk_m,
    speed_pct_for_duty,
)
from armbench.bench.suites.accuracy import AccuracySuite, path_figures
from armbench.bench.suites.base import Suite, SuiteContext
from armbench.bench.suites.repeatability import POSE_NAMES, RepeatabilitySuite, speed_label
from armbench.bench.suites.startup_recovery import (
    ATMEGA328P_EEPROM_CYCLES,
    CONDITIONS,
    StartupRecoverySuite,
    eeprom_life_years,
    parse_condition,
)
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.kinematics import ik
from armbench.drivers.model.protocol import REPLY_LEN, TICKS_PER_RAD, encode_reply
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.eeprom import RATED_CYCLES
from armbench.metrics import (
    distance_characteristics,
    error_summary,
    iso_cube_poses,
    path_errors,
    pose_accuracy,
    pose_repeatability,
    square_yz,
)
from armbench.record import Measurement, Trial
from armbench.record.limits import LimitsConfig

ROOT = Path(__file__).resolve().parent.parent
SETTINGS = RobotSettings()
#: Bound of one suite run on fake:// (s of loop time: robot time on the virtual clock).
ROBOT_S = 600.0


# --- running a suite the way the runner does -----------------------------------------------------


async def _run(suite: Suite, params: Mapping[str, Any], arm: Arm, *, truth: bool,
               power: bool, seed: int = 1) -> tuple[list[Trial], list[Measurement], float]:
    ctx = SuiteContext(arm=arm, settings=SETTINGS, limits=LimitsConfig(), params=params,
                       rng=random.Random(seed), power=EmulatorPower(arm) if power else None,
                       truth=EmulatorTruth(arm, SETTINGS) if truth else None)
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    trials = [await suite.run_trial(ctx, i, tp) for i, tp in enumerate(suite.plan(params))]
    return trials, suite.summarize(ctx, trials), loop.time() - t0


def run_fake(suite: Suite, overrides: Mapping[str, Any], *, truth: bool = True,
             power: bool = True,
             port: str = "fake://") -> tuple[list[Trial], dict[str, Measurement], float]:
    """Run ``suite`` with its defaults overridden by ``overrides`` on ``fake://`` (virtual time);
    returns the trials, the suite-level measurements by name and the robot time (s)."""
    params = suite.params(SETTINGS, overrides)

    async def main() -> tuple[list[Trial], list[Measurement], float]:
        async with asyncio.timeout(ROBOT_S), Arm.connect(port) as arm:
            return await _run(suite, params, arm, truth=truth, power=power)

    trials, ms, robot_s = run_virtual(main())
    return trials, {m.name: m for m in ms}, robot_s


def _by_name(trial: Trial) -> dict[str, float]:
    return {m.name: m.value for m in trial.measurements}


def _positions(samples: Sequence[Mapping[str, Any]], key: str) -> np.ndarray:
    return np.array([s[key] for s in samples], dtype=np.float64)


# --- parameters and helpers ----------------------------------------------------------------------


def test_duty_for_speed_follows_law_12() -> None:
    assert duty_for_speed_pct(100) == 99
    assert duty_for_speed_pct(50) == 97
    assert duty_for_speed_pct(10) == 81
    for pct in (100, 50, 10):
        assert speed_pct_for_duty(duty_for_speed_pct(pct)) == pytest.approx(pct)
    with pytest.raises(ValueError):
        duty_for_speed_pct(0)


@pytest.mark.parametrize("suite_cls", [AccuracySuite, RepeatabilitySuite, StartupRecoverySuite])
def test_defaults_validate_and_plan(suite_cls: type[Suite]) -> None:
    suite = suite_cls()
    params = suite.params(SETTINGS, {})
    plan = suite.plan(params)
    assert plan and all(isinstance(t, dict) for t in plan)
    expected = {"accuracy": 6, "repeatability": 3 * (30 + 10 + 10), "startup-recovery": 21}
    assert len(plan) == expected[suite.name]


def test_default_square_is_reachable_but_the_brief_counterexample_is_not() -> None:
    assert not any(s.within_limits for s in ik((0.5, 0.1, 0.4), SETTINGS))
    with pytest.raises(SettingsError) as err:
        AccuracySuite().params(SETTINGS, {"centre_m": [0.5, 0.1, 0.4]})
    assert err.value.field == "suites.accuracy.centre_m"
    with pytest.raises(SettingsError) as err:
        RepeatabilitySuite().params(SETTINGS, {"cube_centre_m": [0.5, 0.1, 0.4]})
    assert err.value.field == "suites.repeatability.cube_centre_m"


@pytest.mark.parametrize(("suite_cls", "key", "value"), [
    (AccuracySuite, "side_m", 0.9),
    (AccuracySuite, "styles", ["paper", "fast"]),
    (AccuracySuite, "laps", 0),
    (AccuracySuite, "nonsense", 1),
    (RepeatabilitySuite, "speeds_pct", [100, 100]),
    (RepeatabilitySuite, "plane", "C1-C3-C5-C7"),
    (RepeatabilitySuite, "vap_poses", ["P6"]),
    (StartupRecoverySuite, "conditions", ["cw-sideways-near"]),
    (StartupRecoverySuite, "joint_sets", [[1, 5]]),
    (StartupRecoverySuite, "cut_fraction", [0.8, 0.2]),
])
def test_bad_parameters_are_refused_naming_the_field(suite_cls: type[Suite], key: str,
                                                     value: object) -> None:
    suite = suite_cls()
    with pytest.raises(SettingsError) as err:
        suite.params(SETTINGS, {key: value})
    assert err.value.field.startswith(f"suites.{suite.name}")


def test_conditions_parse_and_predict() -> None:
    assert len(CONDITIONS) == 10
    c = parse_condition("ccw-toward-far")
    assert (c.motion, c.relation, c.zone, c.moving, c.expected_to_recover) == (
        "ccw", "toward", "far", True, False)
    assert parse_condition("stopped-near").expected_to_recover
    with pytest.raises(ValueError):
        parse_condition("stopped-toward-near")


def test_eeprom_life_projection() -> None:
    assert ATMEGA328P_EEPROM_CYCLES == RATED_CYCLES
    assert eeprom_life_years(50.0, 2000.0) == pytest.approx(1.0)
    assert math.isinf(eeprom_life_years(0.0, 2000.0))


def test_an_unmeasurable_trial_is_an_error_not_a_crash() -> None:
    """A target the arm cannot reach (validation bypassed) ends the trial with status error."""
    suite = AccuracySuite()
    params = suite.default_params(SETTINGS) | {"centre_m": [0.5, 0.1, 0.4]}

    async def main() -> Trial:
        async with asyncio.timeout(60), Arm.connect("fake://") as arm:
            ctx = SuiteContext(arm=arm, settings=SETTINGS, limits=LimitsConfig(), params=params,
                               rng=random.Random(0))
            return await suite.run_trial(ctx, 0, {"style": "paper", "lap": 0})

    trial = run_virtual(main())
    assert trial.status == "error"
    assert trial.error is not None and "JointLimitError" in trial.error


# --- accuracy ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def accuracy_run() -> tuple[list[Trial], dict[str, Measurement], float]:
    return run_fake(AccuracySuite(), {"laps": 1}, port="fake://?profile=ideal")  # exact truth


def test_accuracy_coordinated_beats_the_paper_style(
        accuracy_run: tuple[list[Trial], dict[str, Measurement], float]) -> None:
    trials, ms, _ = accuracy_run
    assert [t.status for t in trials] == ["done", "done"]
    assert [t.params["style"] for t in trials] == ["paper", "coordinated"]
    paper, coord = ms["accuracy.paper.mean_mm"].value, ms["accuracy.coordinated.mean_mm"].value
    assert coord < paper
    assert ms["accuracy.improvement_ratio"].value == pytest.approx(paper / coord)
    assert ms["accuracy.improvement_ratio"].value >= 5.0
    assert ms["accuracy.improvement_ratio"].better == "higher"
    assert ms["accuracy.true_improvement_ratio"].value >= 5.0
    for style in ("paper", "coordinated"):
        for key in ("mean_mm", "rms_mm", "max_mm", "x_rms_mm", "y_max_mm", "z_mean_mm",
                    "true_mean_mm", "true_max_mm", "belief_mean_mm", "lap_time_s"):
            assert f"accuracy.{style}.{key}" in ms, key
        # The truth is paired with each reply's own ground-truth sample: the firmware's belief
        # and the truth differ by the wire resolution only (no transmission lag).
        assert ms[f"accuracy.{style}.belief_mean_mm"].value < 0.1
    assert ms["accuracy.paper.x_mean_mm"].better is None  # a signed bias has no direction


def test_accuracy_figures_are_the_metric_functions_on_the_samples(
        accuracy_run: tuple[list[Trial], dict[str, Measurement], float]) -> None:
    trials, ms, _ = accuracy_run
    params = AccuracySuite().params(SETTINGS, {"laps": 1})
    corners = square_yz(params["centre_m"], params["side_m"])
    for trial in trials:
        style = trial.params["style"]
        samples = trial.samples
        assert len(samples) > 50
        for s in samples:
            assert set(s) >= {"t_s", "q_rad", "reported_m", "true_m"}
            assert s["reported_m"] == pytest.approx(fk_m(s["q_rad"], SETTINGS), abs=1e-6)
        summary = error_summary(path_errors(_positions(samples, "reported_m"), corners))
        true = error_summary(path_errors(_positions(samples, "true_m"), corners))
        got = _by_name(trial)
        assert got[f"accuracy.{style}.mean_mm"] == pytest.approx(summary.mean_mm)
        assert got[f"accuracy.{style}.rms_mm"] == pytest.approx(summary.rms_mm)
        assert got[f"accuracy.{style}.max_mm"] == pytest.approx(summary.max_mm)
        assert got[f"accuracy.{style}.y_rms_mm"] == pytest.approx(summary.y.rms_mm)
        assert got[f"accuracy.{style}.true_mean_mm"] == pytest.approx(true.mean_mm)
        # One lap per style: the suite-level figure is the trial's.
        assert ms[f"accuracy.{style}.mean_mm"].value == pytest.approx(summary.mean_mm)
        assert path_figures(samples, corners)["mean_mm"] == pytest.approx(summary.mean_mm)


# --- repeatability ------------------------------------------------------------------------------

REPEAT = {"cycles": 3, "speeds_pct": [100, 50], "vap_cycles": 2, "path_cycles": 2,
          "settle_s": 0.1, "cube_side_m": 0.06}


@pytest.fixture(scope="module")
def repeatability_run() -> tuple[list[Trial], dict[str, Measurement], float]:
    return run_fake(RepeatabilitySuite(), REPEAT)


def test_repeatability_iso_figures(
        repeatability_run: tuple[list[Trial], dict[str, Measurement], float]) -> None:
    trials, ms, _ = repeatability_run
    assert all(t.status == "done" for t in trials), [t.error for t in trials]
    assert {t.params["duty"] for t in trials} == {99, 97}
    for v in ("v100", "v50"):
        assert ms[f"repeatability.{v}.cycles"].value == 3
        for pose in POSE_NAMES:
            base = f"repeatability.{v}.{pose.lower()}"
            for key in ("ap_mm", "ap_x_mm", "ap_y_mm", "ap_z_mm", "rp_mm", "true_ap_mm",
                        "true_rp_mm"):
                assert f"{base}.{key}" in ms, f"{base}.{key}"
            rp = ms[f"{base}.rp_mm"].value
            assert math.isfinite(rp) and 0.0 <= rp < 1.0
            assert ms[f"{base}.ap_mm"].value < 1.0
            assert ms[f"{base}.ap_x_mm"].better is None
        for key in ("ad_mm", "rd_mm", "true_rd_mm", "path.at_mm", "path.rt_mm",
                    "path.true_at_mm", "p1.vap_mm", "p2.true_vap_mm", "p4.vap_mm"):
            assert f"repeatability.{v}.{key}" in ms, key
        assert ms[f"repeatability.{v}.path.at_mm"].value < 2.0


def test_repeatability_figures_are_the_metric_functions_on_the_samples(
        repeatability_run: tuple[list[Trial], dict[str, Measurement], float]) -> None:
    trials, ms, _ = repeatability_run
    params = RepeatabilitySuite().params(SETTINGS, REPEAT)
    poses = iso_cube_poses(params["cube_centre_m"], params["cube_side_m"], params["plane"])
    for pct in (100, 50):
        label = f"repeatability.{speed_label(pct)}"
        cycles = [t for t in trials if t.params["kind"] == "pose" and t.params["speed_pct"] == pct]
        assert len(cycles) == 3
        for k, pose in enumerate(POSE_NAMES):
            samples = [s for t in cycles for s in t.samples if s["pose"] == pose]
            assert len(samples) == 3
            assert all(s["commanded_m"] == pytest.approx(poses[k].tolist()) for s in samples)
            for key, prefix in (("reported_m", ""), ("true_m", "true_")):
                pts = _positions(samples, key)
                ap = pose_accuracy(pts, poses[k])
                rp = pose_repeatability(pts)
                base = f"{label}.{pose.lower()}.{prefix}"
                assert ms[f"{base}ap_mm"].value == pytest.approx(ap.ap_p_mm)
                assert ms[f"{base}ap_z_mm"].value == pytest.approx(ap.ap_z_mm)
                assert ms[f"{base}rp_mm"].value == pytest.approx(rp.rp_mm)
        p2 = _positions([s for t in cycles for s in t.samples if s["pose"] == "P2"],
                        "reported_m")
        p4 = _positions([s for t in cycles for s in t.samples if s["pose"] == "P4"],
                        "reported_m")
        d = distance_characteristics(p2, p4, poses[1], poses[3])
        assert ms[f"{label}.ad_mm"].value == pytest.approx(d.ad_p_mm)
        assert ms[f"{label}.rd_mm"].value == pytest.approx(d.rd_p_mm)


# --- start-up recovery --------------------------------------------------------------------------

STARTUP = {"conditions": ["stopped-near", "stopped-far", "cw-away-near", "ccw-away-far",
                          "cw-toward-near"],
           "joint_sets": [[2, 3, 4]], "trials": 5, "recovery_timeout_s": 8.0,
           "wear_duration_s": 10.0}


@pytest.fixture(scope="module")
def startup_run() -> tuple[list[Trial], dict[str, Measurement], float]:
    return run_fake(StartupRecoverySuite(), STARTUP)


def _outcome(trial: Trial) -> Mapping[str, Any]:
    (outcome,) = [s for s in trial.samples if s.get("event") == "outcome"]
    return outcome


def test_startup_recovery_campaign(
        startup_run: tuple[list[Trial], dict[str, Measurement], float]) -> None:
    trials, ms, _ = startup_run
    assert all(t.status == "done" for t in trials), [t.error for t in trials]
    cuts = [t for t in trials if t.params["kind"] == "cut"]
    assert [t.params["condition"] for t in cuts] == STARTUP["conditions"]
    for t in cuts:
        o = _outcome(t)
        m = _by_name(t)
        assert m["startup.recovered"] == (1.0 if o["recovered"] else 0.0)
        assert o["cut_true_q_rad"] is not None and o["joints"] == [2, 3, 4]
        fault = next(s for s in t.samples if s.get("event") == "fault")
        assert fault["true_q_rad"] is not None
        if o["condition"].startswith("stopped"):
            assert o["recovered"], o
            assert m["startup.position_error_mrad"] < 1.0
        if o["condition"] in ("cw-away-near", "ccw-away-far"):
            # Moving away from the Hall sensor: the recovery drives back to it and succeeds.
            assert o["motion"][1:] == [o["condition"].split("-")[0]] * 3
            assert o["recovered"], o
            assert m["startup.recovery_time_s"] > 0.1
            assert o["final_q_rad"][1:] == pytest.approx([0.0, 0.0, 0.0], abs=2e-4)
        if o["condition"] == "cw-toward-near":
            # Towards the Hall sensor: the recovery drives away from it into the limit.
            assert not o["recovered"] and o["failure"] == "position"
            assert o["stalled_joints"], o
            assert m["startup.position_error_mrad"] > 10.0
            assert any(s.get("event") == "rescue" and s["done"] for s in t.samples)
        assert m["startup.eeprom_writes"] >= 0
    assert ms["startup.success_rate_pct"].value == pytest.approx(80.0)
    assert ms["startup.success_rate_pct"].better == "higher"
    assert ms["startup.expected_success_rate_pct"].value == pytest.approx(100.0)
    assert ms["startup.cw-toward-near.success_rate_pct"].value == 0.0
    assert ms["startup.position_error_max_mrad"].value > 10.0
    assert ms["startup.recovery_time_max_s"].value == pytest.approx(max(
        _outcome(t)["recovery_s"] for t in cuts if _outcome(t)["recovered"]))


def test_startup_eeprom_wear(
        startup_run: tuple[list[Trial], dict[str, Measurement], float]) -> None:
    trials, ms, _ = startup_run
    (wear,) = [t for t in trials if t.params["kind"] == "wear"]
    (total,) = [s for s in wear.samples if s.get("event") == "wear"]
    phases = [s for s in wear.samples if s.get("event") == "wear_phase"]
    assert [s["phase"] for s in phases] == ["ptp", "streaming"]
    per_hour = max(total["max_cell_wear"]) * 3600.0 / total["elapsed_s"]
    assert ms["startup.eeprom_cell_wear_per_hour"].value == pytest.approx(per_hour)
    assert ms["startup.eeprom_writes_per_hour"].value > 0
    years = ms["startup.eeprom_life_years"].value
    assert years == pytest.approx(RATED_CYCLES / (per_hour * 2000.0))
    assert ms["startup.eeprom_life_years"].better == "higher"
    assert ms["startup.eeprom_life_hours"].value == pytest.approx(years * 2000.0)
    for phase in phases:
        assert f"startup.{phase['phase']}.eeprom_writes_per_hour" in ms


def test_startup_without_truth_checks_against_the_known_position() -> None:
    trials, ms, _ = run_fake(StartupRecoverySuite(), {
        "conditions": ["stopped-far", "ccw-away-near", "ccw-toward-near"],
        "joint_sets": [[3, 4]], "trials": 3, "recovery_timeout_s": 6.0,
        "wear_duration_s": 0.0}, truth=False)
    outcomes = [_outcome(t) for t in trials]
    assert [o["recovered"] for o in outcomes] == [True, True, False]
    assert all(o["compared_with"] == "expected_rad" for o in outcomes)
    assert all(o["cut_true_q_rad"] is None for o in outcomes)
    assert ms["startup.success_rate_pct"].value == pytest.approx(100.0 * 2 / 3)


def test_startup_without_power_switch_skips_the_cuts() -> None:
    trials, ms, _ = run_fake(StartupRecoverySuite(), {"trials": 2, "wear_duration_s": 0.0},
                             power=False)
    assert [t.status for t in trials] == ["done", "done"]
    assert all(t.samples[0]["event"] == "skipped" and not t.measurements for t in trials)
    assert ms["startup.trials_measured"].value == 0
    assert "startup.success_rate_pct" not in ms


# --- over a real pty, in real time ---------------------------------------------------------------


@pytest.fixture
def pty_port(tmp_path: Path) -> Any:
    log = (tmp_path / "emulate.log").open("w")
    proc = subprocess.Popen([sys.executable, "-m", "armbench", "emulate", "--pty"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=log, text=True,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    try:
        assert proc.stdout is not None
        # starting Python and the emulator takes seconds of CPU: far more on a loaded machine
        ready, _, _ = select.select([proc.stdout], [], [], 120.0)
        line = proc.stdout.readline() if ready else ""
        assert "serving the arm on " in line, f"emulate did not start: {line!r}"
        yield line.split("serving the arm on ", 1)[1].split()[0]
    finally:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
        log.close()


def test_accuracy_over_a_pty_in_real_time(pty_port: str) -> None:
    """A tiny lap (4 cm square) each way against ``armbench emulate --pty``: no ground truth over
    a pty, so only the figures of the reported joints (the paper's situation)."""
    suite = AccuracySuite()
    params = suite.params(SETTINGS, {"laps": 1, "side_m": 0.04, "speed_m_s": 0.05,
                                     "settle_s": 0.1})

    async def main() -> tuple[list[Trial], list[Measurement], float]:
        # a starved emulator process may fall silent for longer than the default 0.5 s, and runs
        # slower than the host's clock, which a move's timeout measures
        async with asyncio.timeout(300), Arm.connect(pty_port, reply_timeout_s=5.0,
                                                     move_timeout_scale=10.0) as arm:
            return await _run(suite, params, arm, truth=False, power=False)

    trials, ms_list, robot_s = asyncio.run(main())
    ms = {m.name: m for m in ms_list}
    assert [t.status for t in trials] == ["done", "done"], [t.error for t in trials]
    assert all("true_m" not in s for t in trials for s in t.samples)
    assert "accuracy.paper.true_mean_mm" not in ms
    assert ms["accuracy.coordinated.mean_mm"].value < ms["accuracy.paper.mean_mm"].value
    # the host's seconds here (~10 on an idle machine): bounded only by the timeout above, as a
    # loaded host runs the laps slower; the laps' robot time is judged on fake://
    assert robot_s > 0.0


def test_replies_read_at_once_are_sampled_on_the_lines_clock() -> None:
    """A host too busy to read lets the replies wait in the port's buffer and reads them at once
    (one loop time for all): the recorder still keeps one sample per ``sample_period_s`` of the
    line, which carried them one reply period apart at least, not one per read (a busy host's
    lap had 86 mm of its 752 mm path unsampled). A real pty; the test is the arm, writing a
    hundred replies in one go, joint 1's ticks numbering them."""
    master, slave = os.openpty()
    period_s, backlog = 0.01, 100
    reply_s = REPLY_LEN * SETTINGS.serial.byte_time_s
    per_sample = math.ceil(period_s / reply_s - 1e-9)  # replies of the line in one period

    async def main() -> list[dict[str, Any]]:
        # the far end is silent between its writes: the reply timeout bounds a hung test only
        arm = Arm(os.ttyname(slave), SETTINGS, reply_timeout_s=60.0)
        opening = asyncio.ensure_future(arm.open())
        try:
            while not opening.done():  # until the driver reads a first reply
                os.write(master, encode_reply(0, 0, 0, 0))
                await asyncio.sleep(0.05)
            await opening
            ctx = SuiteContext(arm=arm, settings=SETTINGS, limits=LimitsConfig(), params={},
                               rng=random.Random(0))
            async with StateRecorder(ctx, asyncio.get_running_loop().time(), period_s) as rec:
                os.write(master, b"".join(encode_reply(k, 0, 0, 0)
                                          for k in range(1, backlog + 1)))
                await arm.wait_state(lambda s: s.ticks[0] == backlog, timeout_s=60.0)
            return rec.samples
        finally:
            await arm.close()

    try:
        samples = asyncio.run(main())
    finally:
        os.close(master)
        os.close(slave)
    replies = [round(s["q_rad"][0] * TICKS_PER_RAD) for s in samples]
    assert replies[0] == 0 and replies[-1] == backlog, replies
    gaps = [b - a for a, b in itertools.pairwise(replies)]
    assert min(gaps) > 0 and max(gaps) <= per_sample, replies
    times = [s["t_s"] for s in samples]
    assert times == sorted(times)
