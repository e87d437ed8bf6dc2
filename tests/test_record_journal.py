"""The record grows by appending (issue 20): a finished trial costs one journal line, whatever came
before; results.json is written at checkpoints and rebuilt from the journal after a crash; a kept
trial's samples are on disk, not in memory. Real files in a temporary directory throughout."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

import pytest

from armbench.record import (
    CAPTURE_FILE,
    JOURNAL_FILE,
    RESULTS_FILE,
    Environment,
    RecordError,
    RecordWriter,
    RunRecord,
    StoredSamples,
    Trial,
    continued_clock_s,
    load_record,
)
from armbench.record.limits import SPEC_VERSION


def _record(planned: tuple[str, ...] = ("acc",)) -> RunRecord:
    env = Environment(armbench_version="0.1.0", git_revision="abc", python="3.11.7",
                      platform="test", port="fake://", settings={}, seed=3, faults=(),
                      limits_spec_version=SPEC_VERSION, config_path=None)
    return RunRecord(run_id="run-1", created="2024-05-01T12:00:00+00:00", environment=env,
                     planned_suites=list(planned))


def _samples(index: int, n: int = 200) -> list[dict[str, Any]]:
    return [{"t_s": i * 0.01, "reported_m": [0.1 + index * 1e-3, 0.2, 0.3 + i * 1e-6]}
            for i in range(n)]


def _trial(index: int, n: int = 200) -> Trial:
    return Trial(index, float(index), 0.5, {"i": index}, _samples(index, n))


def _encodings(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """The indices of the trials encoded (``Trial.to_json``) from now on."""
    encoded: list[int] = []
    to_json = Trial.to_json

    def counting(self: Trial, *args: Any, **kwargs: Any) -> Any:
        encoded.append(self.index)
        return to_json(self, *args, **kwargs)

    monkeypatch.setattr(Trial, "to_json", counting)
    return encoded


def _written_bytes() -> int:
    """Bytes this process has handed to write(2) so far (Linux /proc)."""
    for line in Path("/proc/self/io").read_text().splitlines():
        if line.startswith("wchar:"):
            return int(line.split()[1])
    raise AssertionError("no wchar in /proc/self/io")


@pytest.mark.skipif(not Path("/proc/self/io").exists(), reason="needs Linux /proc/self/io")
def test_bytes_written_per_trial_stay_flat_as_trials_grow(tmp_path: Path) -> None:
    w = RecordWriter(tmp_path, _record())
    w.begin_suite("acc", "1")
    results_inode = w.path.stat().st_ino
    costs = []
    for i in range(300):
        before = _written_bytes()
        w.add_trial("acc", _trial(i))
        costs.append(_written_bytes() - before)
    line_bytes = (tmp_path / JOURNAL_FILE).stat().st_size / 300
    early, late = sum(costs[10:30]) / 20, sum(costs[-20:]) / 20
    # Before the journal, trial k rewrote results.json with all k trials: late ~ 15x early here.
    assert late <= 1.2 * early + 512, (early, late)
    # the journal line, and the trial's text for results.json encoded ahead (indented: longer)
    assert late <= 3.0 * line_bytes, (late, line_bytes)
    assert w.path.stat().st_ino == results_inode          # not rewritten trial by trial
    before = _written_bytes()
    w.end_suite("acc")
    final = w.path.stat().st_size
    assert _written_bytes() - before <= 1.1 * final + 4096  # results.json written once, streamed
    assert not (tmp_path / JOURNAL_FILE).exists()
    assert [t.index for t in load_record(w.path).suites["acc"].trials] == list(range(300))


def test_kept_samples_are_on_disk_and_read_back_equal(tmp_path: Path) -> None:
    w = RecordWriter(tmp_path, _record())
    w.begin_suite("acc", "1")
    w.add_trial("acc", _trial(0))
    kept = w.record.suites["acc"].trials[0]
    assert isinstance(kept.samples, StoredSamples) and kept.samples.path.name == JOURNAL_FILE
    assert kept.samples == _samples(0) and len(kept.samples) == 200
    assert kept.samples[3] == _samples(0)[3] and list(kept.samples)[-1] == _samples(0)[-1]
    w.end_suite("acc")                                     # results.json now holds them
    assert isinstance(kept.samples, StoredSamples) and kept.samples.path.name == RESULTS_FILE
    assert kept.samples == _samples(0)
    assert w.record.suites["acc"].trials[0] == _trial(0)


def test_a_crash_mid_suite_loses_no_finished_trial(tmp_path: Path) -> None:
    w = RecordWriter(tmp_path, _record())
    w.begin_suite("acc", "1")
    for i in range(3):
        w.add_trial("acc", _trial(i))
    del w                                                   # killed: no end_suite, no write
    with (tmp_path / JOURNAL_FILE).open("ab") as fh:      # a line the kill cut short
        fh.write(b'{"suite": "acc", "trial": {"index": 3, "sta')
    on_disk = load_record(tmp_path / RESULTS_FILE)
    assert [t.index for t in on_disk.suites["acc"].trials] == [0, 1, 2]
    assert list(on_disk.suites["acc"].trials[2].samples) == _samples(2)

    resumed = RecordWriter.resume(tmp_path)
    assert not (tmp_path / JOURNAL_FILE).exists()          # folded into results.json
    assert [t.index for t in resumed.completed_trials("acc")] == [0, 1, 2]
    resumed.add_trial("acc", _trial(3))
    resumed.end_suite("acc")
    assert [t.index for t in load_record(tmp_path / RESULTS_FILE).suites["acc"].trials] == [
        0, 1, 2, 3]


def test_a_journal_replayed_over_a_record_that_holds_it_adds_nothing(tmp_path: Path) -> None:
    """A kill after results.json was replaced but before the journal was removed."""
    w = RecordWriter(tmp_path, _record())
    w.begin_suite("acc", "1")
    w.add_trial("acc", Trial(0, 0.0, 0.5, {}, [], status="error", error="PortLostError"))
    w.add_trial("acc", _trial(1))
    w.add_trial("acc", _trial(0))                          # re-measured: 0 superseded
    shutil.copy(tmp_path / JOURNAL_FILE, tmp_path / "kept")
    w.end_suite("acc")
    os.replace(tmp_path / "kept", tmp_path / JOURNAL_FILE)
    record = load_record(tmp_path / RESULTS_FILE)
    suite = record.suites["acc"]
    assert [(t.index, t.status) for t in suite.trials] == [(0, "done"), (1, "done")]
    assert [(t.index, t.status) for t in suite.superseded_trials] == [(0, "error")]
    assert record.verdict == "pass"


def test_a_bad_journal_line_is_named(tmp_path: Path) -> None:
    w = RecordWriter(tmp_path, _record())
    w.begin_suite("acc", "1")
    w.add_trial("acc", _trial(0))
    with (tmp_path / JOURNAL_FILE).open("ab") as fh:
        fh.write(b"not json\n")
        fh.write(b'{"suite": "acc", "trial": {"index": 1}}\n')
    with pytest.raises(RecordError, match=rf"{JOURNAL_FILE}:2: is not valid JSON"):
        load_record(tmp_path / RESULTS_FILE)
    lines = (tmp_path / JOURNAL_FILE).read_bytes().splitlines(keepends=True)
    (tmp_path / JOURNAL_FILE).write_bytes(lines[0] + b'{"suite": "other", "trial": {}}\n')
    with pytest.raises(RecordError, match=r":2: suite 'other' is not in the record"):
        load_record(tmp_path / RESULTS_FILE)


def test_a_resumed_run_clock_continues_after_its_capture(tmp_path: Path) -> None:
    w = RecordWriter(tmp_path, _record())
    w.begin_suite("acc", "1", started_s=0.0)
    w.add_trial("acc", Trial(0, 1.0, 4.0, {}, [{"t_s": 0.0}]))   # ends at 5 s
    (tmp_path / CAPTURE_FILE).write_text(
        '{"t_s": 4.9, "dir": "out", "frame": "$0#", "error": null}\n'
        '{"t_s": 7.5, "dir": "in", "frame": "$1#", "error": null}\n', encoding="ascii")
    record = load_record(w.path)
    assert record.end_s == 5.0
    assert continued_clock_s(tmp_path, record) == 7.5      # the capture went on after the trial
    resumed = RecordWriter.resume(tmp_path)
    assert resumed.elapsed_s() >= 7.5


def test_streamed_results_json_is_the_text_the_whole_record_encodes_to(tmp_path: Path) -> None:
    """Streaming trial by trial from disk changes no byte of results.json."""
    from armbench.record.jsonformat import _encode

    w = RecordWriter(tmp_path, _record(("acc", "rep")))
    w.begin_suite("acc", "1", {"side_m": 0.1})
    for i in range(3):
        w.add_trial("acc", _trial(i, 30))
    w.add_trial("acc", Trial(3, 3.0, 0.5, {}, [], status="error", error="PortLostError"))
    w.add_trial("acc", Trial(3, 4.0, 0.5, {}, _samples(3, 5)))
    w.end_suite("acc")
    w.begin_suite("rep", "2")
    w.add_trial("rep", _trial(0, 1))
    w.write()
    in_memory = load_record(w.path)                       # every sample in memory
    assert w.path.read_text(encoding="utf-8") == _encode(in_memory.to_json()) + "\n"


def test_a_trial_already_in_results_json_is_copied_not_encoded_again(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A run writes results.json at every suite's begin and end: a trial that is there already,
    unchanged, is copied from the file being replaced (the same bytes); a trial changed since
    (a new object around the same stored samples) is encoded again."""
    from dataclasses import replace

    from armbench.record.jsonformat import _encode

    w = RecordWriter(tmp_path, _record(("acc", "rep")))
    w.begin_suite("acc", "1")
    for i in range(3):
        w.add_trial("acc", _trial(i, 30))
    w.end_suite("acc")                                    # the three trials encoded here
    encoded = _encodings(monkeypatch)
    w.begin_suite("rep", "2")
    assert encoded == []                                  # copied
    trials = w.record.suites["acc"].trials
    trials[1] = replace(trials[1], duration_s=9.5)        # changed, same stored samples
    w.write()
    assert encoded == [1]
    in_memory = load_record(w.path)
    assert in_memory.suites["acc"].trials[1].duration_s == 9.5
    assert w.path.read_text(encoding="utf-8") == _encode(in_memory.to_json()) + "\n"


def test_a_trial_is_encoded_as_it_is_added_not_at_its_suites_end(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A suite's end rewrites results.json with all its trials: each trial's text there is
    made when the trial is added (while the run goes on), kept beside the record until that
    write, and the write copies it (the same bytes as encoding it then)."""
    from dataclasses import replace

    from armbench.record.jsonformat import _encode

    w = RecordWriter(tmp_path, _record())
    w.begin_suite("acc", "1")
    for i in range(3):
        w.add_trial("acc", _trial(i, 30))
    assert w.ahead_trials == 3
    trials = w.record.suites["acc"].trials
    trials[2] = replace(trials[2], duration_s=7.5)        # changed since: encoded again
    encoded = _encodings(monkeypatch)
    w.end_suite("acc")
    assert encoded == [2]
    assert w.ahead_trials == 0
    in_memory = load_record(w.path)
    assert [t.duration_s for t in in_memory.suites["acc"].trials] == [0.5, 0.5, 7.5]
    assert w.path.read_text(encoding="utf-8") == _encode(in_memory.to_json()) + "\n"
