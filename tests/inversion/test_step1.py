"""Step 1: the closed-form quasi-static flow fit."""

from pathlib import Path

import numpy as np
import pytest

from mpipe.inversion.step1 import flow_signals, quasi_static_flow, step1

FS = 100_000.0
RHO = 1.2
TRUE = dict(k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013)
ROOT = Path(__file__).resolve().parents[2]


def pressure(n=2000):
    t = np.arange(n) / FS
    return 1200 * np.tanh(3 * np.sin(2 * np.pi * 150 * t)) + 200 * np.sin(2 * np.pi * 450 * t)


def test_signals_signs():
    p = np.array([0.0, 2000.0, 4000.0])
    d1, d2, d3 = flow_signals(p, 1800.0, FS, RHO)
    assert np.all(d1 >= 0)  # |dp|^(3/2): no sign
    assert d2[0] > 0 and d2[2] < 0  # sign of dp
    assert np.all(d3 > 0)  # p rising


@pytest.mark.parametrize("solver", ["lstsq", "nelder-mead"])
def test_exact_on_quasi_static_flow(solver):
    p = pressure()
    u = quasi_static_flow(p, FS, rho=RHO, **TRUE)
    r = step1(p, u, FS, rho=RHO, lam=TRUE["lam"], p_m=TRUE["p_m"], solver=solver)
    tol = 1e-6 if solver == "lstsq" else 1e-3  # Nelder-Mead stops at a 1 % simplex
    for fit in (r.closing, r.opening):
        assert fit.k == pytest.approx(TRUE["k"], rel=tol)
        assert fit.S == pytest.approx(TRUE["S"], rel=10 * tol)
        assert fit.y_m == pytest.approx(TRUE["y_m"], rel=tol)
        assert fit.c[0] < 0 < fit.c[1] and fit.c[2] < 0
    assert r.closing.n_samples + r.opening.n_samples <= p.size


def test_zero_mean_flow():
    p = pressure()
    u = quasi_static_flow(p, FS, rho=RHO, **TRUE)
    r = step1(p, u - u.mean(), FS, rho=RHO, lam=TRUE["lam"], p_m=TRUE["p_m"], zero_mean=True)
    assert r.closing.k == pytest.approx(TRUE["k"], rel=1e-6)
    assert r.closing.y_m == pytest.approx(TRUE["y_m"], rel=1e-6)


def test_p_m_defaults_to_max_p():
    p = pressure()
    u = quasi_static_flow(p, FS, rho=RHO, **TRUE)
    assert step1(p, u, FS, rho=RHO, lam=0.013).p_m == p.max()


def test_unphysical_fit_is_bounded():
    p = pressure()
    rng = np.random.default_rng(0)
    u = rng.normal(size=p.size) * 1e-6 + 1e-9 * np.gradient(p) * FS  # c3 > 0: unphysical
    r = step1(p, u, FS, rho=RHO, lam=0.013, p_m=1800.0)
    for fit in (r.closing, r.opening):
        assert fit.solver == "lsq_linear"
        assert fit.c[0] < 0 and fit.c[1] > 0 and fit.c[2] < 0


def test_refinement_drops_shut_samples():
    # mouth pressure so high that the reed shuts over part of the cycle
    p = pressure()
    params = dict(TRUE, p_m=3000.0)
    u = quasi_static_flow(p, FS, rho=RHO, **params)
    r = step1(p, u, FS, rho=RHO, lam=0.013, p_m=3000.0)
    raw = step1(p, u, FS, rho=RHO, lam=0.013, p_m=3000.0, refine=False)
    assert r.closing.n_dropped + r.opening.n_dropped > 0
    for b in ("closing", "opening"):
        err = abs(r.branch(b).k / params["k"] - 1)
        assert err < abs(raw.branch(b).k / params["k"] - 1)


def test_bad_branch_and_short_input():
    p = pressure(10)
    with pytest.raises(ValueError, match="branch"):
        step1(p, p * 0, FS, rho=RHO, lam=0.013).branch("middle")
    with pytest.raises(ValueError, match="samples"):
        step1(np.ones(5), np.ones(5), FS, rho=RHO, lam=0.013)


def test_quasi_static_model_run_recovers_k_and_y_m():
    """physics.md H check: small m, k_c = 0 -> y_m within 1 %, k within 4 %."""
    from mpipe.calibration import load_calibration
    from mpipe.model import prepare_bore, simulate
    from mpipe.reed import ReedParameters
    from mpipe.reflection import reflection_function

    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    air = cal.air_properties()
    kernel = prepare_bore(reflection_function(cal.bore, air, fs=FS), air)
    reed = ReedParameters(
        k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1500.0, lam=0.013, m=0.005, g=3000.0, k_c=0.0
    )
    sim = simulate(reed, kernel, 32000)
    p, u = sim.p[-2000:], sim.u[-2000:]
    r = step1(p, u, FS, rho=air.rho, lam=0.013, p_m=reed.p_m)
    for fit in (r.closing, r.opening):
        assert fit.y_m == pytest.approx(reed.y_m, rel=0.01)
        assert fit.k == pytest.approx(reed.k, rel=0.04)
