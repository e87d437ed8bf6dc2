"""armbench.record: judging, the record schema, atomic writes, path safety, resume,
fixtures."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import RobotSettings, SettingsError
from armbench.record import (
    JOURNAL_FILE,
    RESULTS_FILE,
    SCHEMA,
    Environment,
    Measurement,
    RecordError,
    RecordWriter,
    RunRecord,
    Trial,
    atomic_write_bytes,
    capture_environment,
    default_better,
    git_revision,
    judge,
    load_record,
    path_inside,
    run_directory,
    validate_record,
)
from armbench.record.environment import NOT_A_CHECKOUT
from armbench.record.limits import SPEC_VERSION, Limit, LimitsConfig, parse_limits

FIXTURES = Path(__file__).parent / "fixtures"
RECORDS = FIXTURES / "records"

CONFIG = parse_limits({
    "spec_version": SPEC_VERSION,
    "limits": {
        "acc.mean_mm": {"high": 5.0, "unit": "mm"},
        "acc.*": {"high": 50.0, "unit": "mm"},
        "rate_pct": {"low": 95.0, "unit": "%"},
    },
})


def _env() -> Environment:
    return Environment(armbench_version="0.1.0", git_revision="abc", python="3.11.7",
                       platform="test", port="fake://", settings={}, seed=3, faults=(),
                       limits_spec_version=SPEC_VERSION, config_path="bench.toml")


def _record(planned: tuple[str, ...] = ("acc",)) -> RunRecord:
    return RunRecord(run_id="run-1", created="2024-05-01T12:00:00+00:00", environment=_env(),
                     planned_suites=list(planned))


def _trial(index: int, value: float = 1.0, *, error: str | None = None,
           samples: list[dict[str, Any]] | None = None) -> Trial:
    if error is not None:
        return Trial(index, float(index), 0.5, {"i": index}, samples or [], status="error",
                     error=error)
    return Trial(index, float(index), 0.5, {"i": index},
                 samples or [{"t_s": 0.0, "reported_m": [0.1, 0.2, 0.3]}],
                 [judge("acc.mean_mm", value, "mm", CONFIG)])


def _files(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


# --------------------------------------------------------------------------------------------
# judge, measurements, trials
# --------------------------------------------------------------------------------------------


def test_judge_pass_fail_unjudged() -> None:
    ok = judge("acc.mean_mm", 5.0, "mm", CONFIG, description="d")
    assert (ok.outcome, ok.limit, ok.better, ok.description) == (
        "pass", CONFIG.limits["acc.mean_mm"], "lower", "d")
    assert judge("acc.mean_mm", 5.0001, "mm", CONFIG).outcome == "fail"
    wild = judge("acc.max_mm", 20.0, "mm", CONFIG)
    assert wild.outcome == "pass" and wild.limit is not None and wild.limit.metric == "acc.*"
    free = judge("other_mm", 1e6, "mm", CONFIG)
    assert (free.outcome, free.limit) == ("unjudged", None)
    assert judge("acc.mean_mm", 1e6, "mm", None).outcome == "unjudged"
    assert judge("rate_pct", 90.0, "%", CONFIG, better="higher").outcome == "fail"


def test_better_defaults_by_unit_and_can_be_declared() -> None:
    for unit in ("mm", "rad", "s", "m", "deg", "ms"):
        assert default_better(unit) == "lower"
    for unit in ("%", "writes", "bool", ""):
        assert default_better(unit) is None
    assert judge("n", 3, "writes", None).better is None
    assert judge("n", 3, "writes", None, better="lower").better == "lower"
    assert judge("r", 3, "s", None, better="higher").better == "higher"


def test_judge_refuses_a_limit_in_another_unit() -> None:
    with pytest.raises(SettingsError) as info:
        judge("acc.mean_mm", 0.004, "m", CONFIG)
    assert info.value.field == 'limits."acc.mean_mm".unit'
    assert "'m'" in str(info.value)


def test_measurement_values_are_finite_floats() -> None:
    m = judge("a", np.float32(1.5), "mm", None)  # type: ignore[arg-type]
    assert type(m.value) is float and m.value == 1.5
    for bad in (math.nan, math.inf, True, "1"):
        with pytest.raises(RecordError, match="value"):
            Measurement("a", bad, "mm", None, "unjudged", None)  # type: ignore[arg-type]
    with pytest.raises(RecordError, match="outcome"):
        Measurement("a", 1.0, "mm", None, "ok", None)  # type: ignore[arg-type]
    with pytest.raises(RecordError, match="wildcards"):
        Measurement("a.*", 1.0, "mm", None, "unjudged", None)


def test_trial_checks() -> None:
    with pytest.raises(RecordError, match="error"):
        Trial(0, 0.0, 1.0, status="error")
    with pytest.raises(RecordError, match="error"):
        Trial(0, 0.0, 1.0, error="why")
    with pytest.raises(RecordError, match="duration_s"):
        Trial(0, 0.0, -1.0)
    with pytest.raises(RecordError, match="index"):
        Trial(-1, 0.0, 1.0)
    m = judge("a", 1.0, "mm", None)
    with pytest.raises(RecordError, match="twice"):
        Trial(0, 0.0, 1.0, measurements=[m, m])
    t = Trial(2, 1.5, 2.0)
    assert t.ended_s == 3.5 and t.samples == () and t.measurements == ()


# --------------------------------------------------------------------------------------------
# Verdict
# --------------------------------------------------------------------------------------------


def test_verdict_precedence(tmp_path: Path) -> None:
    w = RecordWriter(tmp_path, _record(("acc", "rep")))
    verdicts = [w.record.verdict]                         # nothing ran yet
    w.begin_suite("acc", "1")
    w.add_trial("acc", _trial(0, 9.0))                    # a failed measurement...
    verdicts.append(w.record.verdict)                     # ...but the run is not over
    w.end_suite("acc")
    w.begin_suite("rep", "1")
    w.end_suite("rep")
    verdicts.append(w.record.verdict)
    w.begin_suite("err", "1")
    w.add_trial("err", _trial(0, error="PortLostError: gone"))
    verdicts.append(w.record.verdict)                     # error beats incomplete and fail
    assert verdicts == ["incomplete", "incomplete", "fail", "error"]


def test_verdict_pass_and_suite_error(tmp_path: Path) -> None:
    w = RecordWriter(tmp_path, _record())
    w.begin_suite("acc", "1")
    w.add_trial("acc", _trial(0, 1.0))
    w.end_suite("acc", [judge("acc.mean_mm", 1.0, "mm", CONFIG)])
    assert w.record.verdict == "pass"
    w2 = RecordWriter(tmp_path / "b", _record())
    w2.begin_suite("acc", "1")
    w2.end_suite("acc", error="timeout waiting for the arm")
    assert w2.record.verdict == "error"
    assert load_record(w2.path).suites["acc"].error == "timeout waiting for the arm"


# --------------------------------------------------------------------------------------------
# Writing: after every trial, atomically, strict JSON
# --------------------------------------------------------------------------------------------


def test_record_on_disk_after_every_trial(tmp_path: Path) -> None:
    w = RecordWriter(tmp_path, _record())
    assert _files(tmp_path) == [RESULTS_FILE]
    assert load_record(w.path).verdict == "incomplete"
    w.begin_suite("acc", "1", {"side_m": 0.1})
    for i in range(3):
        w.add_trial("acc", _trial(i))
        # A writer killed here leaves a valid record holding every finished trial.
        on_disk = load_record(tmp_path / RESULTS_FILE)
        assert [t.index for t in on_disk.suites["acc"].trials] == list(range(i + 1))
        assert on_disk.suites["acc"].status == "running"
        # no temporary file left; the trials since the suite began are in the journal
        assert _files(tmp_path) == sorted([RESULTS_FILE, JOURNAL_FILE])
    w.end_suite("acc", [judge("acc.mean_mm", 1.0, "mm", CONFIG)])
    assert _files(tmp_path) == [RESULTS_FILE]            # results.json holds them all now
    final = load_record(w.path)
    assert final.suites["acc"].status == "done" and final.verdict == "pass"
    assert final.suites["acc"].params == {"side_m": 0.1}


def test_written_file_round_trips_exactly(tmp_path: Path) -> None:
    w = RecordWriter(tmp_path, _record())
    w.begin_suite("acc", "1", {"v": [1, 2]})
    w.add_trial("acc", _trial(0, samples=[{"t_s": 0.0, "xyz": np.array([1.0, 2.0, 3.0]),
                                           "n": np.int64(3), "note": "ünïcode [\n]"}]))
    w.end_suite("acc", [judge("acc.mean_mm", 1.0, "mm", CONFIG)])
    raw = json.loads(w.path.read_text(encoding="utf-8"))
    assert raw["suites"]["acc"]["trials"][0]["samples"] == [
        {"t_s": 0.0, "xyz": [1.0, 2.0, 3.0], "n": 3, "note": "ünïcode [\n]"}]
    assert validate_record(raw).to_json() == raw
    assert '"xyz": [1.0, 2.0, 3.0]' in w.path.read_text(encoding="utf-8")


def test_nan_in_samples_is_refused_before_anything_changes(tmp_path: Path) -> None:
    w = RecordWriter(tmp_path, _record())
    w.begin_suite("acc", "1")
    with pytest.raises(RecordError, match=r"trials\[index 0\].*NaN"):
        w.add_trial("acc", _trial(0, samples=[{"t_s": math.nan}]))
    assert w.record.suites["acc"].trials == []
    with pytest.raises(RecordError, match="params"):
        w.begin_suite("bad", "1", {"x": object()})


def test_atomic_write_keeps_the_old_file_on_failure(tmp_path: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "f.json"
    atomic_write_bytes(target, b"old")

    def broken_replace(src: str, dst: str) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(RecordError, match="No space left"):
        atomic_write_bytes(target, b"new")
    assert target.read_bytes() == b"old"
    assert _files(tmp_path) == ["f.json"]


def test_interrupt_during_write_leaves_old_file_and_no_temp(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "f.json"
    atomic_write_bytes(target, b"old")

    def interrupted(fd: int) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "fsync", interrupted)
    with pytest.raises(KeyboardInterrupt):
        atomic_write_bytes(target, b"new")
    assert target.read_bytes() == b"old"
    assert _files(tmp_path) == ["f.json"]


def test_new_files_follow_the_umask(tmp_path: Path) -> None:
    old = os.umask(0o022)
    try:
        atomic_write_bytes(tmp_path / "f", b"x")
    finally:
        os.umask(old)
    assert (tmp_path / "f").stat().st_mode & 0o777 == 0o644


def test_writer_refuses_to_overwrite_a_record(tmp_path: Path) -> None:
    RecordWriter(tmp_path, _record())
    with pytest.raises(RecordError, match="already holds a run record"):
        RecordWriter(tmp_path, _record())
    RecordWriter(tmp_path, _record(), overwrite=True)


def test_writer_api_misuse(tmp_path: Path) -> None:
    w = RecordWriter(tmp_path, _record())
    with pytest.raises(RecordError, match="has not begun"):
        w.add_trial("acc", _trial(0))
    w.begin_suite("acc", "1")
    w.add_trial("acc", _trial(0))
    with pytest.raises(RecordError, match="already measured"):
        w.add_trial("acc", _trial(0))
    w.end_suite("acc", [judge("acc.mean_mm", 1.0, "mm", CONFIG)])
    with pytest.raises(RecordError, match="begin it"):
        w.add_trial("acc", _trial(1))
    w.begin_suite("other", "1")
    with pytest.raises(RecordError, match="also a measurement of suite 'acc'"):
        w.end_suite("other", [judge("acc.mean_mm", 1.0, "mm", CONFIG)])
    assert w.record.planned_suites == ["acc", "other"]


# --------------------------------------------------------------------------------------------
# Paths stay inside the run directory
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["../x.json", "a/../../x.json", "/etc/passwd", "", "..",
                                  "a\0b"])
def test_path_inside_refuses_escapes(tmp_path: Path, name: str) -> None:
    with pytest.raises(RecordError) as info:
        path_inside(tmp_path, name)
    assert isinstance(info.value, ArmbenchError)


def test_path_inside_refuses_symlinks_pointing_out(tmp_path: Path) -> None:
    run = tmp_path / "run"
    outside = tmp_path / "outside"
    run.mkdir()
    outside.mkdir()
    (run / "plots").symlink_to(outside, target_is_directory=True)
    (run / RESULTS_FILE).symlink_to(outside / "stolen.json")
    with pytest.raises(RecordError, match="symlink"):
        path_inside(run, "plots/a.png")
    with pytest.raises(RecordError, match="symlink"):
        RecordWriter(run, _record())
    assert not (outside / "stolen.json").exists()
    assert path_inside(run, "sub/a.png") == run / "sub" / "a.png"


def test_run_directory(tmp_path: Path) -> None:
    root = tmp_path / "runs"
    d = run_directory(root, "2024-05-01-accuracy")
    assert d == root / "2024-05-01-accuracy" and d.is_dir()
    assert run_directory(root, "2024-05-01-accuracy") == d
    for bad in ("../escape", "a/b", "..", ".", "", "a\\b", "/abs"):
        with pytest.raises(RecordError, match="run name"):
            run_directory(root, bad)
    (tmp_path / "elsewhere").mkdir()
    (root / "linked").symlink_to(tmp_path / "elsewhere", target_is_directory=True)
    with pytest.raises(RecordError, match="outside"):
        run_directory(root, "linked")
    (root / "file").write_text("x")
    with pytest.raises(RecordError, match="not a directory"):
        run_directory(root, "file")
    assert not (tmp_path / "escape").exists()


def test_writer_file_name_and_artifacts_stay_inside(tmp_path: Path) -> None:
    for bad in ("../results.json", "sub/results.json", "/tmp/results.json"):
        with pytest.raises(RecordError, match="file name"):
            RecordWriter(tmp_path, _record(), filename=bad)
    w = RecordWriter(tmp_path, _record(), filename="run.json")
    assert w.path == tmp_path / "run.json"
    assert w.artifact_path("junit.xml") == tmp_path / "junit.xml"
    with pytest.raises(RecordError):
        w.artifact_path("../junit.xml")


# --------------------------------------------------------------------------------------------
# Resume
# --------------------------------------------------------------------------------------------


def _interrupted_run(tmp_path: Path) -> Path:
    """A run stopped by a lost port: suite 'acc' done, 'rep' with trials 0 and 1 done and 2
    errored, 'last' never started."""
    w = RecordWriter(tmp_path, _record(("acc", "rep", "last")))
    w.begin_suite("acc", "1", started_s=0.0)
    w.add_trial("acc", _trial(0))
    w.end_suite("acc", [judge("acc.mean_mm", 1.0, "mm", CONFIG)], ended_s=10.0)
    w.begin_suite("rep", "2", {"speeds_pct": [25, 50]}, started_s=11.0)
    for i in range(2):
        w.add_trial("rep", Trial(i, 12.0 + i, 1.0, {}, [{"t_s": 0.0}]))
    w.add_trial("rep", Trial(2, 14.0, 1.5, {}, [], status="error", error="PortLostError"))
    w.end_suite("rep", error="lost the robot", ended_s=15.5)
    (tmp_path / f".{RESULTS_FILE}.deadbeef.tmp").write_text("{half a reco")  # crash leftover
    return w.path


def test_resume_continues_where_the_run_stopped(tmp_path: Path) -> None:
    _interrupted_run(tmp_path)
    w = RecordWriter.resume(tmp_path)
    assert _files(tmp_path) == [RESULTS_FILE]                # stale temp file removed
    assert len(w.record.resumed) == 1
    assert w.record.verdict == "error"
    assert w.suite_done("acc") and not w.suite_done("rep") and not w.suite_done("last")
    assert [t.index for t in w.completed_trials("rep")] == [0, 1]
    assert w.completed_trials("last") == []
    assert w.elapsed_s() >= 15.5                              # the run clock continues

    assert w.begin_suite("acc", "1") is w.record.suites["acc"]  # done: unchanged
    suite = w.begin_suite("rep", "2", {"speeds_pct": [25, 50]})
    assert suite.status == "running" and suite.error is None and suite.ended_s is None
    w.add_trial("rep", Trial(2, w.elapsed_s(), 1.0, {}, [{"t_s": 0.0}]))
    w.end_suite("rep")
    w.begin_suite("last", "1")
    w.end_suite("last")

    final = load_record(w.path)
    rep = final.suites["rep"]
    assert [(t.index, t.status) for t in rep.trials] == [(0, "done"), (1, "done"), (2, "done")]
    assert [(t.index, t.error) for t in rep.superseded_trials] == [(2, "PortLostError")]
    assert final.verdict == "pass"
    assert final.resumed == w.record.resumed


def test_resume_refuses_changed_suite_conditions(tmp_path: Path) -> None:
    _interrupted_run(tmp_path)
    w = RecordWriter.resume(tmp_path)
    with pytest.raises(RecordError, match="version"):
        w.begin_suite("rep", "3", {"speeds_pct": [25, 50]})
    with pytest.raises(RecordError, match="params"):
        w.begin_suite("rep", "2", {"speeds_pct": [25, 100]})
    with pytest.raises(RecordError, match="does not exist"):
        RecordWriter.resume(tmp_path / "nothing-here")


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------


def _valid() -> dict[str, Any]:
    data: dict[str, Any] = json.loads((RECORDS / "passing.json").read_text(encoding="utf-8"))
    return data


def test_validate_refuses_other_schemas() -> None:
    data = _valid()
    del data["schema"]
    with pytest.raises(RecordError, match="not an armbench run record"):
        validate_record(data)
    data["schema"] = "armbench-run/2"
    with pytest.raises(RecordError, match=r"'armbench-run/2' is not supported.*armbench-run/1"):
        validate_record(data)
    with pytest.raises(RecordError, match="expected an object"):
        validate_record([1, 2])


@pytest.mark.parametrize(("edit", "where"), [
    (lambda d: d.pop("run_id"), "run_id"),
    (lambda d: d["environment"].pop("git_revision"), "environment.git_revision"),
    (lambda d: d["suites"]["accuracy"]["trials"][1]["measurements"][0].pop("value"),
     "suites.accuracy.trials[1].measurements[0].value"),
    (lambda d: d["suites"]["accuracy"]["trials"][0].update(duration_s="long"),
     "suites.accuracy.trials[0].duration_s"),
    (lambda d: d["suites"]["startup-recovery"].update(status="paused"),
     "suites.startup-recovery.status"),
    (lambda d: d["suites"]["startup-recovery"]["measurements"][0].update(outcome="ok"),
     "suites.startup-recovery.measurements[0].outcome"),
    (lambda d: d["suites"]["accuracy"]["trials"][0]["samples"].append(3),
     "suites.accuracy.trials[0].samples[48]"),
    (lambda d: d["suites"]["accuracy"]["trials"][0].update(status="error"),
     "suites.accuracy.trials[0]"),
    (lambda d: d["suites"]["accuracy"].update(name="other"), "suites.accuracy.name"),
    (lambda d: d.update(verdict="great"), "verdict"),
    (lambda d: d["suites"]["startup-recovery"]["measurements"].append(
        d["suites"]["accuracy"]["measurements"][0]), "suites.startup-recovery.measurements"),
])
def test_validate_names_the_bad_field(edit: Any, where: str) -> None:
    data = _valid()
    edit(data)
    with pytest.raises(RecordError) as info:
        validate_record(data)
    assert info.value.where == where, str(info.value)


def test_validate_ignores_unknown_keys() -> None:
    data = _valid()
    data["added_in_a_later_version"] = {"x": 1}
    data["suites"]["accuracy"]["trials"][0]["extra"] = True
    assert validate_record(data).run_id == data["run_id"]


def test_load_record_errors(tmp_path: Path) -> None:
    with pytest.raises(RecordError, match="does not exist"):
        load_record(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(RecordError, match="not valid JSON"):
        load_record(tmp_path / "bad.json")
    (tmp_path / "nan.json").write_text('{"schema": "armbench-run/1", "x": NaN}')
    with pytest.raises(RecordError, match=r"nan\.json: verdict: missing"):
        load_record(tmp_path / "nan.json")
    with pytest.raises(RecordError, match="is a directory"):
        load_record(tmp_path)


# --------------------------------------------------------------------------------------------
# Environment
# --------------------------------------------------------------------------------------------


def test_capture_environment() -> None:
    cfg = LimitsConfig(path="bench.toml")
    env = capture_environment(port="fake://", settings=RobotSettings().with_d4(0.05), seed=7,
                              faults=[{"kind": "power_cut", "at_s": 1.0}], limits=cfg)
    assert env.port == "fake://" and env.seed == 7
    assert env.settings["geometry"]["d4_m"] == 0.05
    assert env.faults == ({"kind": "power_cut", "at_s": 1.0},)
    assert (env.limits_spec_version, env.config_path) == (SPEC_VERSION, "bench.toml")
    assert env.python.count(".") == 2 and env.platform and env.armbench_version
    rev = env.git_revision
    assert rev in ("unknown", NOT_A_CHECKOUT) or (len(rev) == 40 and int(rev, 16) >= 0)
    bare = capture_environment()
    assert bare.settings == RobotSettings().to_mapping()
    assert (bare.limits_spec_version, bare.config_path, bare.faults) == (None, None, ())


def test_git_revision_tolerates_failure(monkeypatch: pytest.MonkeyPatch) -> None:
    def no_git(*args: Any, **kwargs: Any) -> None:
        raise FileNotFoundError("git")

    def hangs(*args: Any, **kwargs: Any) -> None:
        raise subprocess.TimeoutExpired("git", 5.0)

    monkeypatch.setattr(subprocess, "run", no_git)
    assert git_revision() == "unknown"
    monkeypatch.setattr(subprocess, "run", hangs)
    assert git_revision() == "unknown"


def test_new_record_defaults() -> None:
    r = RunRecord.new(_env(), ["a"])
    assert r.schema == SCHEMA and r.reference == {"paper_mean_error_mm": 12.4}
    assert r.created.endswith("+00:00") and r.run_id != RunRecord.new(_env()).run_id
    assert RunRecord.new(_env(), run_id="mine").run_id == "mine"


# --------------------------------------------------------------------------------------------
# Fixture records
# --------------------------------------------------------------------------------------------


def _make_records(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    """tests/fixtures/make_records.py, loaded by path (``tests`` is not a package)."""
    spec = importlib.util.spec_from_file_location("armbench_make_records",
                                                  FIXTURES / "make_records.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(("name", "verdict"), [
    ("passing", "pass"), ("failing", "fail"), ("regressed", "regression"),
    ("interrupted", "error"),
])
def test_fixture_records_validate(name: str, verdict: str) -> None:
    raw = json.loads((RECORDS / f"{name}.json").read_text(encoding="utf-8"))
    rec = validate_record(raw)
    assert raw["verdict"] == rec.verdict == verdict
    assert rec.to_json() == raw
    assert {"accuracy", "startup-recovery"} <= set(rec.suites)
    acc = rec.suites["accuracy"]
    assert {t.params["style"] for t in acc.trials} == {"paper", "coordinated"}
    assert set(acc.trials[0].samples[0]) == {"t_s", "reported_m", "true_m"}


def test_fixture_records_are_up_to_date(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The committed fixtures are what make_records.py writes now (regenerate them with
    ``python3 -m tests.fixtures.make_records`` when this fails)."""
    monkeypatch.setattr(os, "fsync", lambda fd: None)  # content matters here, not durability
    paths = _make_records(monkeypatch).build(tmp_path)
    assert sorted(paths) == sorted(["passing", "failing", "regressed", "interrupted"])
    for name, path in paths.items():
        fresh = json.loads(path.read_text(encoding="utf-8"))
        committed = json.loads((RECORDS / f"{name}.json").read_text(encoding="utf-8"))
        _assert_close(fresh, committed, name)


