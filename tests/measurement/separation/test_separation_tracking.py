"""Tests of theta over the blocks: a drifting temperature is followed (physics.md E.5)."""

from __future__ import annotations

import numpy as np
import pandas as pd

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


def test_chains_of_blocks_follow_a_drift_and_give_the_same_numbers_on_two_workers():
    # 3 s cross-faded from 20 to 26 degC: three chains of CHAIN_BLOCKS blocks, the later
    # ones starting from the take's start values 2-6 degC away; each still lands on the
    # drift, and two worker processes give the table of one, to the last digit
    from mpipe.measurement.separation.tracking import CHAIN_BLOCKS

    n = int(3.0 * FS)
    a, _, _ = random_take(n, 20.0, seed=5)
    b, _, _ = random_take(n, 26.0, seed=5)
    w = np.linspace(0, 1, n)[:, None]
    x = (1 - w) * a + w * b
    one = separate(x, FS, CAL, SeparationConfig(mach=0.0))
    two = separate(x, FS, CAL, SeparationConfig(mach=0.0), workers=2)
    assert int(one.blocks["temperature_raw_c"].notna().sum()) > 2 * CHAIN_BLOCKS
    pd.testing.assert_frame_equal(one.blocks, two.blocks)
    bl = one.blocks[one.blocks.trusted]
    truth = 20.0 + 6.0 * bl.time_s / (n / FS)
    assert np.max(np.abs(bl.temperature_raw_c - truth)) < 0.8
    assert np.max(np.abs(bl.temperature_c - truth)) < 0.5
