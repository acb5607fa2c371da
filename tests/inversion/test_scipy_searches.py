"""scipy's searches on the scaled, bounded problem, and the dispatch by name."""

import numpy as np
import pytest

from mpipe.inversion.scipy_searches import minimise, scipy_search


@pytest.mark.parametrize("method", ["rosenbrock", "powell", "nelder-mead"])
def test_bounded_quadratic_respects_bounds(method):
    seen = []
    target = np.log([3.0, 0.02, 5e4])
    lower, upper = np.array([0.1, 1e-3, 1e3]), np.array([2.0, 1.0, 1e6])

    def f(x):
        seen.append(x.copy())
        return float(np.sum((np.log(x) - target) ** 2))

    r = minimise(
        f,
        np.array([1.0, 1e-2, 1e5]),
        method=method,
        lower=lower,
        upper=upper,
        max_evaluations=3000,
        f_tolerance=0.0 if method == "rosenbrock" else 1e-10,
        step_tolerance=1e-6,
    )
    seen = np.array(seen)
    assert np.all(seen >= lower * (1 - 1e-12)) and np.all(seen <= upper * (1 + 1e-12))
    # the constrained minimum sits on the upper bound of x0
    np.testing.assert_allclose(r.x, [2.0, 0.02, 5e4], rtol=1e-3)


def test_scipy_search_rejects_unknown_method():
    # the unknown method is refused before the objective is ever called
    with pytest.raises(ValueError, match="method"):
        scipy_search(lambda x: float(np.sum(x**2)), np.array([1.0, 1.0]), method="bfgs")
