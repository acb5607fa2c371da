"""Each note started again from the other notes' constants, on a separable sum of squares.

The shards are replaced by a sum of squares known in closed form: a window's controls are
its note's true ones when fitted, and its r^T r is the squared log distance of the
constants it holds from the nearest of its note's minima (a true one, and for one note a
second, worse one). A note in its worse minimum must move to the constants of a note in
the true one; a note at its best must not move.
"""

import dataclasses
from types import SimpleNamespace

import numpy as np

from mpipe.inversion.whole_take.note_starts import alternatives, note_sums, swapped_origin
from mpipe.inversion.whole_take.warm_starts import Origin
from mpipe.reed.parameters import ReedParameters

TRUE = np.array([8.66e6, 0.013])  # k (Pa/m), lambda (m): one reed for every note
WORSE = np.array([8.0e6, 0.0098])  # a second minimum of the last note, 40 units higher


def _sum(slow, note, last):
    """Squared log distance from the nearest minimum of the note (+40 at the worse one)."""
    minima = [(TRUE, 0.0)] + ([(WORSE, 40.0)] if note == last else [])
    return min(1e3 * float(np.sum(np.log(slow / m) ** 2)) + c for m, c in minima)


class _Shards:
    """Two shards of whole chains; ``warm`` returns each window's (controls, r^T r)."""

    def __init__(self, problems, ranges, last):
        self.problems, self.ranges, self.last, self.calls = problems, ranges, last, 0

    def call(self, method, per_shard):
        assert method == "warm"
        self.calls += 1
        out = []
        for (a, _), (chains, _, slows) in zip(self.ranges, per_shard, strict=True):
            rows = {}
            for chain, slow in zip(chains, slows, strict=True):
                for i in chain:
                    q = self.problems[a + i]
                    rows[i] = (np.array([1800.0]), _sum(np.asarray(slow), q.note, self.last))
            out.append([rows[i] for i in sorted(rows)])
        return out


def _run(slow):
    notes = [0] * 4 + [1] * 4 + [2] * 4
    problems = [SimpleNamespace(note=n, informs=True, start=1000 * i,
                                target=SimpleNamespace(p=np.ones(8)))
                for i, n in enumerate(notes)]  # fmt: skip
    shards = _Shards(problems, [(0, 8), (8, 12)], last=2)
    slow = np.asarray(slow, float)
    rr = np.array([_sum(slow[n], n, 2) for n in notes])
    layout = SimpleNamespace(names=("p_m", "k", "lam"), n_fast=1)
    state = SimpleNamespace(slow=slow, fast=np.full((len(notes), 1), 1800.0), t=20.0)

    def origin_here(origin):
        return dataclasses.replace(origin, slow={n: slow[n] for n in range(3)}, t=20.0,
                                   fast={q.start: state.fast[i] for i, q in
                                         enumerate(problems)})  # fmt: skip

    return SimpleNamespace(take=SimpleNamespace(problems=problems, layout=layout,
                                                shards=shards),
                           state=state, blocks=SimpleNamespace(rr=rr), notes=(0, 1, 2),
                           origin_here=origin_here)  # fmt: skip


TABLE1 = dict(k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10)
ORIGIN = Origin(ReedParameters(**TABLE1), 2000.0)


def test_a_note_in_a_worse_minimum_starts_again_from_another_notes_constants():
    near = TRUE * np.array([1.01, 0.99])  # the first two notes right (within noise)
    run = _run([near, TRUE, WORSE])
    moved = swapped_origin(run, ORIGIN)
    assert moved is not None
    origin, notes = moved
    assert notes == [2]
    # the last note takes the first note's constants (the second agrees with them: one
    # start of each group), which lie in the true minimum's basin; the others stay
    np.testing.assert_allclose(origin.slow[2], near)
    assert _sum(origin.slow[2], 2, 2) < _sum(WORSE, 2, 2)
    np.testing.assert_allclose(origin.slow[0], near)
    assert origin.t == 20.0 and set(origin.fast) == {q.start for q in run.take.problems}


def test_notes_all_at_their_best_do_not_move():
    run = _run([TRUE * 1.01, TRUE, TRUE * 0.99])
    assert swapped_origin(run, ORIGIN) is None
    # one note: nothing to start from
    one = _run([WORSE, TRUE, TRUE])
    one.state.slow = one.state.slow[:1]
    assert swapped_origin(one, ORIGIN) is None


def test_alternatives_skip_agreeing_notes_and_note_sums_count_informing_windows():
    slow = np.array([TRUE, TRUE * 1.01, WORSE, WORSE * 1.02])
    # notes 0 and 1 agree (within 5 % in ln), as do 2 and 3: one of each other group
    assert alternatives(slow) == [[2], [2], [0], [0]]
    problems = [SimpleNamespace(note=n, informs=i != 1) for i, n in enumerate([0, 0, 1, 1])]
    sums = note_sums(problems, [1.0, 5.0, 2.0, None])
    assert sums[0] == 1.0 and np.isinf(sums[1])
