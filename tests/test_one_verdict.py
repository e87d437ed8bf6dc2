"""One judgement: ``armbench compare A B`` and ``armbench run --baseline A`` judge every metric
alike, from the same config, with the same exit status; ``armbench config show`` prints the
config both read."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from armbench.bench.runner import RunOptions, run_sync
from armbench.bench.suites import load_suite, suite_names
from armbench.cli import main as cli
from armbench.drivers.model.settings import RobotSettings
from armbench.record import load_record
from armbench.record.baseline import compare
from armbench.record.limits import parse_limits
from armbench.record.verdict import (
    EXIT_ERROR,
    EXIT_FAIL,
    EXIT_INCOMPLETE,
    EXIT_INTERRUPTED,
    EXIT_PASS,
    EXIT_REGRESSION,
    load_config,
    worst_exit_status,
)

RECORDS = Path(__file__).parent / "fixtures" / "records"

#: One coordinated lap of a small square; tight tolerances so that some variants regress and
#: others do not, with an absolute slack on some metrics and not on others.
CONFIG = """\
spec_version = "armbench-limits/1"

[suites.accuracy]
laps = 1
styles = ["coordinated"]
side_m = 0.04

[regression]
default_tolerance_pct = 3.0

[regression.metrics."accuracy.coordinated.*_mm"]
tolerance_pct = 5.0
tolerance_abs = 0.002
"""

#: The runs judged against the baseline (fake://, seed 0): seeds, payloads, profile, settings.
VARIANTS = [
    ("seed1", "fake://?seed=1", None),
    ("seed2", "fake://?seed=2", None),
    ("seed7", "fake://?seed=7", None),
    ("payload0.3", "fake://?payload=0.3", None),
    ("payload1", "fake://?payload=1", None),
    ("payload2.5", "fake://?payload=2.5", None),
    ("ideal", "fake://?profile=ideal", None),
    ("same", "fake://", None),
    ("backlash", "fake://", "[emulator.physics.j2]\nbacklash_deg = 0.6\n"),
    ("longer-a2", "fake://?seed=3", "[emulator.physics.geometry_error]\na2_m = 0.003\n"),
]


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, dict[str, Path]]:
    root = tmp_path_factory.mktemp("verdict")
    config = root / "bench.toml"
    config.write_text(CONFIG, encoding="utf-8")
    base = root / "base"
    run_sync(RunOptions(suites=["accuracy"], ports=["fake://"], config=config, out=base,
                        workers=1, capture=False), progress=None)
    judged: dict[str, Path] = {}
    for name, port, settings in VARIANTS:
        settings_file = None
        if settings is not None:
            settings_file = root / f"{name}.toml"
            settings_file.write_text(settings, encoding="utf-8")
        out = root / name
        run_sync(RunOptions(suites=["accuracy"], ports=[port], config=config, out=out,
                            baseline=base / "results.json", settings=settings_file,
                            workers=1, capture=False), progress=None)
        judged[name] = out
    return config, base, judged


def test_compare_and_run_baseline_agree_on_every_metric(
        runs: tuple[Path, Path, dict[str, Path]], capsys: pytest.CaptureFixture[str]) -> None:
    config, base, judged = runs
    statuses = set()
    for name, out in judged.items():
        record = load_record(out / "results.json")
        assert record.baseline is not None
        capsys.readouterr()
        status = cli.main(["compare", str(base), str(out), "--config", str(config), "--json"])
        printed = capsys.readouterr()
        data = json.loads(printed.out)
        assert "note" not in printed.err  # the config the run was judged with
        by_run = {r.name: r.to_json() for r in record.baseline.rows}
        by_compare = {r["name"]: r for r in data["rows"]}
        assert by_compare == by_run, name
        assert data["regressed"] == record.baseline.regressed, name
        # no limits in the config: the run's verdict is the regression alone, as compare's
        assert status == run_status(record.verdict), name
        statuses.add(status)
    assert statuses == {EXIT_PASS, EXIT_REGRESSION}  # the variants exercise both outcomes
    # without --config: the packaged default, and a note that the run was judged otherwise
    cli.main(["compare", str(base), str(next(iter(judged.values()))), "--json"])
    err = capsys.readouterr().err
    assert f"run B was judged with the config {config}" in err and "--config" in err


def run_status(verdict: str) -> int:
    return {"pass": EXIT_PASS, "regression": EXIT_REGRESSION}[verdict]


def test_compare_without_config_judges_with_the_packaged_default(
        capsys: pytest.CaptureFixture[str]) -> None:
    passing, regressed = str(RECORDS / "passing.json"), str(RECORDS / "regressed.json")
    cli.main(["compare", passing, regressed, "--json"])
    rows = json.loads(capsys.readouterr().out)["rows"]
    default = load_config(None)
    assert rows
    for row in rows:
        tol = default.tolerance_for(row["name"])
        assert (row["tolerance_pct"], row["tolerance_abs"]) == (tol.tolerance_pct,
                                                                 tol.tolerance_abs)
    record, baseline = load_record(regressed), load_record(passing)
    assert [r.to_json() for r in compare(record, baseline, default).rows] == rows


def _origins(text: str) -> dict[str, str]:
    """``table.key`` -> the origin comment of each ``key = value  # origin`` line."""
    out, table = {}, ""
    for line in text.splitlines():
        if line.startswith("["):
            table = line.split("]")[0].strip("[")
        elif " = " in line and "  # " in line:
            key = line.split(" = ", 1)[0]
            out[f"{table}.{key}" if table else key] = line.rsplit("  # ", 1)[1]
    return out


