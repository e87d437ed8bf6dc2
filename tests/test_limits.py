"""armbench.record.limits: the limits file format, errors naming the field, wildcard precedence."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from armbench.drivers.model.errors import ArmbenchError
from armbench.drivers.model.settings import SettingsError
from armbench.record.limits import (
    DEFAULT_TOLERANCE_PCT,
    SPEC_VERSION,
    Limit,
    LimitsConfig,
    Tolerance,
    best_match,
    load_limits,
    parse_limits,
)

EXAMPLE = """
spec_version = "armbench-limits/1"
[limits."accuracy.coordinated.mean_mm"]
high = 5.0          # or low =, or both
unit = "mm"
[limits."repeatability.p1.rp_mm"]
high = 2.0
unit = "mm"
[limits."startup.recovery_rate_pct"]
low = 95
high = 100
unit = "%"
[regression]
default_tolerance_pct = 10.0
[regression.metrics."accuracy.coordinated.mean_mm"]
tolerance_pct = 20.0
tolerance_abs = 0.5
[bench]
settle_s = 0.5
[suites.accuracy]
side_m = 0.1
centre_m = [0.35, 0.0, 0.45]
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bench.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _parse(**tables: Any) -> LimitsConfig:
    return parse_limits({"spec_version": SPEC_VERSION, **tables})


def test_example_file_loads(tmp_path: Path) -> None:
    path = _write(tmp_path, EXAMPLE)
    cfg = load_limits(path)
    assert cfg.spec_version == SPEC_VERSION
    assert cfg.path == str(path)
    assert cfg.limits["accuracy.coordinated.mean_mm"] == Limit(
        "accuracy.coordinated.mean_mm", "mm", None, 5.0)
    rate = cfg.limits["startup.recovery_rate_pct"]
    assert (rate.low, rate.high, rate.unit) == (95.0, 100.0, "%")
    assert isinstance(rate.low, float)
    assert cfg.default_tolerance_pct == 10.0
    assert cfg.tolerance_for("accuracy.coordinated.mean_mm") == Tolerance(20.0, 0.5)
    assert cfg.tolerance_for("repeatability.p1.rp_mm") == Tolerance(10.0, 0.0)
    assert cfg.bench_params() == {"settle_s": 0.5}
    assert cfg.suite_params("accuracy") == {"side_m": 0.1, "centre_m": [0.35, 0.0, 0.45]}
    assert cfg.suite_params("absent") == {}


def test_suite_params_are_copies() -> None:
    cfg = _parse(suites={"accuracy": {"centre_m": [0.35, 0.0, 0.45]}}, bench={"a": [1]})
    cfg.suite_params("accuracy")["centre_m"].append(9)
    cfg.bench_params()["a"].append(2)
    assert cfg.suite_params("accuracy") == {"centre_m": [0.35, 0.0, 0.45]}
    assert cfg.bench_params() == {"a": [1]}


def test_empty_config_judges_nothing() -> None:
    cfg = LimitsConfig()
    assert cfg.limit_for("accuracy.coordinated.mean_mm") is None
    assert cfg.tolerance_for("x") == Tolerance(DEFAULT_TOLERANCE_PCT)
    assert _parse().limits == {}


def test_tolerance_pct_defaults_to_the_files_default() -> None:
    cfg = _parse(regression={"default_tolerance_pct": 15.0,
                             "metrics": {"a.*": {"tolerance_abs": 0.2}}})
    assert cfg.tolerance_for("a.b") == Tolerance(15.0, 0.2)
    assert cfg.tolerance_for("b") == Tolerance(15.0, 0.0)
    assert Tolerance(10.0, 0.5).allowance(-4.0) == pytest.approx(0.9)


