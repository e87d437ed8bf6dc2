"""The CI example of ``docs/ci.md`` works as written: its GitHub Actions ``run:`` lines, run by a
shell with ``armbench`` on the PATH, exit 0 for a clean pair, 3 for a regressed pair and 1 for a
limit failure, and append their summary to ``$GITHUB_STEP_SUMMARY``."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import yaml  # type: ignore[import-untyped]

from armbench.record import load_record
from armbench.record.verdict import EXIT_FAIL, EXIT_PASS, EXIT_REGRESSION

DOC = Path(__file__).resolve().parent.parent / "docs" / "ci.md"

#: The lab's bench.toml of the example: one coordinated lap, tight regression tolerances.
BENCH = """\
spec_version = "armbench-limits/1"

[limits."accuracy.coordinated.mean_mm"]
high = {high}
unit = "mm"

[suites.accuracy]
laps = 1
styles = ["coordinated"]
side_m = 0.04

[regression]
default_tolerance_pct = 1.0
"""


def _workflow_steps() -> tuple[str, str]:
    """The ``run:`` lines of the GitHub example that call ``armbench run``: (baseline, judge)."""
    text = DOC.read_text(encoding="utf-8")
    github = text[text.index("## GitHub Actions"):]
    block = re.search(r"```yaml\n(.*?)```", github, re.S)
    assert block is not None
    workflow: dict[str, Any] = yaml.safe_load(block.group(1))
    runs = [step["run"] for job in workflow["jobs"].values() for step in job["steps"]
            if "armbench run" in step.get("run", "")]
    baseline = next(r for r in runs if "--baseline" not in r)
    judge = next(r for r in runs if "--baseline" in r)
    assert "--summary \"$GITHUB_STEP_SUMMARY\"" in judge
    return baseline, judge


def _shell(command: str, cwd: Path, port: str, tmp_path: Path) -> tuple[int, str]:
    bin_dir = tmp_path / "bin"
    if not bin_dir.exists():
        bin_dir.mkdir()
        shim = bin_dir / "armbench"
        shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m armbench "$@"\n')
        shim.chmod(0o755)
    env = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}",
           "ARM_PORT": port, "GITHUB_STEP_SUMMARY": str(cwd / "step-summary.md")}
    done = subprocess.run(["bash", "-c", command], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=600)
    return done.returncode, done.stdout + done.stderr


def _job(tmp_path: Path, name: str, baseline: Path, high: float) -> Path:
    """A checkout of the pull request: its bench.toml, the baseline artifact of main."""
    cwd = tmp_path / name
    cwd.mkdir()
    (cwd / "bench.toml").write_text(BENCH.format(high=high), encoding="utf-8")
    shutil.copytree(baseline, cwd / "baseline")
    return cwd


def test_the_ci_example_judges_by_exit_status(tmp_path: Path) -> None:
    baseline_step, judge_step = _workflow_steps()
    main = tmp_path / "main"
    main.mkdir()
    (main / "bench.toml").write_text(BENCH.format(high=5.0), encoding="utf-8")
    status, out = _shell(baseline_step, main, "fake://", tmp_path)
    assert status == EXIT_PASS, out
    record = load_record(main / "baseline" / "results.json")
    every = sum(1 for _ in record.iter_measurements())
    assert f"done: {every} measurement(s)" in out  # the terminal counts what the report does
    assert out.count("verdict") == 1, out  # printed once

    clean = _job(tmp_path, "clean", main / "baseline", high=5.0)
    status, out = _shell(judge_step, clean, "fake://", tmp_path)
    assert status == EXIT_PASS, out
    summary = (clean / "step-summary.md").read_text(encoding="utf-8")
    assert "PASS (exit 0)" in summary and "0 regressed" in summary

    heavy = _job(tmp_path, "heavy", main / "baseline", high=5.0)
    status, out = _shell(judge_step, heavy, "fake://?payload=2.5", tmp_path)
    assert status == EXIT_REGRESSION, out
    summary = (heavy / "step-summary.md").read_text(encoding="utf-8")
    assert "REGRESSION (exit 3)" in summary and "| regressed |" in summary

    tight = _job(tmp_path, "tight", main / "baseline", high=1e-6)
    status, out = _shell(judge_step, tight, "fake://", tmp_path)
    assert status == EXIT_FAIL, out
    summary = (tight / "step-summary.md").read_text(encoding="utf-8")
    assert "FAIL (exit 1)" in summary and "accuracy.coordinated.mean_mm" in summary
    # the step summary is appended to, never replaced
    (tight / "current").rename(tight / "first")
    _shell(judge_step, tight, "fake://", tmp_path)
    assert (tight / "step-summary.md").read_text(encoding="utf-8").count("### armbench") == 2
