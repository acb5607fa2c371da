"""Each note's own kernel temperature: agreement, a note left out, never a good note flagged."""

import math

import numpy as np
import pytest

from mpipe.inversion.trust.note_temperature import DISAGREE_P, note_temperatures


def _windows(temps, per_note=2, se=0.2, rng=None):
    """Groups, minima and SEs of windows whose minima scatter by ``se`` about their note's."""
    groups, minima, ses = [], [], []
    for g, t in enumerate(temps, start=1):
        for _ in range(per_note):
            groups.append(g)
            minima.append(t + (0.0 if rng is None else rng.normal(0.0, se)))
            ses.append(se)
    return groups, minima, ses


def test_notes_at_one_temperature_are_not_flagged():
    # 400 takes of 4 notes (2 windows each) at one temperature, window SEs right: the test
    # flags about DISAGREE_P of them; at most 1 % may be (the within-note floor only widens)
    flagged = 0
    for seed in range(400):
        rng = np.random.default_rng(seed)
        notes = note_temperatures(*_windows([20.0] * 4, rng=rng))
        flagged += notes.disagree
        assert not notes.excluded or notes.disagree
    assert flagged <= 4, flagged


def test_one_note_far_from_the_others_is_left_out_and_named():
    # three notes at 20 degC and one 2 degC off (10 of its SEs): it is left out, the
    # others then agree, and the reason names it; in 20 of 20 seeds
    for seed in range(20):
        rng = np.random.default_rng(seed)
        notes = note_temperatures(*_windows([20.0, 22.0, 20.0, 20.0], rng=rng))
        assert list(notes.excluded) == [2], (seed, notes)
        assert notes.first_p < DISAGREE_P and notes.p_value > DISAGREE_P
        assert "segment 2" in notes.reason() and "disagree" in notes.reason()


def test_a_note_at_a_bound_is_left_out_first_and_two_notes_are_never_split():
    groups, minima, ses = _windows([20.0, 20.1, 19.9])
    notes = note_temperatures(groups, minima, ses, unplayable=[3])
    assert list(notes.excluded) == [3] and "search bound" in notes.excluded[3]
    assert notes.disagree and "left out" in notes.reason()
    # two notes that disagree: which is wrong cannot be told; flagged, neither left out
    two = note_temperatures(*_windows([20.0, 21.5]))
    assert two.disagree and not two.excluded and "disagree" in two.reason()
    # one note: nothing to compare
    one = note_temperatures(*_windows([20.0]))
    assert not one.disagree and one.reason() == "" and math.isnan(one.first_p)


def test_the_chi_square_is_the_weighted_one():
    notes = note_temperatures([1, 2, 3], [19.0, 20.0, 21.0], [0.5, 0.5, 1.0])
    mean = (19.0 * 4 + 20.0 * 4 + 21.0) / 9
    expected = 4 * (19 - mean) ** 2 + 4 * (20 - mean) ** 2 + (21 - mean) ** 2
    assert notes.first_chi2 == pytest.approx(expected, rel=1e-12) and notes.first_dof == 2
