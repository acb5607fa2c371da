"""The joint fit of a note: recovery of the shared reed, its SE, the one-window limit."""

from pathlib import Path

import numpy as np
import pytest

from mpipe.acoustics.reflection import reflection_function
from mpipe.inversion.fit.least_squares import trust_region
from mpipe.inversion.fit.objective import F2Objective, ObjectiveSettings, TargetWindow
from mpipe.inversion.fit.window import window_bounds
from mpipe.inversion.pooling.note_fit import fit_note, note_covariance, split_names
from mpipe.inversion.settings import InversionConfig
from mpipe.inversion.trust.uncertainty import covariance
from mpipe.measurement.calibration import load_calibration
from mpipe.reed.bore_kernel import prepare_bore
from mpipe.reed.model import simulate
from mpipe.reed.parameters import ReedParameters

FS = 100_000.0
N = 2000  # 20 ms windows
ROOT = Path(__file__).resolve().parents[3]
TABLE1 = ReedParameters(
    k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
)
#: k, S and the fast pair free: quick, and every slow one well determined by a 0.1 s note
CONFIG = InversionConfig(free=("k", "S", "y_m", "p_m"))
NAMES = (*split_names(CONFIG.search_parameters)[0], *split_names(CONFIG.search_parameters)[1])
TRUTH = np.array([getattr(TABLE1, n) for n in NAMES])


@pytest.fixture(scope="module")
def note():
    cal = load_calibration(ROOT / "calibration" / "simplified_clarinet.yaml")
    air = cal.air_properties()
    kernel = prepare_bore(reflection_function(cal.bore, air, fs=FS), air)
    sim = simulate(TABLE1, kernel, 20000)
    return kernel, sim.p, sim.u


def _windows(kernel, p, u, starts):
    objectives, bounds = [], []
    order = [CONFIG.search_parameters.index(n) for n in NAMES]
    for s in starts:
        target = TargetWindow(p[s : s + N], u[s : s + N], p[:s], u[:s], FS, False)
        settings = ObjectiveSettings(lead_s=CONFIG.lead_s)
        objectives.append(F2Objective(kernel, target, settings, TABLE1, CONFIG.search_parameters))
        bounds.append(window_bounds(CONFIG, p, s, N, FS)[order])
    return objectives, np.array(bounds)


def _noisy(p, seed, snr_db=45.0):
    rng = np.random.default_rng(seed)
    return p + rng.normal(size=p.size) * np.std(p) * 10 ** (-snr_db / 20)


def test_the_pooled_fit_recovers_the_shared_reed(note):
    # 3 seeds of a 0.1 s note (5 windows) at 45 dB (white noise on p), started 5 % off in
    # the slow parameters and 2 % off in the fast ones. Measured (2026-11-27): k and S at
    # z = (0.9, 1.1), (-2.8, -3.0), (-2.3, -2.5) of their joint SE (~0.06 %): within 2 SE
    # in 1 of 3 seeds only. The SE misses about half the scatter here: the noise on p also
    # enters each window's measured history (the lead-in and p+), which the sandwich does
    # not count, as in the per-window fit. Asserted: convergence, and every seed within
    # 4 SE (and 0.5 %) of the truth; the 2-SE coverage is an open point (issue 29).
    kernel, p0, u = note
    for seed in range(3):
        p = _noisy(p0, seed)
        objectives, bounds = _windows(kernel, p, u, range(10000, 20000, N))
        rng = np.random.default_rng(100 + seed)
        start = np.tile(TRUTH, (len(objectives), 1))
        start[:, :2] *= np.exp(0.02 * rng.normal(size=(len(objectives), 2)))
        start[:, 2:] *= np.exp(0.05 * rng.normal(size=TRUTH.size - 2))
        fit = fit_note(objectives, start, bounds, 2)
        assert fit.converged and fit.cost < 0.1 * fit.start_cost
        cov, _ = note_covariance(fit, [o.target.p for o in objectives], FS)
        err = np.log(fit.x[0, 2:] / TRUTH[2:])
        assert np.all(np.abs(err) < 4 * np.sqrt(np.diag(cov.slow)))
        assert np.all(np.abs(err) < 0.005)


def test_one_window_pooled_is_the_per_window_fit(note):
    kernel, p0, u = note
    p = _noisy(p0, 7)
    objectives, bounds = _windows(kernel, p, u, [14000])
    start = (TRUTH * np.array([1.02, 0.98, 1.04, 0.96]))[None, :]
    fit = fit_note(objectives, start, bounds, 2, x_tolerance=1e-9, f_tolerance=0.0)
    obj = objectives[0]
    order = [NAMES.index(n) for n in obj.free]
    own = trust_region(
        obj.residuals, start[0, order], lower=bounds[0, order, 0], upper=bounds[0, order, 1],
        x_tolerance=1e-9, f_tolerance=None, max_evaluations=2000, jacobian=obj.jacobian,
    )  # fmt: skip
    np.testing.assert_allclose(fit.x[0, order], own.x, rtol=1e-5)
    cov, _ = note_covariance(fit, [obj.target.p], FS)
    per_window = covariance(fit.jacobians[0], fit.residuals[0], NAMES, pressure=obj.target.p, fs=FS)
    np.testing.assert_allclose(cov.window(0), per_window.cov, rtol=1e-6)


def test_pooled_se_of_a_slow_parameter_is_below_the_per_window_one(note):
    kernel, p0, u = note
    p = _noisy(p0, 3)
    objectives, bounds = _windows(kernel, p, u, range(10000, 20000, N))
    fit = fit_note(objectives, np.tile(TRUTH, (len(objectives), 1)), bounds, 2)
    cov, _ = note_covariance(fit, [o.target.p for o in objectives], FS)
    own = [
        covariance(j, r, NAMES, pressure=o.target.p, fs=FS).cov
        for j, r, o in zip(fit.jacobians, fit.residuals, objectives, strict=True)
    ]
    pooled = np.sqrt(np.diag(cov.slow))
    single = np.sqrt(np.median([np.diag(c)[2:] for c in own], axis=0))
    # five windows: the note's information on the slow ones is at least one window's
    assert np.all(pooled < single)


def test_the_fit_stops_by_its_step_in_standard_errors(note):
    # the stop is measured in SEs, not in a relative fall of the cost: the fit stopped by
    # it lies within 0.05 SE (the note's own covariance) of the same fit run on to a step
    # of 1e-12, in every slow and every fast parameter
    kernel, p0, u = note
    p = _noisy(p0, 5)
    objectives, bounds = _windows(kernel, p, u, range(10000, 20000, N))
    start = np.tile(TRUTH, (len(objectives), 1))
    start[:, :2] *= 0.98
    start[:, 2:] *= 1.05
    fit = fit_note(objectives, start, bounds, 2, x_tolerance=0.0)  # the SE rule alone
    assert fit.converged and "SE in every parameter" in fit.message
    full = fit_note(objectives, start, bounds, 2, x_tolerance=1e-12, se_tolerance=0.0,
                    max_iterations=500)  # fmt: skip
    cov, _ = note_covariance(full, [o.target.p for o in objectives], FS)
    slow = np.log(fit.x[0, 2:] / full.x[0, 2:]) / np.sqrt(np.diag(cov.slow))
    assert np.all(np.abs(slow) < 0.05), slow
    for i in range(len(objectives)):
        fast = np.log(fit.x[i, :2] / full.x[i, :2]) / np.sqrt(np.diag(cov.window(i))[:2])
        assert np.all(np.abs(fast) < 0.05), (i, fast)
