"""Several arms in one run (``armbench run --port P1 --port P2 ...``) with real parts: arms served
by ``armbench emulate --pty`` processes behind a real labgrid coordinator and exporter (through
ser2net) and on their bare ptys, the fleet page read as a user would and in headless Chromium.
One arm lost mid-run runs on virtual time (its emulator loses power): how the fleet takes it does
not depend on real time. Nothing is mocked; ``fake://`` arms are the emulator in-process (what
``fake://`` is)."""

from __future__ import annotations

import io
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import time
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest
from chromium import CHROMIUM, Chromium
from conftest import ONE_WORKER
from test_report import cells, parse

from armbench.bench.runner.fleet_run import arm_name, fleet_exit_status, parse_arms
from armbench.bench.runner.options import DEFAULT_CONFIG
from armbench.bench.suites.accuracy_contract import ACCURACY
from armbench.cli import main as cli
from armbench.drivers.model.errors import ArmbenchError
from armbench.metrics import path_errors, square_yz
from armbench.record import RunRecord, load_record
from armbench.record.fleet_index import read_fleet_index
from armbench.reports.pages.fleet_page import render_fleet
from armbench.reports.render.format import format_value
from armbench.reports.render.scorecard import headline_figure, headline_measurement

ROOT = Path(__file__).resolve().parents[1]
ARTIFACTS = ROOT / "test-artifacts"

try:
    from test_labgrid import Lab, lab  # noqa: F401  (the real lab fixture: coordinator + exporter)
except (ImportError, pytest.skip.Exception):
    Lab = None  # type: ignore[assignment, misc]

needs_lab = pytest.mark.skipif(Lab is None, reason="labgrid or ser2net not installed")
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None or not hasattr(os, "posix_spawn"),
    reason="headless Chromium not installed (apt-get install chromium)")


def _one_lap(tmp: Path) -> Path:
    """The default limits with one lap per accuracy style (a real-time run of ~20 s), with reply
    and connection timeouts of seconds and move timeouts ten times the driver's: an emulator
    process starved of CPU may fall silent for longer than the defaults and runs slower than the
    host's clock; the arm lost here is lost by killing its emulator."""
    config = tmp / "one-lap.toml"
    config.write_text(DEFAULT_CONFIG.read_text(encoding="utf-8")
                      + "\n[bench]\nreply_timeout_s = 5.0\nconnect_timeout_s = 30.0\n"
                      + "move_timeout_scale = 10.0\n"
                      + "\n[suites.accuracy]\nlaps = 1\n", encoding="utf-8")
    return config


def _cli(*args: str) -> tuple[int, str]:
    out = io.StringIO()
    with redirect_stdout(out):
        status = cli.main(["run", *args])
    return status, out.getvalue()


def _headline(record: RunRecord, k: int) -> float:
    m = headline_measurement(record.suites[ACCURACY.suite], ACCURACY.headlines[k])
    assert m is not None
    return m.value


# --- naming and exit statuses -----------------------------------------------------------------

def test_arm_names_and_ports() -> None:
    arms = parse_arms(["/dev/ttyUSB0", "left=socket://10.0.0.2:4001", "fake://?seed=3",
                       "labgrid://bench-3?coordinator=lab:20408"])
    assert [(a.name, a.port) for a in arms] == [
        ("dev-ttyUSB0", "/dev/ttyUSB0"), ("left", "socket://10.0.0.2:4001"),
        ("fake-seed-3", "fake://?seed=3"), ("bench-3", "labgrid://bench-3?coordinator=lab:20408")]
    assert arm_name("rfc2217://127.0.0.1:7000") == "127.0.0.1-7000"
    assert arm_name("fake://") == "fake"
    with pytest.raises(ArmbenchError, match="both named 'fake'"):
        parse_arms(["fake://", "fake://?"])
    with pytest.raises(ArmbenchError, match="given twice"):
        parse_arms(["a=fake://", "b=fake://"])
    with pytest.raises(ArmbenchError, match="no port after the arm name 'a'"):
        parse_arms(["a=", "fake://"])
    with pytest.raises(ArmbenchError, match="arm name 'a b'"):
        parse_arms(["a b=fake://", "fake://"])
    assert fleet_exit_status([0, 1, 0]) == 1
    assert fleet_exit_status([0, 2, 1]) == 2
    assert fleet_exit_status([3, 1, 0]) == 1  # a limit failed outweighs a regression
    assert fleet_exit_status([4, 1, 3]) == 4  # an incomplete run outweighs both
    assert fleet_exit_status([4, 2]) == 2
    assert fleet_exit_status([130, 0]) == 130
    assert fleet_exit_status([0, 0]) == 0


