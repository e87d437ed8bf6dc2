"""Where a finished trial goes in its suite (``SuiteRecord.place``, ``current``, ``holds``):
in index order, one current trial per index, an errored one re-measured moved to the superseded
trials, a done one never measured twice, whatever order the workers finish them in. Checked
against the rule written out plainly (a scan and a sort per trial, as the record did before it
bisected: a campaign places 10 000 trials)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from armbench.record import RecordError, SuiteRecord, Trial

#: Finished trials as (index, done?) in the order they finish: an index may come again after an
#: error (a retry, a resumed run) and, wrongly, after it was done.
FINISHES = st.lists(st.tuples(st.integers(0, 30), st.booleans()), max_size=60)


def _trial(index: int, done: bool, k: int) -> Trial:
    return Trial(index, float(k), 1.0, status="done" if done else "error",
                 error=None if done else f"PortLostError {k}")


def _plain_rule(trials: list[Trial], superseded: list[Trial], trial: Trial) -> bool:
    """The rule as a scan and a sort; False where the trial is refused (already measured)."""
    for i, old in enumerate(trials):
        if old.index == trial.index:
            if old.status == "done":
                return False
            superseded.append(trials.pop(i))
            break
    trials.append(trial)
    trials.sort(key=lambda t: t.index)
    return True


@given(FINISHES)
def test_placed_trials_follow_the_plain_rule(finishes: list[tuple[int, bool]]) -> None:
    suite = SuiteRecord(name="s", version="1")
    trials: list[Trial] = []
    superseded: list[Trial] = []
    for k, (index, done) in enumerate(finishes):
        trial = _trial(index, done, k)
        if _plain_rule(trials, superseded, trial):
            suite.place(trial)
            assert suite.holds(trial)
        else:
            with pytest.raises(RecordError, match="already measured"):
                suite.place(trial)
            assert not suite.holds(trial)
        assert suite.trials == trials and suite.superseded_trials == superseded
    for index in range(31):
        expected = next((t for t in trials if t.index == index), None)
        assert suite.current(index) is expected
    assert all(suite.holds(t) for t in (*trials, *superseded))


def test_a_loaded_record_is_in_index_order_whatever_its_file_says() -> None:
    """A suite read from JSON whose trials are out of order (a hand-edited file) is put in
    index order, so a trial placed later finds the one it re-measures."""
    suite = SuiteRecord(name="s", version="1")
    for k, index in enumerate((3, 1, 2)):
        suite.place(_trial(index, index != 1, k))
    data = suite.to_json()
    data["trials"] = list(reversed(data["trials"]))
    loaded = SuiteRecord.from_json(data, "suites.s")
    assert [t.index for t in loaded.trials] == [1, 2, 3]
    loaded.place(_trial(1, True, 9))
    assert [t.index for t in loaded.superseded_trials] == [1]
    with pytest.raises(RecordError, match=r"trials\[index 2\]"):
        loaded.place(_trial(2, True, 10))
