"""The one temperature of a take's bore kernel (mpipe.inversion.preparation.kernel)."""

import numpy as np
import pandas as pd

from mpipe.inversion.preparation.kernel import bore_kernel, table_temperature, take_temperature


def test_take_temperature_is_the_median_of_what_the_signals_carry(shipped_calibration):
    cal = shipped_calibration
    assert take_temperature(np.array([18.0, 19.0, np.nan, 25.0]), cal) == 19.0
    assert take_temperature(None, cal) == cal.air.temperature_c
    assert take_temperature(np.full(3, np.nan), cal) == cal.air.temperature_c


def test_table_temperature_prefers_the_fitted_one(shipped_calibration):
    cal = shipped_calibration
    fitted = pd.DataFrame({"kernel_temperature_c": [19.9, 19.9]})
    assert table_temperature(fitted, np.array([18.0]), cal) == 19.9
    old = pd.DataFrame({"k": [1.0]})  # a table written before the fit existed
    assert table_temperature(old, np.array([18.0]), cal) == 18.0


def test_a_warmer_kernel_is_a_faster_bore(shipped_calibration):
    # the reflection function's first strong return (the round trip to the bell) comes
    # earlier in warmer air, by the ratio of the sound speeds
    cold, air_cold = bore_kernel(shipped_calibration, 100_000.0, 15.0)
    warm, air_warm = bore_kernel(shipped_calibration, 100_000.0, 25.0)
    t_cold, t_warm = (int(np.argmin(k.h)) for k in (cold, warm))
    ratio = air_warm.c / air_cold.c
    assert ratio > 1.015 and abs(t_cold / t_warm - ratio) < 0.005
