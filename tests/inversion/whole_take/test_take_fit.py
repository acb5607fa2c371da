"""The take fit's cold starts and the choice between their runs (take_fit.py)."""

from types import SimpleNamespace

import numpy as np
import pytest

from mpipe.inversion.whole_take.cold_starts import cold_windows
from mpipe.inversion.whole_take.take_fit import THIN, THIN_MIN, rival_costs, thinned


def _problem(start: int, amplitude: float):
    t = np.arange(200) / 1.0e4
    return SimpleNamespace(start=start, target=SimpleNamespace(p=amplitude * np.sin(2e3 * t)))


def _run(starts, rr, weight, t, prior=(20.0, 0.5)):
    problems = tuple(SimpleNamespace(start=s) for s in starts)
    return SimpleNamespace(take=SimpleNamespace(problems=problems, prior=prior),
                           blocks=SimpleNamespace(rr=np.asarray(rr, float)), weight=weight,
                           state=SimpleNamespace(t=t))  # fmt: skip


def test_cold_windows_are_the_first_and_the_loudest_steady_window():
    problems = [_problem(100 * i, a) for i, a in enumerate([900.0, 1000.0, 3000.0, 2000.0])]
    assert cold_windows(problems, [False, True, False, True]) == [1, 3]
    assert cold_windows(problems, [True, True, True, True]) == [0, 2]
    # the first steady window is the loudest: one cold start
    assert cold_windows(problems, [False, False, True, False]) == [2]


def test_rival_costs_compare_on_the_first_runs_weight_and_the_windows_both_kept():
    first = _run([0, 10, 20], [4.0, 1.0, 1.0], weight=2.0, t=20.5)
    # the second run left out window 10 and weighs its own windows differently
    second = _run([0, 20], [2.0, 1.0], weight=7.0, t=20.0)
    costs = rival_costs([first, second])
    # windows 0 and 20 only, at the first run's weight, plus the prior's term
    assert costs == pytest.approx([2.0 * (4.0 + 1.0) + 1.0, 2.0 * (2.0 + 1.0) + 0.0])
    assert int(np.argmin(costs)) == 1


def test_the_thinned_take_keeps_every_note_and_every_thin_th_window_of_a_long_one():
    notes = [0] * 40 + [1] * 3 + [2] * 9
    problems = [SimpleNamespace(note=n) for n in notes]
    kept = thinned(problems)
    by_note = {n: [i for i in kept if notes[i] == n] for n in (0, 1, 2)}
    assert by_note[0] == list(range(0, 40, THIN))  # a long note: every THIN-th window
    assert by_note[1] == [40, 41, 42]  # a note shorter than THIN_MIN: all of it
    # a note too short for THIN_MIN windows at every THIN-th: THIN_MIN spread over it
    assert len(by_note[2]) == THIN_MIN and by_note[2][0] == 43 and by_note[2][-1] == 51
    assert kept == sorted(kept) and len(set(kept)) == len(kept)


def test_a_chains_first_window_keeps_the_lower_of_its_two_minima():
    # window 0 (a note's onset) has two basins: x = 1 (sum of squares 1.0), where its only
    # start leads, and x = 3 (0.1), where its successor's controls lead; the later windows
    # have one basin each. Warmed forward alone, window 0 stays at 1; fitted again from
    # window 1's controls it takes 3. A second chain whose first window's own minimum is
    # the lower (0.2 against 0.5 from its successor's controls) keeps it.
    from mpipe.inversion.whole_take.take_shards import Shard

    def fast_fit(i, x0, slow):
        x0 = float(np.ravel(x0)[0])
        if i == 0:
            return (np.array([1.0]), 1.0) if x0 < 2 else (np.array([3.0]), 0.1)
        if i == 2:
            return (np.array([4.5]), 0.5) if x0 > 3.5 else (np.array([3.5]), 0.2)
        return np.array([3.0 + 1.5 * (i == 3)]), 0.2

    shard = SimpleNamespace(problems=[None] * 4, fast_fit=fast_fit)
    out = Shard.warm(shard, [[0, 1], [2, 3]], [[np.array([1.0])], [np.array([3.0])]],
                     [None, None])  # fmt: skip
    assert [float(x[0][0]) for x in out] == [3.0, 3.0, 3.5, 4.5]
    assert [x[1] for x in out] == [0.1, 0.2, 0.2, 0.2]
