"""``scripts/trial_cpu.py``: the trials' CPU in the workers, compared between variants."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest
from script_loader import SCRIPTS, load_script

SCRIPT = SCRIPTS / "trial_cpu.py"


def _script() -> ModuleType:
    return load_script("trial_cpu")


def test_a_variant_is_a_name_an_interpreter_and_run_options() -> None:
    variant = _script().variant
    assert variant("plain=/venv/bin/python") == ("plain", "/venv/bin/python", [])
    assert variant("'no capture=/a b/python' --no-capture accuracy") == (
        "no capture", "/a b/python", ["--no-capture", "accuracy"])
    for bad in ("", "python", "=python", "name=", "--no-capture"):
        with pytest.raises(argparse.ArgumentTypeError, match="NAME=PYTHON"):
            variant(bad)


@pytest.mark.slow
def test_each_variant_runs_and_its_trials_cpu_is_counted() -> None:
    done = subprocess.run([sys.executable, str(SCRIPT), "--repeats", "1",
                           f"one={sys.executable} accuracy",
                           f"capture-off={sys.executable} --no-capture accuracy"],
                          capture_output=True, text=True, timeout=600, check=True)
    runs = re.findall(r"run 1 (\S+): (\d+) jobs, ([\d.]+) s of robot time, trials' CPU ([\d.]+) s",
                      done.stdout)
    assert [r[0] for r in runs] == ["one", "capture-off"], done.stdout
    for _, jobs, robot_s, cpu_s in runs:
        assert int(jobs) > 0 and float(robot_s) > 0 and float(cpu_s) > 0
    assert runs[0][1:3] == runs[1][1:3]  # the same trials, with or without a capture
    assert "one: least" in done.stdout and "capture-off: least" in done.stdout


def test_an_interpreter_that_cannot_run_is_named_in_one_line(tmp_path: Path) -> None:
    missing = tmp_path / "no-venv" / "python"
    done = subprocess.run([sys.executable, str(SCRIPT), "--repeats", "1", f"gone={missing}"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    assert done.stderr.strip().splitlines() == [
        f"trial_cpu.py: cannot run {str(missing)!r}: [Errno 2] No such file or directory: "
        f"{str(missing)!r}"]