def test_config_show_prints_the_effective_config(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Defaults, then the --config file, then the flags, merged, each value's origin in a
    comment; every suite's parameters written out; and the output, given back to --config,
    is the same configuration."""
    assert cli.main(["config", "show"]) == EXIT_PASS
    text = capsys.readouterr().out
    shown = tomllib.loads(text)
    default = load_config(None)
    config = parse_limits(shown)
    assert (config.limits, config.tolerances) == (default.limits, default.tolerances)
    assert set(shown["suites"]) == set(suite_names())
    for name in suite_names():
        assert shown["suites"][name] == json.loads(json.dumps(
            load_suite(name).params(RobotSettings(), {})))
    assert shown["bench"]["retries"] == 0 and shown["bench"]["capture"] is True
    origins = _origins(text)
    assert origins["bench.retries"] == "default"
    assert origins["suites.accuracy.laps"] == "suite default"

    mine = tmp_path / "mine.toml"
    mine.write_text(CONFIG + "\n[bench]\nretries = 2\nworkers = 1\n", encoding="utf-8")
    assert cli.main(["config", "show", "accuracy", "--config", str(mine), "--workers",
                     "3"]) == EXIT_PASS
    text = capsys.readouterr().out
    shown, origins = tomllib.loads(text), _origins(text)
    assert shown["regression"]["default_tolerance_pct"] == 3.0
    assert origins["regression.default_tolerance_pct"] == str(mine)
    assert (shown["bench"]["retries"], origins["bench.retries"]) == (2, str(mine))
    assert (shown["bench"]["workers"], origins["bench.workers"]) == (3, "--workers")
    assert origins["bench.reply_timeout_s"] == "default"
    assert list(shown["suites"]) == ["accuracy"]
    accuracy = shown["suites"]["accuracy"]
    assert (accuracy["laps"], accuracy["styles"], accuracy["side_m"]) == (
        1, ["coordinated"], 0.04)
    assert origins["suites.accuracy.laps"] == str(mine)
    assert accuracy["duty"] == 99 and origins["suites.accuracy.duty"] == "suite default"
    assert "limits" not in shown  # the file replaces the packaged one: no limit of its own

    again = tmp_path / "again.toml"
    again.write_text(text, encoding="utf-8")
    assert cli.main(["config", "show", "accuracy", "--config", str(again)]) == EXIT_PASS
    assert tomllib.loads(capsys.readouterr().out) == shown
    assert cli.main(["config", "show", "--config", str(tmp_path / "nope.toml")]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert "nope.toml" in err and len(err.strip().splitlines()) == 1
    assert cli.main(["config", "show", "--workers", "0"]) == EXIT_ERROR
    assert "--workers" in capsys.readouterr().err


def test_the_worst_exit_status_of_several_outcomes() -> None:
    assert worst_exit_status([EXIT_PASS, EXIT_REGRESSION]) == EXIT_REGRESSION
    assert worst_exit_status([EXIT_REGRESSION, EXIT_FAIL]) == EXIT_FAIL
    assert worst_exit_status([EXIT_FAIL, EXIT_INCOMPLETE]) == EXIT_INCOMPLETE
    assert worst_exit_status([EXIT_INCOMPLETE, EXIT_ERROR]) == EXIT_ERROR
    assert worst_exit_status([EXIT_ERROR, EXIT_INTERRUPTED]) == EXIT_INTERRUPTED
    assert worst_exit_status([]) == EXIT_PASS
