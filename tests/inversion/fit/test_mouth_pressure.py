"""Step 1's mouth pressure estimate: exact on a quasi-static flow; input checks."""

import numpy as np
import pytest

from mpipe.inversion.fit.mouth_pressure import estimate_p_m
from mpipe.inversion.fit.step1 import quasi_static_flow, step1

FS = 100_000.0
RHO = 1.2
TRUE = dict(k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013)


def pressure(n=2000):
    t = np.arange(n) / FS
    return 1200 * np.tanh(3 * np.sin(2 * np.pi * 150 * t)) + 200 * np.sin(2 * np.pi * 450 * t)


def test_p_m_estimate_exact_on_quasi_static_flow():
    # max p = 1400 Pa, 22 % below the true p_m: the profile of F1 finds the truth.
    p = pressure()
    u = quasi_static_flow(p, FS, rho=RHO, **TRUE)
    assert p.max() < 0.8 * TRUE["p_m"]
    r = step1(p, u, FS, rho=RHO, lam=TRUE["lam"], p_m="estimate")
    assert r.p_m_method == "estimate"
    assert r.p_m == pytest.approx(TRUE["p_m"], rel=1e-5)
    for fit in (r.closing, r.opening):
        assert fit.k == pytest.approx(TRUE["k"], rel=1e-4)
        assert fit.y_m == pytest.approx(TRUE["y_m"], rel=1e-4)
        assert fit.S == pytest.approx(TRUE["S"], rel=1e-3)
    # zero-mean flow (measured data): the mean flow is not needed either
    pm = estimate_p_m(p, u - u.mean(), FS, rho=RHO, lam=TRUE["lam"], zero_mean=True)
    assert pm == pytest.approx(TRUE["p_m"], rel=1e-5)


def test_p_m_estimate_input_checks():
    p = pressure()
    u = quasi_static_flow(p, FS, rho=RHO, **TRUE)
    with pytest.raises(ValueError, match="bounds"):
        estimate_p_m(p, u, FS, rho=RHO, lam=0.013, bounds=(2.0, 1.0))
    with pytest.raises(ValueError, match="max p"):
        estimate_p_m(p - 5000.0, u, FS, rho=RHO, lam=0.013)


def test_a_p_m_estimate_at_a_search_bound_names_its_window(caplog):
    # issue 42: "step 1: the p_m estimate ... lies at a search bound" did not say where
    import logging

    p = pressure()
    u = quasi_static_flow(p, FS, rho=RHO, **TRUE)
    caplog.set_level(logging.WARNING, logger="mpipe.inversion.fit.mouth_pressure")
    # the truth (1800 Pa) lies above [max p, 1.05 max p]: the estimate ends on the bound
    estimate_p_m(p, u, FS, rho=RHO, lam=TRUE["lam"], bounds=(1.0, 1.05),
                 where="window at 0.250-0.300 s")  # fmt: skip
    assert "step 1 (window at 0.250-0.300 s): the p_m estimate" in caplog.text, caplog.text
