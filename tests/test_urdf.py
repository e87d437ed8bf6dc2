"""``armbench urdf``: the URDF loaded by an independent library (``yourdfpy``) has the forward
kinematics of armbench's DH model, to 1e-9 m, at random joint angles inside the limits, and what a
planner needs: limits from the settings, law (12) and the twin, collision and inertial elements,
a ``<ros2_control>`` block."""

from __future__ import annotations

import io
import math
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yourdfpy

from armbench.cli.main import main
from armbench.drivers.host.motion import joint_speed_rad_s
from armbench.drivers.model.kinematics import fk
from armbench.drivers.model.protocol import MAX_DUTY
from armbench.drivers.model.settings import Geometry, JointSettings, RobotSettings
from armbench.drivers.model.urdf import NOMINAL_EFFORT_NM, robot_urdf
from armbench.fakes.firmware.emulator_settings import emulator_settings
from armbench.frontends.ros2_node.state_topics import node_urdf

OTHER = RobotSettings(
    geometry=Geometry(d1_m=0.42, d2_m=-0.012, a2_m=0.33, a3_m=0.29, d4_m=0.07),
    joints=(JointSettings("j1", 50.0, -2.0, 2.2, 0.3, -1, -0.1),
            JointSettings("j2", 50.0, -0.8, 1.1, math.pi / 2, 1, 0.0, i2c_address=0x10),
            JointSettings("j3", 38.0, -1.5, 1.0, -0.2, -1, 0.0, i2c_address=0x11),
            JointSettings("j4", 28.0, -0.5, 2.0, 0.1, 1, 0.0, i2c_address=0x12)))


def _load(text: str) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(io.StringIO(text), build_scene_graph=True, load_meshes=False)


@pytest.mark.parametrize("settings", [RobotSettings(), OTHER], ids=["default", "other"])
def test_urdf_forward_kinematics_matches_dh(settings: RobotSettings) -> None:
    robot = _load(robot_urdf(settings))
    assert robot.validate()
    joints = robot.actuated_joints
    assert [j.name for j in joints] == ["j1", "j2", "j3", "j4"]
    for joint, js in zip(joints, settings.joints, strict=True):
        assert joint.type == "revolute"
        assert joint.limit.lower == js.lower_rad and joint.limit.upper == js.upper_rad
    rng = np.random.default_rng(16)
    worst = 0.0
    for _ in range(200):
        q = [rng.uniform(j.lower_rad, j.upper_rad) for j in settings.joints]
        robot.update_cfg(dict(zip(["j1", "j2", "j3", "j4"], q, strict=True)))
        pose = robot.get_transform("link4", "base_link")
        worst = max(worst, float(np.abs(pose - fk(q, settings)).max()))
    assert worst < 1e-9


def test_urdf_command_writes_the_file_or_prints_it(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    settings_file = tmp_path / "robot.toml"
    settings_file.write_text("[geometry]\nd4_m = 0.05\n")
    out = tmp_path / "arm.urdf"
    assert main(["urdf", "--settings", str(settings_file), "--out", str(out)]) == 0
    assert out.read_text() == node_urdf(RobotSettings().with_d4(0.05))
    assert main(["urdf"]) == 0
    assert capsys.readouterr().out == node_urdf(RobotSettings())
    assert main(["urdf", "--out", str(tmp_path / "missing" / "x.urdf")]) == 2
    assert "--out" in capsys.readouterr().err


def test_urdf_command_from_the_shell() -> None:
    done = subprocess.run([sys.executable, "-m", "armbench", "urdf"], capture_output=True,
                          text=True, check=True)
    assert _load(done.stdout).robot.name == "robolink"


def test_limits_a_planner_can_use_come_from_law_12_and_the_twin() -> None:
    """Velocity: the joint's speed at the fastest duty by law (12) (the driver's own function);
    effort: the twin's pull-out torque through the gear (a nominal one without a twin)."""
    settings = RobotSettings()
    physics = emulator_settings(settings).physics
    assert physics is not None
    robot = _load(node_urdf(settings))
    for joint, js, twin in zip(robot.actuated_joints, settings.joints, physics.joints,
                               strict=True):
        assert joint.limit.velocity == pytest.approx(joint_speed_rad_s(MAX_DUTY,
                                                                       js.steps_per_rad))
        assert joint.limit.effort == pytest.approx(twin.pullout_nm * js.gear_ratio
                                                   * twin.efficiency)
    bare = _load(robot_urdf(settings))  # the capture's: no twin
    assert {j.limit.effort for j in bare.actuated_joints} == {NOMINAL_EFFORT_NM}


def test_every_moving_link_has_collision_and_a_positive_inertia() -> None:
    settings = RobotSettings()
    physics = emulator_settings(settings).physics
    assert physics is not None
    robot = _load(node_urdf(settings))
    assert robot.validate()
    shaped = 0
    for i in range(1, 5):
        link = robot.link_map[f"link{i}_root"]
        assert len(link.collisions) == len(link.visuals)  # a collision for each shape drawn
        shaped += bool(link.collisions)
        assert link.inertial is not None and link.inertial.mass > 0
        assert np.all(np.linalg.eigvalsh(link.inertial.inertia) > 0)
    assert shaped == 3  # link 4 has no length without a gripper offset (d4 = 0)
    assert robot.link_map["link2_root"].inertial.mass == physics.joints[1].mass_kg


def test_the_ros2_control_block_names_the_joints_and_their_interfaces() -> None:
    settings = OTHER
    root = ET.fromstring(robot_urdf(settings))
    (block,) = root.findall("ros2_control")
    joints = block.findall("joint")
    assert [j.get("name") for j in joints] == [j.name for j in settings.joints]
    for element, js in zip(joints, settings.joints, strict=True):
        (command,) = element.findall("command_interface")
        assert command.get("name") == "position"
        limits = {p.get("name"): float(p.text or "nan") for p in command.findall("param")}
        assert limits == {"min": js.lower_rad, "max": js.upper_rad}
        assert [s.get("name") for s in element.findall("state_interface")] == ["position",
                                                                               "velocity"]
