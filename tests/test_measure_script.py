"""``scripts/measure.py``: measured figures land in ``measurements/`` generated, with the date,
the machine, the commit and the command, and never over a file already there. The script runs
as a real process on real commands (a Python one-liner stands in for a figure script)."""

from __future__ import annotations

import platform
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path
from types import ModuleType

from script_loader import load_script

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "measure.py"


def _script() -> ModuleType:
    return load_script("measure")


def _measure(out: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), "--out-dir", str(out), *args],
                          capture_output=True, text=True, timeout=120, check=False)


def test_a_measurement_is_a_dated_file_with_machine_commit_command_and_output(
        tmp_path: Path) -> None:
    day = datetime.now(UTC)
    figures = '{"figures": [{"name": "toy.rate", "value": 42.5, "unit": "1/s", "ratio": 0.5}]}'
    done = _measure(tmp_path, "--topic", "toy", "--note", "a quiet machine", "run", "--",
                    sys.executable, "-c", f"print({figures!r})")
    assert done.returncode == 0, done.stderr
    [written] = tmp_path.iterdir()
    assert written.name in {f"{day:%Y-%m-%d}-toy.md", f"{datetime.now(UTC):%Y-%m-%d}-toy.md"}
    text = written.read_text(encoding="utf-8")
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                          text=True, check=True).stdout.strip()
    assert f"`{head}`" in text
    assert "print(" in text and "| exit status | 0 |" in text
    assert platform.python_version() in text and "CPUs" in text
    assert "a quiet machine" in text
    assert figures in text and "```json" in text  # the output as printed
    assert "| `toy.rate` | 42.5 | 1/s | 0.5 |" in text  # armbench perf's figures as a table
    assert str(written) in done.stderr


def test_a_second_measurement_never_replaces_the_first(tmp_path: Path) -> None:
    first = _measure(tmp_path, "--topic", "toy", "run", "--", sys.executable, "-c", "print(1)")
    assert first.returncode == 0, first.stderr
    [one] = tmp_path.iterdir()
    before = one.read_bytes()
    second = _measure(tmp_path, "--topic", "toy", "run", "--", sys.executable, "-c", "print(2)")
    assert second.returncode == 0, second.stderr
    assert {p.name for p in tmp_path.iterdir()} == {one.name, one.stem + "-2.md"}
    assert one.read_bytes() == before


def test_the_commands_status_is_kept_and_its_output_bounded(tmp_path: Path) -> None:
    measure = _script()
    size = measure.MAX_OUTPUT_BYTES + 1000
    done = _measure(tmp_path, "--topic", "loud", "run", "--", sys.executable, "-c",
                    f"import sys; sys.stdout.write('x' * {size}); sys.exit(3)")
    assert done.returncode == 3
    [written] = tmp_path.iterdir()
    text = written.read_text(encoding="utf-8")
    assert "| exit status | 3 |" in text
    assert "(1000 bytes more of output left out.)" in text
    assert text.count("x") < size


def test_the_recipes_run_the_figure_scripts_and_perf() -> None:
    measure = _script()
    assert measure.command_of("perf", ["--only", "emulator"])[-4:] == [
        "perf", "--json", "--only", "emulator"]
    for recipe, script in (("dask", "dask_throughput.py"), ("ros2", "ros2_figures.py"),
                           ("foreign-arm", "foreign_arm_figures.py"),
                           ("same-figures", "same_figures.py"), ("trial-cpu", "trial_cpu.py"),
                           ("emulator-share", "emulator_share.py")):
        command = measure.command_of(recipe, [])
        assert Path(command[1]) == ROOT / "scripts" / script
        assert Path(command[1]).is_file()


def test_a_bad_request_is_one_line_and_writes_nothing(tmp_path: Path) -> None:
    for args in (["nosuch"], ["run"], ["--topic", "Bad Name", "run", "--", "true"]):
        done = _measure(tmp_path, *args)
        assert done.returncode == 2, args
        assert done.stderr.strip().splitlines()[-1].startswith("measure.py: error:"), args
    assert not tmp_path.exists() or list(tmp_path.iterdir()) == []
