"""reports: the run report and the run index, checked on their content (parsed HTML), their
safety (CSP, no URL, no markup from record text) and the ``report``/``compare`` commands."""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from html.parser import HTMLParser
from pathlib import Path

import pytest

from armbench.bench.suites.startup_contract import STARTUP
from armbench.cli import main as cli
from armbench.cli.perf import PerfOptions
from armbench.record import (
    Environment,
    Measurement,
    RunRecord,
    SuiteRecord,
    Trial,
    load_record,
)
from armbench.reports import (
    CSP,
    VERDICT_MARKS,
    build_report_html,
    format_number,
    format_value,
    render_index,
    render_report,
)
from armbench.reports.pages.index import KEY_METRICS, key_metrics
from armbench.reports.render.capture_summary import summarize_capture

RECORDS = Path(__file__).parent / "fixtures" / "records"
FIXTURES = ("passing", "failing", "regressed", "interrupted")
#: Plots per fixture: the lead plot beside the scorecard, accuracy (paths, error over time,
#: reported vs true), repeatability (cube, scatter), startup-recovery (outcomes by condition,
#: times and errors); the interrupted run never started repeatability.
SVG_COUNT = {"passing": 8, "failing": 8, "regressed": 8, "interrupted": 6}

HOSTILE = ("<script>alert(1)</script>", '"><img src=x onerror=alert(1)>', "</svg><script>")


# --------------------------------------------------------------------------------------------
# A small DOM over html.parser
# --------------------------------------------------------------------------------------------

_VOID = {"area", "base", "br", "col", "embed", "hr", "img", "input", "link", "meta", "source",
         "track", "wbr"}


@dataclass
class Node:
    tag: str
    attrs: dict[str, str | None]
    children: list[Node | str] = field(default_factory=list)

    def iter(self, tag: str | None = None) -> Iterator[Node]:
        for c in self.children:
            if isinstance(c, Node):
                if tag is None or c.tag == tag:
                    yield c
                yield from c.iter(tag)

    def text(self) -> str:
        return "".join(c if isinstance(c, str) else c.text() for c in self.children)

    def classes(self) -> set[str]:
        return set((self.attrs.get("class") or "").split())

    def by_id(self, ident: str) -> Node | None:
        return next((n for n in self.iter() if n.attrs.get("id") == ident), None)


class _Builder(HTMLParser):
    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.root = Node("#document", {})
        self.stack = [self.root]

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        node = Node(tag, dict(attrs))
        self.stack[-1].children.append(node)
        if tag not in _VOID:
            self.stack.append(node)

    def handle_startendtag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.stack[-1].children.append(Node(tag, dict(attrs)))

    def handle_endtag(self, tag: str) -> None:
        for i in range(len(self.stack) - 1, 0, -1):
            if self.stack[i].tag == tag:
                del self.stack[i:]
                return

    def handle_data(self, data: str) -> None:
        self.stack[-1].children.append(data)


def parse(html: str) -> Node:
    b = _Builder()
    b.feed(html)
    b.close()
    return b.root


def rows_of(section: Node) -> list[Node]:
    return list(section.iter("tr"))


def cells(row: Node) -> list[str]:
    return [c.text().strip() for c in row.iter() if c.tag in ("td", "th")]


def check_safe(html: str, doc: Node) -> None:
    """No script, no event handler, no URL, nothing fetched; the CSP meta in place."""
    assert "http://" not in html and "https://" not in html
    tags = list(doc.iter())
    assert not [n for n in tags if n.tag in ("script", "img", "iframe", "object", "embed",
                                             "link", "base", "form")]
    assert not [(n.tag, a) for n in tags for a in n.attrs if a.lower().startswith("on")]
    for n in tags:
        for a in ("src", "href", "xlink:href", "action", "formaction"):
            v = n.attrs.get(a)
            if v is not None:
                assert ":" not in v.split("/")[0], (n.tag, a, v)  # relative or #anchor only
    metas = [n for n in doc.iter("meta")
             if (n.attrs.get("http-equiv") or "").lower() == "content-security-policy"]
    assert len(metas) == 1 and metas[0].attrs["content"] == CSP
    assert "default-src 'none'" in CSP and "script-src" not in CSP
    head = next(doc.iter("head"))
    first = [n for n in head.iter() if n.tag == "meta"]
    assert first[0].attrs.get("charset") == "utf-8"
    assert first[1] is metas[0]  # the CSP comes before anything it governs