@pytest.mark.parametrize(("data", "field", "reason"), [
    ({"spec_version": SPEC_VERSION, "limit": {}}, "limit", "not a known key"),
    ({}, "spec_version", "missing"),
    ({"spec_version": "armbench-limits/2"}, "spec_version", "not supported"),
    ({"spec_version": SPEC_VERSION, "limits": []}, "limits", "not a table"),
    ({"spec_version": SPEC_VERSION, "limits": {"a.b": 5}}, 'limits."a.b"', "not a table"),
    ({"spec_version": SPEC_VERSION, "limits": {"a.b": {"high": 5}}}, 'limits."a.b".unit',
     "missing"),
    ({"spec_version": SPEC_VERSION, "limits": {"a.b": {"high": 5, "unit": 1}}},
     'limits."a.b".unit', "not a string"),
    ({"spec_version": SPEC_VERSION, "limits": {"a.b": {"unit": "mm"}}}, 'limits."a.b"',
     "neither low nor high"),
    ({"spec_version": SPEC_VERSION, "limits": {"a.b": {"low": 6, "high": 5, "unit": "mm"}}},
     'limits."a.b".low', "6 must be <= 5 (high)"),
    ({"spec_version": SPEC_VERSION, "limits": {"a.b": {"high": "5", "unit": "mm"}}},
     'limits."a.b".high', "must be a number"),
    ({"spec_version": SPEC_VERSION, "limits": {"a.b": {"high": True, "unit": "mm"}}},
     'limits."a.b".high', "must be a number"),
    ({"spec_version": SPEC_VERSION, "limits": {"a.b": {"low": math.nan, "unit": "mm"}}},
     'limits."a.b".low', "nan must be a finite number"),
    ({"spec_version": SPEC_VERSION, "limits": {"a.b": {"high": 5, "unit": "mm", "hi": 1}}},
     'limits."a.b".hi', "not a known key"),
    ({"spec_version": SPEC_VERSION, "limits": {"a b": {"high": 5, "unit": "mm"}}},
     'limits."a b"', "not a metric name"),
    ({"spec_version": SPEC_VERSION, "regression": {"tolerance": 1}}, "regression.tolerance",
     "not a known key"),
    ({"spec_version": SPEC_VERSION, "regression": {"default_tolerance_pct": -1}},
     "regression.default_tolerance_pct", ">= 0"),
    ({"spec_version": SPEC_VERSION, "regression": {"metrics": {"a": {}}}},
     'regression.metrics."a"', "neither"),
    ({"spec_version": SPEC_VERSION, "regression": {"metrics": {"a": {"tolerance_abs": "x"}}}},
     'regression.metrics."a".tolerance_abs', "'x' must be a number >= 0"),
    ({"spec_version": SPEC_VERSION, "regression": {"metrics": {"a": {"pct": 1}}}},
     'regression.metrics."a".pct', "not a known key"),
    ({"spec_version": SPEC_VERSION, "suites": {"accuracy": 3}}, 'suites."accuracy"',
     "not a table"),
    ({"spec_version": SPEC_VERSION, "bench": 3}, "bench", "not a table"),
])
def test_errors_name_the_field(data: dict[str, Any], field: str, reason: str) -> None:
    with pytest.raises(SettingsError) as info:
        parse_limits(data)
    assert info.value.field == field
    assert reason in str(info.value)
    assert str(info.value).startswith(field)
    assert isinstance(info.value, ArmbenchError)


def test_file_errors(tmp_path: Path) -> None:
    with pytest.raises(SettingsError, match="does not exist"):
        load_limits(tmp_path / "missing.toml")
    with pytest.raises(SettingsError, match="is a directory"):
        load_limits(tmp_path)
    with pytest.raises(SettingsError, match="not valid TOML"):
        load_limits(_write(tmp_path, "spec_version = \n"))


def test_limit_bounds_are_inclusive_and_nan_fails() -> None:
    both = Limit("m", "mm", 1.0, 5.0)
    assert both.check(1.0) and both.check(5.0) and both.check(3.0)
    assert not both.check(0.999) and not both.check(5.001) and not both.check(math.nan)
    assert Limit("m", "mm", high=5.0).check(-1e9)
    assert Limit("m", "%", low=95.0).check(1e9)
    assert both.describe() == "1 .. 5 mm"
    assert Limit("m", "mm", high=5.0).describe() == "<= 5 mm"
    assert Limit("m", "", low=1.0).describe() == ">= 1"


def test_most_specific_limit_wins() -> None:
    cfg = _parse(limits={
        "repeatability.*": {"high": 9.0, "unit": "mm"},
        "repeatability.*.rp_mm": {"high": 2.0, "unit": "mm"},
        "repeatability.v100.*.rp_mm": {"high": 3.0, "unit": "mm"},
        "repeatability.v100.p1.rp_mm": {"high": 4.0, "unit": "mm"},
        "*": {"high": 100.0, "unit": "mm"},
    })

    def high(metric: str) -> float | None:
        limit = cfg.limit_for(metric)
        return None if limit is None else limit.high

    assert high("repeatability.v100.p1.rp_mm") == 4.0       # exact name
    assert high("repeatability.v100.p2.rp_mm") == 3.0       # more literal characters
    assert high("repeatability.v50.p2.rp_mm") == 2.0        # '*' spans dots
    assert high("repeatability.v50.p2.ap_mm") == 9.0
    assert high("accuracy.paper.mean_mm") == 100.0
    assert _parse().limit_for("anything") is None


def test_wildcard_ties_prefer_the_later_wildcard_then_sort_order() -> None:
    # Same number of literal characters: the longer literal prefix is more specific.
    assert best_match(["a.*.c", "a.b.*"], "a.b.c") == "a.b.*"
    # Full tie: the pattern that sorts first, whatever the input order.
    assert best_match(["a*c*", "a*b*"], "abc") == "a*b*"
    assert best_match(["a*b*", "a*c*"], "abc") == "a*b*"
    assert best_match(["b*", "*b"], "bb") == "b*"
    assert best_match(["*b", "b*"], "bb") == "b*"
    # Fewer wildcards when literals and first wildcard agree.
    assert best_match(["a*b*", "a*b"], "aXb") == "a*b"
    # Regex characters in names are literal.
    assert best_match(["a.b"], "aXb") is None
    assert best_match(["rate_%"], "rate_%") == "rate_%"


@given(st.from_regex(r"[a-z0-9_]{1,8}(\.[a-z0-9_]{1,8}){0,3}", fullmatch=True))
def test_an_exact_name_beats_every_wildcard(metric: str) -> None:
    parts = metric.split(".")
    patterns = ["*", f"{parts[0]}*", f"*{parts[-1]}", metric, metric[:-1] + "*"]
    assert best_match(patterns, metric) == metric
