"""The windows' mouth-pressure slopes from their neighbours (mouth_slopes.py)."""

import numpy as np
import pytest

from mpipe.inversion.whole_take.mouth_slopes import (
    MAX_RAMP,
    MIN_WINDOWS,
    SLOPE_SETTLED,
    mouth_slopes,
    slopes_moved,
)

HOP = 0.02  # s, the shipped windows'
REACH = 0.02  # s, centre to lead-in start: 10 ms lead-in and half a 20 ms window


def test_a_line_is_recovered_in_each_note():
    # two notes of 1 s: a crescendo of +540 Pa/s, then a diminuendo of -300 Pa/s; every
    # window's slope is its own note's, to rounding (a line is its own local line)
    t = np.arange(100) * HOP
    notes = (t >= 1.0).astype(int)
    p_m = np.where(notes == 0, 1800 + 540 * t, 2500 - 300 * (t - 1.0))
    s = mouth_slopes(t, notes, p_m, REACH)
    np.testing.assert_allclose(s, np.where(notes == 0, 540.0, -300.0), rtol=1e-9)


def test_a_short_note_holds_its_mouth_pressure():
    t = np.arange(MIN_WINDOWS - 1) * HOP
    s = mouth_slopes(t, np.zeros(t.size, int), 1800 + 540 * t, REACH)
    assert np.all(s == 0.0)


def test_a_bend_is_followed_not_smoothed():
    # a crescendo that stops (the score's bend at 0.6 s): each window's slope is its side's,
    # the line before the bend or after it, not one across it (which tilts 0.2 s each side)
    t = np.arange(60) * HOP
    p_m = np.where(t < 0.6, 1800 + 540 * t, 1800 + 540 * 0.6)
    s = mouth_slopes(t, np.zeros(t.size, int), p_m, REACH)
    np.testing.assert_allclose(s, np.where(t < 0.59, 540.0, 0.0), atol=1e-9)


def test_the_release_is_played_at_the_line_before_it():
    # a steady note whose last two windows' p_m fall (the release): drawn through the
    # informing windows only, every slope is 0, the release's too; drawn through all, the
    # steady windows keep 0 (the line before them) and the release's windows tilt
    t = np.arange(30) * HOP
    p_m = np.full(t.size, 2100.0)
    p_m[-2:] = [1200.0, 300.0]
    informs = np.ones(t.size, bool)
    informs[-2:] = False
    held = mouth_slopes(t, np.zeros(t.size, int), p_m, REACH, informs)
    assert np.all(held == 0.0)
    tilted = mouth_slopes(t, np.zeros(t.size, int), p_m, REACH)
    assert np.all(tilted[:28] == 0.0) and np.all(tilted[28:] < -500.0)


def test_a_steep_onset_is_limited():
    t = np.arange(10) * HOP
    p_m = np.full(t.size, 2000.0)
    p_m[:3] = [100.0, 800.0, 1600.0]  # the first windows' p_m rising steeply
    s = mouth_slopes(t, np.zeros(t.size, int), p_m, REACH)
    assert np.all(np.abs(s) * REACH <= MAX_RAMP * p_m * (1 + 1e-12))


@pytest.mark.parametrize("seed", range(4))
def test_the_slopes_noise_is_the_local_lines(seed):
    # a steady note of 2 s whose windows' p_m carry white noise of 5 Pa: the slope's
    # standard deviation over 400 draws is about one least-squares line's, sigma /
    # sqrt(sum dt^2) over 21 windows 20 ms apart: the choice among three such lines adds
    # 6 % (2000 draws); 4 seeds, all must pass, within 0.95-1.2 of it (the draws' own
    # sampling error is 3.5 %)
    rng = np.random.default_rng(seed)
    t = np.arange(100) * HOP
    draws = np.array([mouth_slopes(t, np.zeros(100, int), 1800 + 5.0 * rng.standard_normal(100),
                                   REACH)[50] for _ in range(400)])  # fmt: skip
    dt = np.arange(-10, 11) * HOP
    expected = 5.0 / np.sqrt(dt @ dt)
    assert 0.95 * expected < np.std(draws) < 1.2 * expected
    # and at the lead-in's start it is under a twentieth of one window's p_m noise
    assert REACH * 1.2 * expected < 0.05 * 5.0


def test_slopes_settle_by_their_rms_move():
    p_m = np.full(50, 2000.0)
    old = np.zeros(50)
    small = np.full(50, 0.9 * SLOPE_SETTLED * 2000.0 / REACH)
    assert not slopes_moved(old, small, p_m, REACH)
    assert slopes_moved(old, small / 0.9 * 1.1, p_m, REACH)
    one = old.copy()
    one[0] = 3 * SLOPE_SETTLED * 2000.0 / REACH  # one window alone: its rms share
    assert not slopes_moved(old, one, p_m, REACH)
