"""The run index's trends (``armbench report --index RUNS_DIR``) over real records made by tiny
runs: one series per unit under test and kind of target, true figures apart from believed ones,
each point judged by its own run's limit. Checked on the index's data
(:func:`armbench.reports.render.trends.trend_series`), then on the page and the plot.

The runs are real: ``fake://`` (the emulator on virtual time, with ground truth) and
``socket://`` (the same emulator served on a real TCP socket: a target without truth, as a
ser2net-served arm is)."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from test_report import parse

from armbench.bench.runner import RunOptions, run_bench
from armbench.bench.suites import SUITES, Suite, SuiteContext
from armbench.drivers.model.kinematics import tcp_position
from armbench.drivers.model.settings import RobotSettings
from armbench.fakes.clock.vclock import run_virtual
from armbench.record import Measurement, RunRecord, Trial, load_record
from armbench.record.suite_contract import Headline, forget, register
from armbench.reports import render_index
from armbench.reports.render import plots_over_runs
from armbench.reports.render.trends import TrendSeries, trend_series

LABEL = "mean TCP error"


class TrendSuite(Suite):
    """``trend``: trial k moves joint 1 to ``0.1 (k + 1)`` rad; its figure is the distance of
    the TCP the encoders report from the commanded one (``trend.err_mm``) and, with a truth
    source, of the true TCP from it (``trend.true_err_mm``); the suite's are their means."""

    name = "trend"
    version = "1"

    def default_params(self, settings: RobotSettings) -> dict[str, Any]:
        return {"trials": 2}

    def plan(self, params: Mapping[str, Any]) -> list[dict[str, Any]]:
        return [{"q1": 0.1 * (k + 1)} for k in range(params["trials"])]

    def metric_names(self, params: Mapping[str, Any]) -> frozenset[str]:
        return frozenset({"trend.err_mm", "trend.true_err_mm", "trend.mean_mm",
                          "trend.true_mean_mm"})

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        target = [trial_params["q1"], 0.0, 0.0, 0.0]
        state = await ctx.arm.move_joints(target, 90)
        assert state is not None
        await asyncio.sleep(0.05)
        commanded = [float(x) for x in tcp_position(target, ctx.settings)]
        ms = [ctx.judge("trend.err_mm", 1000 * math.dist(state.tcp_m(ctx.settings), commanded),
                        "mm")]
        true_m = None if ctx.truth is None else ctx.truth.true_position_m()
        if true_m is not None:
            ms.append(ctx.judge("trend.true_err_mm", 1000 * math.dist(true_m, commanded), "mm"))
        return Trial(index, 0.0, 0.0, params=dict(trial_params), measurements=ms)

    def summarize(self, ctx: SuiteContext, trials: Sequence[Trial]) -> list[Measurement]:
        out = []
        for name, mean in (("trend.err_mm", "trend.mean_mm"),
                           ("trend.true_err_mm", "trend.true_mean_mm")):
            values = [m.value for t in trials for m in t.measurements if m.name == name]
            if values:
                out.append(ctx.judge(mean, sum(values) / len(values), "mm"))
        return out


@dataclass(frozen=True, slots=True)
class TrendContract:
    """The contract of ``trend``: one headline, with a true figure beside it."""

    suite: str = "trend"
    order: int = 900
    has_true_figures: bool = True

    @property
    def headlines(self) -> tuple[Headline, ...]:
        return (Headline(LABEL, "trend.mean_mm"),)


