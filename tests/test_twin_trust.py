"""A twin a lab without a laser tracker can trust, on the foreign arms (simulators written apart
from armbench, ``tests/foreign_arms/`` and the shared ``foreign_arm.py``) served in real time
over TCP: each calibrated once (``armbench calibrate --port``, no reference instrument), then a
held-out accuracy run of the same arm, twin-checked with the default and the calibrated twin.
The arms are calibrated and run all at once, each by processes of its own: they wait on their
arms in real time.

* never worse, joint by joint: the calibrated twin's RMS divergence on the held-out run at most
  1.1 × the default twin's or 1.5 × the capture's floor;
* ``calibrate --budget-s 120`` ends within 130 s (the threshold arm's calibration, timed);
* a fitted twin runs the suites' motions no slower than the default twin;
* where the arm's effect is outside the twin's model family (the threshold arm whose loss grows
  during the session), twin-check fails the calibrated twin and names the joint and where;
* geometry from what a lab has: twelve reference poses with 0.1 mm of noise give the offsets
  within 0.05° and the lengths within 0.3 mm on three tracker arms; a touch-off with a scripted
  operator (it sees the tool through the arm's tracker, as a person's eyes would) gives them
  with their uncertainties.

Slow (real time, minutes): ``pytest -m slow``. Every figure is printed (``-s``). Assertions rest
on what the link guarantees: a loaded machine starves the arms' processes (a patient reply
timeout), and only CPU time (interleaved, best of five) is compared between twins.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from foreign_arms.serve import SHARED_MISSING, foreign_arm, shared_arm_script
from foreign_arms.tracker_client import TrackerStream
from test_calibrate_reference import ScriptedOperator
from test_twin_check import _lap

from armbench.bench.calibrate.calibration import calibrate_port, calibrate_reference
from armbench.bench.calibrate.capture_data import load_capture
from armbench.bench.calibrate.model import ReferencePose
from armbench.bench.calibrate.procedure import HOLD_POSES_RAD
from armbench.bench.twin_check.check import TwinCheck, twin_check
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.settings import RobotSettings, load_settings
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.twin.physics import DEFAULT_ARM

pytestmark = pytest.mark.slow
#: The tests of the calibrated arms run on one pytest-xdist worker: it calibrates them all at
#: once (:func:`sessions`), which another worker would do again.
CALIBRATED_ARMS = pytest.mark.xdist_group("twin-trust-calibrated")

ROOT = Path(__file__).resolve().parents[1]
#: Each arm: its script, its hidden behaviour, the calibration's budget (s). The threshold arm
#: at the issue's 120 s (timed); the others at 90 s (at 60 s the held-out blocks hold two
#: corners and no streamed edge: most joints keep the prior, which the check allows but which
#: shows little).
ARMS: dict[str, tuple[str, tuple[str, ...], float]] = {
    "stall": ("stall", (), 90.0),
    "jitter": ("jitter", (), 90.0),
    "tracker": ("tracker", ("--play-deg", "0.5,0.5,1.0,0.5", "--offset-deg", "0.3,-0.4,0.4,0",
                            "--a2-error-mm", "4", "--a3-error-mm", "-4"), 90.0),
    "threshold": ("threshold", (), 120.0),
    "shared": ("shared", ("--physics",), 90.0),
    "drift": ("threshold", ("--drift-per-min", "1.5"), 90.0),
}
#: A loaded machine may starve the arm's process for seconds: not the arm's doing.
PATIENT = ('spec_version = "armbench-limits/1"\n\n[bench]\nreply_timeout_s = 5.0\n'
           "connect_timeout_s = 30.0\nmove_timeout_scale = 10.0\n\n[suites.accuracy]\nlaps = 1\n")


@dataclass(frozen=True, slots=True)
class Calibrated:
    """An arm calibrated over TCP and checked on a held-out accuracy run."""

    name: str
    fit: Path
    wall_s: float
    default: TwinCheck
    calibrated: TwinCheck


def _armbench(*args: str, timeout_s: float = 900.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "armbench", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout_s, check=False)


def _show(label: str, r: TwinCheck) -> str:
    worst = [round(max((p.per_allowed(j) for p in r.parts), default=0.0), 2) for j in range(4)]
    return (f"{label}: {r.verdict} rms {[round(v, 1) for v in r.rms_counts]} floor "
            f"{[round(v, 1) for v in r.floor_counts]} worst part {worst}")


def _session(name: str, url: str, folder: Path) -> tuple[float, Path]:
    """Calibrate the arm at ``url`` into ``folder`` (timed, wall clock), then its held-out
    accuracy run: the calibration's wall time and the run's capture."""
    _, _, budget = ARMS[name]
    (folder / "patient.toml").write_text(PATIENT)
    t0 = time.monotonic()
    done = _armbench("calibrate", "--port", url, "--budget-s", f"{budget:g}",
                     "--reply-timeout", "5", "--out", str(folder / "fit"))
    wall_s = time.monotonic() - t0
    assert done.returncode == 0, done.stderr[-3000:]
    held = _armbench("run", "accuracy", "--port", url, "--config", str(folder / "patient.toml"),
                     "--workers", "1", "--out", str(folder / "held"))
    capture = folder / "held" / "capture.mcap"
    # 4: the run ended in error (the stall arm stalls lifting at a corner at full duty and the
    # move times out, as it is built to): its capture holds what the arm did
    assert held.returncode in (0, 1, 4) and capture.exists(), (held.stdout[-2000:]
                                                               + held.stderr[-2000:])
    return wall_s, capture


Session = tuple[Path, float, Path] | BaseException


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Session]:
    """Every arm calibrated and run at once, each its own processes against its own arm: they
    wait on their arms in real time, so together they take about as long as the longest. Per
    arm: its folder, the calibration's wall time and the held-out run's capture, or what went
    wrong (its tests fail with it; the others go on)."""
    names = [n for n in ARMS if ARMS[n][0] != "shared" or shared_arm_script() is not None]
    folders = {n: tmp_path_factory.mktemp(n) for n in names}
    with contextlib.ExitStack() as arms_up, ThreadPoolExecutor(len(names)) as pool:
        arms = {n: arms_up.enter_context(foreign_arm(ARMS[n][0], *ARMS[n][1])) for n in names}
        futures = {n: pool.submit(_session, n, arms[n].url, folders[n]) for n in names}
        out: dict[str, Session] = {}
        for n, f in futures.items():
            error = f.exception()
            out[n] = error if error is not None else (folders[n], *f.result())
        return out


@pytest.fixture(scope="module", params=list(ARMS))
def calibrated(request: pytest.FixtureRequest, sessions: dict[str, Session]) -> Calibrated:
    """The arm ``request.param`` calibrated (timed, wall clock) and its held-out run checked."""
    name = request.param
    if name not in sessions:
        pytest.skip(SHARED_MISSING)
    outcome = sessions[name]
    if isinstance(outcome, BaseException):
        raise outcome
    folder, wall_s, capture = outcome
    _, _, budget = ARMS[name]
    fitted = load_settings(folder / "fit" / "robot.toml")
    result = Calibrated(name, folder / "fit", wall_s,
                        twin_check(load_capture(capture, RobotSettings()), RobotSettings()),
                        twin_check(load_capture(capture, fitted), fitted))
    print(f"\n{name} (budget {budget:g} s, {wall_s:.1f} s wall)")
    print("  " + _show("default", result.default))
    print("  " + _show("calibrated", result.calibrated))
    for choice in json.loads((folder / "fit" / "robot.json").read_text())["held_out"]:
        print(f"  j{choice['joint']}: {choice['why'][:200]}")
    return result


@CALIBRATED_ARMS
def test_never_worse_on_any_joint(calibrated: Calibrated) -> None:
    """The calibrated twin on the held-out run: at most 1.1 × the default twin's RMS or 1.5 ×
    the capture's floor, on every joint."""
    d, c = calibrated.default, calibrated.calibrated
    for j in range(4):
        bound = max(1.1 * d.rms_counts[j], 1.5 * c.floor_counts[j])
        assert c.rms_counts[j] <= bound, (calibrated.name, j + 1, c.rms_counts, d.rms_counts,
                                          c.floor_counts)


