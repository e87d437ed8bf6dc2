"""What goes on beside a run's trials: its caller's work (``run_arms_sync(ahead=...)``, a
``RunAhead``): the run command imports the report's modules once the run is under way and draws
each suite's plots once its summary is in the record, so that the report written when the run
ends finds them drawn (``reports.render.svg_cache``) and is the same page as one drawn from
nothing; and each suite's summary, computed off the run's loop so that the loop goes on sending
the next suite's trials to the workers."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, ClassVar

import pytest
from conftest import packaged_limits_with
from matplotlib.figure import Figure
from test_runner import TinySuite

from armbench.bench.runner import RunOptions, run_arms_sync, run_sync
from armbench.bench.suites import SUITES, SuiteContext
from armbench.cli.commands.run_files import ReportAhead
from armbench.record import Measurement, RunRecord, Trial, load_record
from armbench.reports.pages import page
from armbench.reports.pages.page import build_report_html
from armbench.reports.render import svg_cache
from armbench.reports.render.format import jinja_environment
from armbench.reports.render.views import Figures

RECORDS = Path(__file__).parent / "fixtures" / "records"
#: The packaged limits with one lap of the square and two joint cycles: what goes on beside a
#: run does not depend on how many trials its suites have.
SHORT_SUITES = """
[suites.accuracy]
laps = 1

[suites.joints]
cycles = 2
"""


@pytest.fixture
def short_config(tmp_path: Path) -> Path:
    """The packaged limits with fewer trials per suite."""
    return packaged_limits_with(tmp_path / "bench.toml", SHORT_SUITES)


class Heard:
    """A ``RunAhead`` that writes down what it hears, and where."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, str, Any]] = []

    def started(self) -> None:
        self.calls.append(("started", threading.current_thread().name, None))

    def summarized(self, record: RunRecord, suite: str) -> None:
        s = record.suites[suite]
        self.calls.append(("summarized", suite, (s.ended_s is not None, len(s.measurements))))


@pytest.mark.parametrize("ports", [[], ["a=fake://", "b=fake://?seed=3"]])
def test_the_run_says_when_it_is_under_way_and_when_each_summary_is_in(
        tmp_path: Path, short_config: Path, ports: list[str]) -> None:
    heard = Heard()
    result = run_arms_sync(RunOptions(suites=["accuracy"], ports=ports, workers=1,
                                      config=short_config, out=tmp_path / "run"),
                           progress=None, ahead=heard)
    assert result.exit_status == 0
    arms = max(1, len(ports))
    assert heard.calls[0][0] == "started"
    assert [c[0] for c in heard.calls].count("started") == arms
    summaries = [c for c in heard.calls if c[0] == "summarized"]
    assert len(summaries) == arms
    for _, suite, (ended, measured) in summaries:  # the summary is in the record when heard
        assert suite == "accuracy" and ended and measured > 0