@pytest.fixture(autouse=True)
def _trend_registered(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setitem(SUITES, "trend", f"{__name__}:TrendSuite")
    register(TrendContract())
    yield
    forget("trend")


def _config(tmp_path: Path, name: str, high_mm: float, true_high_mm: float) -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(f"""spec_version = "armbench-limits/1"

[limits."trend.mean_mm"]
high = {high_mm!r}
unit = "mm"

[limits."trend.true_mean_mm"]
high = {true_high_mm!r}
unit = "mm"
""")
    return path


def _fake_run(runs: Path, name: str, config: Path, port: str = "fake://",
              dut: str | None = None) -> RunRecord:
    outcome = run_virtual(run_bench(RunOptions(suites=["trend"], ports=[port], config=config,
                                               out=runs / name, dut=dut, workers=1)))
    assert outcome.record.suites["trend"].status == "done", outcome.record.suites["trend"].error
    return load_record(runs / name / "results.json")


async def _socket_run(runs: Path, config: Path, dut: str) -> RunRecord:
    from armbench.fakes.firmware.arm_emulator import ArmEmulator
    from armbench.fakes.links.serve import TcpServer

    server = TcpServer(ArmEmulator())
    host, port = await server.start()
    slow = config.with_name("socket.toml")  # a starved process may answer late: seconds
    slow.write_text(config.read_text() + "\n[bench]\nreply_timeout_s = 5.0\n"
                    "connect_timeout_s = 30.0\nmove_timeout_scale = 10.0\n")
    try:
        outcome = await run_bench(RunOptions(suites=["trend"], ports=[f"socket://{host}:{port}"],
                                             config=slow, out=runs / "socket", dut=dut))
    finally:
        await server.close()
    assert outcome.record.suites["trend"].status == "done", outcome.record.suites["trend"].error
    return load_record(runs / "socket" / "results.json")


def _mean(record: RunRecord, name: str) -> float:
    return record.suite_measurements()[name].value


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """Five runs of ``trend``: arm-1 on fake:// twice (the second with a limit its believed
    figure exceeds), arm-1 served on a socket, arm-2 on fake://, and an unnamed fake:// arm."""
    tmp = tmp_path_factory.mktemp("trends")
    runs = tmp / "runs"
    mp = pytest.MonkeyPatch()
    mp.setitem(SUITES, "trend", f"{__name__}:TrendSuite")
    try:
        loose = _config(tmp, "loose", 100.0, 100.0)
        first = _fake_run(runs, "a-first", loose, dut="arm-1")
        believed = _mean(first, "trend.mean_mm")
        assert believed > 0
        tight = _config(tmp, "tight", believed / 2, 100.0)  # the same arm, the same figures
        _fake_run(runs, "b-tight", tight, dut="arm-1")
        asyncio.run(_socket_run(runs, loose, "arm-1"))
        _fake_run(runs, "c-other", loose, port="fake://?seed=5", dut="arm-2")
        _fake_run(runs, "d-unnamed", loose)
        yield runs
    finally:
        mp.undo()


def _records(runs: Path) -> dict[str, RunRecord]:
    return {d.name: load_record(d / "results.json") for d in sorted(runs.iterdir())
            if (d / "results.json").is_file()}


def _series(runs: Path) -> tuple[dict[int, str], list[TrendSeries]]:
    records = _records(runs)
    numbered = dict(enumerate(records, start=1))
    return numbered, [s for s in trend_series([(k, records[d]) for k, d in numbered.items()])
                      if s.suite == "trend"]


def test_series_never_join_units_or_kinds_of_target(runs: Path) -> None:
    numbered, series = _series(runs)
    by_key = {(s.view, s.unit_under_test, s.kind): [numbered[p.run] for p in s.points]
              for s in series}
    assert by_key == {
        ("believed", "arm-1", "fake"): ["a-first", "b-tight"],
        ("believed", "arm-1", "socket"): ["socket"],
        ("believed", "arm-2", "fake"): ["c-other"],
        ("believed", "port fake://", "fake"): ["d-unnamed"],
        ("true", "arm-1", "fake"): ["a-first", "b-tight"],
        ("true", "arm-2", "fake"): ["c-other"],
        ("true", "port fake://", "fake"): ["d-unnamed"],
    }
    records = _records(runs)
    for s in series:  # each point is its run's own figure of its view, never another's
        for p in s.points:
            name = "trend.true_mean_mm" if s.view == "true" else "trend.mean_mm"
            assert (p.metric, p.value) == (name, _mean(records[numbered[p.run]], name))


def test_a_socket_run_has_no_true_figure_and_none_stands_in(runs: Path) -> None:
    socket = _records(runs)["socket"]
    assert socket.environment.kind == "socket" and not socket.environment.declares_truth
    assert "trend.true_mean_mm" not in socket.suite_measurements()
    _, series = _series(runs)
    assert all(s.kind != "socket" for s in series if s.view == "true")
    assert all(p.metric.rpartition(".")[2].startswith("true_")
               for s in series if s.view == "true" for p in s.points)


def test_each_point_is_judged_by_its_own_runs_limit(runs: Path) -> None:
    numbered, series = _series(runs)
    records = _records(runs)
    believed = next(s for s in series if (s.view, s.unit_under_test, s.kind)
                    == ("believed", "arm-1", "fake"))
    first, tight = believed.points
    assert first.value == pytest.approx(tight.value)  # the same arm measured the same
    assert (first.high, first.outside) == (100.0, False)
    assert tight.high == pytest.approx(first.value / 2) and tight.outside
    assert records[numbered[tight.run]].suite_measurements()["trend.mean_mm"].outcome == "fail"
    true = next(s for s in series if (s.view, s.unit_under_test, s.kind)
                == ("true", "arm-1", "fake"))
    assert [(p.high, p.outside) for p in true.points] == [(100.0, False), (100.0, False)]


def test_the_index_draws_and_lists_the_point_outside_its_limit(runs: Path) -> None:
    numbered, series = _series(runs)
    page = parse(render_index(runs).read_text(encoding="utf-8"))
    table = next(t for t in page.iter("table") if "runs" in t.classes())
    rows = [[c.text().strip() for c in r.iter("td")] for r in list(table.iter("tr"))[1:]]
    tight_id = _records(runs)["b-tight"].run_id
    socket_id = _records(runs)["socket"].run_id
    number = {rid: int(r[0]) for r in rows for rid in (tight_id, socket_id)
              if r[1].startswith(rid)}  # the page's own numbering
    captions = {f.text(): f for f in page.iter("figure")}
    believed = next(c for c in captions if f"{LABEL} (believed)" in c)
    true = next(c for c in captions if f"{LABEL} (true)" in c)
    assert f"outside the limit: run {number[tight_id]} (arm-1 · fake)" in believed
    assert "outside" not in true
    def described(caption: str) -> str:  # what the plot tells a screen reader: every point
        return "".join(n.attrs.get("aria-label") or "" for n in captions[caption].iter("svg"))

    assert f"arm-1 · socket: run {number[socket_id]} " in described(believed)
    assert f"run {number[socket_id]} " not in described(true)  # the socket run: no true figure
    row = next(r for r in rows if r[1].startswith(socket_id))
    assert "arm-1" in row and "socket" in row
    # the plot: the point above its limit line is drawn as a cross, the others as points
    s = next(x for x in series if (x.view, x.unit_under_test) == ("believed", "arm-1"))
    fig = plots_over_runs.trend_plots([plots_over_runs.TrendPanel(
        "t", "mm", list(numbered), [plots_over_runs.TrendLine(
            s.label, [p.run for p in s.points], [p.value for p in s.points],
            [p.outside for p in s.points], [p.low for p in s.points],
            [p.high for p in s.points])])])
    crosses = [line for line in fig.axes[0].lines if line.get_marker() == "X"]
    assert len(crosses) == 1
    x = np.asarray(crosses[0].get_xdata(), dtype=np.float64)
    y = np.asarray(crosses[0].get_ydata(), dtype=np.float64)
    high = s.points[1].high
    assert x.tolist() == [s.points[1].run] and high is not None and y[0] > high
