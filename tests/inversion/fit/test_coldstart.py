"""The global cold start finds the global minimum where a single local start does not."""

import numpy as np

from mpipe.inversion.fit.coldstart import ColdStartOptions, global_search, sobol_design
from mpipe.inversion.fit.least_squares import trust_region

T = np.linspace(0.0, 0.05, 500)
TRUTH = np.array([220.0, 0.8])  # frequency (Hz) and amplitude (Pa) of a sinusoid


def model(x):
    return x[1] * np.sin(2 * np.pi * x[0] * T)


DATA = model(TRUTH)
LOWER, UPPER = np.array([50.0, 0.2]), np.array([2000.0, 4.0])


def residuals(x):
    return DATA - model(x)


def objective(x):
    return float(np.linalg.norm(residuals(x)))


def polish(x0):
    return trust_region(residuals, x0, lower=LOWER, upper=UPPER, max_evaluations=500)


def test_sobol_design_fills_the_log_box():
    pts = sobol_design(LOWER, UPPER, 250, seed=3)
    assert pts.shape == (256, 2)  # rounded up to a power of two
    assert np.all(pts >= LOWER) and np.all(pts <= UPPER)
    # balanced in log coordinates: each half of each axis holds half the points
    mid = np.sqrt(LOWER * UPPER)
    assert np.all(np.sum(pts < mid, axis=0) == 128)
    np.testing.assert_array_equal(pts, sobol_design(LOWER, UPPER, 256, seed=3))  # reproducible


def test_single_start_is_trapped_global_search_is_not():
    # a frequency far from the truth: the local search settles on a side lobe
    seed = np.array([600.0, 0.5])
    local = polish(seed)
    assert abs(local.x[0] / TRUTH[0] - 1) > 0.1
    options = ColdStartOptions(design_points=256, local_starts=6, local_evaluations=60)
    found = global_search(objective, residuals, LOWER, UPPER, [seed], polish, options=options)
    np.testing.assert_allclose(found.search.x, TRUTH, rtol=1e-6)
    assert found.agreeing >= 1 and found.local_f.size == 6
    assert found.search.n_evaluations > found.design_evaluations == 256
    again = global_search(objective, residuals, LOWER, UPPER, [seed], polish, options=options)
    np.testing.assert_array_equal(again.search.x, found.search.x)  # one answer per input