def test_the_run_command_draws_each_suite_ahead_and_the_report_only_the_traffic(
        tmp_path: Path, short_config: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every suite's plots are drawn in the thread of its own, and the report written at the
    end draws only the traffic plot (its capture is whole only then) and compiles no template
    (compiled in that thread too)."""
    from armbench.cli.commands import run_files
    from armbench.cli.main import main

    ahead: list[tuple[str, str]] = []
    draw = page.draw_ahead

    def watched(record: RunRecord, suite: str) -> None:
        ahead.append((threading.current_thread().name, suite))
        draw(record, suite)

    in_report: list[int] = []
    write = run_files.write_reports

    def counted(record: RunRecord, out_dir: Path, **options: Any) -> None:
        before = svg_cache.misses()
        write(record, out_dir, **options)
        in_report.append(svg_cache.misses() - before)

    env = jinja_environment()
    compiled: list[str] = []
    compile_template = env.compile

    def compiling(source: str, name: str | None = None, *args: Any, **kwargs: Any) -> Any:
        compiled.append(threading.current_thread().name)
        return compile_template(source, name, *args, **kwargs)

    monkeypatch.setattr(page, "draw_ahead", watched)
    monkeypatch.setattr("armbench.cli.commands.run.write_reports", counted)
    monkeypatch.setattr(env, "compile", compiling)
    svg_cache.clear()
    env.cache.clear()  # type: ignore[union-attr]  # the environment keeps a cache
    status = main(["run", "accuracy", "joints", "--workers", "1", "--config", str(short_config),
                   "--out", str(tmp_path / "run")])
    assert status == 0 and (tmp_path / "run" / "report.html").exists()
    assert ahead == [("armbench-report-ahead", "accuracy"), ("armbench-report-ahead", "joints")]
    assert in_report == [1]
    # the templates were compiled ahead too: the report compiled none
    assert compiled and set(compiled) == {"armbench-report-ahead"}, compiled


@pytest.mark.parametrize("fixture", ["passing", "interrupted"])
def test_a_page_is_the_same_whether_its_plots_were_drawn_ahead(fixture: str) -> None:
    record = load_record(RECORDS / f"{fixture}.json")
    svg_cache.clear()
    cold = build_report_html(record)
    drawn_cold = svg_cache.misses()
    svg_cache.clear()
    ahead = ReportAhead()
    ahead.started()
    for name in record.suites:
        ahead.summarized(record, name)
    ahead.finish()
    ahead.summarized(record, next(iter(record.suites)))  # after finish: nothing more is drawn
    before = svg_cache.misses()
    assert before > drawn_cold  # the plots were drawn again, ahead
    assert build_report_html(record) == cold
    assert svg_cache.misses() == before


def line(ys: list[float]) -> Figure:
    """A plot function its name finds."""
    fig = Figure(figsize=(2, 1))
    fig.add_subplot().plot(ys)
    return fig


def test_the_same_inputs_are_drawn_once_and_other_ones_again() -> None:
    svg_cache.clear()
    figs = Figures()
    start = svg_cache.misses()
    first = figs.make(line, ([0.0, 1.0],), "a line", "caption")
    again = figs.make(line, ([0.0, 1.0],), "a line", "caption")
    assert svg_cache.misses() == start + 1
    assert 'id="f1-' in first.svg and 'id="f2-' in again.svg and 'id="f1-' not in again.svg
    assert str(again.svg) == str(first.svg).replace('"f1-', '"f2-').replace("#f1-", "#f2-")
    other = figs.make(line, ([0.0, 1.5],), "a line", "caption")
    relabelled = figs.make(line, ([0.0, 1.0],), "a line", "caption", "its slope 1")
    assert svg_cache.misses() == start + 3
    assert "its slope 1" in relabelled.svg and "its slope 1" not in first.svg
    assert str(other.svg).replace('"f3-', '"f1-').replace("#f3-", "#f1-") != str(first.svg)


def test_a_plot_its_name_does_not_find_is_drawn_every_time() -> None:
    """Two closures share a qualified name: a name cannot tell their plots apart."""
    def scaled(k: float) -> Any:
        def plot(ys: list[float]) -> Figure:
            return line([k * y for y in ys])
        return plot

    svg_cache.clear()
    figs = Figures()
    start = svg_cache.misses()
    one = figs.make(scaled(1.0), ([0.0, 1.0],), "a line", "caption")
    two = figs.make(scaled(2.0), ([0.0, 1.0],), "a line", "caption")
    assert svg_cache.misses() == start + 2
    assert str(two.svg).replace('"f2-', '"f1-').replace("#f2-", "#f1-") != str(one.svg)


def blank(k: float) -> Figure:
    """A plot function its name finds, whose plot has nothing to draw (the cheapest SVG): its
    input alone tells its plots apart."""
    return Figure(figsize=(0.1, 0.1))


def test_at_most_so_many_plots_are_kept_the_oldest_used_going_first() -> None:
    """Which plots are kept is the claim, not what they show: blank plots, and no collection
    after each (a full one in this process, as no page sets its objects aside)."""
    svg_cache.clear()
    figs = Figures(collect=False)
    for k in range(svg_cache.MAX_DRAWN):
        figs.make(blank, (float(k),), "a plot", "caption")
    figs.make(blank, (0.0,), "a plot", "caption")  # used again: now the newest
    start = svg_cache.misses()
    figs.make(blank, (-1.0,), "a plot", "caption")  # one more: plot 1 goes
    figs.make(blank, (0.0,), "a plot", "caption")
    assert svg_cache.misses() == start + 1
    figs.make(blank, (1.0,), "a plot", "caption")
    assert svg_cache.misses() == start + 2


class BesideSuite(TinySuite):
    """``beside``: its summary asks the run's loop to run a callback and waits for it, which only
    a summary off the loop's thread can see done."""

    name = "beside"
    loop: ClassVar[asyncio.AbstractEventLoop | None] = None

    async def run_trial(self, ctx: SuiteContext, index: int,
                        trial_params: Mapping[str, Any]) -> Trial:
        BesideSuite.loop = asyncio.get_running_loop()
        return await super().run_trial(ctx, index, trial_params)

    def summarize(self, ctx: SuiteContext, trials: Sequence[Trial]) -> list[Measurement]:
        ran = threading.Event()
        assert BesideSuite.loop is not None
        BesideSuite.loop.call_soon_threadsafe(ran.set)
        if not ran.wait(30):
            raise RuntimeError("the run's loop did not run during the summary")
        return super().summarize(ctx, trials)


@pytest.fixture
def _beside_registered(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    monkeypatch.setitem(SUITES, "beside", f"{__name__}:BesideSuite")
    yield


@pytest.mark.usefixtures("_beside_registered")
def test_a_summary_is_computed_while_the_loop_goes_on(tmp_path: Path) -> None:
    outcome = run_sync(RunOptions(suites=["beside"], out=tmp_path / "run", workers=1),
                       progress=None)
    suite = outcome.record.suites["beside"]
    assert suite.error is None, suite.error
    assert "tiny.move_mean_s" in {m.name for m in suite.measurements}
    assert load_record(tmp_path / "run" / "results.json").suites["beside"].measurements