# --- fake:// fleets: layout, baseline, the fleet page -------------------------------------------

@pytest.fixture(scope="module")
def fake_fleets(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Fleet ``a`` (two emulated arms) and fleet ``b`` of the same arms against ``a`` as
    baseline, arm ``heavy`` carrying a 0.4 kg payload this time; one lap per accuracy style
    (what a fleet does with its arms' runs does not depend on their length), each arm's trials
    measured in this process (``ONE_WORKER``: nor on where they are measured; with more, each
    arm would start worker processes of its own)."""
    root = tmp_path_factory.mktemp("fleets")
    strict = root / "strict.toml"  # accuracy regresses when 1 % worse than its baseline
    text = DEFAULT_CONFIG.read_text(encoding="utf-8")
    loose = "tolerance_pct = 20.0\ntolerance_abs = 0.2"
    assert loose in text
    strict.write_text(text.replace(loose, "tolerance_pct = 1.0\ntolerance_abs = 0.0")
                      + "\n[suites.accuracy]\nlaps = 1\n", encoding="utf-8")
    status, out = _cli("accuracy", "--port", "light=fake://", "--port", "heavy=fake://?seed=5",
                       "--out", str(root / "a"), "--config", str(strict), *ONE_WORKER)
    assert status == 0, out
    status, out = _cli("accuracy", "--port", "light=fake://", "--port",
                       "heavy=fake://?seed=5&payload=0.4", "--out", str(root / "b"),
                       "--baseline", str(root / "a"), "--config", str(strict), *ONE_WORKER)
    assert status == 3, out  # regressed, every limit held
    (root / "b.out").write_text(out, encoding="utf-8")
    return root


def test_each_arm_gets_a_run_folder_of_its_own(fake_fleets: Path) -> None:
    a = fake_fleets / "a"
    index = read_fleet_index(a)
    assert [(x.name, x.port, x.verdict, x.exit_status) for x in index.arms] == [
        ("light", "fake://", "pass", 0), ("heavy", "fake://?seed=5", "pass", 0)]
    assert index.exit_status == 0
    for name in ("light", "heavy"):
        folder = a / name
        for f in ("results.json", "report.html", "junit.xml", "capture.mcap", "runner.json"):
            assert (folder / f).is_file(), folder / f
        record = load_record(folder / "results.json")
        assert record.run_id == f"{index.fleet_id}-{name}"
        assert record.suites[ACCURACY.suite].status == "done"
    # the two arms are two emulators seeded apart: their figures differ
    light, heavy = (load_record(a / n / "results.json") for n in ("light", "heavy"))
    assert _headline(light, 4) != _headline(heavy, 4)
    # the same arm alone gives the same record: a fleet does not change what an arm measures
    status, _ = _cli("accuracy", "--port", "solo=fake://?seed=5", "--out",
                     str(fake_fleets / "alone"), "--config", str(fake_fleets / "strict.toml"),
                     *ONE_WORKER)
    alone = load_record(fake_fleets / "alone" / "results.json")
    assert status == 0 and alone.environment.port == "fake://?seed=5"
    assert [_headline(alone, k) for k in range(5)] == [_headline(heavy, k) for k in range(5)]
    assert not (fake_fleets / "alone" / "fleet.json").exists()


def test_the_fleet_page_puts_the_arms_side_by_side(fake_fleets: Path) -> None:
    b = fake_fleets / "b"
    out = (fake_fleets / "b.out").read_text(encoding="utf-8")
    records = [load_record(b / n / "results.json") for n in ("light", "heavy")]
    doc = parse((b / "fleet.html").read_text(encoding="utf-8"))
    table = next(t for t in doc.iter("table") if "fleet" in (t.attrs.get("class") or ""))
    rows = [cells(r) for r in table.iter("tr")]
    assert rows[0] == ["figure", "light", "heavy", "min", "max", "mean", "std"]
    for h in ACCURACY.headlines:  # the true figure where the runs hold one, as the scorecard
        found = [headline_figure(rec.suites[ACCURACY.suite], h) for rec in records]
        true = any(f is not None and f[1] is not None for f in found)
        row = next(r for r in rows if r[0] == h.label + (" (true)" if true else ""))
        ms = [f[0] for f in found if f is not None]
        assert len(ms) == 2
        for cell, m in zip(row[1:3], ms, strict=True):
            assert cell.startswith(format_value(m.value, m.unit)), (h.label, cell, m.value)
        values = [m.value for m in ms]
        assert row[3] == format_value(min(values), ms[0].unit)
        assert row[4] == format_value(max(values), ms[0].unit)
        assert row[5] == format_value(statistics.fmean(values), ms[0].unit)
        assert row[6] == format_value(statistics.stdev(values), ms[0].unit)
    # the payload moved heavy's figures: it drifted from its own baseline; light did not
    light, heavy = records
    assert light.baseline is not None and not light.baseline.regressions
    assert heavy.baseline is not None and heavy.baseline.regressions
    assert out.splitlines()[0] == "fleet of 2 arm(s): exit 3, not passed: heavy", out
    assert "REGRESSION" in out.splitlines()[2] and "regressed: accuracy." in out.splitlines()[2]
    arms = next(t for t in doc.iter("table") if "arms" in (t.attrs.get("class") or ""))
    arm_rows = {r[0]: r for r in (cells(x) for x in arms.iter("tr"))}
    assert "PASS" in arm_rows["light"][2] and arm_rows["light"][5] == "-"
    assert "REGRESSION" in arm_rows["heavy"][2]
    assert heavy.baseline.regressions[0].name in arm_rows["heavy"][5]
    drifted = [r for r in rows if any("worse" in c for c in r[1:3])]
    assert drifted and all("worse" not in r[1] for r in drifted)  # light's column: same
    assert "heavy: REGRESSION (exit 3)" in doc.text()


def test_a_baseline_fleet_must_hold_the_same_arms(fake_fleets: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    status, _ = _cli("accuracy", "--port", "light=fake://", "--port", "other=fake://?seed=2",
                     "--out", str(fake_fleets / "c"), "--baseline", str(fake_fleets / "a"))
    assert status == 2
    err = capsys.readouterr().err
    assert "same arms" in err and str(fake_fleets / "a" / "other" / "results.json") in err
    assert not (fake_fleets / "c").exists()  # refused before any arm ran


# --- a lost arm (virtual time); real parts: labgrid, ser2net, ptys -------------------------------

def _run_process(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "armbench", "run", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_one_arm_lost_mid_run_the_others_complete(tmp_path: Path) -> None:
    """Arm ``arm-b`` falls silent mid-run (its emulator loses power, as an arm whose cable is
    pulled does): its run ends in error with what it measured on disk, the other two complete,
    and the fleet says so. On virtual time: how the fleet takes one arm's failure does not depend
    on real time, nor on where each arm's trials are measured (here in this process). A port
    lost over a real link is in ``test_outage_campaign.py`` and
    ``test_arm_driver.py::test_port_lost_mid_move``; a fleet over real ptys and ser2net in
    ``test_accuracy_on_two_labgrid_places_at_once``."""
    cut = tmp_path / "power-cut.toml"  # mid-lap: a lap of the 4 cm square takes ~5 s
    cut.write_text('[[faults]]\nkind = "power_cut"\nat_s = 3.0\n', encoding="utf-8")
    config = tmp_path / "two-small-laps.toml"
    config.write_text('spec_version = "armbench-limits/1"\n\n[suites.accuracy]\nlaps = 2\n'
                      'styles = ["coordinated"]\nside_m = 0.04\n', encoding="utf-8")
    out_dir = tmp_path / "fleet"
    status, stdout = _cli("accuracy", "--config", str(config), "--out", str(out_dir),
                          "--port", "arm-a=fake://", "--port", f"arm-b=fake://?faults={cut}",
                          "--port", "arm-c=fake://?seed=5", *ONE_WORKER)
    assert status == 4, stdout  # incomplete: an arm lost mid-run
    lines = stdout.splitlines()
    assert lines[0] == "fleet of 3 arm(s): exit 4, not passed: arm-b", stdout
    arm_lines = {line.split()[0]: line for line in lines[1:4]}
    assert "ERROR" in arm_lines["arm-b"] and "exit 4" in arm_lines["arm-b"]
    for name in ("arm-a", "arm-c"):
        assert "PASS" in arm_lines[name] and "exit 0" in arm_lines[name], stdout
        record = load_record(out_dir / name / "results.json")
        assert record.verdict == "pass" and len(record.suites[ACCURACY.suite].trials) == 2
    lost = load_record(out_dir / "arm-b" / "results.json")  # what it measured stays on disk
    assert lost.verdict in ("error", "incomplete")
    trials = lost.suites[ACCURACY.suite].trials
    assert any(t.error is not None and "no valid reply" in t.error for t in trials), trials
    index = read_fleet_index(out_dir)
    assert [a.exit_status for a in index.arms] == [0, 4, 0] and index.exit_status == 4
    html = (out_dir / "fleet.html").read_text(encoding="utf-8")
    assert "arm-b: ERROR (exit 4)" in html
    assert (out_dir / "arm-b" / "report.html").is_file()


def _figures(out_dir: Path, names: tuple[str, ...]) -> dict[str, list[float]]:
    return {n: [_headline(load_record(out_dir / n / "results.json"), k) for k in range(4)]
            for n in names}


def _along_the_path(record: RunRecord, style: str) -> tuple[float, float]:
    """The lap of ``style``: its mean distance to the square along the path the arm reported
    (each stretch between two samples weighted by its length, not by the time it took: the
    dwell at a corner and when the host happened to read do not count) and the longest stretch
    between two samples (mm). The distance moves by at most as much as the arm: an average over
    stretches at most ``h`` long is within ``h / 4`` of the path's own."""
    suite = record.suites[ACCURACY.suite]
    corners = square_yz(suite.params[ACCURACY.centre], float(suite.params[ACCURACY.side]))
    (lap,) = (t for t in suite.trials if t.params[ACCURACY.style] == style)
    points = np.array([s["reported_m"] for s in lap.samples], dtype=np.float64)
    error_mm = path_errors(points, corners, closed=True).euclidean_mm
    step_mm = 1000.0 * np.linalg.norm(np.diff(points, axis=0), axis=1)
    mean_mm = float(np.sum(step_mm * (error_mm[1:] + error_mm[:-1]) / 2) / np.sum(step_mm))
    return mean_mm, float(step_mm.max())


@needs_lab
def test_accuracy_on_two_labgrid_places_at_once(lab: Lab, tmp_path: Path) -> None:
    config = str(_one_lap(tmp_path))
    arms = ("arm-a", "arm-b")
    status, out = _cli("accuracy", "--config", config, "--out", str(tmp_path / "lab"),
                       *(x for n in arms for x in ("--port", lab.port(n))))
    assert status == 0, out
    assert [line.split()[0] for line in out.splitlines()[1:3]] == list(arms)  # place names
    via_lab = _figures(tmp_path / "lab", arms)
    # the same two emulators through their bare ptys (ser2net let go of them with the places)
    devices = dict(re.findall(r"(arm-\w):\n  RawSerialPort:\n    port: (\S+)",
                              (lab.folder / "exporter.yaml").read_text(encoding="utf-8")))
    status, out = _cli("accuracy", "--config", config, "--out", str(tmp_path / "pty"),
                       *(x for n in arms for x in ("--port", f"{n}={devices[n]}")))
    assert status == 0, out
    via_pty = _figures(tmp_path / "pty", arms)
    report = {n: [round(a / b, 4) for a, b in zip(via_lab[n], via_pty[n], strict=True)]
              for n in arms}
    paths = {f"{n} {style}": [_along_the_path(load_record(tmp_path / link / n / "results.json"),
                                              style) for link in ("lab", "pty")]
             for n in arms for style in ACCURACY.styles}
    ARTIFACTS.mkdir(exist_ok=True)
    (ARTIFACTS / "fleet-labgrid-vs-pty.json").write_text(json.dumps(
        {"labgrid": via_lab, "pty": via_pty, "ratio": report, "along the path": paths},
        indent=1), encoding="utf-8")
    # The same arm through labgrid and ser2net as through its bare pty: the same path (the
    # coordinated one up to when each waypoint came: micrometres in docs/fleet.md). The
    # headline figures are averages over the lap's time, in which the host's timing counts (a
    # busy host reacts late: the arm waits at a corner, a waypoint streamed late stops it on the
    # square), so they are compared over repeated runs in docs/fleet.md, not here. Along the
    # path the figures are the arm's own, up to where the samples fell: this catches a lost or
    # doubled frame stream, or a lap that is not the square (the places are told apart by the
    # names above: their emulators drive the same path).
    for name, ((lab_mm, lab_step_mm), (pty_mm, pty_step_mm)) in paths.items():
        assert abs(lab_mm - pty_mm) <= (lab_step_mm + pty_step_mm) / 4, (
            name, lab_mm, pty_mm, lab_step_mm, pty_step_mm)


# --- the fleet page in a browser ------------------------------------------------------------------

@needs_chromium
def test_the_fleet_page_answers_first_in_chromium(fake_fleets: Path, tmp_path: Path) -> None:
    page = render_fleet(fake_fleets / "b", tmp_path / "fleet.html")
    chrome = Chromium(tmp_path)
    try:
        chrome.open_page()
        chrome.load(page.as_uri(), 1280, 800)
        facts = chrome.probe()
        ARTIFACTS.mkdir(exist_ok=True)
        chrome.screenshot(ARTIFACTS / "fleet-first-screen.png", max_height=800)
        problems = chrome.problems()
        requests = chrome.requests()
    finally:
        chrome.close()
    verdict, table = facts["first"]
    assert verdict is not None and table is not None
    assert verdict[1] <= facts["innerHeight"] and table[1] <= facts["innerHeight"], facts
    assert facts["scrollWidth"] <= facts["innerWidth"] and facts["overflowing"] == 0, facts
    assert facts["scripts"] == 0
    assert "Verdict:" in facts["verdict"]
    assert problems == []
    assert requests == [page.as_uri()]


def test_an_interrupted_fleet_is_resumed(tmp_path: Path) -> None:
    """Ctrl-C stops every arm (exit 130, each record kept); ``--resume FLEET_DIR`` continues
    each arm where it stopped."""
    fleet = tmp_path / "fleet"
    run = _run_process("accuracy", "--workers", "1", "--out", str(fleet),
                       "--port", "a=fake://", "--port", "b=fake://?seed=5")
    try:
        deadline = time.monotonic() + 60
        while not all((fleet / n / "results.json").exists() for n in "ab"):
            assert time.monotonic() < deadline and run.poll() is None, "the arms start"
            time.sleep(0.05)
        # at once: on an idle machine (and the compiled build) the six trials take ~2 s
        run.send_signal(signal.SIGINT)
        stdout, stderr = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert run.returncode == 130, stdout + stderr
    assert "Traceback" not in stderr
    before = {n: len(load_record(fleet / n / "results.json").suites[ACCURACY.suite].trials)
              for n in "ab"}
    assert all(k < 6 for k in before.values()), before
    assert read_fleet_index(fleet).exit_status == 130
    status, _ = _cli("--resume", str(fleet), "--port", "fake://")
    assert status == 2  # a fleet continues on its own ports
    status, out = _cli("--resume", str(fleet), *ONE_WORKER)  # as the run was given
    assert status == 0, out
    for n in "ab":
        record = load_record(fleet / n / "results.json")
        assert record.verdict == "pass" and len(record.suites[ACCURACY.suite].trials) == 6
    assert [line.split()[0] for line in out.splitlines()[1:3]] == ["a", "b"]
    assert read_fleet_index(fleet).exit_status == 0
