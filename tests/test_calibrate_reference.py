"""Geometry from what a lab has (``bench/calibrate/reference.py``, ``touch_off.py``): tool
positions measured at known joint angles (``--reference poses.csv``) and plate points the operator
jogs the tool onto (``--touch-off plate.toml``) give the DH lengths, the joint offsets and the
play, with their standard errors.

The arm here is the emulator (virtual time) with hidden lengths, offsets and play; the
measurements are drawn as a lab's instrument would give them (the tool position with 0.1 mm of
normal noise per coordinate; a plate whose points sit 0.02 mm off their drawing, touched to
within 0.15 mm). The touch-off's operator is scripted: it sees where the tool really is (the
emulator's truth stands for a person's eyes on the tool and the plate) and jogs the joints,
through the nominal model, until the tool is on the point. The real-time tests on foreign arms
are in ``tests/test_twin_trust.py``."""

from __future__ import annotations

import io
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import tomli_w

from armbench.bench.calibrate.calibration import calibrate_port, calibrate_reference
from armbench.bench.calibrate.model import ReferencePose
from armbench.bench.calibrate.procedure import HOLD_POSES_RAD
from armbench.bench.calibrate.reference import (
    Plate,
    PlatePoint,
    ReferenceError,
    kinematic_model,
    read_plate,
    read_reference,
    write_reference,
)
from armbench.bench.calibrate.touch_off import Jog
from armbench.bench.runner.truth import EmulatorTruth
from armbench.cli.commands.touch_operator import TerminalOperator, parse_jog
from armbench.cli.main import main
from armbench.drivers.model.kinematics import tcp_position
from armbench.drivers.model.protocol import TICKS_PER_RAD
from armbench.drivers.model.settings import RobotSettings, load_settings
from armbench.fakes.clock.vclock import run_virtual

#: The hidden arm: its lengths (m), offsets (deg) and play (deg) off the default's.
HIDDEN: dict[str, Any] = {"emulator": {"physics": {
    "geometry_error": {"d1_m": 0.0012, "d2_m": -0.0008, "a2_m": 0.0035, "a3_m": -0.0025},
    "j1": {"offset_error_deg": 0.32, "backlash_deg": 0.6},
    "j2": {"offset_error_deg": -0.41, "backlash_deg": 0.45},
    "j3": {"offset_error_deg": 0.27, "backlash_deg": 0.7}}}}
LENGTH_MM = 0.3
OFFSET_DEG = 0.05
TICK_RAD = 1.0 / TICKS_PER_RAD


def _hidden(folder: Path) -> Path:
    path = folder / "hidden.toml"
    path.write_text(tomli_w.dumps(HIDDEN))
    return path


def _check(fitted: dict[str, Any]) -> None:
    """The fitted lengths within 0.3 mm and offsets within 0.05° of the hidden arm's, each
    identified, with a standard error. (The fit's offset is the link's less the reported angle
    less the prior's Hall error, which the hidden arm shares: the default's.)"""
    physics = HIDDEN["emulator"]["physics"]
    for name, value in physics["geometry_error"].items():
        f = fitted[f"emulator.physics.geometry_error.{name}"]
        assert f.identified and f.sigma is not None, f
        assert abs(f.value - value) * 1e3 <= LENGTH_MM, (name, f.value, value)
    for j in (1, 2, 3):
        f = fitted[f"emulator.physics.j{j}.offset_error_deg"]
        assert f.identified and f.sigma is not None, f
        assert abs(f.value - physics[f"j{j}"]["offset_error_deg"]) <= OFFSET_DEG, (j, f.value)


