"""The wheel as users install it, outside the checkout: the README's commands run from a fresh
virtual environment in a folder that is not the checkout, so nothing works only from a checkout
(package data, default configs, templates, the firmware sources).

The venv sees this environment's site-packages for the dependencies (installing them again would
take minutes and test pip, not armbench) and holds the wheel itself, which it imports first."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import venv
from pathlib import Path

import pytest

#: What ``firmware build`` and ``avr://`` need (Debian packages named by ``fakes/avr/harness.py``).
_AVR_TOOLS = ("avr-gcc", "simavr", "gcc")


@pytest.fixture(scope="module")
def installed(armbench_wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The ``bin`` folder of a fresh venv holding the release wheel."""
    home = tmp_path_factory.mktemp("user-venv")
    venv.EnvBuilder(with_pip=True, system_site_packages=True).create(home)
    bin_dir = home / ("Scripts" if os.name == "nt" else "bin")
    # --ignore-installed: the environment the venv sees may hold armbench of the same version
    # (the README's command installs it), which pip would take as already satisfied
    done = subprocess.run([str(bin_dir / "python"), "-m", "pip", "install", "-q", "--no-deps",
                           "--ignore-installed", str(armbench_wheel)], capture_output=True,
                          text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    return bin_dir


def _armbench(bin_dir: Path, *args: str, cwd: Path,
              timeout_s: float = 600) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["XDG_CACHE_HOME"] = str(cwd / "cache")  # the firmware build's output, not the user's
    return subprocess.run([str(bin_dir / "armbench"), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout_s, check=False)


@pytest.mark.slow
def test_the_installed_package_is_the_wheel(installed: Path, tmp_path: Path) -> None:
    done = subprocess.run([str(installed / "python"), "-c",
                           "import armbench, json; print(json.dumps(armbench.__file__))"],
                          cwd=tmp_path, capture_output=True, text=True, check=True)
    assert Path(json.loads(done.stdout)).is_relative_to(installed.parent)


@pytest.mark.slow
def test_the_readme_main_job_runs_from_the_install(installed: Path, tmp_path: Path) -> None:
    """``armbench run`` (every suite on the built-in emulator), then ``report`` and ``compare``
    of the run it wrote, with the packaged default config and the report's templates."""
    run = _armbench(installed, "run", "--out", "first", cwd=tmp_path)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    for name in ("results.json", "report.html", "junit.xml", "capture.mcap"):
        assert (tmp_path / "first" / name).is_file(), name
    report = _armbench(installed, "report", "first", cwd=tmp_path)
    assert report.returncode == 0, report.stderr
    compare = _armbench(installed, "compare", "first/results.json", "first/results.json",
                        cwd=tmp_path)
    assert compare.returncode == 0, compare.stdout + compare.stderr


@pytest.mark.slow
@pytest.mark.parametrize("args", [("--help",), ("--version",), ("fk", "0", "0", "0", "0"),
                                  ("ik", "0.4", "0", "0.6"), ("urdf",),
                                  ("i2c", "scan"), ("move", "--port", "fake://", "0.1", "0", "0",
                                                    "0")])
def test_light_readme_commands_run_from_the_install(installed: Path, tmp_path: Path,
                                                    args: tuple[str, ...]) -> None:
    done = _armbench(installed, *args, cwd=tmp_path, timeout_s=120)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]


@pytest.mark.slow
def test_the_firmware_builds_and_serves_from_the_install(installed: Path, tmp_path: Path) -> None:
    """The firmware's C sources ship in the wheel: ``firmware build`` compiles them, and
    ``emulate --firmware`` serves the four boards in simavr."""
    missing = [t for t in _AVR_TOOLS if shutil.which(t) is None]
    if missing:
        pytest.skip(f"{', '.join(missing)} not installed (Debian: gcc-avr avr-libc simavr "
                    "libsimavr-dev gcc)")
    build = _armbench(installed, "firmware", "build", cwd=tmp_path)
    assert build.returncode == 0, build.stderr[-2000:]
    images = Path(build.stdout.strip().splitlines()[-1])
    assert sorted(p.name for p in images.glob("joint*.elf")) == [
        f"joint{k}.elf" for k in range(1, 5)]
    serve = _armbench(installed, "emulate", "--firmware", str(images), "--tcp", "127.0.0.1:0",
                      "--duration", "2", cwd=tmp_path, timeout_s=180)
    assert serve.returncode == 0, serve.stdout[-2000:] + serve.stderr[-2000:]
    assert "serving the firmware in the loop on socket://127.0.0.1:" in serve.stdout


@pytest.mark.slow
def test_the_ros_message_definitions_ship_in_the_wheel(installed: Path, tmp_path: Path) -> None:
    """What the ROS 2 front end builds (control_msgs, tf2_msgs) is package data of the wheel
    (built without ROS): every definition file it names, and the upstream licences."""
    probe = ("import json\n"
             "from armbench.frontends.ros2_node.msgs_build import INTERFACES, PACKAGES\n"
             "files = [INTERFACES / p.name / f for p in PACKAGES for f in p.files]\n"
             "files += [INTERFACES / p.name / 'LICENSE' for p in PACKAGES]\n"
             "print(json.dumps({'root': str(INTERFACES), 'missing': [str(f) for f in files\n"
             "                  if not f.is_file()], 'count': len(files)}))\n")
    done = subprocess.run([str(installed / "python"), "-c", probe], cwd=tmp_path,
                          capture_output=True, text=True, check=True)
    found = json.loads(done.stdout)
    assert Path(found["root"]).is_relative_to(installed.parent), found  # the wheel's, installed
    assert found["missing"] == [] and found["count"] == 6, found
