"""``armbench fk`` / ``armbench ik`` through ``armbench.cli.main.main``: output, exit status,
errors."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from armbench.cli.main import main
from armbench.drivers.model.kinematics import fk_dh, tcp_position
from armbench.drivers.model.settings import RobotSettings

DEFAULT = RobotSettings()
NUMBER = re.compile(r"[-+]?\d+\.\d+")


def _run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


def _json(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, Any]:
    status, out, err = _run(capsys, *argv, "--json")
    assert err == ""
    assert out.count("\n") == 1
    return status, json.loads(out)


def _line(out: str, start: str) -> str:
    lines = [ln for ln in out.splitlines() if ln.strip().startswith(start)]
    assert len(lines) == 1, out
    return lines[0]


# ---------------------------------------------------------------------------------- fk


def test_fk_zero_pose_text(capsys: pytest.CaptureFixture[str]) -> None:
    status, out, err = _run(capsys, "fk", "0", "0", "0", "0")
    assert (status, err) == (0, "")
    tcp = _line(out, "TCP:")
    assert "x = 0.000 mm, y = -9.000 mm, z = 1020.000 mm" in tcp
    assert [float(v) for v in NUMBER.findall(tcp)[-3:]] == [0.0, -0.009, 1.02]
    rows = [[float(v) for v in NUMBER.findall(ln)] for ln in out.splitlines()
            if ln.startswith("  [")]
    np.testing.assert_allclose(rows, fk_dh([0, math.pi / 2, 0, 0], DEFAULT.geometry), atol=1e-9)


def test_fk_dh_angles_and_gripper_offset(capsys: pytest.CaptureFixture[str]) -> None:
    status, out, _ = _run(capsys, "fk", "--dh", "0", "0", "0", "0")
    assert status == 0
    assert "x = 630.000 mm, y = -9.000 mm, z = 390.000 mm" in _line(out, "TCP:")
    status, out, _ = _run(capsys, "fk", "0", "0", "0", "0", "--d4", "0.1")
    assert status == 0
    assert "x = 100.000 mm, y = -9.000 mm, z = 1020.000 mm" in _line(out, "TCP:")


@pytest.mark.parametrize("argv", [
    ("fk", "0.1", "-0.2", "0", "-1.5", "--json"),
    ("fk", "--json", "--", "0.1", "-0.2", "0", "-1.5"),
    ("fk", "0.1", "-2e-1", "0", "-15E-1", "--json"),
    ("fk", "--json", "1e-1", "-.2", "-0", "-1.5"),
])
def test_fk_negative_positionals(capsys: pytest.CaptureFixture[str], argv: tuple[str, ...]) -> None:
    status, out, err = _run(capsys, *argv)
    # joint 4 at -1.5 rad is outside its -30..120° limits: a warning, no error
    assert err == ("armbench fk: warning: joint 4 at -1.5 rad (-85.9437°) is outside its limits "
                   "-30..120°\n")
    data = json.loads(out)
    assert status == 0
    q = [0.1, -0.2, 0.0, -1.5]
    assert data["q_protocol_rad"] == q
    np.testing.assert_allclose(data["tcp_m"], tcp_position(q, DEFAULT), atol=1e-12)
    np.testing.assert_allclose(data["tcp_mm"], np.asarray(data["tcp_m"]) * 1000, atol=1e-9)
    np.testing.assert_allclose(data["pose"], fk_dh(data["theta_dh_rad"], DEFAULT.geometry),
                               atol=1e-12)
    assert data["convention"] == "protocol"


def test_fk_settings_file(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    path.write_text("[geometry]\nd1_m = 0.5\nd4_m = 0.02\n")
    status, data = _json(capsys, "fk", "0", "0", "0", "0", "--settings", str(path))
    assert status == 0
    np.testing.assert_allclose(data["tcp_m"], [0.02, -0.009, 1.13], atol=1e-12)
    assert data["d4_m"] == 0.02


@pytest.mark.parametrize(("argv", "message"), [
    (("fk", "1", "2", "3"), "required"),
    (("fk", "1", "2", "3", "x"), "invalid float"),
    (("fk", "1", "2", "3", "4", "5"), "unrecognized"),
    (("ik", "0.1", "0.2"), "required"),
    (("ik", "0.1", "0.2", "0.3", "--roll"), "expected one argument"),
])
def test_bad_arguments_exit_2(capsys: pytest.CaptureFixture[str], argv: tuple[str, ...],
                              message: str) -> None:
    with pytest.raises(SystemExit) as info:
        main(list(argv))
    assert info.value.code == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert message in err


@pytest.mark.parametrize(("argv", "message"), [
    (("fk", "0", "nan", "0", "0"), "finite"),
    (("fk", "0", "0", "0", "0", "--d4", "inf"), "--d4"),
    (("fk", "0", "0", "0", "0", "--settings", "/nonexistent/robot.toml"), "does not exist"),
    (("ik", "0.4", "0", "0.6", "--settings", "/nonexistent/robot.toml"), "does not exist"),
    (("ik", "0.4", "0", "0.6", "--roll", "nan"), "roll"),
])
def test_user_errors_one_line_exit_2(capsys: pytest.CaptureFixture[str], argv: tuple[str, ...],
                                     message: str) -> None:
    status, out, err = _run(capsys, *argv)
    assert status == 2
    assert out == ""
    assert err.count("\n") == 1 and err.startswith(f"armbench {argv[0]}: error:")
    assert message in err


# ---------------------------------------------------------------------------------- ik


def test_ik_text_lists_every_branch_and_limits(capsys: pytest.CaptureFixture[str]) -> None:
    status, out, err = _run(capsys, "ik", "0.4", "-0.1", "0.6")
    assert (status, err) == (0, "")
    assert "4 solution(s)" in out
    front_up = _line(out, "front-up")
    assert front_up.endswith("within limits")
    q = [float(v) for v in NUMBER.findall(front_up)]
    np.testing.assert_allclose(tcp_position(q, DEFAULT), [0.4, -0.1, 0.6], atol=1e-6)
    back_up = _line(out, "back-up")
    assert "OUT OF LIMITS" in back_up
    assert "j1 = 2.874784 rad (164.71°) above upper limit 2.443461 rad (140.00°)" in back_up
    assert "j3 = 1.511507 rad (86.60°) above upper limit" in back_up


def test_ik_dh_prints_dh_angles(capsys: pytest.CaptureFixture[str]) -> None:
    _, out_q, _ = _run(capsys, "ik", "0.4", "-0.1", "0.6")
    status, out_dh, _ = _run(capsys, "ik", "0.4", "-0.1", "0.6", "--dh")
    assert status == 0
    assert "DH θ1..θ4" in out_dh
    q = [float(v) for v in NUMBER.findall(_line(out_q, "front-up"))[:4]]
    th = [float(v) for v in NUMBER.findall(_line(out_dh, "front-up"))[:4]]
    assert th[0] == q[0] and th[2] == q[2]
    assert math.isclose(th[1], q[1] + math.pi / 2, abs_tol=2e-6)


def test_ik_json_round_trips_and_negative_coordinates(capsys: pytest.CaptureFixture[str]) -> None:
    status, data = _json(capsys, "ik", "-0.4", "-0.1", "0.6", "--roll", "-0.3", "--d4", "0.05")
    assert data["target_m"] == [-0.4, -0.1, 0.6]
    assert data["roll_rad"] == -0.3 and data["d4_m"] == 0.05
    sols = data["solutions"]
    assert [s["branch"] for s in sols] == ["front-up", "front-down", "back-up", "back-down"]
    settings = DEFAULT.with_d4(0.05)
    for s in sols:
        np.testing.assert_allclose(tcp_position(s["q_protocol_rad"], settings),
                                   [-0.4, -0.1, 0.6], atol=1e-9)
        assert math.isclose(s["q_protocol_rad"][3], -0.3)
        assert s["within_limits"] == (not s["violations"])
        for v in s["violations"]:
            assert v["joint"] in ("j1", "j2", "j3", "j4") and v["bound"] in ("lower", "upper")
    assert status == (0 if any(s["within_limits"] for s in sols) else 1)


def test_ik_no_solution_within_limits_exits_1(capsys: pytest.CaptureFixture[str]) -> None:
    status, out, err = _run(capsys, "ik", "0.5", "0.1", "0.4")
    assert (status, err) == (1, "")
    assert "no solution is inside the joint limits" in out
    assert "j2 = -1.020891 rad (-58.49°) below lower limit -0.785398 rad (-45.00°)" in out


def test_ik_aliases_shown(capsys: pytest.CaptureFixture[str]) -> None:
    status, out, _ = _run(capsys, "ik", "0", "-0.009", "1.02")
    assert status == 0
    assert "1 solution(s)" in out
    assert "coincides with front-down, back-up, back-down" in out


@pytest.mark.parametrize(("argv", "reason"), [
    (("ik", "2", "0", "0"), "beyond the reach"),
    (("ik", "--", "-2", "0", "0"), "beyond the reach"),
    (("ik", "0", "0", "0.8"), "cylinder"),
    (("ik", "0", "0", "nan"), "finite"),
])
def test_ik_unreachable_exit_2(capsys: pytest.CaptureFixture[str], argv: tuple[str, ...],
                               reason: str) -> None:
    status, out, err = _run(capsys, *argv)
    assert status == 2
    assert out == ""
    assert err.startswith("armbench ik: error: target (") and err.count("\n") == 1
    assert "unreachable" in err and reason in err


def test_fk_deg_and_the_joint_limit_warning(capsys: pytest.CaptureFixture[str]) -> None:
    """``fk 90 0 0 0`` took 90 rad silently; now it warns (and names --deg), and ``--deg``
    gives the pose of 90° with no warning."""
    assert main(["fk", "90", "0", "0", "0", "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["within_limits"] is False
    assert "joint 1 at 90 rad" in captured.err and "--deg" in captured.err
    assert main(["fk", "90", "0", "0", "0", "--deg", "--json"]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert captured.err == "" and data["within_limits"] is True
    assert data["q_protocol_rad"] == pytest.approx([math.pi / 2, 0, 0, 0])
    assert main(["fk", "1.5707963267948966", "0", "0", "0", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["tcp_m"] == pytest.approx(data["tcp_m"])