# --------------------------------------------------------------------------------------------
# Fixture reports, rendered once per module
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def pages(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[str, Node]]:
    out = tmp_path_factory.mktemp("reports")
    result = {}
    for name in FIXTURES:
        path = render_report(RECORDS / f"{name}.json", out / f"{name}.html")
        html = path.read_text(encoding="utf-8")
        result[name] = (html, parse(html))
    return result


@pytest.mark.parametrize("name", FIXTURES)
def test_fixture_report_is_safe_and_self_contained(pages: dict[str, tuple[str, Node]],
                                                   name: str) -> None:
    html, doc = pages[name]
    check_safe(html, doc)
    svgs = list(doc.iter("svg"))
    assert len(svgs) == SVG_COUNT[name]
    for svg in svgs:
        assert svg.attrs.get("viewbox") and "width" not in svg.attrs
        assert svg.attrs.get("role") == "img" and svg.attrs.get("aria-label")
    ids = [n.attrs["id"] for n in doc.iter() if n.attrs.get("id")]
    assert len(ids) == len(set(ids)), "element ids must be unique across the plots"
    assert "<?xml" not in html and "<!DOCTYPE svg" not in html
    assert "@media print" in html and "max-width: 640px" in html
    assert len(html.encode()) < 1_000_000


@pytest.mark.parametrize("name", FIXTURES)
def test_verdict_word_and_symbol(pages: dict[str, tuple[str, Node]], name: str) -> None:
    record = load_record(RECORDS / f"{name}.json")
    _, doc = pages[name]
    banner = doc.by_id("verdict")
    assert banner is not None
    symbol, word = VERDICT_MARKS[record.verdict]
    text = banner.text()
    assert f"Verdict: {word}" in text and symbol in text
    assert f"v-{record.verdict}" in banner.classes()
    assert word in next(doc.iter("title")).text()


@pytest.mark.parametrize("name", FIXTURES)
def test_every_measurement_with_its_value(pages: dict[str, tuple[str, Node]],
                                          name: str) -> None:
    record = load_record(RECORDS / f"{name}.json")
    _, doc = pages[name]
    rows = [cells(r) for t in doc.iter("table") if "measurements" in t.classes()
            for r in rows_of(t)]
    for suite in record.suites.values():
        for m in suite.measurements:
            match = [r for r in rows if r and r[0].startswith(m.name)]
            assert match, m.name
            assert format_number(m.value, unit=m.unit) == match[0][1]
            assert (m.limit.describe() if m.limit else "-") in match[0]
        for t in suite.trials:
            for m in t.measurements:
                assert [r for r in rows if r[:3] == [f"trial {t.index}", m.name + m.description,
                                                     format_number(m.value, unit=m.unit)]], (
                    t.index, m.name)


@pytest.mark.parametrize("name", FIXTURES)
def test_failing_rows_carry_a_text_marker(pages: dict[str, tuple[str, Node]], name: str) -> None:
    record = load_record(RECORDS / f"{name}.json")
    _, doc = pages[name]
    section = doc
    failed = {m.name for _, _, m in record.iter_measurements() if m.outcome == "fail"}
    marked = 0
    for row in rows_of(section):
        c = cells(row)
        if not c or not any(c[0].startswith(n) or (len(c) > 1 and c[1].startswith(n))
                            for n in failed):
            continue
        if "✘ FAIL" in c:
            marked += 1
            assert "row-fail" in row.classes()
    assert marked >= len(failed)
    if not failed:
        assert "✘ FAIL" not in section.text()


def test_accuracy_shows_the_paper_figure(pages: dict[str, tuple[str, Node]]) -> None:
    for name in FIXTURES:
        _, doc = pages[name]
        acc = doc.by_id("accuracy")
        assert acc is not None
        text = acc.text()
        assert "12.4 mm" in text
        record = load_record(RECORDS / f"{name}.json")
        ours = record.suite_measurements()["accuracy.coordinated.mean_mm"].value
        assert f"{format_number(ours, unit='mm')} mm" in text
        svg_labels = " ".join(s.attrs.get("aria-label") or "" for s in acc.iter("svg"))
        assert "YZ plane" in svg_labels and "over time" in svg_labels
        assert "Reported against true position" in svg_labels  # fixtures carry true_m
        # the paper's mean is drawn in the error-over-time plot
        assert any("paper §7 mean 12.4 mm" in s.text() for s in acc.iter("svg"))


