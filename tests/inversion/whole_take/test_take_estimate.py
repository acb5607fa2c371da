"""The take estimate's own checks (take_estimate.py)."""

from mpipe.inversion.whole_take.take_estimate import RIVAL_MARGIN, rival_checks


def test_two_minima_the_data_barely_tell_apart_are_said():
    # one start, or two runs far apart in cost: nothing to say
    assert rival_checks(()) == ()
    assert rival_checks((1500.0,)) == ()
    assert rival_checks((2417.0, 2136.0)) == ()
    # within the margin, whichever run came first
    for costs in ((2136.0, 2136.0 + 0.5 * RIVAL_MARGIN), (2136.0 + 0.5 * RIVAL_MARGIN, 2136.0)):
        (reason,) = rival_checks(costs)
        assert "two minima" in reason and "barely prefer" in reason
    # exactly at the margin the data do tell them apart
    assert rival_checks((100.0, 100.0 + RIVAL_MARGIN)) == ()
