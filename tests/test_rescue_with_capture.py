"""A stalled start-up recovery is rescued while the run writes its capture: the runner's logged
power switch keeps the re-referencing of the switch it wraps (without it every rescue read
"operator must re-reference the arm" and, on avr://, every later trial found a silent arm)."""

from __future__ import annotations

import io
from pathlib import Path

from armbench.bench.runner import RunOptions, run_sync
from armbench.bench.runner.part_events import LoggedReReferencingPower, logged_power
from armbench.bench.runner.power import EmulatorPower
from armbench.bench.suites import ReReferencing
from armbench.drivers.capture.part import PartWriter
from armbench.drivers.capture.read import iter_events
from armbench.record import load_record

CONFIG = """spec_version = "armbench-limits/1"

[suites.startup-recovery]
trials = 2
conditions = ["cw-toward-near", "stopped-near"]
joint_sets = [[2, 3, 4]]
wear_duration_s = 0.0
"""


class _Relay:
    """A relay: it switches, nothing more (stands in for a lab's relay command)."""

    async def power_off(self) -> None: ...

    async def power_on(self) -> None: ...


def test_logging_keeps_what_the_switch_can_do(tmp_path: Path) -> None:
    part = PartWriter(tmp_path / "p.part", 0.0)
    relay = logged_power(_Relay(), part, "s", 0)
    assert not isinstance(relay, ReReferencing)
    assert not isinstance(relay, LoggedReReferencingPower)
    emulated = logged_power(EmulatorPower(object()), part, "s", 0)
    assert isinstance(emulated, ReReferencing)


def test_a_stalled_recovery_is_rescued_with_the_capture_on(tmp_path: Path) -> None:
    (tmp_path / "bench.toml").write_text(CONFIG)
    outcome = run_sync(RunOptions(suites=["startup-recovery"], config=tmp_path / "bench.toml",
                                  out=tmp_path / "run", seed=3), progress=io.StringIO())
    record = load_record(tmp_path / "run" / "results.json")
    trials = record.suites["startup-recovery"].trials
    assert all(t.status == "done" for t in trials), [t.error for t in trials]
    toward = next(t for t in trials if t.params["condition"] == "cw-toward-near")
    rescues = [s for s in toward.samples if s.get("event") == "rescue"]
    assert rescues and rescues[0]["done"], rescues
    kinds = [event.kind for event in iter_events(tmp_path / "run" / "capture.mcap")]
    assert "re_reference" in kinds
    assert outcome.out_dir == tmp_path / "run"
