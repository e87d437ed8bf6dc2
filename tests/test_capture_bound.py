"""The capture can be turned off and bounded in size (issue 20): at the bound it stops with one
event line and nothing else of the run is lost. Real files and real fake:// runs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from armbench.drivers.capture.jsonl import (
    CaptureWriter,
    capture_options,
    merge_capture,
    read_capture,
)
from armbench.drivers.capture.read import capture_stopped
from armbench.drivers.model.settings import SettingsError
from armbench.record import CAPTURE_FILE, RESULTS_FILE, load_record

ROOT = Path(__file__).resolve().parents[1]
FRAME = "$01000,99,01000,99,01000,99,01000,99#"


def _write_frames(path: Path, n: int, *, max_bytes: int | None = None,
                  t0_s: float = 0.0) -> CaptureWriter:
    w = CaptureWriter(path, t0_s, batch_records=7, max_bytes=max_bytes)
    for i in range(n):
        w.frame(t0_s + 0.01 * (i + 1), "out", FRAME)
    w.close()
    return w


def test_a_bounded_capture_stops_with_an_event_within_its_bound(tmp_path: Path) -> None:
    path = tmp_path / "c.jsonl"
    w = _write_frames(path, 1000, max_bytes=20_000)
    assert w.stopped and path.stat().st_size <= 20_000
    last = json.loads(path.read_text().splitlines()[-1])
    assert last["event"] == "capture stopped: the size bound of 20000 bytes was reached"
    frames = list(read_capture(path))                      # the event is not a frame
    assert 200 < len(frames) < 1000 and all(r.frame == FRAME for r in frames)
    assert last["t_s"] >= frames[-1].t_s
    assert capture_stopped(path)

    unbounded = tmp_path / "u.jsonl"
    assert not _write_frames(unbounded, 1000).stopped
    assert len(list(read_capture(unbounded))) == 1000 and not capture_stopped(unbounded)


def test_merging_parts_respects_the_bound_once(tmp_path: Path) -> None:
    capture = tmp_path / CAPTURE_FILE
    for i in range(3):
        _write_frames(tmp_path / f"p{i}.jsonl", 300, t0_s=0.0)
    assert not merge_capture(tmp_path / "p0.jsonl", capture, 0.0, 40_000)
    size_one = capture.stat().st_size
    assert merge_capture(tmp_path / "p1.jsonl", capture, 3.0, 40_000)   # crosses the bound
    stopped_size = capture.stat().st_size
    assert size_one < stopped_size <= 40_000
    assert merge_capture(tmp_path / "p2.jsonl", capture, 6.0, 40_000)   # nothing more
    assert capture.stat().st_size == stopped_size
    times = [r.t_s for r in read_capture(capture)]
    assert times == sorted(times) and times[0] == pytest.approx(0.01)


def test_capture_options_from_the_bench_table_and_the_flags() -> None:
    assert capture_options({}) == (True, None)
    assert capture_options({"capture": False, "capture_max_bytes": 10}) == (False, 10)
    assert capture_options({"capture": False}, enabled=True) == (True, None)
    assert capture_options({"capture_max_bytes": 10}, max_mb=2.5) == (True, 2_500_000)
    for bench, where in (({"capture": "no"}, "bench.capture"),
                         ({"capture_max_bytes": 0}, "bench.capture_max_bytes"),
                         ({"capture_max_bytes": 1.5}, "bench.capture_max_bytes"),
                         ({"capture_max_bytes": True}, "bench.capture_max_bytes")):
        with pytest.raises(SettingsError, match=where):
            capture_options(bench)
    for mb in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(SettingsError, match="--capture-max-mb"):
            capture_options({}, max_mb=mb)


def _run(out: Path, config: Path, *flags: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "armbench", "run", "accuracy", "--config",
                           str(config), "--out", str(out), "--workers", "1", "--seed", "2",
                           *flags], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          check=False)


def _figures(out: Path) -> dict[str, float]:
    record = load_record(out / RESULTS_FILE)
    return {m.name: m.value for _, _, m in record.iter_measurements()}


def test_a_run_without_or_with_a_bounded_capture_measures_the_same(tmp_path: Path) -> None:
    config = tmp_path / "bench.toml"
    config.write_text('spec_version = "armbench-limits/1"\n[suites.accuracy]\nlaps = 1\n')
    full = _run(tmp_path / "full", config)
    assert full.returncode == 0, full.stderr
    assert (tmp_path / "full" / CAPTURE_FILE).stat().st_size > 120_000  # MCAP, zstd

    off = _run(tmp_path / "off", config, "--no-capture")
    assert off.returncode == 0, off.stderr
    assert not (tmp_path / "off" / CAPTURE_FILE).exists()
    assert not list((tmp_path / "off").glob(".capture.part*"))

    bounded = _run(tmp_path / "bounded", config, "--capture-max-mb", "0.1")
    assert bounded.returncode == 0, bounded.stderr
    assert "capture stopped" in bounded.stderr
    capture = tmp_path / "bounded" / CAPTURE_FILE
    assert capture.stat().st_size <= 100_000 and capture_stopped(capture)
    assert not list((tmp_path / "bounded").glob(".capture.part*"))
    assert _figures(tmp_path / "off") == _figures(tmp_path / "full") == _figures(
        tmp_path / "bounded")

    config.write_text('spec_version = "armbench-limits/1"\n[bench]\ncapture = false\n'
                      '[suites.accuracy]\nlaps = 1\n')
    table_off = _run(tmp_path / "table-off", config)
    assert table_off.returncode == 0, table_off.stderr
    assert not (tmp_path / "table-off" / CAPTURE_FILE).exists()
    config.write_text('spec_version = "armbench-limits/1"\n[bench]\ncapture_max_bytes = -3\n')
    bad = _run(tmp_path / "bad", config)
    assert bad.returncode == 2 and "bench.capture_max_bytes" in bad.stderr
    assert not (tmp_path / "bad").exists()
