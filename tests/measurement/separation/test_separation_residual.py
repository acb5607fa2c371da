"""Tests of the null-filter residual of one block (physics.md E.3, E.5).

Its minimum lies at the true theta.
"""

from __future__ import annotations

import numpy as np
import pytest

from mpipe.measurement.separation.blocks import cross_spectra
from mpipe.measurement.separation.residual import residual_cost
from mpipe.measurement.separation.waves import Geometry, Theta
from tests.measurement.separation.separation_fields import CAL, FS, random_take


@pytest.mark.parametrize("temperature_c, mach", [(20.0, 0.0), (27.0, 0.008)])
def test_residual_minimum_at_true_theta(temperature_c, mach):
    x, _, _ = random_take(4000, temperature_c, mach)
    geo = Geometry.from_calibration(CAL)
    margin = 125
    sp = cross_spectra(x[500 - margin : 2500 + margin], FS, 100.0, 7000.0, margin)
    true = Theta(CAL.air_properties(temperature_c).c, 1.0, mach)
    j0 = residual_cost(true, sp, geo)
    assert j0 < 1e-9 * np.mean(sp.mic_power)
    for d in (
        (0.3, 0, 0),
        (-0.3, 0, 0),
        (0, 0.1, 0),
        (0, -0.1, 0),
        (0, 0, 0.002),
        (0, 0, -0.002),
    ):
        other = Theta(true.c + d[0], true.eta + d[1], true.mach + d[2])
        assert residual_cost(other, sp, geo) > 100 * j0
