"""The pytest plugin is a good guest: with armbench installed, pytest in another project starts and
runs as before, even where pytest-asyncio (a test extra of armbench) is not installed.

As a new user would: a fresh virtual environment with pytest and the armbench wheel (no test
extras), and an unrelated folder with a trivial test."""

from __future__ import annotations

import subprocess
import venv
from pathlib import Path

import pytest

TRIVIAL = "def test_one_plus_one():\n    assert 1 + 1 == 2\n"
WANTS_ARM = "async def test_uses_the_arm(arm):\n    pass\n"


@pytest.fixture(scope="module")
def guest_env(armbench_wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The python of a fresh venv holding pytest and armbench (its dependencies left out: the
    plugin must not need them to start)."""
    home = tmp_path_factory.mktemp("venv")
    venv.EnvBuilder(with_pip=True).create(home)
    python = home / "bin" / "python"
    for args in (["pytest"], ["--no-deps", str(armbench_wheel)]):
        done = subprocess.run([str(python), "-m", "pip", "install", "-q", *args],
                              capture_output=True, text=True, timeout=600, check=False)
        assert done.returncode == 0, done.stderr[-3000:]
    return python


def _pytest(python: Path, folder: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(python), "-m", "pytest", "-q", "-p", "no:cacheprovider"],
                          cwd=folder, capture_output=True, text=True, timeout=300, check=False)


@pytest.mark.slow
def test_an_unrelated_project_runs_as_before(guest_env: Path, tmp_path: Path) -> None:
    plugins = subprocess.run([str(guest_env), "-c", "import importlib.metadata as m; print("
                              "[e.value for e in m.entry_points(group='pytest11')])"],
                             capture_output=True, text=True, check=True).stdout
    assert "armbench.cli.plugin.pytest_plugin" in plugins  # installed, so pytest loads it
    (tmp_path / "test_other.py").write_text(TRIVIAL, encoding="utf-8")
    done = _pytest(guest_env, tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "1 passed" in done.stdout and "rror" not in done.stdout + done.stderr


@pytest.mark.slow
def test_the_arm_fixture_says_what_is_missing(guest_env: Path, tmp_path: Path) -> None:
    (tmp_path / "test_other.py").write_text(TRIVIAL, encoding="utf-8")
    (tmp_path / "test_bench.py").write_text(WANTS_ARM, encoding="utf-8")
    done = _pytest(guest_env, tmp_path)
    assert done.returncode == 1
    assert "1 passed, 1 error" in done.stdout  # the fixture fails at set-up, saying why
    assert "needs pytest-asyncio" in done.stdout
