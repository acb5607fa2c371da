"""Tests of theta over the blocks: a drifting temperature is followed (physics.md E.5)."""

from __future__ import annotations

import numpy as np

from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.stage import separate
from tests.measurement.separation.separation_fields import CAL, FS, random_take


def test_drifting_temperature_is_tracked():
    # (d) in short: the take is cut from two fields 3 degC apart, cross-faded linearly
    n = int(1.2 * FS)
    a, _, _ = random_take(n, 20.0, seed=3)
    b, _, _ = random_take(n, 23.0, seed=3)
    w = np.linspace(0, 1, n)[:, None]
    x = (1 - w) * a + w * b
    res = separate(x, FS, CAL, SeparationConfig(mach=0.0))
    bl = res.blocks[res.blocks.trusted]
    truth = 20.0 + 3.0 * bl.time_s / (n / FS)
    # a cross-fade of two temperatures is not one temperature; allow for that
    assert np.max(np.abs(bl.temperature_c - truth)) < 0.4
    assert bl.temperature_c.iloc[-1] - bl.temperature_c.iloc[0] > 2.4