def test_baseline_change_shown_for_the_regressed_run(pages: dict[str, tuple[str, Node]]) -> None:
    record = load_record(RECORDS / "regressed.json")
    assert record.baseline is not None and record.verdict == "regression"
    _, doc = pages["regressed"]
    tables = [t for t in doc.iter("table") if "measurements" in t.classes()]
    header = [c for r in rows_of(tables[0])[:1] for c in cells(r)]
    assert {"baseline", "change", "change %", "tolerance", "vs baseline"} <= set(header)
    rows = {cells(r)[0]: (r, cells(r)) for t in tables for r in rows_of(t) if cells(r)}
    for b in record.baseline.rows:
        key = next(k for k in rows if k.startswith(b.name))
        row, c = rows[key]
        assert format_value(b.baseline, b.unit) in c
        assert format_value(b.change_abs, b.unit, signed=True) in c
        if b.regressed:
            assert "✘ REGRESSED" in c and "row-regressed" in row.classes()
    verdict = doc.by_id("verdict")
    assert verdict is not None
    assert "regressed against baseline 20240503T091500Z-a1b2c3" in verdict.text()


def test_passing_run_has_no_baseline_columns(pages: dict[str, tuple[str, Node]]) -> None:
    _, doc = pages["passing"]
    assert "vs baseline" not in doc.text()
    assert "No baseline was given" in doc.text()


def test_failing_startup_trial_and_its_conditions(pages: dict[str, tuple[str, Node]]) -> None:
    _, doc = pages["failing"]
    st = doc.by_id("startup-recovery")
    assert st is not None
    rows = [(r, cells(r)) for r in rows_of(st)]
    lost = [(r, c) for r, c in rows if c and c[0] == "3"]
    assert lost and "row-fail" in lost[0][0].classes()
    assert "✘ not recovered (position)" in lost[0][1]
    text = st.text()
    assert "cuts that did not recover, with their conditions" in text
    assert "condition cw-toward-far, joints [2, 3, 4]" in text
    assert "startup.position_error_mrad = 37.2 mrad (limit <= 2 mrad)" in text
    assert "projected life" in text and "100,000" in text
    env = doc.by_id("environment")
    assert env is not None and "uart_corrupt" in env.text() and "probability=0.002" in env.text()


def test_interrupted_run_renders_what_it_has(pages: dict[str, tuple[str, Node]]) -> None:
    _, doc = pages["interrupted"]
    assert doc.by_id("repeatability") is None  # never started: no section
    assert doc.by_id("accuracy") is not None and doc.by_id("startup-recovery") is not None
    verdict = doc.by_id("verdict")
    assert verdict is not None
    assert "ERROR" in verdict.text()
    assert "device disconnected" in verdict.text()
    assert "planned suite repeatability never started" in verdict.text()
    summary = doc.by_id("summary")
    assert summary is not None
    rows = [cells(r) for r in rows_of(summary)]
    assert any(r[0] == "repeatability" and "not started" in r for r in rows)
    st = doc.by_id("startup-recovery")
    assert st is not None and "⚠ ERROR" in st.text()


def test_repeatability_table_per_pose_and_speed(pages: dict[str, tuple[str, Node]]) -> None:
    record = load_record(RECORDS / "passing.json")
    _, doc = pages["passing"]
    rep = doc.by_id("repeatability")
    assert rep is not None
    text = rep.text()
    for speed in (25, 50, 100):
        assert f"{speed} %" in text
        for p in range(1, 6):
            m = record.suite_measurements()[f"repeatability.v{speed}.p{p}.rp_mm"]
            assert format_number(m.value) in text
    assert "†" not in text  # every value recorded, none recomputed


# --------------------------------------------------------------------------------------------
# Hostile text
# --------------------------------------------------------------------------------------------


