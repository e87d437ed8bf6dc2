"""The verdict matrix of ``docs/ci.md`` as a test (issue 37, point 8): every row of that table is
run as written — truth present or absent, a power switch or none, one situation — and its verdict,
exit status and run folder asserted. The table is the test's data, so the docs cannot drift from
what the bench does.

Truth present: ``fake://`` (virtual time). Truth absent: the same emulator served over a real TCP
socket by ``armbench emulate --tcp`` (real time; a 1 cm square laps in about a second). The
"relay" is a ``--power-command`` that switches nothing: a relay cannot be real here, so the
power cuts it makes leave the arm powered (the suite still measures each recovery)."""

from __future__ import annotations

import re
import signal
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import pytest
from conftest import cli
from far_end import ROOT, Emulator, emulator_maker
from netutil import free_port
from test_exit_classes import MID_RUN_LAPS, _lose_after_first_trial

from armbench.record import load_record
from armbench.record.verdict import load_config

DOC = ROOT / "docs" / "ci.md"


@dataclass(frozen=True)
class Row:
    """One row of the table: its cells, as written."""

    truth: str
    power: str
    situation: str
    verdict: str
    exit: int
    folder: bool

    @property
    def id(self) -> str:
        return f"{self.truth}-{self.power}-{self.situation}".replace(" ", "_").replace(",", "")


def matrix_rows(text: str) -> list[Row]:
    """The rows of the "verdict matrix" table of ``docs/ci.md``."""
    section = text.split("## The verdict matrix", 1)[1].split("\n## ", 1)[0]
    rows = []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 6 or cells[0] in ("truth", "---") or set(cells[0]) <= {"-"}:
            continue
        rows.append(Row(cells[0], cells[1], cells[2], cells[3], int(cells[4]),
                        cells[5] == "yes"))
    return rows


ROWS = matrix_rows(DOC.read_text(encoding="utf-8"))


def _config(extra: str = "") -> str:
    """The packaged limits (those of the styles run here), a one-lap 1 cm coordinated square and
    two power cuts of a stopped arm, plus ``extra``; the live link's patience for a starved
    emulator process."""
    lines = ['spec_version = "armbench-limits/1"',
             "[bench]\nconnect_timeout_s = 30.0\nreply_timeout_s = 5.0\nmove_timeout_scale = 10.0"
             "\noutage_timeout_s = 3.0",
             '[suites.accuracy]\nlaps = 1\nstyles = ["coordinated"]\nside_m = 0.01\n'
             "settle_s = 0.0",
             '[suites.startup-recovery]\ntrials = 2\nconditions = ["stopped-near"]\n'
             "joint_sets = [[2, 3, 4]]\nwear_duration_s = 0"]
    for name, lim in load_config(None).limits.items():
        if "paper" in name or "improvement" in name or f'"{name}"' in extra:
            continue
        bounds = "".join(f"{k} = {v!r}\n" for k, v in (("low", lim.low), ("high", lim.high))
                         if v is not None)
        lines.append(f'[limits."{name}"]\n{bounds}unit = "{lim.unit}"')
    return "\n\n".join(lines) + "\n" + extra


TRUE_LIMIT = '\n[limits."accuracy.coordinated.true_mean_mm"]\nhigh = 0.5\nunit = "mm"\n'
TYPO = '\n[limits."accuracy.cordinated.mean_mm"]\nhigh = 0.001\nunit = "mm"\n'


@dataclass(frozen=True)
class Situation:
    """What a row's situation runs: the suite, the config's extra tables, more flags, and
    whether the suite is planned with no trial."""

    suite: str
    extra: str = ""
    flags: tuple[str, ...] = ()
    zero_trials: bool = False


SITUATIONS: dict[str, Situation] = {
    "nothing wrong": Situation("accuracy"),
    "a true figure over its limit": Situation("accuracy", TRUE_LIMIT),
    "zero trials": Situation("startup-recovery", zero_trials=True),
    "a limit name misspelled": Situation("accuracy", TYPO),
    "the power cuts skipped": Situation("startup-recovery"),
    "the power cuts skipped, suite optional": Situation(
        "startup-recovery", flags=("--optional", "startup-recovery")),
    "the power cuts made": Situation("startup-recovery"),
    "a true figure required": Situation(
        "accuracy", flags=("--require", "accuracy.coordinated.true_mean_mm")),
    "port refused": Situation("accuracy"),
    "link lost mid-run": Situation("accuracy"),
}


@pytest.fixture
def served(tmp_path: Path) -> Iterator[Callable[[], Emulator]]:
    """Starts the emulator on a real TCP socket when a row needs it (stopped at the end)."""
    with emulator_maker(tmp_path) as make:
        yield lambda: make("tcp")


def test_the_table_covers_every_axis() -> None:
    """The table holds both truths, a power switch and none, and every situation the issue
    names; each situation has its run here."""
    assert {r.truth for r in ROWS} == {"present", "absent"}
    assert {r.power for r in ROWS} >= {"yes", "none", "relay"}
    assert {r.situation for r in ROWS} == set(SITUATIONS)
    assert {r.exit for r in ROWS} == {0, 1, 2, 4, 5}


@pytest.mark.parametrize("row", ROWS, ids=[r.id for r in ROWS])
def test_verdict_matrix(row: Row, tmp_path: Path, served: Callable[[], Emulator],
                        capsys: pytest.CaptureFixture[str]) -> None:
    situation = SITUATIONS[row.situation]
    config = _config(situation.extra)
    if situation.zero_trials:
        config = re.sub(r"trials = 2\n", "trials = 0\n", config)
    if row.situation == "link lost mid-run":
        config = config.replace("laps = 1\n", f"laps = {MID_RUN_LAPS}\n")
    (tmp_path / "bench.toml").write_text(config, encoding="utf-8")
    out = tmp_path / "run"
    args = ["run", situation.suite, "--config", str(tmp_path / "bench.toml"), "--out", str(out),
            "--no-capture", "--workers", "1", *situation.flags]
    emulator = None
    if row.truth == "absent":
        if row.situation == "port refused":
            args += ["--port", f"socket://127.0.0.1:{free_port()}"]
        else:
            emulator = served()
            args += ["--port", emulator.port]
    if row.power == "relay":
        args += ["--power-command", "true", "true"]  # a relay that switches nothing (mock)
    if row.situation == "link lost mid-run":
        assert emulator is not None
        rig = SimpleNamespace(lose=lambda: emulator.stop(signal.SIGKILL))
        status, output = _lose_after_first_trial(rig, args)  # type: ignore[arg-type]
    else:
        status, output, err = cli(capsys, *args)
        output += err
    assert status == row.exit, output
    assert out.exists() == row.folder, output
    if row.folder:
        record = load_record(out / "results.json")
        assert record.verdict == row.verdict, output
        assert (record.environment.truth_source is not None) == (row.truth == "present")
    if row.truth == "absent" and row.situation == "a true figure over its limit":
        assert "no reference instrument" in output
        assert "resting on the encoders alone: accuracy: coordinated mean path error" in output
