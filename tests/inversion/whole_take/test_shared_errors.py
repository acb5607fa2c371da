"""Errors shared by a take's windows: calibration scale and front end (shared_errors)."""

import math

import pandas as pd
import pytest

from mpipe.inversion.fit.window import invert_window
from mpipe.inversion.preparation.kernel import bore_kernel
from mpipe.inversion.settings import PARAMETER_NAMES, InversionConfig
from mpipe.inversion.trust.combinations import combination_values
from mpipe.inversion.whole_take.shared_errors import (
    SCALE_EXPONENTS,
    calibration_columns,
    sensitivity_se_db,
)
from mpipe.reed.model import simulate
from mpipe.reed.parameters import ReedParameters

FS = 100_000.0
TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)
START = 30000
CHECKED = ("k", "S", "y_m", "p_m", "lam", "p_M", "gamma", "zeta")


def _values(reed, kernel, rho) -> dict:
    values = {k: float(getattr(reed, k)) for k in (*PARAMETER_NAMES, "y_c")}
    return {**values, **combination_values(values, kernel.z0, rho)}


def test_a_scale_error_of_p_and_u_moves_the_parameters_by_the_derived_exponents(
    shipped_calibration,
):
    # the model's own take, refitted after p and u are both scaled by 1.02 (a 0.17 dB
    # calibration error): d ln q / d ln a must be the exponents derived for y_c held
    kernel, air = bore_kernel(shipped_calibration, FS, 20.0)
    sim = simulate(TABLE1, kernel, START + 4000)
    config = InversionConfig()
    base = invert_window(sim.p, sim.u, FS, START, kernel, air.rho, config, zero_mean=False,
                         warm=TABLE1)  # fmt: skip
    a = 1.02
    scaled = invert_window(a * sim.p, a * sim.u, FS, START, kernel, air.rho, config,
                           zero_mean=False, warm=base.reed)  # fmt: skip
    x0, x1 = _values(base.reed, kernel, air.rho), _values(scaled.reed, kernel, air.rho)
    for name in CHECKED:
        exponent = math.log(x1[name] / x0[name]) / math.log(a)
        assert exponent == pytest.approx(SCALE_EXPONENTS[name], abs=0.05), name


def test_calibration_columns_scale_each_window_by_its_exponent(shipped_calibration):
    se_db, source = sensitivity_se_db(shipped_calibration)
    assert se_db == 0.15 and "default" in source
    table = pd.DataFrame({"p_M": [3000.0, 4000.0], "gamma": [0.5, 0.6], "lam": [0.01, 0.01]})
    out = calibration_columns(table, 0.2)
    rel = math.log(10) / 20 * 0.2  # 2.33 % per 0.2 dB
    assert out["p_M_se_calibration"].tolist() == pytest.approx([3000 * rel, 4000 * rel])
    assert out["gamma_se_calibration"].tolist() == [0.0, 0.0]
    assert out["lam_se_calibration"].tolist() == pytest.approx([0.005 * rel] * 2)