@CALIBRATED_ARMS
def test_budget_120_ends_within_130_s(calibrated: Calibrated) -> None:
    """``calibrate --budget-s 120`` (the threshold arm's) ends within 130 s of wall time, its
    robot time within the budget."""
    if ARMS[calibrated.name][2] != 120.0:
        pytest.skip("timed on the arm calibrated with --budget-s 120")
    obs = json.loads((calibrated.fit / "robot.json").read_text())["observations"]
    assert obs["robot_time_s"] <= 120.0
    assert calibrated.wall_s <= 130.0, calibrated.wall_s


@CALIBRATED_ARMS
def test_a_fitted_twin_runs_the_suites_no_slower(calibrated: Calibrated,
                                                 tmp_path: Path) -> None:
    """The accuracy suite's lap on the fitted twin and on the default twin (virtual time),
    interleaved (each first in turn), best of five in CPU time of this thread: the fitted one
    no slower (a fifth of slack: a lap's CPU time too varies with what else the machine runs,
    which the best of five and the alternating order damp)."""
    fitted = calibrated.fit / "robot.toml"
    best = {"default": math.inf, "fitted": math.inf}
    twins = [("default", "fake://"), ("fitted", f"fake://?settings={fitted}")]
    for round_ in range(5):
        for label, port in twins[::1 if round_ % 2 else -1]:
            t0 = time.thread_time()
            try:
                run_virtual(_lap(port, tmp_path / f"{label}.jsonl"))
            except Exception as exc:  # a twin that stalls like its arm may end its lap early
                print(f"  {label} lap: {exc!r}")
            best[label] = min(best[label], time.thread_time() - t0)
    print(f"  lap CPU s: {best}")
    assert best["fitted"] <= 1.2 * best["default"] + 0.02, best


