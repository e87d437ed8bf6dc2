"""The record's JSON text (``record/jsonformat.py``) against the standard library's encoder, on
drawn values: the text reads back to the value and has the record's layout (written plainly
here with ``json.dumps``); a flat value is what ``json.dumps`` writes with the record's options;
the pieces of ``iter_encode`` join to the whole text; a value that is not strict JSON is a
``RecordError`` naming where it is."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from armbench.record.fields import RecordError
from armbench.record.jsonformat import _compact, _encode, _to_json_text, iter_encode

SCALARS = (st.none() | st.booleans() | st.integers(-(2**70), 2**70)
           | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=12))
VALUES = st.recursive(SCALARS, lambda inner: st.lists(inner, max_size=6)
                      | st.dictionaries(st.text(max_size=8), inner, max_size=6), max_leaves=40)


def _dumps(value: Any) -> str:
    return json.dumps(value, ensure_ascii=False, allow_nan=False, separators=(", ", ": "))


def _flat(v: Any) -> bool:
    return isinstance(v, (str, int, float, bool, type(None))) or (
        isinstance(v, list) and all(isinstance(x, (str, int, float, bool, type(None)))
                                    for x in v))


def _reference(value: Any, level: int) -> str:
    """The layout the record's files have, written plainly with ``json.dumps``: containers
    indented one space per level; flat lists, and flat objects of at most 120 characters, on
    one line."""
    pad = " " * (level + 1)
    if isinstance(value, dict) and value:
        text = _dumps(value)
        if all(map(_flat, value.values())) and len(text) <= 120:
            return text
        return "{\n" + ",\n".join(f"{pad}{_dumps(k)}: {_reference(v, level + 1)}"
                                   for k, v in value.items()) + "\n" + " " * level + "}"
    if isinstance(value, list) and value and not _flat(value):
        return "[\n" + ",\n".join(f"{pad}{_reference(v, level + 1)}" for v in value) + (
            "\n" + " " * level + "]")
    return _dumps(value)


@given(VALUES, st.integers(0, 3))
def test_the_text_reads_back_and_is_the_layout(value: Any, level: int) -> None:
    text = _encode(value, level)
    assert json.loads(text) == value
    assert text == _reference(value, level)


@given(SCALARS | st.lists(SCALARS, max_size=6) | st.dictionaries(st.text(max_size=8), SCALARS,
                                                                   max_size=6))
def test_a_flat_value_is_written_as_json_dumps_writes_it(value: Any) -> None:
    assert _compact(value) == _dumps(value)


@given(VALUES, st.integers(0, 3))
def test_the_pieces_join_to_the_text(value: Any, level: int) -> None:
    pieces = list(iter_encode(value, level))
    assert all(isinstance(p, str) for p in pieces)
    assert "".join(map(str, pieces)) == _encode(value, level)


def test_numpy_values_are_their_lists_and_numbers() -> None:
    value = {"q_rad": np.array([0.5, -1.25]), "n": np.int64(3), "x": np.float64(0.1)}
    assert json.loads(_encode(value)) == {"q_rad": [0.5, -1.25], "n": 3, "x": 0.1}


@pytest.mark.parametrize("bad", [math.nan, math.inf, [1.0, -math.inf], {"a": [math.nan]},
                                 [[0.5], math.nan], [[0.5], -math.inf]])
def test_not_strict_json_names_where(bad: Any) -> None:
    with pytest.raises(RecordError, match=r"suites\.x\.trials\[0\].*NaN and infinity"):
        _to_json_text({"value": bad}, "suites.x.trials[0]")


def test_an_unknown_type_names_where() -> None:
    with pytest.raises(RecordError, match=r"suites\.x.*object is not JSON serialisable"):
        _to_json_text({"value": [object()]}, "suites.x")
