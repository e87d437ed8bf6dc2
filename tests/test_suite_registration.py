"""A suite's report section and its contract are found by registration: adding a suite's
section is adding its module to ``reports/sections/``, adding its contract is defining it with
``register``; no list elsewhere names them."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

import armbench.reports.sections as sections
from armbench.record.suite_contract import ACCURACY, AccuracyNames, contracts, register
from armbench.reports.page import SECTIONS
from armbench.reports.scorecard import HEADLINES, TRUTH_SUITES


def test_every_contract_has_its_section_and_headlines() -> None:
    names = [c.suite for c in contracts()]
    assert names[:2] == ["accuracy", "repeatability"]  # the order they are defined in
    assert set(SECTIONS) == set(names)
    assert list(HEADLINES) == names
    assert {"accuracy", "repeatability", "joints", "ros2-square"} == TRUTH_SUITES


def test_a_section_module_added_to_the_package_is_found(tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "gripper.py").write_text(
        'SUITE = "gripper"\n\n\ndef build(record, suite, view, figs):\n    return "built"\n',
        encoding="utf-8")
    (tmp_path / "notes.py").write_text('"""No SUITE: not a section."""\n', encoding="utf-8")
    monkeypatch.setattr(sections, "__path__", [*sections.__path__, str(tmp_path)])
    monkeypatch.delitem(sys.modules, "armbench.reports.sections.gripper", raising=False)
    found = sections.registered_sections()
    assert set(found) == {*SECTIONS, "gripper"}
    assert found["gripper"](None, None, None, None) == "built"  # type: ignore[arg-type, comparison-overlap]
    sys.modules.pop("armbench.reports.sections.gripper", None)
    sys.modules.pop("armbench.reports.sections.notes", None)


def test_two_sections_of_one_suite_are_refused(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "zz_accuracy_again.py").write_text(
        f'SUITE = "{ACCURACY.suite}"\n\n\ndef build(*args):\n    return None\n', encoding="utf-8")
    monkeypatch.setattr(sections, "__path__", [*sections.__path__, str(tmp_path)])
    with pytest.raises(ImportError, match="two report sections of suite 'accuracy'"):
        sections.registered_sections()
    sys.modules.pop("armbench.reports.sections.zz_accuracy_again", None)


def test_a_second_contract_of_one_suite_is_refused() -> None:
    with pytest.raises(ValueError, match="two contracts of suite 'accuracy'"):
        register(AccuracyNames())


def test_the_suites_are_those_their_contracts_name() -> None:
    """``armbench run``'s suites, in their default order, are the contracts that name a suite
    class, and each class runs the suite of its contract's name."""
    from armbench.bench.suites import SUITES, suite_class

    assert list(SUITES) == ["accuracy", "repeatability", "startup-recovery", "joints"]
    for name in SUITES:
        assert suite_class(name).name == name
    assert "twin-check" not in SUITES  # recorded by armbench twin-check, run by no suite
