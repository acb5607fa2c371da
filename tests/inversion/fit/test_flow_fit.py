"""Step 1's flow fit on one branch: regressor signs, bounded fit, shut-reed refinement."""

import numpy as np

from mpipe.inversion.fit.flow_fit import flow_signals
from mpipe.inversion.fit.step1 import quasi_static_flow, step1

FS = 100_000.0
RHO = 1.2
TRUE = dict(k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013)


def pressure(n=2000):
    t = np.arange(n) / FS
    return 1200 * np.tanh(3 * np.sin(2 * np.pi * 150 * t)) + 200 * np.sin(2 * np.pi * 450 * t)


def test_signals_signs():
    p = np.array([0.0, 2000.0, 4000.0])
    d1, d2, d3 = flow_signals(p, 1800.0, FS, RHO)
    assert np.all(d1 >= 0)  # |dp|^(3/2): no sign
    assert d2[0] > 0 and d2[2] < 0  # sign of dp
    assert np.all(d3 > 0)  # p rising


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
