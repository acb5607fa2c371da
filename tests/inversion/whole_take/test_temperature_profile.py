"""R(T) over the notes kept: from the memo of the whole take's, at little cost."""

import pytest

from mpipe.inversion.whole_take.temperature_profile import FINE_C, Profile, memo_start, settle

#: Six windows whose F2^2 are parabolas in T: four at 20 degC, two of a bad note at 22.5.
MINIMA = (20.0, 20.0, 20.0, 20.0, 22.5, 22.5)


def _solver(minima, calls):
    def solve(t, warm):
        calls.append(t)
        rows = [{"f2": (1e3 * (t - m) ** 2 + 10.0) ** 0.5} for m in minima]
        return sum(r["f2"] ** 2 for r in rows), list(warm), rows

    return solve


def test_the_profile_without_a_note_settles_from_the_memo():
    calls = []
    whole = Profile(_solver(MINIMA, calls), [None] * 6)
    vertex, _, _ = settle(whole, 20.3, 15.0, 25.0, 20)
    assert vertex == pytest.approx(20.0 + 2 * 2.5 / 6, abs=0.02)  # pulled by the bad note
    keep = [True] * 4 + [False] * 2
    calls.clear()
    sub = whole.subset(keep, _solver(MINIMA[:4], calls))
    assert sub(20.3) == pytest.approx(sum((1e3 * 0.3**2 + 10.0) for _ in range(4)))
    assert not calls  # from the memo
    start = memo_start(sub)
    vertex, curvature, centre = settle(sub, start, 15.0, 25.0, len(sub.tried) + 20, coarse=False)
    assert vertex == pytest.approx(20.0, abs=0.02) and curvature == pytest.approx(4e3, rel=0.01)
    assert len(calls) <= 6, calls  # two fine triples at most
    for d in (-FINE_C, 0.0, FINE_C):
        assert round(centre + d, 4) in sub.tried