def _assert_close(a: object, b: object, where: str) -> None:
    """Equal JSON, floats to 1e-9 relative (numpy builds may differ in the last bits)."""
    if isinstance(a, float) and isinstance(b, (int, float)):
        assert math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12), where
    elif isinstance(a, dict) and isinstance(b, dict):
        assert list(a) == list(b), where
        for k in a:
            _assert_close(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list) and isinstance(b, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_close(x, y, f"{where}[{i}]")
    else:
        assert a == b, where


def test_limit_json_shape() -> None:
    m = judge("acc.mean_mm", 1.0, "mm", CONFIG)
    assert m.to_json()["limit"] == {"metric": "acc.mean_mm", "unit": "mm", "low": None,
                                    "high": 5.0}
    assert Measurement.from_json(m.to_json(), "m") == m
    assert m.limit == Limit("acc.mean_mm", "mm", None, 5.0)


def test_a_new_writer_removes_what_a_writer_killed_mid_write_left(tmp_path: Path) -> None:
    """A run killed during its first write leaves ``.results.json.<id>.tmp`` and no record; a
    fresh run into that folder removes it (as a resume does), and nothing else."""
    stale = tmp_path / ".results.json.0123456789ab.tmp"
    stale.write_text('{"torn')
    other = tmp_path / "notes.tmp"
    other.write_text("the user's")
    RecordWriter(tmp_path, _record())
    assert not stale.exists() and other.read_text() == "the user's"
    assert not list(tmp_path.glob(".results.json.*"))
