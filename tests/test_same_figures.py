"""``scripts/same_figures.py``: the check that a refactoring kept every figure of a run."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from types import ModuleType
from typing import Any

from script_loader import load_script


def _script() -> ModuleType:
    return load_script("same_figures")


def _m(name: str, value: float | None) -> dict[str, Any]:
    return {"name": name, "value": value, "unit": "mm", "outcome": "pass"}


RECORD: dict[str, Any] = {"suites": {"accuracy": {
    "measurements": [_m("accuracy.paper.mean_mm", 20.0), _m("accuracy.none", None)],
    "trials": [{"index": 0, "measurements": [_m("accuracy.paper.mean_mm", 19.5)]}]}}}


def test_the_same_record_has_no_difference(tmp_path: Path) -> None:
    same = _script()
    path = tmp_path / "results.json"
    path.write_text(json.dumps(RECORD), encoding="utf-8")
    assert same.main([str(path), str(tmp_path)]) == 0


def test_a_changed_missing_or_relabelled_figure_is_reported() -> None:
    same = _script()
    other = copy.deepcopy(RECORD)
    suite = other["suites"]["accuracy"]
    suite["trials"][0]["measurements"][0]["value"] = 19.5 + 1e-9
    suite["measurements"][0]["outcome"] = "fail"
    suite["measurements"].pop(1)
    diff = same.differences(RECORD, other, 1e-12)
    assert diff == ["only in A: accuracy/accuracy.none",
                    "differs: accuracy/accuracy.paper.mean_mm: 20.0 mm pass vs 20.0 mm fail",
                    "differs: accuracy/trial 0/accuracy.paper.mean_mm: 19.5 mm pass vs "
                    f"{19.5 + 1e-9} mm pass"]
    suite["trials"][0]["measurements"][0]["value"] = 19.5 * (1 + 1e-13)
    assert len(same.differences(RECORD, other, 1e-12)) == 2
