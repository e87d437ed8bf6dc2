"""The ``joints`` suite: ISO 230-2 bidirectional positioning per joint, its figures against hand
computations, on the emulator (fake://, virtual time) with and without truth, and through
``armbench run joints``."""

from __future__ import annotations

import json
import math
import random
from pathlib import Path
from typing import Any

import pytest

from armbench.bench.runner.truth import EmulatorTruth
from armbench.bench.suites import load_suite, suite_names
from armbench.bench.suites.base import SuiteContext
from armbench.bench.suites.joints import JointsSuite, joint_figures
from armbench.cli.main import main
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.twin.physics import DEFAULT_JOINT_PHYSICS
from armbench.metrics import MetricsInputError
from armbench.metrics.iso230 import axis_positioning
from armbench.record import Measurement, Trial
from armbench.record.limits import LimitsConfig

SETTINGS = RobotSettings()


def test_iso230_hand_computed() -> None:
    """Two targets, three approaches each way: the figures by the standard's formulas."""
    up = [[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]]
    down = [[-1.0, -1.0, -1.0], [4.0, 5.0, 6.0]]
    f = axis_positioning([0.0, 10.0], up, down)
    # means ↑ 2, 0; ↓ −1, 5; s ↑ 1, 0; ↓ 0, 1; B = 3, −5
    assert f.reversal == 5.0 and f.mean_reversal == -1.0
    assert f.repeatability == max(2 + 0 + 3, 4, 0, 0 + 2 + 5, 0, 4)
    assert f.systematic == 5.0 - (-1.0)
    assert f.accuracy == max(2 + 2, -1 + 0, 0 + 0, 5 + 2) - min(2 - 2, -1 - 0, 0 - 0, 5 - 2)
    with pytest.raises(MetricsInputError):
        axis_positioning([0.0], [[1.0]], [[1.0, 2.0]])


def test_registered() -> None:
    assert "joints" in suite_names()
    assert isinstance(load_suite("joints"), JointsSuite)


def test_validation_names_the_field() -> None:
    suite = JointsSuite()
    with pytest.raises(SettingsError, match=r"suites\.joints\.joints"):
        suite.params(SETTINGS, {"joints": [5]})
    with pytest.raises(SettingsError, match=r"suites\.joints\.overtravel_rad"):
        suite.params(SETTINGS, {"targets_frac": [0.0, 0.5], "overtravel_rad": 0.1})
    with pytest.raises(SettingsError, match=r"suites\.joints\.cycles"):
        suite.params(SETTINGS, {"cycles": 1})


def _run(overrides: dict[str, Any], *, truth: bool) -> tuple[list[Trial], dict[str, Measurement]]:
    suite = JointsSuite()
    params = suite.params(SETTINGS, overrides)

    async def go() -> tuple[list[Trial], list[Measurement]]:
        async with Arm.connect("fake://") as arm:
            ctx = SuiteContext(arm=arm, settings=SETTINGS, limits=LimitsConfig(), params=params,
                               rng=random.Random(0),
                               truth=EmulatorTruth(arm, SETTINGS) if truth else None)
            trials = [await suite.run_trial(ctx, i, tp)
                      for i, tp in enumerate(suite.plan(params))]
            return trials, suite.summarize(ctx, trials)

    trials, ms = run_virtual(go())
    return trials, {m.name: m for m in ms}


def test_reversal_is_the_play_on_an_unloaded_joint() -> None:
    """Joint 1 turns about the vertical: no gravity holds its play, so the true reversal error is
    the gear play less the stick-slip overshoot (default arm: 0.25° less up to 0.03°); the
    encoder, on the motor, does not see it (a few counts of deadband)."""
    trials, ms = _run({"joints": [1], "cycles": 3, "targets_frac": [0.4, 0.5, 0.6]},
                      truth=True)
    assert trials[0].status == "done" and len(trials[0].samples) == 3 * 2 * 3
    p = DEFAULT_JOINT_PHYSICS[0]
    b = ms["joints.j1.true_reversal_mrad"].value / 1000
    assert p.backlash_rad - p.stick_rad - 1e-4 <= b <= p.backlash_rad + 1e-4
    assert ms["joints.j1.reversal_mrad"].value < 0.5
    assert ms["joints.j1.true_mean_reversal_mrad"].value < 0  # moving up, the link lags
    for name in ("accuracy_mrad", "repeatability_mrad", "systematic_mrad"):
        assert math.isfinite(ms[f"joints.j1.{name}"].value)


def test_without_truth_only_reported_figures() -> None:
    trials, ms = _run({"joints": [4], "cycles": 2, "targets_frac": [0.3, 0.6]}, truth=False)
    assert "joints.j4.accuracy_mrad" in ms
    assert not any(name.startswith("joints.j4.true_") for name in ms)
    assert joint_figures(trials[0].samples, "true_rad") == {}


def test_armbench_run_joints(tmp_path: Path) -> None:
    out = tmp_path / "run"
    config = tmp_path / "bench.toml"
    config.write_text('spec_version = "armbench-limits/1"\n[suites.joints]\njoints = [2]\n'
                      "cycles = 2\ntargets_frac = [0.3, 0.7]\n")
    assert main(["run", "joints", "--config", str(config), "--out", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    names = {m["name"] for m in results["suites"]["joints"]["measurements"]}
    assert {"joints.j2.accuracy_mrad", "joints.j2.true_reversal_mrad"} <= names
