"""Errors shared by a take's windows: calibration scale and front end (shared_errors)."""

import dataclasses
import math

import numpy as np
import pandas as pd
import pytest

from mpipe.inversion.fit.window import invert_window
from mpipe.inversion.preparation.kernel import bore_kernel
from mpipe.inversion.settings import PARAMETER_NAMES, InversionConfig
from mpipe.inversion.trust.budget import combine
from mpipe.inversion.trust.combinations import combination_values
from mpipe.inversion.whole_take.shared_errors import (
    QUANTITIES,
    SCALE_EXPONENTS,
    FrontEnd,
    calibration_columns,
    failed_refits,
    frontend_columns,
    sensitivity_se_db,
    shared_components,
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
    assert math.isnan(se_db) and "not stated" in source
    table = pd.DataFrame({"p_M": [3000.0, 4000.0], "gamma": [0.5, 0.6], "lam": [0.01, 0.01]})
    out = calibration_columns(table, 0.2)
    rel = math.log(10) / 20 * 0.2  # 2.33 % per 0.2 dB
    assert out["p_M_se_calibration"].tolist() == pytest.approx([3000 * rel, 4000 * rel])
    assert out["gamma_se_calibration"].tolist() == [0.0, 0.0]
    assert out["lam_se_calibration"].tolist() == pytest.approx([0.005 * rel] * 2)


def test_an_unstated_calibration_stays_out_of_the_error_bars(shipped_calibration):
    # issue 38: an unstated microphone calibration added 0.15 dB (1.73 % of p_m) to every
    # window; only a stated uncertainty enters <q>_se, the assumed one has its own column
    table = pd.DataFrame({"p_m": [1800.0], "p_m_se_noise": [9.0], "determined_p_m": [True],
                          "status": ["ok"]})  # fmt: skip
    out, record = shared_components(
        np.zeros(10), np.zeros(10), 1e5, table, shipped_calibration, InversionConfig(),
        zero_mean=False, kernel_c=20.0,
    )  # fmt: skip
    assert "p_m_se_calibration" not in out
    assert out["p_m_se_scale"].iloc[0] == pytest.approx(1800.0 * math.log(10) / 20 * 0.15)
    assert combine(out, 0.1)["p_m_se"].iloc[0] == pytest.approx(9.0)
    assert record["sensitivity_se_db"] is None and "not stated" in record["sensitivity_se_source"]
    stated = dataclasses.replace(
        shipped_calibration,
        microphones=(dataclasses.replace(shipped_calibration.microphones[0],
                                         sensitivity_se_db=0.05),
                     *shipped_calibration.microphones[1:]),
    )  # fmt: skip
    out, record = shared_components(
        np.zeros(10), np.zeros(10), 1e5, table, stated, InversionConfig(),
        zero_mean=False, kernel_c=20.0,
    )  # fmt: skip
    rel = math.log(10) / 20 * 0.05
    assert "p_m_se_scale" not in out and record["sensitivity_se_db"] == 0.05
    assert combine(out, 0.1)["p_m_se"].iloc[0] == pytest.approx(math.hypot(9.0, 1800 * rel))


def test_a_failed_front_end_refit_is_not_counted_as_no_effect():
    # issue 38: a parameter whose re-fits all failed (NaN sensitivity) was left out of the
    # root sum of squares, i.e. counted as 0; it must leave the component NaN (not measured)
    table = pd.DataFrame({"p_m": [1800.0], "p_M": [3000.0]})
    nan = np.full(len(QUANTITIES), np.nan)
    good = np.full(len(QUANTITIES), 0.01)
    out = frontend_columns(table, {"temperature": good, "eta": nan})
    assert np.isnan(out["p_m_se_frontend"].iloc[0]) and np.isnan(out["p_M_se_frontend"].iloc[0])
    assert failed_refits({"temperature": good, "eta": nan}) == ["eta"]
    both = frontend_columns(table, {"temperature": good, "eta": 2 * good})
    assert both["p_m_se_frontend"].iloc[0] == pytest.approx(1800 * math.hypot(0.01, 0.02))


def test_correlated_front_end_errors_combine_through_their_correlation():
    # two parameters whose errors correlate fully and whose effects are opposite cancel;
    # uncorrelated they add in quadrature (limit cases of d^T R d)
    se = np.array([0.75, 0.12, 1e-3, 6e-6])
    corr = np.eye(4)
    corr[0, 1] = corr[1, 0] = 1.0
    front = FrontEnd(np.zeros(4), np.zeros(4), 20.0, np.array([20.0, 1.0, 0.0, 0.0]), se, 5e3,
                     None, corr * np.outer(se, se))  # fmt: skip
    r = front.correlation(["temperature", "eta"])
    assert r == pytest.approx(np.ones((2, 2)))
    table = pd.DataFrame({"p_m": [1800.0], "p_M": [3000.0]})
    d = np.full(len(QUANTITIES), 0.01)
    sens = {"temperature": d, "eta": -d}
    cancelled = frontend_columns(table, sens, r)
    assert cancelled["p_m_se_frontend"].iloc[0] == pytest.approx(0.0, abs=1e-9)
    assert frontend_columns(table, sens)["p_m_se_frontend"].iloc[0] == pytest.approx(
        1800 * math.hypot(0.01, 0.01)
    )
    # no covariance, or one that does not match the SEs: independent
    assert dataclasses.replace(front, level_cov=None).correlation(["temperature", "eta"]) == (
        pytest.approx(np.eye(2))
    )
    assert dataclasses.replace(front, level_se=2 * se).correlation(["eta", "mach"]) == (
        pytest.approx(np.eye(2))
    )
