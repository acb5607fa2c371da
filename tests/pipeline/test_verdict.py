"""The take's verdict: a note resting on a minority of its windows, not any window flagged."""

import pandas as pd

from mpipe.pipeline.verdict import overall_verdict


def test_a_note_resting_on_a_minority_of_its_windows_makes_the_take_check():
    status = ["ok"] * 8 + ["at-bound"] + ["ok", "at-bound", "at-bound", "at-bound"]
    windows = pd.DataFrame({"segment": [1] * 9 + [3] * 4, "status": status})
    label, kind = overall_verdict("pass", windows)
    # the second note (segment 3) has 1 of 4 windows ok; the first, 8 of 9, is not named
    assert kind == "check"
    assert "note 2: 1 of 4 windows ok" in label
    assert "note 1" not in label
    # the same first note alone: one window at a bound does not ask for a look
    assert overall_verdict("pass", windows.iloc[:9])[1] == "pass"


def test_the_note_named_is_the_takes_note_number_when_the_table_has_it():
    windows = pd.DataFrame({"segment": [1, 1, 1, 3, 3, 3], "note_number": [1, 1, 1, 2, 2, 2],
                            "status": ["ok", "ok", "ok", "ok", "at-bound", "failed"]})  # fmt: skip
    label, kind = overall_verdict("pass", windows)
    assert kind == "check" and "note 2: 1 of 3 windows ok" in label
