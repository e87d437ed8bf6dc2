"""``--out`` that is safe to rerun (issue 42): a second run into the same ``--out`` is refused
(naming ``--overwrite``) and leaves the first as it was; with ``--overwrite`` it replaces the
run's files and nothing else; a run without ``--out`` gets a folder of its own under ``runs/``
and ``runs/latest`` points at the newest."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from conftest import cli, one_line_error

from armbench.record import load_record

#: One lap of one style: a run in a few seconds.
CONFIG = """\
spec_version = "armbench-limits/1"

[limits."accuracy.coordinated.mean_mm"]
high = 5.0
unit = "mm"

[suites.accuracy]
laps = 1
styles = ["coordinated"]
"""


@pytest.fixture
def lab(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A lab's folder with its bench.toml, the working directory of the runs."""
    (tmp_path / "bench.toml").write_text(CONFIG, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    return cli(capsys, "run", "accuracy", "--config", "bench.toml", "--workers", "1", "-q", *args)


def test_the_same_out_again_is_refused_or_replaced_with_overwrite(
        lab: Path, capsys: pytest.CaptureFixture[str]) -> None:
    status, _, err = _run(capsys, "--out", "current")
    assert status == 0, err
    first = load_record(lab / "current" / "results.json").run_id
    (lab / "current" / "notes.txt").write_text("the lab's own notes", encoding="utf-8")
    before = (lab / "current" / "results.json").read_bytes()

    status, _, err = _run(capsys, "--out", "current")
    one_line_error(status, err, "already holds a run record", "--overwrite")
    assert (lab / "current" / "results.json").read_bytes() == before

    status, out, err = _run(capsys, "--out", "current", "--overwrite")
    assert status == 0, err
    second = load_record(lab / "current" / "results.json").run_id
    assert second != first and second in out
    assert (lab / "current" / "notes.txt").read_text(encoding="utf-8") == "the lab's own notes"
    names = {p.name for p in (lab / "current").iterdir()}
    assert names == {"notes.txt", "results.json", "junit.xml", "report.html", "capture.mcap",
                     "runner.json"}, names
    assert first not in (lab / "current" / "junit.xml").read_text(encoding="utf-8")


def test_overwrite_never_takes_a_file_of_the_users_for_a_run(
        lab: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (lab / "mine").mkdir()
    (lab / "mine" / "results.json").write_text("my own results", encoding="utf-8")
    status, _, err = _run(capsys, "--out", "mine", "--overwrite")
    one_line_error(status, err, "--overwrite", "not a run record", "left as it is")
    assert (lab / "mine" / "results.json").read_text(encoding="utf-8") == "my own results"
    status, _, err = _run(capsys, "--overwrite")
    one_line_error(status, err, "--overwrite", "give --out")


def test_a_fleet_folder_is_replaced_arm_by_arm(lab: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    ports = ("--port", "a=fake://", "--port", "b=fake://?seed=2")
    status, _, err = _run(capsys, *ports, "--out", "fleet")
    assert status == 0, err
    first = load_record(lab / "fleet" / "a" / "results.json").run_id
    status, _, err = _run(capsys, *ports, "--out", "fleet")
    one_line_error(status, err, "already holds a fleet run", "--overwrite")
    status, _, err = _run(capsys, *ports, "--out", "fleet", "--overwrite")
    assert status == 0, err
    assert load_record(lab / "fleet" / "a" / "results.json").run_id != first


def test_runs_latest_points_at_the_newest_run(lab: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    ids = []
    for _ in range(2):
        status, out, err = _run(capsys)
        assert status == 0, err
        ids.append(out.split()[1].rstrip(":"))  # "run ID: verdict pass (exit 0)"
    assert sorted(p.name for p in (lab / "runs").iterdir()) == sorted([*ids, "latest"])
    latest = lab / "runs" / "latest"
    assert latest.is_symlink() and os.readlink(latest) == ids[-1]
    assert load_record(latest / "results.json").run_id == ids[-1]
    # a "latest" of the user's own is never replaced
    latest.unlink()
    latest.mkdir()
    status, _, err = _run(capsys)
    assert status == 0 and "runs/latest is not a link to a run: not updated" in err, err
    assert latest.is_dir() and not latest.is_symlink()
