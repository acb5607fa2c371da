"""The reed opening driven by a pressure signal reproduces the model's own reed."""

import dataclasses

import numpy as np
import pytest

from mpipe.reed.model import simulate
from mpipe.reed.opening import opening, opening_summary, reed_displacement


@pytest.mark.parametrize("p_m", [1800.0, 3000.0])
def test_driven_by_the_models_pressure_the_reed_is_the_models(setup, p_m):
    # the model's p drives the reed recurrence to the model's y (same equation, another
    # start state that decays within a few ms); the opening is the model's h, and the
    # fraction of the time shut is the model's: none at the Table 1 p_m, a fifth of each
    # period at 3000 Pa, where the reed beats against the lay
    _, _, reed, _, kernel = setup
    reed = dataclasses.replace(reed, p_m=p_m)
    sim = simulate(reed, kernel, 20000)
    y = reed_displacement(reed, sim.p, kernel.fs)
    tail = slice(5000, None)  # after 50 ms
    np.testing.assert_allclose(y[tail], sim.y[tail], rtol=0, atol=1e-6 * reed.y_m)
    h = opening(reed, sim.p, kernel.fs, 15000, 2000)
    # from a 5 ms lead: within 0.01 % of y_m from the first sample
    np.testing.assert_allclose(h, sim.h[15000:17000], rtol=0, atol=1e-4 * reed.y_m)
    summary = opening_summary(h)
    shut = float(np.mean(sim.h[15000:17000] <= 0))
    assert abs(summary["closed_fraction"] - shut) < 0.01
    assert (shut == 0.0) if p_m < 2000 else (0.1 < shut < 0.3)
    assert 0 < summary["h_mean"] < reed.y_m


def test_a_reed_that_never_closes_is_never_shut(setup):
    _, _, reed, _, kernel = setup
    p = 300.0 * np.sin(2 * np.pi * 150.0 * np.arange(4000) / kernel.fs)  # soft playing
    s = opening_summary(opening(reed, p, kernel.fs, 2000, 2000))
    assert s["closed_fraction"] == 0.0 and s["h_min"] > 0
    # static: h = y_m - (p_m - p) / k on average
    assert abs(s["h_mean"] - (reed.y_m - reed.p_m / reed.k)) < 0.05 * reed.y_m