def _hostile_record() -> RunRecord:
    s0, s1, s2 = HOSTILE
    env = Environment(armbench_version=s0, git_revision=s1, python="3.11", platform=s2,
                      port=s2 + s0, settings={s0: s1, "joints": {s1: {"lower_deg": s2}}},
                      seed=1, faults=({"kind": s0, "description": s1, "joint": s2},),
                      limits_spec_version=None, config_path=s1)
    bad = Measurement(s0, 1.5, s1, None, "unjudged", None, s2)
    record = RunRecord(run_id=s0, created=s1, environment=env,
                       planned_suites=["accuracy", "repeatability", "startup-recovery", s0, s1])
    square = [[0.35, y, z] for y, z in ((-0.05, 0.4), (0.05, 0.4), (0.05, 0.5), (-0.05, 0.5))]
    record.suites["accuracy"] = SuiteRecord(
        name="accuracy", version=s0, status="done", ended_s=10.0,
        params={"centre_m": [0.35, 0.0, 0.45], "side_m": 0.1, s0: s1},
        trials=[Trial(0, 0.0, 4.0, {"style": "paper", "lap": s1},
                      [{"t_s": float(i), "reported_m": p, "true_m": p, s0: s2}
                       for i, p in enumerate(square)], [bad])],
        measurements=[Measurement("accuracy." + s0, 2.0, "mm", None, "unjudged", "lower", s1)])
    record.suites["repeatability"] = SuiteRecord(
        name="repeatability", version="1", status="done", ended_s=20.0,
        params={"cube_centre_m": [0.35, 0.0, 0.4], "cube_side_m": 0.2},
        trials=[Trial(i, 10.0 + i, 1.0, {"kind": "pose", "speed_pct": 50, "cycle": s0},
                      [{"t_s": 0.1, "pose": pose, "commanded_m": [0.35, 0.0, 0.4],
                        "reported_m": [0.35, 0.0001 * i, 0.4]} for pose in (s0, s1, s2)])
                for i in range(3)])
    record.suites["startup-recovery"] = SuiteRecord(
        name="startup-recovery", version="1", status="error", error=s1, ended_s=30.0,
        trials=[Trial(0, 20.0, 2.0, {"kind": "cut", "condition": s0, "joints": s2},
                      [{"t_s": 0.5, "event": "fault", "kind": s0},
                       {"t_s": 1.0, "event": "outcome", "recovered": False, "failure": s2,
                        "condition": s0}],
                      [Measurement("startup.recovered", 0.0, "bool", None, "fail", "higher", s0)]),
                Trial(1, 23.0, 1.0, {"kind": "cut", "condition": s1}, [], status="error",
                      error=s0)])
    record.suites[s0] = SuiteRecord(
        name=s0, version=s1, status="done", ended_s=40.0, params={s2: s0},
        trials=[Trial(0, 30.0, 1.0, {s0: s1}, [{s1: s2}], [bad])],
        measurements=[Measurement(s2 + ".x", 3.0, s0, None, "unjudged", None, s1)])
    return record


def test_hostile_strings_render_as_text(tmp_path: Path) -> None:
    s0, s1, s2 = HOSTILE
    run = tmp_path / "run"
    run.mkdir()
    (run / "capture.jsonl").write_text(
        json.dumps({"t_s": 0.1, "dir": "in", "frame": s0, "error": s1}) + "\n" +
        json.dumps({"t_s": 0.2, "dir": "out", "frame": s2, "error": None}) + "\n",
        encoding="utf-8")
    record = _hostile_record()
    html = render_report(record, run / "report.html", capture=run / "capture.jsonl").read_text(
        encoding="utf-8")
    doc = parse(html)
    check_safe(html, doc)
    for s in HOSTILE:
        assert s not in html
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    assert "&#34;&gt;&lt;img src=x onerror=alert(1)&gt;" in html
    assert "&lt;/svg&gt;&lt;script&gt;" in html
    text = doc.text()
    for s in HOSTILE:
        assert s in text  # shown to the reader, as text
    # record text never reaches a plot: pose names fall back to neutral labels
    svgs = list(doc.iter("svg"))
    assert svgs
    svg_text = " ".join(s.text() for s in svgs)
    assert "alert" not in svg_text and "pose 1" in svg_text
    assert doc.by_id("traffic") is not None