def _poses(rng: np.random.Generator) -> list[ReferencePose]:
    """The twelve hold poses of the procedure, each joint approached from a side of its own
    (every joint from both sides over the poses), the tool's true position (the hidden arm's
    links through its actual model, the play on the side of the approach; the prior's gravity
    and deflection as the emulator has them: the same masses) with 0.1 mm of noise."""
    from armbench.bench.calibrate.fit import base_physics
    from armbench.fakes.firmware.emulator_settings import actual_robot
    from armbench.fakes.twin.physics import Mechanism

    hidden = RobotSettings.from_mapping(HIDDEN)
    physics = base_physics(hidden)
    actual = actual_robot(hidden)
    mech = Mechanism(physics, hidden, lambda: [0.0] * 4)
    out = []
    for k, q in enumerate(HOLD_POSES_RAD):
        approach = [1 if (k >> j) & 1 else -1 for j in range(4)]
        tau = mech.gravity_nm(q)
        link = []
        for j in range(4):
            p = physics.joints[j]
            side = math.copysign(1, tau[j]) if abs(tau[j]) > p.hold_nm else -approach[j]
            link.append(q[j] + p.hall_error_rad + side * p.backlash_rad / 2
                        + tau[j] / p.stiffness_nm_per_rad)
        xyz = tcp_position(link, actual) + rng.normal(0.0, 1e-4, 3)
        out.append(ReferencePose(list(q), [float(v) for v in xyz], 1e-4, approach))
    return out


def test_twelve_reference_poses_give_the_geometry(tmp_path: Path) -> None:
    """Twelve poses with 0.1 mm of noise, written as a reference file and read back: lengths
    within 0.3 mm, offsets within 0.05°, the plays within 0.05° too; the settings file holds
    them with their standard errors and its header says what is still the prior's."""
    path = tmp_path / "poses.csv"
    write_reference(_poses(np.random.default_rng(7)), path)
    poses = read_reference(path)
    assert len(poses) == 12
    result = calibrate_reference(str(path), poses, RobotSettings(), tmp_path / "robot.toml")
    fitted = {f.key: f for f in result.fitted}
    _check(fitted)
    for j in (1, 2, 3):
        f = fitted[f"emulator.physics.j{j}.backlash_deg"]
        assert abs(f.value - HIDDEN["emulator"]["physics"][f"j{j}"]["backlash_deg"]) <= 0.05, f
    text = (tmp_path / "robot.toml").read_text()
    assert "fitted from 12 measured tool positions" in text
    assert "emulator.physics.geometry_error.a2_m" in load_settings(tmp_path / "robot.toml"
                                                                   ).uncertainty


@pytest.mark.parametrize(("line", "problem"), [
    ("1,2,3,4,++++,1,2,3,0.1", None),
    ("1,2,x,4,++++,1,2,3,0.1", "'x' is not a number"),
    ("1,2,3,4,+*++,1,2,3,0.1", "approach '+*++' is not four of + and -"),
    ("1,2,3,4,++++,1,2,3,0", "sigma_mm 0 is not > 0"),
    ("1,2,3,4,++++,1,2,3", "8 cells, the header names 9"),
])
def test_a_bad_reference_file_names_its_line(tmp_path: Path, line: str,
                                             problem: str | None) -> None:
    path = tmp_path / "poses.csv"
    path.write_text("# measured with a caliper\nq1_deg,q2_deg,q3_deg,q4_deg,approach,x_mm,y_mm,"
                    f"z_mm,sigma_mm\n{line}\n")
    if problem is None:
        assert read_reference(path)[0].approach == [1, 1, 1, 1]
        return
    with pytest.raises(ReferenceError, match="line 3") as err:
        read_reference(path)
    assert problem in str(err.value)


