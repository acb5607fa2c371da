"""Trust-region least squares in log parameters: exact recovery, bounds, budget."""

import numpy as np
import pytest

from mpipe.inversion.fit.least_squares import trust_region

T = np.linspace(0.0, 0.02, 400)


def damped_sine(x):
    """A damped sinusoid in SI-like units: amplitude (Pa), decay (1/s), frequency (Hz)."""
    a, g, f = x
    return a * np.exp(-g * T) * np.sin(2 * np.pi * f * T)


def test_recovers_an_exact_nonlinear_model():
    truth = np.array([1500.0, 300.0, 210.0])
    data = damped_sine(truth)
    r = trust_region(
        lambda x: data - damped_sine(x),
        np.array([1000.0, 150.0, 190.0]),
        lower=np.array([10.0, 1.0, 100.0]),
        upper=np.array([1e5, 1e4, 400.0]),
        max_evaluations=2000,
    )
    assert r.converged and r.method == "trust-region"
    np.testing.assert_allclose(r.x, truth, rtol=1e-6)
    assert r.f < 1e-6
    # the Jacobian at the solution is d residual / d ln x: compare with central differences
    for i in range(3):
        step = np.zeros(3)
        step[i] = 1e-6
        col = -(damped_sine(truth * np.exp(step)) - damped_sine(truth * np.exp(-step))) / 2e-6
        np.testing.assert_allclose(r.jacobian[:, i], col, rtol=2e-3, atol=1e-3 * np.abs(col).max())
    assert np.all(np.diff(r.history) <= 0)  # best-so-far history


def test_bound_is_respected_and_reached():
    truth = np.array([1500.0, 300.0, 210.0])
    data = damped_sine(truth)
    upper = np.array([1e5, 200.0, 400.0])  # the true decay lies above the upper bound
    r = trust_region(
        lambda x: data - damped_sine(x),
        np.array([1000.0, 100.0, 205.0]),
        lower=np.array([10.0, 1.0, 100.0]),
        upper=upper,
        max_evaluations=2000,
    )
    assert np.all(r.x <= upper * (1 + 1e-12))
    assert np.log(upper[1] / r.x[1]) < 1e-6  # pinned on the bound


def test_budget_ends_the_search_unconverged():
    data = damped_sine(np.array([1500.0, 300.0, 210.0]))
    calls = []

    def residuals(x):
        calls.append(1)
        return data - damped_sine(x)

    r = trust_region(
        residuals,
        np.array([100.0, 10.0, 150.0]),
        lower=np.array([10.0, 1.0, 100.0]),
        upper=np.array([1e5, 1e4, 400.0]),
        max_evaluations=12,
    )
    assert not r.converged and r.message == "evaluation budget spent"
    assert r.n_evaluations == len(calls) <= 12 + 4  # the budget in model runs, Jacobians included


def test_infeasible_candidates_do_not_win():
    data = damped_sine(np.array([1500.0, 300.0, 210.0]))

    def residuals(x):
        if x[2] > 250.0:  # a region where the "model" does not run
            return np.full(T.size, 1e9 / np.sqrt(T.size))
        return data - damped_sine(x)

    r = trust_region(
        residuals,
        np.array([1000.0, 200.0, 200.0]),
        lower=np.array([10.0, 1.0, 100.0]),
        upper=np.array([1e5, 1e4, 400.0]),
        max_evaluations=2000,
        infeasible_norm=1e9,
    )
    assert r.f < 1e-3 and r.x[2] < 250.0


def test_secant_method_recovers_the_model_with_fewer_runs_and_a_true_jacobian():
    # from the same start the Broyden-updated search reaches scipy's minimum with fewer
    # residual evaluations, and the Jacobian it returns is the difference Jacobian at x
    truth = np.array([1500.0, 300.0, 210.0])
    rng = np.random.default_rng(3)
    data = damped_sine(truth) + 5.0 * rng.standard_normal(T.size)
    kw = dict(lower=np.array([10.0, 1.0, 100.0]), upper=np.array([1e5, 1e4, 400.0]))
    x0 = np.array([1400.0, 280.0, 205.0])
    full = trust_region(lambda x: data - damped_sine(x), x0, max_evaluations=2000, **kw)
    fast = trust_region(
        lambda x: data - damped_sine(x), x0, max_evaluations=2000, secant=True, **kw
    )
    assert fast.converged and full.converged
    assert fast.f == pytest.approx(full.f, rel=1e-6)
    np.testing.assert_allclose(fast.x, full.x, rtol=1e-4)
    assert fast.n_evaluations < full.n_evaluations
    for i in range(3):
        step = np.zeros(3)
        step[i] = 1e-6
        col = -(damped_sine(fast.x * np.exp(step)) - damped_sine(fast.x * np.exp(-step))) / 2e-6
        np.testing.assert_allclose(
            fast.jacobian[:, i], col, rtol=2e-3, atol=1e-3 * np.abs(col).max()
        )


def _sine_jacobian(x):
    """Exact d damped_sine / d x (columns: amplitude, decay, frequency)."""
    a, g, f = x
    e, w = np.exp(-g * T), 2 * np.pi * f * T
    return np.column_stack(
        [e * np.sin(w), -a * T * e * np.sin(w), a * e * np.cos(w) * 2 * np.pi * T]
    )


@pytest.mark.parametrize("secant", [False, True])
def test_an_exact_jacobian_reaches_the_same_minimum_with_fewer_runs(secant):
    # given the residuals' own Jacobian (one call instead of n), both searches reach the
    # minimum the difference Jacobian reaches, in fewer residual evaluations, and return
    # the exact Jacobian d r / d ln x = x d r / d x at it; 3 noise seeds
    truth = np.array([1500.0, 300.0, 210.0])
    kw = dict(lower=np.array([10.0, 1.0, 100.0]), upper=np.array([1e5, 1e4, 400.0]))
    x0 = np.array([1400.0, 280.0, 205.0])
    for seed in range(3):
        data = damped_sine(truth) + 5.0 * np.random.default_rng(seed).standard_normal(T.size)
        calls = []

        def jac(x, data=data, calls=calls):
            calls.append(1)
            return data - damped_sine(x), -_sine_jacobian(x)

        diff = trust_region(lambda x, d=data: d - damped_sine(x), x0, secant=secant, **kw)
        exact = trust_region(lambda x, d=data: d - damped_sine(x), x0, secant=secant,
                             jacobian=jac, **kw)  # fmt: skip
        assert exact.converged and diff.converged and calls
        assert exact.f == pytest.approx(diff.f, rel=1e-6)
        np.testing.assert_allclose(exact.x, diff.x, rtol=1e-4)
        assert exact.n_evaluations < diff.n_evaluations
        np.testing.assert_allclose(exact.jacobian, -_sine_jacobian(exact.x) * exact.x, rtol=1e-9)
