"""What a run tested: the unit under test (``--dut``, ``--meta``, the config's ``[dut]``), the CI
job and armbench's own revision, recorded in ``results.json``, ``junit.xml``, the report and the
Markdown summary; checked on real runs of a tiny suite over ``fake://`` (the emulator on virtual
time) and on real git repositories."""

from __future__ import annotations

import io
import json
import shutil
import subprocess
import tomllib
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from contextlib import redirect_stdout
from pathlib import Path

import pytest
from test_report import parse
from test_runner import write_config

from armbench.bench.runner import RunOptions, prepare
from armbench.bench.suites import SUITES
from armbench.cli import main as cli
from armbench.cli.commands.config import render_config
from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import SettingsError
from armbench.record import git_revision, load_record
from armbench.record.ci_run import CiRun, ci_run
from armbench.record.dut import MAX_TEXT, Dut
from armbench.record.environment import NOT_A_CHECKOUT
from armbench.record.limits import parse_limits

RECORDS = Path(__file__).parent / "fixtures" / "records"

#: The ``[dut]`` table of the bench config the end-to-end run is given.
DUT_TABLE = """
[dut]
name = "from-the-file"
serial = "RL-0042"
firmware_commit = "0000000"
host_commit = "feedface"

[dut.meta]
rig = "A"
"""

GITHUB = {"GITHUB_ACTIONS": "true", "GITHUB_REPOSITORY": "lab/arm-bench",
          "GITHUB_SHA": "3f2a9c1d" * 5, "GITHUB_RUN_ID": "9912", "GITHUB_RUN_ATTEMPT": "2",
          "GITHUB_WORKFLOW": "hil", "GITHUB_REF_NAME": "main",
          "GITHUB_SERVER_URL": "https://github.example"}
GITLAB = {"GITLAB_CI": "true", "CI_PROJECT_PATH": "lab/arm-bench", "CI_COMMIT_SHA": "c0ffee" * 6,
          "CI_PIPELINE_ID": "77", "CI_JOB_ID": "1234", "CI_COMMIT_REF_NAME": "release/2",
          "CI_JOB_URL": "https://gitlab.example/lab/arm-bench/-/jobs/1234",
          "CI_PIPELINE_URL": "https://gitlab.example/lab/arm-bench/-/pipelines/77"}
CI_VARIABLES = (*GITHUB, *GITLAB)


