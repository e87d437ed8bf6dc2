"""armbench.record.baseline: regressions in both directions, tolerances, new/missing metrics,
errors."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import pytest

from armbench.drivers.model.errors import ArmbenchError
from armbench.record import (
    Better,
    Environment,
    Measurement,
    RecordWriter,
    RunRecord,
    SuiteRecord,
    judge,
    load_record,
)
from armbench.record.baseline import (
    BaselineError,
    Comparison,
    ComparisonRow,
    compare,
    format_comparison,
    load_baseline,
)
from armbench.record.limits import SPEC_VERSION, LimitsConfig, Tolerance, parse_limits

RECORDS = Path(__file__).parent / "fixtures" / "records"

Values = dict[str, tuple[float, str, Better | None]]


def _env(spec: str | None = SPEC_VERSION) -> Environment:
    return Environment(armbench_version="0.1.0", git_revision="0123456789abcdef", python="3.11",
                       platform="test", port=None, settings={}, seed=None, faults=(),
                       limits_spec_version=spec, config_path=None)


def _run(values: Values, run_id: str = "run", spec: str | None = SPEC_VERSION) -> RunRecord:
    """A finished record with one suite holding ``values`` as suite-level measurements."""
    ms = [Measurement(name, v, unit, None, "unjudged", better)
          for name, (v, unit, better) in values.items()]
    suite = SuiteRecord(name="s", version="1", status="done", ended_s=1.0, measurements=ms)
    return RunRecord(run_id=run_id, created="2024-05-01T00:00:00+00:00", environment=_env(spec),
                     planned_suites=["s"], suites={"s": suite})


def _row(comparison: Comparison, name: str) -> ComparisonRow:
    return next(r for r in comparison.rows if r.name == name)


def _one(value: float, baseline: float, better: Better | None = "lower",
         config: LimitsConfig | None = None, unit: str = "mm") -> ComparisonRow:
    c = compare(_run({"m": (value, unit, better)}), _run({"m": (baseline, unit, better)}, "base"),
                config)
    return _row(c, "m")


def test_lower_is_better_regresses_when_rising_beyond_tolerance() -> None:
    # default tolerance 10 % of 2.0 mm = 0.2 mm
    assert not _one(2.19, 2.0).regressed
    assert _one(2.21, 2.0).regressed
    assert not _one(1.0, 2.0).regressed          # better is never a regression
    row = _one(2.5, 2.0)
    assert (row.change_abs, row.change_pct, row.tolerance) == pytest.approx((0.5, 25.0, 0.2))
    assert (row.status, row.tolerance_pct, row.tolerance_abs, row.better) == (
        "compared", 10.0, 0.0, "lower")


def test_exactly_at_the_tolerance_is_not_a_regression() -> None:
    # 1.1 - 1.0 is 0.10000000000000009 in binary floating point
    assert not _one(1.1, 1.0).regressed
    assert not _one(2.2, 2.0).regressed


def test_higher_is_better_regresses_when_falling() -> None:
    assert _one(89.0, 100.0, "higher").regressed
    assert not _one(91.0, 100.0, "higher").regressed
    assert not _one(200.0, 100.0, "higher").regressed


def test_no_direction_never_regresses() -> None:
    row = _one(1000.0, 1.0, None, unit="writes")
    assert not row.regressed and row.change_abs == 999.0


def test_tolerances_from_the_config() -> None:
    cfg = parse_limits({"spec_version": SPEC_VERSION, "regression": {
        "default_tolerance_pct": 5.0,
        "metrics": {"m": {"tolerance_pct": 20.0, "tolerance_abs": 0.5}},
    }})
    # 20 % of 2 mm + 0.5 mm = 0.9 mm
    assert not _one(2.9, 2.0, config=cfg).regressed
    assert _one(2.91, 2.0, config=cfg).regressed
    assert _one(2.91, 2.0, config=cfg).tolerance == pytest.approx(0.9)
    wild = dataclasses.replace(cfg, tolerances={"*": Tolerance(0.0, 0.0)})
    assert _one(2.0001, 2.0, config=wild).regressed


def test_zero_baseline_needs_absolute_slack() -> None:
    row = _one(0.1, 0.0)
    assert row.regressed and row.change_pct is None
    cfg = LimitsConfig(tolerances={"m": Tolerance(10.0, 0.2)})
    assert not _one(0.1, 0.0, config=cfg).regressed


def test_new_and_missing_metrics_are_listed_not_failed() -> None:
    now = _run({"a": (1.0, "mm", "lower"), "new": (1.0, "mm", "lower")})
    before = _run({"a": (1.0, "mm", "lower"), "gone": (5.0, "s", "lower")}, "base")
    c = compare(now, before)
    assert [(r.name, r.status) for r in c.rows] == [
        ("a", "compared"), ("new", "new"), ("gone", "missing")]
    assert (_row(c, "new").baseline, _row(c, "new").value) == (None, 1.0)
    assert (_row(c, "gone").baseline, _row(c, "gone").value) == (5.0, None)
    assert not c.regressed and c.regressions == []
    assert (c.baseline_run_id, c.baseline_git_revision) == ("base", "0123456789abcdef")


def test_other_limits_spec_or_schema_is_refused() -> None:
    now = _run({"a": (1.0, "mm", "lower")})
    with pytest.raises(BaselineError, match=r"armbench-limits/0.*armbench-limits/1"):
        compare(now, _run({"a": (1.0, "mm", "lower")}, "old", spec="armbench-limits/0"))
    # A baseline run without a limits file is comparable.
    assert not compare(now, _run({"a": (1.0, "mm", "lower")}, "old", spec=None)).regressed
    other = _run({"a": (1.0, "mm", "lower")}, "old")
    other.schema = "armbench-run/0"
    with pytest.raises(BaselineError, match="armbench-run/0"):
        compare(now, other)


def test_a_changed_unit_is_refused() -> None:
    with pytest.raises(BaselineError, match=r"metric 'a'.*'m'.*'mm'"):
        compare(_run({"a": (0.001, "m", "lower")}), _run({"a": (1.0, "mm", "lower")}, "b"))


def test_load_baseline_names_file_and_schema(tmp_path: Path) -> None:
    data = json.loads((RECORDS / "passing.json").read_text(encoding="utf-8"))
    data["schema"] = "armbench-run/7"
    path = tmp_path / "old.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    with pytest.raises(BaselineError) as info:
        load_baseline(path)
    assert "old.json" in str(info.value) and "armbench-run/7" in str(info.value)
    assert isinstance(info.value, ArmbenchError)
    with pytest.raises(BaselineError, match="does not exist"):
        load_baseline(tmp_path / "none.json")
    assert load_baseline(RECORDS / "passing.json").run_id == "20240503T091500Z-a1b2c3"


def test_comparison_goes_into_the_record_and_sets_the_verdict(tmp_path: Path) -> None:
    base = _run({"acc_mm": (2.0, "mm", "lower"), "rate_pct": (100.0, "%", "higher")}, "b")
    w = RecordWriter(tmp_path, RunRecord(run_id="r", created="now", environment=_env(),
                                         planned_suites=["s"]))
    w.begin_suite("s", "1")
    w.end_suite("s", [judge("acc_mm", 3.0, "mm", None),
                      judge("rate_pct", 100.0, "%", None, better="higher")])
    assert w.record.verdict == "pass"
    w.set_baseline(compare(w.record, base))
    saved = load_record(w.path)
    assert saved.verdict == "regression"
    assert saved.baseline == w.record.baseline
    assert saved.baseline is not None and [r.name for r in saved.baseline.regressions] == [
        "acc_mm"]


def test_fixture_regressions() -> None:
    regressed = load_record(RECORDS / "regressed.json")
    passing = load_record(RECORDS / "passing.json")
    assert regressed.baseline is not None
    names = {r.name for r in regressed.baseline.regressions}
    assert "accuracy.coordinated.mean_mm" in names
    assert {n.split(".")[1] for n in names if n.startswith("repeatability.")} == {"v100"}
    assert all(m.outcome != "fail" for _, _, m in regressed.iter_measurements())
    # Comparing again gives the stored comparison.
    cfg = LimitsConfig(tolerances={
        "accuracy.coordinated.mean_mm": Tolerance(20.0, 0.5),
        "repeatability.*": Tolerance(25.0, 0.05),
        "startup.*": Tolerance(25.0),
    })
    assert compare(regressed, passing, cfg) == regressed.baseline


def test_format_comparison() -> None:
    now = _run({"acc_mm": (3.0, "mm", "lower"), "fast_s": (1.0, "s", "lower"),
                "same_mm": (1.0, "mm", "lower"), "new_mm": (1.0, "mm", "lower")})
    base = _run({"acc_mm": (2.0, "mm", "lower"), "fast_s": (2.0, "s", "lower"),
                 "same_mm": (1.0, "mm", "lower"), "old_mm": (1.0, "mm", "lower")}, "base-run")
    text = format_comparison(compare(now, base), run_id="now-run")
    lines = text.splitlines()
    assert lines[0].startswith("run now-run against baseline base-run")
    table = {line.split()[0]: line for line in lines[2:] if line and line.split()[0] in (
        "acc_mm", "fast_s", "same_mm", "new_mm", "old_mm")}
    assert table["acc_mm"].endswith("REGRESSED") and "+50" in table["acc_mm"]
    assert table["fast_s"].endswith("improved")
    assert table["same_mm"].endswith("ok")
    assert table["new_mm"].endswith("new") and table["old_mm"].endswith("missing")
    assert lines[-1] == "3 compared, 1 regressed, 1 new, 1 missing"
    # Every cell sits inside its column of the rule line.
    spans = [(m.start(), m.end()) for m in re.finditer("-+", lines[3])]
    assert [lines[2][a:b].strip() for a, b in spans] == [
        "metric", "unit", "baseline", "value", "change", "change %", "tolerance", "result"]
    assert [table["acc_mm"][a:b].strip() for a, b in spans] == [
        "acc_mm", "mm", "2", "3", "+1", "+50", "0.2", "REGRESSED"]
