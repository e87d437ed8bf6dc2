"""The twin's truth in a twin check's replay (``TwinTruth``: the true joints and TCP at each of
the twin's replies, the TCP divergence's input): what it holds, and that its TCP is one
vectorised forward kinematics per session (a check replays the capture some ten times, each with
the truth where the capture has the arm's; one call per reply was a third of a check's CPU)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

import armbench.bench.calibrate.replay as replay
from armbench.bench.calibrate import load_capture
from armbench.bench.calibrate.replay import TwinTruth, replay_sessions, sessions
from armbench.drivers.host.arm import Arm
from armbench.drivers.model.kinematics import tcp_position
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.clock.vclock import run_virtual
from armbench.fakes.firmware.emulator_settings import actual_robot

SETTINGS = RobotSettings()


async def _moves(capture: Path) -> None:
    """Three joint moves of the default emulated arm, captured."""
    async with Arm.connect("fake://", capture=capture) as arm:
        for target in ((0.4, 0.3, -0.2, 0.5), (-0.3, 0.1, 0.4, -0.4), (0.0, 0.0, 0.0, 0.0)):
            await arm.move_joints(target, 99)


def test_the_twins_truth_is_its_true_tcp_at_each_reply(tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    """Each of the twin's replies has its true joints and their TCP through the twin's actual
    model (its DH lengths and joint offsets, not the nominal ones), computed for all of a
    session's replies at once; a replay without the truth computes none."""
    capture = tmp_path / "capture.jsonl"
    run_virtual(_moves(capture))
    parts = sessions(load_capture(capture, SETTINGS), SETTINGS)
    calls: list[int] = []

    def counted(q: npt.ArrayLike, settings: RobotSettings) -> Any:
        calls.append(len(np.asarray(q)))
        return tcp_position(q, settings)

    monkeypatch.setattr(replay, "tcp_position", counted)
    plain = replay_sessions(parts, SETTINGS, None, None, False)
    assert calls == []
    truth = TwinTruth()
    replies = replay_sessions(parts, SETTINGS, None, truth, False)
    assert replies == plain and len(replies) > 1000
    assert calls == [len(replies)] and len(parts) == 1
    assert len(truth.t_s) == len(truth.q_rad) == len(truth.tcp_m) == len(replies)
    assert truth.t_s == [t for t, _ in replies]
    assert np.array_equal(np.asarray(truth.tcp_m),
                          tcp_position(np.asarray(truth.q_rad), actual_robot(SETTINGS)))
    assert not np.array_equal(np.asarray(truth.tcp_m),
                              tcp_position(np.asarray(truth.q_rad), SETTINGS))
