"""Where windows run: contiguous chunks of windows; nothing to run, nothing dispatched."""

from mpipe.inversion.execution import dispatch, split_chains
from mpipe.inversion.settings import ExecutorConfig


def test_split_chains_contiguous():
    chains = split_chains(list(range(10)), 3)
    assert [c[0] for c in chains] == [0, 4, 7]
    assert sum(chains, []) == list(range(10))
    assert split_chains([1, 2], 5) == [[1], [2]]


def test_dispatch_of_no_windows_starts_no_worker():
    assert dispatch(None, [], None, ExecutorConfig(workers=2), 2, None, None) == []
