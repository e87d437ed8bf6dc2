"""Link outages in the record (issue 20): a trial's events and its ``disturbed`` flag survive the
journal, ``results.json`` and older records; the run-level line on disturbed trials in the verdict
reasons and JUnit; a silence on ``fake://`` (a power cut) is recorded but disturbs nothing. The
outages of real links are in ``tests/test_outage_campaign.py``."""

from __future__ import annotations

import asyncio
import io
import json
from pathlib import Path
from typing import Any

import pytest

from armbench.bench.runner import RunOptions, run_bench
from armbench.cli.commands.run_files import write_reports
from armbench.drivers.host.link_outages import LinkOutage, OutageLog
from armbench.fakes.clock.vclock import VirtualTimeLoop
from armbench.record import (
    Environment,
    RecordError,
    RecordWriter,
    RunRecord,
    Trial,
    load_record,
)
from armbench.record.limits import SPEC_VERSION
from armbench.reports.files.junit import write_junit
from armbench.reports.render.summary import verdict_reasons

OUTAGE = LinkOutage("port lost", "connection reset by peer", 12.0, 12.01, 15.5,
                    reconnect_attempts=4, commands_unacknowledged=1)


def _record() -> RunRecord:
    env = Environment(armbench_version="0.1.0", git_revision="abc", python="3.11.7",
                      platform="test", port="socket://127.0.0.1:4000", settings={}, seed=3,
                      faults=(), limits_spec_version=SPEC_VERSION, config_path=None)
    return RunRecord(run_id="run-1", created="2026-11-24T12:00:00+00:00", environment=env,
                     planned_suites=["accuracy"])


def _trial(index: int, *, disturbed: bool) -> Trial:
    events = [OUTAGE.to_json(20.0, origin_s=10.0)] if disturbed else []
    return Trial(index, 100.0 + index, 5.0, {"lap": index}, [{"t_s": 0.0}], status="done",
                 events=events, disturbed=disturbed)


def test_an_outage_as_an_event_timed_from_the_trials_start() -> None:
    ev = OUTAGE.to_json(20.0, origin_s=10.0)
    assert ev == pytest.approx({"event": "link outage", "kind": "port lost",
                                "cause": "connection reset by peer", "start_t_s": 2.0,
                                "detected_t_s": 2.01, "end_t_s": 5.5, "duration_s": 3.5,
                                "ongoing": False, "reconnect_attempts": 4,
                                "commands_unacknowledged": 1})
    ongoing = LinkOutage("port lost", "EOF", 12.0, 12.0).to_json(20.0, origin_s=13.0)
    assert ongoing["ongoing"] and ongoing["end_t_s"] is None and ongoing["duration_s"] == 8.0
    assert ongoing["start_t_s"] == -1.0  # it began before the trial


def test_the_outage_log_tells_losses_from_silences() -> None:
    log = OutageLog(silence_s=0.5)
    log.reply(1.0, 0.9)  # a gap of 0.1 s: nothing
    log.reply(2.0, 1.0)  # 1 s without a reply: a silence
    log.lost(2.5, "EOF", 2.4, 2)
    log.attempt_failed()
    log.command_lost()
    assert log.ongoing(3.0, 2.4) == LinkOutage("port lost", "EOF", 2.4, 2.5, None, 1, 3)
    log.reply(4.0, 2.4)
    silence, lost = log.between(0.0, 4.2, 4.0)
    assert (silence.kind, silence.started_s, silence.ended_s) == ("reply silence", 1.0, 2.0)
    assert (lost.kind, lost.ended_s, lost.reconnect_attempts) == ("port lost", 4.0, 1)
    assert log.between(3.0, 4.2, 4.0) == [lost]
    assert log.down_s(0.0, 4.2, 4.0) == pytest.approx(1.6)  # silences are not counted
    assert log.ongoing(4.4, 4.0) is None and log.ongoing(4.6, 4.0) is not None
    assert log.count == 2