@CALIBRATED_ARMS
def test_what_the_twin_lacks_is_named(calibrated: Calibrated) -> None:
    """The threshold arm whose loss grows during the session (drives warming up): outside the
    twin's family. twin-check fails its calibrated twin, and under a failing joint says where
    its divergence grows, with the capture's times."""
    if calibrated.name != "drift":
        pytest.skip("the arm whose effect the twin lacks")
    c = calibrated.calibrated
    assert c.verdict == "fail", c.to_json()
    named = [d for d in c.diagnoses if d is not None]
    assert named, c.to_json()
    for d in named:
        print(f"  j{d.joint}: " + " / ".join(d.lines()))
    assert any(d.grows and d.grows[0].spans_s and d.worst_part is not None for d in named)


# --- geometry from reference poses on the tracker arm ---------------------------------------

TRACKER_CONFIGS = (
    ((0.5, 0.5, 1.0, 0.5), (0.3, -0.4, 0.4, 0.0), 4.0, -4.0),
    ((0.3, 0.6, 0.8, 0.2), (-0.25, 0.35, -0.3, 0.0), -3.0, 2.5),
    ((1.0, 0.4, 0.6, 0.5), (0.45, 0.2, -0.45, 0.0), 2.0, 3.5),
)
#: What the lab knows of the tracker arm: it carries no load (a simulation without gravity).
WEIGHTLESS = RobotSettings.from_mapping({"emulator": {"physics": {
    "payload_kg": 0.0, **{f"j{j}": {"mass_kg": 0.0} for j in range(1, 5)}}}})


def _tracker_args(config: tuple[Any, ...]) -> list[str]:
    play, offset, a2, a3 = config
    # "=": a value starting with a minus is not an option
    return [f"--play-deg={','.join(map(str, play))}", f"--offset-deg={','.join(map(str, offset))}",
            f"--a2-error-mm={a2}", f"--a3-error-mm={a3}"]


async def _measure(url: str, tracker: tuple[str, int], rng: np.random.Generator
                   ) -> list[ReferencePose]:
    """The twelve hold poses, each joint approached from a side of its own (over the poses
    every joint from both), the tracker's TCP at rest with 0.1 mm of normal noise per
    coordinate (a lab's instrument)."""
    out = []
    async with TrackerStream(*tracker) as stream, Arm.connect(url, reply_timeout_s=5.0) as arm:
        for k, pose in enumerate(HOLD_POSES_RAD):
            approach = [1 if (k >> j) & 1 else -1 for j in range(4)]
            await arm.move_joints([q - a * 0.04 for q, a in zip(pose, approach, strict=True)],
                                  99, timeout_s=30.0)
            await arm.move_joints(pose, 99, timeout_s=30.0)
            await asyncio.sleep(0.3)
            settled = time.monotonic()
            while stream.samples[-1][0] <= settled:
                await asyncio.sleep(0.01)
            xyz = np.asarray(stream.samples[-1][1:4]) + rng.normal(0.0, 1e-4, 3)
            out.append(ReferencePose(list(arm.state.q_rad), [float(v) for v in xyz], 1e-4,
                                     approach))
    return out