def test_the_command_line_reads_a_reference_file_alone(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """``armbench calibrate --reference poses.csv --out DIR``: no port, no capture; a file that
    cannot be used is bad input (exit status 2, nothing written)."""
    path = tmp_path / "poses.csv"
    write_reference(_poses(np.random.default_rng(3)), path)
    assert main(["calibrate", "--reference", str(path), "--out", str(tmp_path / "cal")]) == 0
    assert "geometry_error.a2_m" in capsys.readouterr().out
    bad = tmp_path / "bad.csv"
    bad.write_text("q1_deg,q2_deg\n1,2\n")
    assert main(["calibrate", "--reference", str(bad), "--out", str(tmp_path / "bad")]) == 2
    assert "the header lacks" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()
    assert main(["calibrate", "--touch-off", str(bad), "--out", str(tmp_path / "t")]) == 2
    assert "--touch-off needs --port" in capsys.readouterr().err


#: The touch-off fixture's points (x, z; m) in front of the arm, each at y = ±0.16 m: steps at
#: several heights (a flat plate alone leaves the elbow's offsets and lengths nearly one
#: unknown: its points differ little in the arm's configuration).
FIXTURE_XZ_M = ((0.45, 0.60), (0.40, 0.70), (0.35, 0.80), (0.30, 0.88), (0.46, 0.66),
                (0.25, 0.90), (0.18, 0.92), (0.45, 0.72))


def _plate(rng: np.random.Generator) -> tuple[Plate, list[tuple[float, float, float]]]:
    """Sixteen points of the fixture as drawn, and where each really is (0.02 mm off per
    coordinate); touched to within 0.15 mm (a wire tick of a joint moves the tool 0.04-0.06
    mm, and where a jog stops scatters by the stick-slip band: about 0.1 mm at a jog's
    speed)."""
    points: list[PlatePoint] = []
    real: list[tuple[float, float, float]] = []
    for x, z in FIXTURE_XZ_M:
        for y in (-0.16, 0.16):
            points.append(PlatePoint(f"P{len(points) + 1}", (x, y, z)))
            dx, dy, dz = (float(v) for v in rng.normal(0, 2e-5, 3))
            real.append((x + dx, y + dy, z + dz))
    return Plate(tuple(points), 2e-5, 1.5e-4), real


class ScriptedOperator:
    """The operator, scripted: it sees where the tool really is (``eyes``: the emulator's truth
    or a tracker stands for a person's eyes) and jogs the joints through the nominal model's
    Jacobian, each time 60 % of the way it predicts (so each joint comes from one side and the
    play stays taken up, as a careful operator approaches a point), the single tick that gets
    nearest once that is less than one, until the tool is within the plate's ``touch_m`` of
    where the point really is (as near as a tick's jogs get it: where in that it stops is the
    touch's error); after 80 jogs it leaves the point out."""

    def __init__(self, eyes: Callable[[], Sequence[float]],
                 real: list[tuple[float, float, float]], plate: Plate) -> None:
        self.eyes, self.real, self.plate = eyes, real, plate

    async def touch(self, point: PlatePoint, jog: Jog) -> bool:
        target = np.asarray(self.real[self.plate.points.index(point)])
        within = self.plate.touch_m
        settings = jog.arm.settings
        for _ in range(80):
            error = target - np.asarray(self.eyes())
            if np.linalg.norm(error) <= within:
                return True
            q = np.asarray(jog.q_rad)
            jac = np.zeros((3, 3))
            for j in range(3):
                dq = np.zeros(4)
                dq[j] = 1e-5
                jac[:, j] = (tcp_position(q + dq, settings) - tcp_position(q, settings)) / 1e-5
            step = 0.6 * np.linalg.lstsq(jac, error, rcond=None)[0]
            if np.max(np.abs(step)) < TICK_RAD:  # the single tick that gets nearest
                ticks = [s * TICK_RAD * np.eye(3)[j] for j in range(3) for s in (1, -1)]
                step = min(ticks, key=lambda d: float(np.linalg.norm(error - jac @ d)))
            await jog.joints([*step, 0.0])
        return False


def test_touch_off_gives_the_geometry(tmp_path: Path) -> None:
    """The operator touches the fixture's sixteen points (scripted, see the module doc; one it
    cannot get within its touch of is left out): every length and offset identified, the
    hidden arm's within three standard errors of it, and those a useful calibration's (lengths
    to 0.5 mm, offsets to 0.12°: the fixture's points differ less in the arm's configuration
    than the reference poses do); the poses carry the jogs' path (the play operator replays
    it; the play itself is the approaches' here, the emulator's truth measures it)."""
    rng = np.random.default_rng(11)
    plate, real = _plate(rng)
    hidden = _hidden(tmp_path)
    operators: list[ScriptedOperator] = []

    class Lazy:
        """Binds the scripted operator to the arm's truth once the procedure has the arm."""

        async def touch(self, point: PlatePoint, jog: Jog) -> bool:
            if not operators:
                eyes = EmulatorTruth(jog.arm).true_position_m
                operators.append(ScriptedOperator(lambda: eyes() or (0.0, 0.0, 0.0), real,
                                                  plate))
            return await operators[0].touch(point, jog)

    result = run_virtual(calibrate_port(f"fake://?settings={hidden}", RobotSettings(),
                                        tmp_path / "robot.toml", budget_s=15.0,
                                        touch=(plate, Lazy())))
    refs = result.observations.references
    assert len(refs) >= 13 and all(r.history_rad for r in refs), len(refs)
    fitted = {f.key: f for f in result.fitted}
    physics = HIDDEN["emulator"]["physics"]
    truths = {**{f"emulator.physics.geometry_error.{k}": v
                 for k, v in physics["geometry_error"].items()},
              **{f"emulator.physics.j{j}.offset_error_deg": physics[f"j{j}"]["offset_error_deg"]
                 for j in (1, 2, 3)}}
    for key, truth in truths.items():
        f = fitted[key]
        assert f.identified and f.sigma is not None, f
        assert "touched plate points" in f.reason, f
        assert f.covers(truth, k=3.0), (key, f.value, f.sigma, truth)
        assert f.sigma <= (0.5e-3 if key.endswith("_m") else 0.12), f


def test_the_terminal_operator_reads_jogs(tmp_path: Path) -> None:
    """The terminal's lines: a tool or joint jog, ``ok``, ``skip``; a line that is none says
    why and reads on; the end of the input leaves the point out."""
    assert parse_jog("x +0.5") == ("tool", 0, 0.0005)
    assert parse_jog("j2 -0.1") == ("joint", 1, math.radians(-0.1))
    assert parse_jog("ok") == "ok" and parse_jog("skip") == "skip"
    assert str(parse_jog("j5 1")).startswith("?") and str(parse_jog("z 500")).startswith("?")
    plate = Plate((PlatePoint("A", (0.45, 0.0, 0.62)),) * 4, 2e-5, 5e-5)
    lines = io.StringIO("j9 1\nz -5\nok\nskip\n")
    said = io.StringIO()

    async def session() -> list[ReferencePose]:
        from armbench.bench.calibrate.touch_off import touch_off
        from armbench.drivers.host.arm import Arm

        async with Arm.connect("fake://") as arm:
            return await touch_off(arm, plate, TerminalOperator(lines, said))

    refs = run_virtual(session())
    assert len(refs) == 1                       # ok, skip, then the input ended: left out
    assert len(refs[0].history_rad or []) == 3  # after the approach, after the jog, the reading
    assert "'j9'" in said.getvalue() and "joints now" in said.getvalue()


def test_a_plate_file(tmp_path: Path) -> None:
    path = tmp_path / "plate.toml"
    path.write_text("[plate]\nsigma_mm = 0.02\ntouch_mm = 0.05\n" + "".join(
        f'[[plate.points]]\nname = "P{k}"\nxyz_mm = [{400 + k}, 0, 300]\n' for k in range(4)))
    plate = read_plate(path)
    assert len(plate.points) == 4 and plate.points[1].xyz_m == pytest.approx((0.401, 0, 0.3))
    assert plate.point_sigma_m == pytest.approx(math.hypot(2e-5, 5e-5))
    path.write_text("[plate]\nsigma_mm = 0.02\ntouch_mm = 0.05\n")
    with pytest.raises(ReferenceError, match="at least 4"):
        read_plate(path)


def test_the_fit_model_is_the_forward_kinematics() -> None:
    """Length and offset errors enter as the emulator's actual model has them."""
    from armbench.fakes.firmware.emulator_settings import actual_robot

    hidden = RobotSettings.from_mapping(HIDDEN)
    physics = HIDDEN["emulator"]["physics"]
    theta = [*physics["geometry_error"].values(),
             *(math.radians(physics[f"j{j}"]["offset_error_deg"]) for j in (1, 2, 3))]
    model = kinematic_model(RobotSettings(), theta)
    actual = actual_robot(hidden)
    q = HOLD_POSES_RAD[3]
    # the actual model also moves joint 4's offset (0 here) and the tool offset (0)
    assert tcp_position(q, model) == pytest.approx(tcp_position(q, actual), abs=1e-9)