def test_events_and_disturbed_survive_the_journal_and_results_json(tmp_path: Path) -> None:
    writer = RecordWriter(tmp_path, _record())
    writer.begin_suite("accuracy", "1", {})
    writer.add_trial("accuracy", _trial(0, disturbed=False))
    writer.add_trial("accuracy", _trial(1, disturbed=True))
    mid = load_record(tmp_path / "results.json")  # the journal replayed
    writer.end_suite("accuracy", [])
    for record in (mid, load_record(tmp_path / "results.json")):
        first, second = record.suites["accuracy"].trials
        assert not first.disturbed and first.events == ()
        assert second.disturbed and second.events == (OUTAGE.to_json(20.0, origin_s=10.0),)
        assert record.disturbed_trials() == [("accuracy", 1)]
        assert record.verdict == ("incomplete" if record is mid else "pass")


def test_a_record_from_before_the_events_loads_undisturbed() -> None:
    old: dict[str, Any] = dict(_trial(0, disturbed=False).to_json())
    del old["events"], old["disturbed"]
    trial = Trial.from_json(json.loads(json.dumps(old)), "trials[0]")
    assert trial.events == () and not trial.disturbed


@pytest.mark.parametrize(("key", "value"), [("disturbed", "yes"), ("events", [{"t_s": 1.0}]),
                                            ("events", ["outage"])])
def test_bad_events_are_named(key: str, value: object) -> None:
    data: dict[str, Any] = {**_trial(0, disturbed=False).to_json(), key: value}
    with pytest.raises(RecordError, match=rf"trials\[0\].*\.{key}"):
        Trial.from_json(data, "trials[0]")


def test_the_run_says_how_many_trials_were_disturbed(tmp_path: Path) -> None:
    writer = RecordWriter(tmp_path, _record())
    writer.begin_suite("accuracy", "1", {})
    for i in range(3):
        writer.add_trial("accuracy", _trial(i, disturbed=i > 0))
    writer.end_suite("accuracy", [])
    record = writer.record
    note = "2 trials disturbed by link outages (accuracy 1, 2): their measurements are kept but"
    assert (record.disturbance_note() or "").startswith(note)
    assert record.verdict == "pass"  # a warning, not another verdict
    assert any(r.startswith(note) for r in verdict_reasons(record))
    write_junit(record, tmp_path / "junit.xml")
    assert 'name="disturbed_trials" value="1, 2"' in (tmp_path / "junit.xml").read_text()
    write_reports(record, tmp_path)
    html = (tmp_path / "report.html").read_text()
    assert note in html and "3 (2 disturbed by link outages)" in html  # the suites table
    record.suites["accuracy"].trials[1:] = []
    assert record.disturbance_note() is None


def test_a_power_cut_on_fake_is_a_silence_in_the_record_not_a_disturbance(
        tmp_path: Path) -> None:
    config = tmp_path / "bench.toml"
    config.write_text('spec_version = "armbench-limits/1"\n\n[suites.accuracy]\nlaps = 1\n'
                      'styles = ["coordinated"]\nside_m = 0.04\n')
    faults = tmp_path / "faults.toml"
    faults.write_text('[[faults]]\nkind = "power_cut"\nat_s = 0.5\n')
    options = RunOptions(suites=["accuracy"], config=config, out=tmp_path / "run", seed=3,
                         faults=faults)
    with asyncio.Runner(loop_factory=lambda: VirtualTimeLoop(0.0)) as runner:
        outcome = runner.run(run_bench(options, progress=io.StringIO()))
    (trial,) = load_record(tmp_path / "run" / "results.json").suites["accuracy"].trials
    assert trial.status == "error" and trial.error is not None
    assert trial.error.startswith("ReplyTimeoutError")
    (ev,) = trial.events
    assert ev["event"] == "link outage" and ev["kind"] == "reply silence" and ev["ongoing"]
    assert 0.0 <= ev["start_t_s"] <= ev["detected_t_s"] <= trial.duration_s
    assert not trial.disturbed and outcome.record.disturbance_note() is None