@pytest.mark.parametrize("config", TRACKER_CONFIGS, ids=["A", "B", "C"])
def test_twelve_reference_poses_on_a_tracker_arm(config: tuple[Any, ...], tmp_path: Path) -> None:
    """Offsets within 0.05° (as the twin puts the link: the fitted offset plus the prior's
    Hall error) and the lengths a2, a3 within 0.3 mm (d1, d2 of 0 too)."""
    _, offset, a2, a3 = config
    with foreign_arm("tracker", *_tracker_args(config)) as arm:
        assert arm.tracker is not None
        poses = asyncio.run(_measure(arm.url, arm.tracker, np.random.default_rng(5)))
    result = calibrate_reference("tracker", poses, WEIGHTLESS, tmp_path / "robot.toml")
    fitted = {f.key: f for f in result.fitted}
    lengths = {"d1_m": 0.0, "d2_m": 0.0, "a2_m": a2 * 1e-3, "a3_m": a3 * 1e-3}
    shown = {k: round(f.value, 5) for k, f in fitted.items()
             if "geometry" in k or "offset_error" in k or "backlash" in k}
    print(f"\ntracker {config}: {shown}")
    for name, truth in lengths.items():
        f = fitted[f"emulator.physics.geometry_error.{name}"]
        assert f.identified and abs(f.value - truth) <= 0.3e-3, (name, f.value, truth)
    for j in range(3):
        f = fitted[f"emulator.physics.j{j + 1}.offset_error_deg"]
        hall = math.degrees(DEFAULT_ARM.joints[j].hall_error_rad)
        assert f.identified and abs(f.value + hall - offset[j]) <= 0.05, (j + 1, f.value)


def test_touch_off_on_a_tracker_arm(tmp_path: Path) -> None:
    """The tracker arm of configuration A touched off on the fixture of
    ``test_calibrate_reference`` by its scripted operator, whose eyes here are the arm's tracker
    (see the module doc): every length and offset identified, the arm's within three standard
    errors of it. A joint whose play the touches cannot show (its jogs onto the points all end
    the same way: the elbow, lowering the tool onto the fixture) keeps the prior's play, and
    its offset, fitted with it, is said to be: there the link's position on that flank
    (the offset less half the play times the way its jogs went) is what the touches measure,
    and is checked."""
    from test_calibrate_reference import _plate

    rng = np.random.default_rng(13)
    plate, real = _plate(rng)
    _, offset, a2, a3 = TRACKER_CONFIGS[0]

    async def session(url: str, tracker: tuple[str, int]) -> Any:
        async with TrackerStream(*tracker) as stream:
            # the operator's eyes: the newest line of the tracker (each jog rests 0.3 s: the
            # tracker's 100 lines a second have seen it by then)
            eyes = ScriptedOperator(lambda: stream.samples[-1][1:4], real, plate)
            return await calibrate_port(url, WEIGHTLESS, tmp_path / "robot.toml", budget_s=12.0,
                                        reply_timeout_s=5.0, touch=(plate, eyes))

    with foreign_arm("tracker", *_tracker_args(TRACKER_CONFIGS[0])) as arm:
        assert arm.tracker is not None
        result = asyncio.run(session(arm.url, arm.tracker))
    fitted = {f.key: f for f in result.fitted}
    refs = result.observations.references
    print(f"\ntouch-off: {len(refs)} points; " + ", ".join(
        f"{k.rsplit('.', 1)[-1]} {f.value:.5g} ± {f.sigma or 0:.2g}" for k, f in fitted.items()
        if "geometry" in k or "offset_error" in k or "backlash" in k))
    assert len(refs) >= 13
    truths = {"geometry_error.d1_m": 0.0, "geometry_error.d2_m": 0.0,
              "geometry_error.a2_m": a2 * 1e-3, "geometry_error.a3_m": a3 * 1e-3,
              **{f"j{j + 1}.offset_error_deg": offset[j]
                 - math.degrees(DEFAULT_ARM.joints[j].hall_error_rad) for j in range(3)}}
    play = TRACKER_CONFIGS[0][0]
    for key, truth in truths.items():
        f = fitted[f"emulator.physics.{key}"]
        assert f.identified and f.sigma is not None, f
        if "its play not seen" in f.reason:   # the link on the flank its jogs all reach
            j = int(key[1]) - 1
            kept = fitted[f"emulator.physics.j{j + 1}.backlash_deg"]
            assert not kept.identified, kept
            path = refs[0].history_rad or []
            way = math.copysign(1.0, path[-1][j] - path[0][j])   # the motor leads by half the
            truth -= way * play[j] / 2                           # play that way
            value = f.value - way * kept.value / 2
        else:
            value = f.value
        assert abs(value - truth) <= 3.0 * f.sigma, (key, value, f.sigma, truth)
