"""The take fit's cold starts and the choice between their runs (take_fit.py)."""

from types import SimpleNamespace

import numpy as np
import pytest

from mpipe.inversion.whole_take.take_fit import cold_windows, rival_costs


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