@pytest.fixture(autouse=True)
def _tiny_registered(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setitem(SUITES, "tiny", "test_runner:TinySuite")
    for name in CI_VARIABLES:  # the CI this test may run in is not the one it sets
        monkeypatch.delenv(name, raising=False)
    yield


def _run_cli(*args: str) -> tuple[int, str]:
    out = io.StringIO()
    with redirect_stdout(out):
        status = cli.main(["run", *args])
    return status, out.getvalue()


def test_a_run_records_its_unit_under_test_and_ci_job_everywhere(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    for name, value in GITHUB.items():
        monkeypatch.setenv(name, value)
    config = write_config(tmp_path, trials=2, extra=DUT_TABLE)
    out, summary = tmp_path / "run", tmp_path / "summary.md"
    status, text = _run_cli("tiny", "--config", str(config), "--out", str(out),
                            "--dut", "arm-7", "--meta", "firmware_commit=1234abcd",
                            "--meta", "rig=B", "--meta", "operator=kim",
                            "--summary", str(summary))
    assert status == 0, text
    # results.json: the flags over the file, key by key
    record = load_record(out / "results.json")
    env = record.environment
    assert env.dut == Dut(name="arm-7", serial="RL-0042", firmware_commit="1234abcd",
                          host_commit="feedface", meta={"rig": "B", "operator": "kim"})
    assert env.ci == CiRun("github-actions", project="lab/arm-bench", commit="3f2a9c1d" * 5,
                           ref="main", workflow="hil", pipeline_id="9912", attempt="2",
                           url="https://github.example/lab/arm-bench/actions/runs/9912/"
                               "attempts/2")
    assert (env.target_kind, env.truth_source) == ("fake", "the emulator's ground truth")
    raw = json.loads((out / "results.json").read_text(encoding="utf-8"))["environment"]
    assert raw["dut"]["serial"] == "RL-0042" and raw["ci"]["pipeline_id"] == "9912"
    assert raw["target"] == {"kind": "fake"}
    # junit.xml: every testsuite carries them as properties
    root = ET.parse(out / "junit.xml").getroot()
    suites = root.findall("testsuite")
    assert suites
    for suite in suites:
        props = {p.get("name"): p.get("value") for p in suite.iter("property")}
        assert props["dut.name"] == "arm-7" and props["dut.serial"] == "RL-0042"
        assert props["dut.firmware_commit"] == "1234abcd"
        assert props["dut.host_commit"] == "feedface"
        assert props["dut.meta.rig"] == "B" and props["dut.meta.operator"] == "kim"
        assert props["ci.url"] == env.ci.url and props["ci.commit"] == "3f2a9c1d" * 5
        assert props["target_kind"] == "fake"
    # the report: the unit in the header, all of it in the environment section
    doc = parse((out / "report.html").read_text(encoding="utf-8"))
    header = next(doc.iter("h1")).text()
    assert "arm-7 (serial RL-0042)" in header and "firmware 1234abcd" in header
    environment = doc.by_id("environment")
    assert environment is not None
    pairs = dict(zip((n.text() for n in environment.iter("dt")),
                     (n.text() for n in environment.iter("dd")), strict=False))
    assert pairs["unit under test"] == "arm-7 (serial RL-0042)"
    assert pairs["firmware commit"] == "1234abcd" and pairs["host commit"] == "feedface"
    assert pairs["rig"] == "B" and pairs["operator"] == "kim"
    assert pairs["CI url"] == env.ci.url
    assert pairs["target"] == "fake (truth: the emulator's ground truth)"
    assert pairs["armbench's own git revision"] == env.git_revision
    # the Markdown summary
    md = summary.read_text(encoding="utf-8")
    assert ("Unit under test: name `arm-7`, serial `RL-0042`, firmware commit `1234abcd`, "
            "host commit `feedface`, meta.rig `B`, meta.operator `kim`.") in md
    assert f"url `{env.ci.url}`" in md and "CI: github-actions" in md


def _dut_error(tmp_path: Path, table: str = "", **flags: object) -> SettingsError:
    config = write_config(tmp_path, trials=1, extra=table)
    with pytest.raises(SettingsError) as info:
        prepare(RunOptions(suites=["tiny"], config=config, out=tmp_path / "r",
                           **flags))  # type: ignore[arg-type]
    return info.value


@pytest.mark.parametrize(("table", "flags", "field", "reason"), [
    ('[dut]\nserial = 42\n', {}, "dut.serial", "is not a string"),
    (f'[dut]\nname = "{"x" * (MAX_TEXT + 1)}"\n', {}, "dut.name",
     f"is longer than {MAX_TEXT} characters"),
    ('[dut]\nhost_commit = "ab\\u001b[31mcd"\n', {}, "dut.host_commit", "not printable"),
    ('[dut]\ncolour = "red"\n', {}, "dut.colour", "is not a known key"),
    ('[dut]\nname = ""\n', {}, "dut.name", "is empty"),
    ('[dut.meta]\n"bad key!" = "v"\n', {}, "dut.meta.bad key!", "is not a key"),
    ("", {"dut": ""}, "--dut", "is empty"),
    ("", {"meta": ("serial",)}, "--meta", "is not KEY=VALUE"),
    ("", {"meta": ("firmware_commit=ab\ncd",)}, "--meta firmware_commit", "not printable"),
    ("", {"dut": "a", "meta": ("name=b",)}, "--meta name", "is given twice"),
])
def test_a_bad_identity_is_refused_naming_its_key(tmp_path: Path, table: str,
                                                  flags: dict[str, object], field: str,
                                                  reason: str) -> None:
    error = _dut_error(tmp_path, "\n" + table, **flags)
    assert error.field == field and reason in error.reason
    assert len(str(error)) < 200  # a long value is cut in the message


def test_the_cli_exits_2_before_anything_is_made(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    config = write_config(tmp_path, trials=1)
    status, _ = _run_cli("tiny", "--config", str(config), "--out", str(tmp_path / "r"),
                         "--meta", "serial=\x07")
    assert status == 2
    err = capsys.readouterr().err
    assert "armbench run: error: --meta serial:" in err and "not printable" in err
    assert not (tmp_path / "r").exists()


def test_a_resumed_run_keeps_the_unit_it_began_on(tmp_path: Path) -> None:
    config = write_config(tmp_path, trials=1)
    status, text = _run_cli("tiny", "--config", str(config), "--out", str(tmp_path / "r"),
                            "--dut", "arm-7")
    assert status == 0, text
    for flags in ({"dut": "arm-8"}, {"meta": ("serial=S2",)}):
        with pytest.raises(ArmbenchError, match="the run being resumed"):
            prepare(RunOptions(resume=tmp_path / "r", **flags))
    plan = prepare(RunOptions(resume=tmp_path / "r"))
    assert plan.dut == Dut(name="arm-7")


def test_records_written_before_the_identity_still_load() -> None:
    record = load_record(RECORDS / "passing.json")
    env = record.environment
    assert not env.dut and env.ci is None and (env.target_kind, env.truth_source) == (None, None)
    assert env.kind == "serial" and not env.declares_truth  # /dev/ttyUSB0: from the port
    assert all(s.wall_s is None and all(t.wall_s is None for t in s.trials)
               for s in record.suites.values())
    data = record.to_json()  # and they are written back as they were
    assert "dut" not in data["environment"] and "target" not in data["environment"]


def test_ci_variables_of_github_and_gitlab() -> None:
    assert ci_run({}) is None
    assert ci_run({**GITHUB, "GITHUB_ACTIONS": "false"}) is None
    gitlab = ci_run(GITLAB)
    assert gitlab == CiRun("gitlab-ci", project="lab/arm-bench", commit="c0ffee" * 6,
                           ref="release/2", pipeline_id="77", job_id="1234",
                           url=GITLAB["CI_JOB_URL"], pipeline_url=GITLAB["CI_PIPELINE_URL"])
    # a value that is not printable text of bounded length is left out, never the run refused
    odd = ci_run({**GITHUB, "GITHUB_REF_NAME": "x" * 600, "GITHUB_WORKFLOW": "a\nb"})
    assert odd is not None and odd.ref is None and odd.workflow is None
    no_url = ci_run({**GITHUB, "GITHUB_SERVER_URL": ""})
    assert no_url is not None and no_url.url is None and no_url.pipeline_id == "9912"
    assert CiRun.from_json(gitlab.to_json(), "ci") == gitlab


@pytest.mark.skipif(shutil.which("git") is None, reason="git not installed")
def test_git_revision_is_armbenchs_own_or_says_it_is_not_a_checkout(tmp_path: Path) -> None:
    def git(*args: str) -> str:
        return subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args],
                              cwd=tmp_path, capture_output=True, text=True,
                              check=True).stdout.strip()

    plain = tmp_path / "site-packages" / "armbench" / "record"
    plain.mkdir(parents=True)
    (plain / "environment.py").write_text("# installed from a wheel\n")
    assert git_revision(plain / "environment.py") == NOT_A_CHECKOUT
    # a wheel installed in a virtual environment inside another project's checkout: that
    # project's revision is not armbench's
    git("init", "-q")
    (tmp_path / "lab.py").write_text("# the lab's host code\n")
    git("add", "lab.py")
    git("commit", "-q", "-m", "lab")
    assert git_revision(plain / "environment.py") == NOT_A_CHECKOUT
    git("add", "site-packages")
    git("commit", "-q", "-m", "a checkout of armbench")
    assert git_revision(plain / "environment.py") == git("rev-parse", "HEAD")


def test_config_show_prints_the_dut_table_with_origins(tmp_path: Path) -> None:
    config = write_config(tmp_path, trials=1, extra=DUT_TABLE)
    text = render_config(RunOptions(suites=["tiny"], config=config, dut="arm-9",
                                    meta=("host_commit=beef", "operator=kim")))
    lines = text.splitlines()
    table = lines[lines.index("[dut]"):]
    assert table[1:5] == ['name = "arm-9"  # --dut', f'serial = "RL-0042"  # {config}',
                          f'firmware_commit = "0000000"  # {config}',
                          'host_commit = "beef"  # --meta']
    meta = lines[lines.index("[dut.meta]"):]
    assert meta[1:3] == [f'rig = "A"  # {config}', 'operator = "kim"  # --meta']
    # the output reads back as a config naming the same unit
    again = parse_limits(tomllib.loads(text))
    assert again.dut == Dut("arm-9", "RL-0042", "0000000", "beef",
                            {"rig": "A", "operator": "kim"})


def test_a_fleet_names_each_arm_as_its_unit(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    config = write_config(tmp_path, trials=1)
    status, _ = _run_cli("tiny", "--config", str(config), "--port", "a=fake://", "--port",
                         "b=fake://?seed=2", "--dut", "arm-1", "--out", str(tmp_path / "f"))
    assert status == 2 and "--dut names one unit" in capsys.readouterr().err
    serial = write_config(tmp_path, trials=1, extra='\n[dut]\nserial = "S1"\n', name="s.toml")
    status, _ = _run_cli("tiny", "--config", str(serial), "--port", "a=fake://", "--port",
                         "b=fake://?seed=2", "--out", str(tmp_path / "f"))
    assert status == 2 and "dut.serial" in capsys.readouterr().err
    assert not (tmp_path / "f").exists()
    status, text = _run_cli("tiny", "--config", str(config), "--port", "a=fake://", "--port",
                            "b=fake://?seed=2", "--meta", "rig=B", "--out", str(tmp_path / "f"))
    assert status == 0, text
    for name in ("a", "b"):
        dut = load_record(tmp_path / "f" / name / "results.json").environment.dut
        assert (dut.name, dut.meta) == (name, {"rig": "B"})
