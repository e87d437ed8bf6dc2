"""The example project of ``docs/pytest.md`` (``examples/pytest-bench/``) passes with ``pytest``:
on the emulator with one arm for the whole session (``armbench_arm_scope = "session"``: the arm
opened once, against once per test with ``--arm-scope function``), over ``socket://`` to an
``armbench emulate --tcp`` process (a real socket, an arm without ground truth: the truth test is
skipped with the reason), and, with the slow tests, after ``pip install "<wheel>[pytest]"`` of
this checkout into a fresh virtual environment. No pytest-asyncio deprecation reminder."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import venv
from pathlib import Path

import pytest
from conftest import shared_wheel
from far_end import Emulator
from test_pytest_plugin import NOT_A_USERS

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "pytest-bench"
UNSET_REMINDER = '"asyncio_default_fixture_loop_scope" is unset'


def _project(tmp_path: Path) -> Path:
    project = tmp_path / "lab-bench-tests"
    shutil.copytree(EXAMPLE, project, ignore=shutil.ignore_patterns("__pycache__"))
    return project


def _pytest(project: Path, *args: str, python: str = sys.executable
            ) -> subprocess.CompletedProcess[str]:
    """``pytest ARGS`` in the project, as its user runs it (every warning shown once; the
    plugins of this environment that ``armbench[pytest]`` does not bring kept out,
    ``test_pytest_plugin.NOT_A_USERS``)."""
    env = {**os.environ, "PYTHONWARNINGS": "default"}
    env.pop("PYTEST_ADDOPTS", None)
    return subprocess.run([python, "-m", "pytest", "-p", "no:cacheprovider", *NOT_A_USERS,
                           "-rs", *args], cwd=project, env=env, capture_output=True, text=True,
                          timeout=600, check=False)


def _counts(done: subprocess.CompletedProcess[str]) -> dict[str, int]:
    last = done.stdout.strip().splitlines()[-1]
    return {word: int(n) for n, word in re.findall(r"(\d+) (passed|failed|skipped|deselected|"
                                                    r"errors?)", last)}


def _opened(done: subprocess.CompletedProcess[str]) -> str:
    found = re.search(r"the arm was opened (\d+) time\(s\) for (\d+) bench test\(s\) "
                      r"\(arm scope (\w+)\)", done.stdout)
    assert found is not None, done.stdout
    return f"{found.group(1)}/{found.group(2)} {found.group(3)}"


def test_every_file_of_the_example_is_shown_in_the_docs() -> None:
    page = (ROOT / "docs" / "pytest.md").read_text(encoding="utf-8")
    files = sorted(p for p in EXAMPLE.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    assert len(files) == 5
    for path in files:
        rel = path.relative_to(EXAMPLE).as_posix()
        assert f"`{rel}`:\n\n```" in page, rel
        assert path.read_text(encoding="utf-8") in page, rel


def test_the_example_on_the_emulator_opens_the_arm_once(tmp_path: Path) -> None:
    project = _project(tmp_path)
    done = _pytest(project)
    assert done.returncode == 0, done.stdout + done.stderr
    assert _counts(done) == {"passed": 7, "skipped": 1}, done.stdout
    assert "for a hardware arm only; fake:// is an emulator" in done.stdout
    assert _opened(done) == "1/6 session"  # one reset for the session
    assert UNSET_REMINDER not in done.stdout + done.stderr

    per_test = _pytest(project, "--arm-scope", "function")
    assert per_test.returncode == 0, per_test.stdout
    assert _opened(per_test) == "6/6 function"

    per_module = _pytest(project, "--arm-scope", "module", "--arm-mismatch", "deselect")
    assert per_module.returncode == 0, per_module.stdout
    assert _counts(per_module) == {"passed": 7, "deselected": 1}, per_module.stdout
    assert _opened(per_module) == "3/6 module"  # test_joints, test_targets, test_truth

    hardware = _pytest(project, "-m", "hardware")
    assert _counts(hardware) == {"skipped": 1, "deselected": 7}, hardware.stdout


def test_over_a_socket_the_truth_test_skips_with_the_reason(tmp_path: Path) -> None:
    project = _project(tmp_path)
    emulator = Emulator(tmp_path, "tcp")
    emulator.start()
    try:
        done = _pytest(project, "--arm-port", emulator.port, "--arm-record", "record")
    finally:
        emulator.stop()
    assert done.returncode == 0, done.stdout + done.stderr
    assert _counts(done) == {"passed": 5, "skipped": 3}, done.stdout
    assert f"no ground truth over {emulator.port}" in done.stdout
    assert "for an emulated arm only" in done.stdout and "for fake:// only" in done.stdout
    assert _opened(done) == "1/6 session"
    assert (project / "record" / "captures" / "session.jsonl").is_file()
    assert "AttributeError" not in done.stdout


def test_no_deprecation_reminder_where_the_project_sets_no_loop_scope(tmp_path: Path) -> None:
    """A project with no pytest-asyncio settings at all: the reminder pytest-asyncio prints
    without the plugin (the control) is gone with it."""
    (tmp_path / "pytest.ini").write_text("[pytest]\n", encoding="utf-8")
    (tmp_path / "test_bench.py").write_text(
        "async def test_moves(arm):\n    await arm.move_joints([0.1, 0, 0, 0], 90)\n",
        encoding="utf-8")
    done = _pytest(tmp_path)
    assert _counts(done) == {"passed": 1}, done.stdout
    assert UNSET_REMINDER not in done.stdout + done.stderr
    without = _pytest(tmp_path, "-p", "no:armbench", "--co")
    assert UNSET_REMINDER in without.stdout + without.stderr


@pytest.mark.slow  # builds the wheel and installs it (~1 min)
def test_the_example_passes_after_installing_the_pytest_extra(
        tmp_path: Path, tmp_path_factory: pytest.TempPathFactory) -> None:
    wheel = shared_wheel(tmp_path_factory, "pure-wheel", pure=True)
    home = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True, system_site_packages=True).create(home)
    python = str(home / "bin" / "python")
    # the extra's requirements as a user's pip resolves them; then the wheel itself into the
    # venv, which the first step takes as satisfied where the environment the venv sees holds
    # armbench of the same version (the README's command installs it)
    for args in ([f"{wheel}[pytest]"], ["--no-deps", "--ignore-installed", str(wheel)]):
        installed = subprocess.run([python, "-m", "pip", "install", "-q", *args],
                                   capture_output=True, text=True, timeout=600, check=False)
        assert installed.returncode == 0, installed.stderr
    project = _project(tmp_path)
    where = subprocess.run([python, "-c", "import armbench; print(armbench.__file__)"],
                           cwd=project, capture_output=True, text=True, check=True)
    assert Path(where.stdout.strip()).is_relative_to(home)
    done = _pytest(project, python=python)
    assert done.returncode == 0, done.stdout + done.stderr
    assert _counts(done) == {"passed": 7, "skipped": 1}, done.stdout
    assert _opened(done) == "1/6 session"
