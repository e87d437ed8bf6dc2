"""Fixtures shared by the test modules: the checkout, and armbench built as a user installs it."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import armbench.cli.main

#: The checkout under test.
ROOT = Path(__file__).resolve().parents[1]
#: What a wheel build reads from the checkout.
BUILD_INPUTS = ("api", "bench", "capture", "cli", "drivers", "fakes", "metrics", "record",
                "reports", "firmware", "pyproject.toml", "setup.py", "README.md")


#: A test that needs a pseudo-terminal: ``pty`` in its name or parameters, as a word.
_NEEDS_PTY = re.compile(r"(?<![a-z])pty(?![a-z])", re.IGNORECASE)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Where the system has no pseudo-terminals (Windows), the tests that need one skip."""
    if hasattr(os, "openpty"):
        return
    skip = pytest.mark.skip(reason="needs a pseudo-terminal: this system has none")
    for item in items:
        if _NEEDS_PTY.search(item.name) or "pty_emulator" in getattr(item, "fixturenames", ()):
            item.add_marker(skip)


def build_wheel(work: Path, *, pure: bool) -> Path:
    """A wheel of this checkout built as ``pip install .`` builds it (mypyc compiling the hot
    modules when a C compiler is at hand, unless ``pure``), from a copy so the checkout gets no
    build folders."""
    copy = work / "src"
    copy.mkdir()
    for name in BUILD_INPUTS:
        source = ROOT / name
        if source.is_dir():
            shutil.copytree(source, copy / name,
                            ignore=shutil.ignore_patterns("__pycache__", "*.so"))
        else:
            shutil.copy2(source, copy / name)
    env = {k: v for k, v in os.environ.items() if k != "ARMBENCH_PURE_PYTHON"}
    if pure:
        env["ARMBENCH_PURE_PYTHON"] = "1"
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                            "-w", str(work / "dist"), str(copy)], env=env,
                           capture_output=True, text=True, timeout=900, check=False)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    (wheel,) = (work / "dist").glob("armbench-*.whl")
    return wheel


def unpack(wheel: Path, tree: Path) -> Path:
    """The installed tree of ``wheel``, as pip lays it out in site-packages."""
    with zipfile.ZipFile(wheel) as z:
        z.extractall(tree)
    return tree


@pytest.fixture(scope="session")
def armbench_wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The release wheel of this checkout (compiled when a C compiler is at hand)."""
    return build_wheel(tmp_path_factory.mktemp("wheel"), pure=False)


@pytest.fixture(scope="session")
def compiled_tree(armbench_wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The release wheel's installed tree, as pip lays it out in site-packages (skips where
    there is no C compiler: the wheel would be plain Python)."""
    if shutil.which(os.environ.get("CC", "cc")) is None:
        pytest.skip("no C compiler: a wheel build installs plain Python")
    return unpack(armbench_wheel, tmp_path_factory.mktemp("installed"))


@pytest.fixture(scope="session")
def pure_tree(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The plain-Python build of this checkout (``ARMBENCH_PURE_PYTHON=1``), unpacked as pip
    installs it: what the compiled build is compared with."""
    work = tmp_path_factory.mktemp("pure")
    return unpack(build_wheel(work, pure=True), work / "installed")


def cli(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    """``armbench ARGS`` in this process: exit status, stdout, stderr."""
    status = armbench.cli.main.main(list(args))
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def one_line_error(status: int, err: str, *expected: str) -> None:
    """Exit status 2 and a single stderr line holding every ``expected`` text, no traceback."""
    lines = err.strip().splitlines()
    assert status == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for text in expected:
        assert text in lines[0], lines[0]
