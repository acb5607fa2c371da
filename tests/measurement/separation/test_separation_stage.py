"""End-to-end tests of the wave separation (physics.md E).

p0 and u0 reconstructed and theta estimated from virtual takes, held theta, bad input
refused.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mpipe.measurement.separation.result import BLOCK_COLUMNS
from mpipe.measurement.separation.settings import SeparationConfig, fixed_config
from mpipe.measurement.separation.stage import separate
from tests.measurement.separation.separation_fields import CAL, FS, band_nrmse, random_take


def test_clean_take_reconstructs_and_estimates_theta():
    # (a) and (c) in short: air 5 degC off the configuration and Mach 0.01
    x, p0, u0 = random_take(int(0.6 * FS), temperature_c=25.0, mach=0.01)
    res = separate(x, FS, CAL, SeparationConfig())
    b = res.blocks[res.blocks.trusted]
    assert abs(np.median(b.temperature_c) - 25.0) < 0.1
    assert abs(np.median(b.mach) - 0.01) < 5e-4
    assert band_nrmse(res.p0, p0) < 5e-3
    assert band_nrmse(res.u0, u0) < 5e-3
    for col in BLOCK_COLUMNS:
        assert col in res.blocks
    assert (b.band_hi_hz <= SeparationConfig().fmax_hz).all() and (b.bins > 10).all()


def test_fixed_theta_matches_true_field():
    x, p0, u0 = random_take(int(0.4 * FS))
    res = separate(x, FS, CAL, fixed_config(SeparationConfig()))
    assert np.allclose(res.blocks.temperature_c, 20.0)
    assert band_nrmse(res.p0, p0) < 1e-3
    assert band_nrmse(res.u0, u0) < 1e-3


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="shape"):
        separate(np.zeros((100, 2)), FS, CAL, SeparationConfig())
    with pytest.raises(ValueError, match="singular"):
        separate(
            np.zeros((1000, 3)),
            FS,
            CAL,
            dataclasses.replace(SeparationConfig(), band_edge_hz=8500.0),
        )
