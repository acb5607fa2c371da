"""The take estimate's own checks (take_estimate.py)."""

import math

import numpy as np

from mpipe.inversion.whole_take.take_estimate import (
    CONFLICT_P,
    RIVAL_MARGIN,
    prior_checks,
    rival_checks,
)


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


def test_a_temperature_its_prior_contradicts_is_said_and_a_right_one_seldom():
    prior = (23.0, 0.05)
    (reason,) = prior_checks(21.0, prior, carried=True)  # the air 2 degC from the stated
    assert "temperature" in reason and "40 of the front end's SEs" in reason
    assert prior_checks(23.15, prior, carried=True) == ()  # 3 SE: within p = 0.001
    assert prior_checks(21.0, prior, carried=False) == ()  # no measurement to contradict
    assert prior_checks(21.0, (23.0, math.inf), carried=True) == ()
    # the conjugate Gaussian: the air drawn from the prior, the playing's own estimate of it
    # with its SE, the fit's T their inverse-variance mean; over 10^5 takes per ratio of
    # SEs the check fires at most at its rate (it reads the prior's SE: conservative)
    rng = np.random.default_rng(0)
    m, s = 20.0, 0.6
    for s_d in (0.05, 0.6, 3.0):
        air = rng.normal(m, s, 100_000)
        own = air + rng.normal(0.0, s_d, air.size)
        t = (m / s**2 + own / s_d**2) / (1 / s**2 + 1 / s_d**2)
        fired = sum(bool(prior_checks(float(x), (m, s), carried=True)) for x in t[:20_000])
        assert fired <= 2 * CONFLICT_P * 20_000, (s_d, fired)
    # and the faulted air, 5 SE of the prior off, is caught whenever the playing measures
    # it well (its SE a tenth of the prior's)
    t = (m / s**2 + (m + 5 * s + rng.normal(0.0, 0.06, 2000)) / 0.06**2) / (1 / s**2 + 1 / 0.06**2)
    assert all(prior_checks(float(x), (m, s), carried=True) for x in t)
