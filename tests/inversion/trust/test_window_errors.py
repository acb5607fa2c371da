"""A window's uncertainty columns: delta method, fixed, gauged and on-bound parameters."""

import math

import numpy as np
import pytest

from mpipe.inversion.trust.uncertainty import covariance
from mpipe.inversion.trust.window_errors import window_uncertainty
from mpipe.reed.parameters import ReedParameters

TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)


def test_window_uncertainty_flags_and_delta_method():
    names = ("k", "y_m", "p_m")
    rng = np.random.default_rng(1)
    jac = rng.standard_normal((400, 3)) * [1.0, 1.0, 50.0]
    cov = covariance(jac, 0.01 * rng.standard_normal(400), names)
    values = {n: getattr(TABLE1, n) for n in ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c")}
    values["y_c"] = TABLE1.y_c
    row = window_uncertainty(cov, values, z_c=5e6, rho=1.2, limit=0.10)
    # delta method: se_x = x se_lnx
    assert row["k_se"] == pytest.approx(TABLE1.k * math.sqrt(cov.cov[0, 0]))
    assert math.isnan(row["S_se"]) and not row["determined_S"]  # fixed
    assert row["determined_p_m"]
    e = np.array([1.0, 1.0, 0.0])  # p_M = k y_m
    assert row["p_M_se"] == pytest.approx(row["p_M"] * math.sqrt(e @ cov.cov @ e))
    gauged = window_uncertainty(cov, values, z_c=5e6, rho=1.2, scale_gauge="lam")
    assert math.isinf(gauged["k_se"]) and not gauged["determined_k"]
    assert gauged["p_M_se"] == pytest.approx(row["p_M_se"])
    bound = window_uncertainty(cov, values, z_c=5e6, rho=1.2, invalid={"k": "on its bound"})
    assert math.isnan(bound["k_se"]) and math.isnan(bound["p_M_se"])
    assert "k: no valid SE" in bound["uncertainty_note"]


def test_the_model_form_component_never_vanishes_silently():
    # issue 38: a window without a period (no pressure to split the residual at its
    # harmonics) had <q>_se_model NaN and nothing said so; with a period it is measured
    names = ("k", "y_m", "p_m")
    rng = np.random.default_rng(2)
    values = {n: getattr(TABLE1, n) for n in ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c")}
    values["y_c"] = TABLE1.y_c
    cov = covariance(rng.standard_normal((400, 3)), 0.01 * rng.standard_normal(400), names)
    row = window_uncertainty(cov, values, z_c=5e6, rho=1.2)
    assert math.isnan(row["p_m_se_model"])
    assert "model form not measured" in row["uncertainty_note"]
    assert "no period" in row["uncertainty_note"]
