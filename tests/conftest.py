"""Fixtures shared by the test modules: the checkout, and armbench built as a user installs it."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

#: The checkout under test.
ROOT = Path(__file__).resolve().parents[1]
#: What a wheel build reads from the checkout.
BUILD_INPUTS = ("armbench", "bench", "drivers", "fakes", "reports", "pyproject.toml", "setup.py",
                "README.md")


@pytest.fixture(scope="session")
def armbench_wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A wheel of this checkout built as ``pip install .`` builds it (mypyc compiling the hot
    modules when a C compiler is at hand), from a copy so the checkout gets no build folders."""
    work = tmp_path_factory.mktemp("wheel")
    copy = work / "src"
    copy.mkdir()
    for name in BUILD_INPUTS:
        source = ROOT / name
        if source.is_dir():
            shutil.copytree(source, copy / name, symlinks=True,
                            ignore=shutil.ignore_patterns("__pycache__", "*.so"))
        else:
            shutil.copy2(source, copy / name)
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps",
                            "-w", str(work / "dist"), str(copy)],
                           capture_output=True, text=True, timeout=900, check=False)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    (wheel,) = (work / "dist").glob("armbench-*.whl")
    return wheel