def test_hostile_run_directory_in_the_index(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    name = HOSTILE[1]
    (runs / name).mkdir(parents=True)
    shutil.copy(RECORDS / "passing.json", runs / name / "results.json")
    html = render_index(runs).read_text(encoding="utf-8")
    doc = parse(html)
    check_safe(html, doc)
    assert name not in html and name in doc.text()


# --------------------------------------------------------------------------------------------
# Other suites, inputs, capture
# --------------------------------------------------------------------------------------------


def test_unknown_suite_gets_a_generic_section() -> None:
    record = load_record(RECORDS / "passing.json")
    record.suites = {}  # only the unknown suite: the others never started
    record.suites["thermal"] = SuiteRecord(
        name="thermal", version="2", status="done", started_s=500.0, ended_s=560.0,
        params={"duration_s": 60},
        trials=[Trial(0, 500.0, 60.0, {"joint": 2}, [{"t_s": 1.0, "temp_c": 41.0}],
                      [Measurement("thermal.j2.max_c", 41.0, "degC", None, "unjudged", None)])],
        measurements=[Measurement("thermal.max_c", 41.0, "degC", None, "unjudged", None,
                                  "hottest joint")])
    doc = parse(build_report_html(record))
    section = next(n for n in doc.iter("section") if "thermal" in
                   next(n.iter("h2")).text())
    text = section.text()
    assert "thermal.max_c" in text and "41" in text and "joint=2" in text
    ident = section.attrs["id"] or ""
    assert ident.startswith("suite-")
    toc = next(doc.iter("nav"))
    assert f"#{ident}" in [a.attrs.get("href") for a in toc.iter("a")]


def test_render_accepts_a_directory_and_finds_the_capture(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    data = json.loads((RECORDS / "interrupted.json").read_text())
    del data["suites"]["accuracy"]  # keep the page small: start-up and traffic
    (run / "results.json").write_text(json.dumps(data))
    lines = [{"t_s": i * 0.01, "dir": "out" if i % 2 else "in",
              "frame": "$31416,31416,31416,31416#", "error": None} for i in range(200)]
    lines[50]["error"] = "bytes outside a frame"
    (run / "capture.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    out = tmp_path / "elsewhere" / "r.html"
    render_report(run, out)
    doc = parse(out.read_text(encoding="utf-8"))
    traffic = doc.by_id("traffic")
    assert traffic is not None
    link = next(a for a in traffic.iter("a"))
    assert link.attrs["href"] == "../run/capture.jsonl"
    text = traffic.text()
    assert "framing errors1 (" in text.replace("\n", "") or "1 (0 out, 1 in)" in text
    assert "bytes outside a frame" in text
    assert len(list(traffic.iter("svg"))) == 1


def test_capture_summary_is_bounded_and_tolerant(tmp_path: Path) -> None:
    path = tmp_path / "capture.jsonl"
    recs = []
    for i in range(1000):
        err = "bytes outside a frame" if i % 100 == 1 else None
        recs.append(json.dumps({"t_s": i * 0.01, "dir": "in" if i % 2 else "out",
                                "frame": "x" * 300, "error": err}))
    recs.insert(10, "not json")
    recs.insert(20, "[1, 2]")
    recs.insert(30, "")
    path.write_text("\n".join(recs) + "\n")
    c = summarize_capture(path, head=5, errors=3)
    assert c.records == 1000 and c.bad_lines == 2
    assert c.errors_in == 10 and c.resyncs == 10
    assert len(c.head) == 5 and len(c.first_errors) == 3
    assert all(len(line.frame) <= 96 for line in c.head)
    assert c.head[0].line == 1 and c.first_errors[0].error == "bytes outside a frame"
    assert c.rate_in.sum() * c.bin_s == pytest.approx(c.frames_in)
    capped = summarize_capture(path, max_records=100)
    assert capped.records == 100 and capped.skipped_records > 0


def test_bad_record_raises_a_record_error(tmp_path: Path) -> None:
    from armbench.record import RecordError

    bad = tmp_path / "results.json"
    bad.write_text('{"schema": "armbench-run/0"}')
    with pytest.raises(RecordError, match="not supported"):
        render_report(bad, tmp_path / "report.html")
    assert not (tmp_path / "report.html").exists()


# --------------------------------------------------------------------------------------------
# Index
# --------------------------------------------------------------------------------------------


@pytest.fixture()
def runs_dir(tmp_path: Path) -> Path:
    runs = tmp_path / "runs"
    # directory names sort differently from creation order on purpose
    for name, dirname in (("regressed", "a"), ("passing", "b"), ("interrupted", "c"),
                          ("failing", "d")):
        (runs / dirname).mkdir(parents=True)
        shutil.copy(RECORDS / f"{name}.json", runs / dirname / "results.json")
    (runs / "e-broken").mkdir()
    (runs / "e-broken" / "results.json").write_text("{not json")
    (runs / "f-empty").mkdir()  # no results.json: not a run
    return runs


def test_index_over_several_runs(runs_dir: Path) -> None:
    (runs_dir / "b" / "report.html").write_text("rendered before")
    out = render_index(runs_dir)
    assert out == runs_dir / "index.html"
    html = out.read_text(encoding="utf-8")
    doc = parse(html)
    check_safe(html, doc)
    table = next(t for t in doc.iter("table") if "runs" in t.classes())
    body = [cells(r) for r in list(table.iter("tr"))[1:]]
    assert [r[0] for r in body] == ["1", "2", "3", "4", "5"]
    ids = [r[1] for r in body]
    assert ids[0].startswith("20240503T091500Z-a1b2c3")  # passing: oldest
    assert ids[1].startswith("20240510T140210Z-d4e5f6")
    assert ids[2].startswith("20240517T081945Z-0718aa")
    assert ids[3].startswith("20240520T163000Z-5e5e5e")
    assert "e-broken" in ids[4] and "not valid JSON" in ids[4]
    assert "✔ PASS" in body[0] and "✘ FAIL" in body[1] and "▼ REGRESSION" in body[2]
    assert "⚠ ERROR" in body[3] and "? UNREADABLE" in body[4]
    # the headline figures, folded below the runs (the table stays on the screen): the true
    # figure where the record holds one, as the scorecard shows
    figures = [t for t in doc.iter("table") if "runs" in t.classes()][1]
    first = cells(list(figures.iter("tr"))[1])
    passing = load_record(runs_dir / "b" / "results.json").suite_measurements()
    coordinated = passing.get("accuracy.coordinated.true_mean_mm",
                              passing["accuracy.coordinated.mean_mm"])
    assert format_value(coordinated.value, "mm") in first
    assert format_value(passing[STARTUP.success_rate].value, "%") in first
    links = [a.attrs["href"] for a in table.iter("a")]
    assert links == ["b/report.html"]  # only the rendered one is linked
    assert "not rendered" in body[1][-1]
    svgs = list(doc.iter("svg"))
    held = [k for k in range(len(KEY_METRICS))
            if any(key_metrics(load_record(runs_dir / d / "results.json"))[k].value is not None
                   for d in "abcd")]
    assert len(held) >= 6 and len(svgs) == len(held)  # a trend plot per headline figure held
    labels = " ".join(s.text() + (s.attrs.get("aria-label") or "") for s in svgs)
    for k in held:
        assert KEY_METRICS[k][1].label in labels


def test_index_keeps_the_order_of_runs_started_in_one_second(tmp_path: Path) -> None:
    """Records made one after the other carry labels finer than the second, so the index lists
    them in the order they started whatever their random run ids."""
    runs = tmp_path / "runs"
    env = load_record(RECORDS / "passing.json").environment
    first = RunRecord.new(env, run_id="zz-first")
    time.sleep(0.002)
    second = RunRecord.new(env, run_id="aa-second")
    for record in (first, second):
        (runs / record.run_id).mkdir(parents=True)
        (runs / record.run_id / "results.json").write_text(json.dumps(record.to_json()))
    assert first.created < second.created
    table = next(parse(render_index(runs).read_text(encoding="utf-8")).iter("table"))
    ids = [cells(r)[1] for r in list(table.iter("tr"))[1:]]
    assert len(ids) == 2 and ids[0].startswith("zz-first") and ids[1].startswith("aa-second")


def test_index_of_an_empty_directory(tmp_path: Path) -> None:
    html = render_index(tmp_path, tmp_path / "out" / "i.html").read_text(encoding="utf-8")
    assert "No run directory" in html and "<svg" not in html


# --------------------------------------------------------------------------------------------
# Commands
# --------------------------------------------------------------------------------------------


def test_report_command(runs_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # the interrupted run (c) has the fewest plots: cheap to render twice
    assert cli.main(["report", str(runs_dir / "c" / "results.json"), "--index",
                     str(runs_dir)]) == 0
    assert (runs_dir / "c" / "report.html").is_file()
    out = capsys.readouterr().out
    assert str(runs_dir / "c" / "report.html") in out and str(runs_dir / "index.html") in out
    html = (runs_dir / "index.html").read_text(encoding="utf-8")
    assert 'href="c/report.html"' in html and 'href="b/report.html"' not in html
    (runs_dir / "c" / "report.html").unlink()
    # a bad directory: reported, the others still rendered, exit 2
    assert cli.main(["report", str(runs_dir / "e-broken"), str(runs_dir / "c")]) == 2
    err = capsys.readouterr().err
    assert "armbench report: error:" in err and "not valid JSON" in err
    assert (runs_dir / "c" / "report.html").is_file()
    assert cli.main(["report", "--index", str(runs_dir)]) == 0
    assert cli.main(["report"]) == 2
    assert cli.main(["report", "--index", str(runs_dir / "nope")]) == 2


def test_compare_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    passing, regressed = str(RECORDS / "passing.json"), str(RECORDS / "regressed.json")
    limits = str(RECORDS.parent / "bench.toml")
    assert cli.main(["compare", passing, regressed, "--limits", limits]) == 3
    out = capsys.readouterr().out
    assert "REGRESSED" in out and "against baseline 20240503T091500Z-a1b2c3" in out
    assert "accuracy.coordinated.mean_mm" in out
    assert cli.main(["compare", passing, passing]) == 0
    assert "0 regressed" in capsys.readouterr().out
    assert cli.main(["compare", passing, regressed, "--limits", limits, "--json"]) == 3
    data = json.loads(capsys.readouterr().out)
    assert data["regressed"] is True and data["baseline_run_id"] == "20240503T091500Z-a1b2c3"
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    assert cli.main(["compare", passing, str(bad)]) == 2
    assert cli.main(["compare", str(tmp_path / "missing.json"), passing]) == 2
    assert cli.main(["compare", passing, regressed, "--limits", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("armbench compare: error:") == 3
    # a directory stands for its results.json
    (tmp_path / "run").mkdir()
    shutil.copy(RECORDS / "regressed.json", tmp_path / "run" / "results.json")
    assert cli.main(["compare", passing, str(tmp_path / "run"), "--config", limits]) == 3


# --------------------------------------------------------------------------------------------
# Performance of a big default run
# --------------------------------------------------------------------------------------------


def test_perf_figures(monkeypatch: pytest.MonkeyPatch) -> None:
    from armbench.cli.perf import report_perf as perf_report

    # the figures' plumbing on a tiny run; armbench perf measures the real workload
    monkeypatch.setattr(perf_report, "_QUICK", {"samples_per_run": 200, "cycles": 2,
                                                "startup_trials": 2, "capture_records": 500})
    figures = {f.name: f for f in perf_report.run(PerfOptions(quick=True, repeats=1))}
    assert set(figures) == {"report.render_s", "report.size_bytes"}
    size = figures["report.size_bytes"]
    assert size.bound == 3_000_000 and size.ratio is not None and size.ratio < 0.5
    render = figures["report.render_s"]
    assert render.bound == 5.0 and render.ratio == pytest.approx(render.value / 5.0)
    # the target (ratio < 1 on the full run) is tracked by armbench perf, not by a timed test
    assert render.value > 0


def test_big_run_keeps_raw_data_out_of_the_page(tmp_path: Path) -> None:
    from armbench.cli.perf.report_perf import big_run_record

    record = big_run_record(samples_per_run=5_000, cycles=2, startup_trials=2)
    record.suites = {"accuracy": record.suites["accuracy"]}  # the long series are here
    html = build_report_html(record)
    assert len(html.encode()) < 500_000
    doc = parse(html)
    # drawn downsampled: no path of the 5 000-sample runs carries them all
    longest = max(len((p.attrs.get("d") or "").split(" L ")) for p in doc.iter("path"))
    assert longest < 2_500
    acc = doc.by_id("accuracy")
    assert acc is not None and "5000" in acc.text()
