"""``armbench perf --only run``: the phase clock of the timed default run."""

from __future__ import annotations

import asyncio
import importlib
import time
import types

import pytest

from armbench.cli.perf import run_perf as perf_run


def test_a_phase_inside_another_is_charged_to_itself_only(
        monkeypatch: pytest.MonkeyPatch) -> None:
    now = [100.0]
    monkeypatch.setattr(time, "perf_counter", lambda: now[0])
    clock = perf_run._Clock()
    now[0] += 1.0                                     # other: 1 s

    def inner() -> None:
        now[0] += 2.0                                 # imports: 2 s

    timed_inner = clock.timed("imports", inner)

    def outer() -> None:
        now[0] += 3.0                                 # report: 3 s before the import
        timed_inner()
        now[0] += 4.0                                 # and 4 s after

    clock.timed("report", outer)()
    now[0] += 5.0                                     # other again: 5 s
    clock.leave()
    assert clock.seconds == {"other": 6.0, "report": 7.0, "imports": 2.0}
    assert set(clock.cpu_seconds) == set(clock.seconds)


def test_a_coroutine_is_timed_from_its_start_to_its_end() -> None:
    clock = perf_run._Clock()

    async def summarize() -> int:
        time.sleep(0.05)
        return 7

    timed = clock.timed("summaries", summarize)
    assert asyncio.run(timed()) == 7
    assert clock.seconds["summaries"] >= 0.05


def test_parts_that_are_not_found_are_named(monkeypatch: pytest.MonkeyPatch) -> None:
    target = types.SimpleNamespace(write=lambda: 1)
    module = types.ModuleType("armbench_perf_test_target")
    module.Writer = target  # type: ignore[attr-defined]
    monkeypatch.setitem(__import__("sys").modules, module.__name__, module)
    monkeypatch.setattr(perf_run, "PHASES", (("record", module.__name__, "Writer.write"),
                                             ("record", module.__name__, "Writer.gone"),
                                             ("report", "armbench_no_such_module", "f")))
    clock = perf_run._Clock()
    missing = perf_run._patch(clock)
    assert missing == [f"{module.__name__}.Writer.gone", "armbench_no_such_module.f"]
    assert target.write() == 1
    assert "record" in clock.seconds


def test_every_timed_part_names_code_that_exists() -> None:
    """A renamed module or method would leave its phase silently untimed."""
    for _, module_name, path in perf_run.PHASES:
        owner = importlib.import_module(module_name)
        for part in path.split("."):
            owner = getattr(owner, part)
        assert callable(owner), (module_name, path)
