"""Shards for CI: ``armbench run --shard I/N`` measures a deterministic 1/N of the trials and
``armbench merge`` joins the shards into the record an unsharded run writes (every trial,
measurement and suite summary; run id and timestamps aside). Real CLI, real emulator."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from campaign_records import record_differences

from armbench.bench.campaign import MergeError, merge_shards
from armbench.bench.runner import RunOptions, run_sync
from armbench.bench.runner.options import shard_assignment
from armbench.cli.main import main

CONFIG = """spec_version = "armbench-limits/1"
[limits."startup.recovery_time_s"]
high = 10.0
unit = "s"
[suites.startup-recovery]
trials = 7
wear_duration_s = 0.0
"""


@pytest.fixture()
def config(tmp_path: Path) -> Path:
    path = tmp_path / "bench.toml"
    path.write_text(CONFIG, encoding="utf-8")
    return path


def _run(config: Path, out: Path, shard: tuple[int, int] | None = None,
         workers: int = 2) -> None:
    run_sync(RunOptions(suites=["startup-recovery"], config=config, out=out, seed=3,
                        shard=shard, workers=workers), progress=None)


def test_shards_partition_the_trials() -> None:
    suites: list[list[dict[str, Any]]] = [
        [{"style": s, "lap": lap} for lap in range(7) for s in ("paper", "coordinated")],
        [{"k": i} for i in range(9)]]
    for n in (1, 2, 3, 5):
        shards = shard_assignment(suites, n)
        assert [len(s) for s in shards] == [14, 9] and all(0 <= x < n for s in shards for x in s)


@pytest.mark.parametrize("n", [2, 3, 4])
def test_shards_are_balanced_across_suites_and_styles(n: int) -> None:
    """Each shard gets its share, within one trial, of every style of every suite: --shard 1/2
    once put every paper-style lap in shard 1 and every coordinated lap in shard 2."""
    accuracy: list[dict[str, Any]] = [{"style": s, "lap": lap} for lap in range(5)
                                      for s in ("paper", "coordinated")]
    startup: list[dict[str, Any]] = [{"kind": "cut", "condition": c, "cycle": i}
                                     for i in range(4) for c in ("idle", "moving", "homing")]
    ones: list[list[dict[str, Any]]] = [[{"x": 1}] for _ in range(2 * n)]  # one trial each
    plan = [accuracy, startup, *ones]
    shards = shard_assignment(plan, n)
    for trials, owners in zip(plan, shards, strict=True):
        for condition in {tuple(sorted((k, v) for k, v in t.items() if isinstance(v, str)))
                          for t in trials}:
            mine = [o for t, o in zip(trials, owners, strict=True)
                    if all(t[k] == v for k, v in condition)]
            counts = [mine.count(i) for i in range(n)]
            assert max(counts) - min(counts) <= 1, (condition, counts)
    singles = [owners[0] for owners in shards[2:]]
    assert sorted(singles) == sorted(list(range(n)) * 2)


def test_three_shards_merge_into_the_unsharded_record(tmp_path: Path, config: Path) -> None:
    _run(config, tmp_path / "full")
    for i in (1, 2, 3):
        _run(config, tmp_path / f"s{i}", (i, 3))
        shard = json.loads((tmp_path / f"s{i}" / "results.json").read_text())
        indices = [t["index"] for t in shard["suites"]["startup-recovery"]["trials"]]
        owners = shard_assignment([[{"kind": "cut"}] * 7], 3)[0]  # one condition: in turn
        assert indices == [k for k in range(7) if owners[k] == i - 1]
        assert shard["suites"]["startup-recovery"]["measurements"] == []  # merge summarises
    outcome = merge_shards([tmp_path / "s3", tmp_path / "s1", tmp_path / "s2"], tmp_path / "m")
    assert outcome.exit_status == 0
    assert record_differences(tmp_path / "full", tmp_path / "m") == []
    # and by the project's own figure check, to 1e-12
    script = Path(__file__).resolve().parent.parent / "scripts" / "same_figures.py"
    if script.exists():
        done = subprocess.run([sys.executable, str(script), str(tmp_path / "full"),
                               str(tmp_path / "m")], capture_output=True, text=True)
        assert done.returncode == 0, done.stdout


def test_merge_refuses_what_is_not_one_run(tmp_path: Path, config: Path) -> None:
    _run(config, tmp_path / "s1", (1, 2), workers=1)
    with pytest.raises(MergeError, match="2/2 missing"):
        merge_shards([tmp_path / "s1"], tmp_path / "m1")
    with pytest.raises(MergeError, match="both shard 1/2"):
        merge_shards([tmp_path / "s1", tmp_path / "s1"], tmp_path / "m2")
    run_sync(RunOptions(suites=["startup-recovery"], config=config, out=tmp_path / "other",
                        seed=4, shard=(2, 2), workers=1), progress=None)
    with pytest.raises(MergeError, match="seed differ"):
        merge_shards([tmp_path / "s1", tmp_path / "other"], tmp_path / "m3")
    _run(config, tmp_path / "whole", workers=1)
    with pytest.raises(MergeError, match="not a shard"):
        merge_shards([tmp_path / "whole"], tmp_path / "m4")
    assert not (tmp_path / "m1").exists()


def test_cli_shard_and_merge(tmp_path: Path, config: Path,
                             capsys: pytest.CaptureFixture[str]) -> None:
    for i in (1, 2):
        assert main(["run", "startup-recovery", "--config", str(config), "--seed", "3",
                     "--out", str(tmp_path / f"s{i}"), "--shard", f"{i}/2", "--workers", "1"]) == 0
    assert main(["merge", str(tmp_path / "s1"), str(tmp_path / "s2"),
                 "--out", str(tmp_path / "m")]) == 0
    out = capsys.readouterr().out
    assert "merged 2 shard(s)" in out and "7 trial(s)" in out
    assert (tmp_path / "m" / "report.html").exists()
    with pytest.raises(SystemExit):
        main(["run", "--shard", "4/3"])
    assert "4/3" in capsys.readouterr().err
