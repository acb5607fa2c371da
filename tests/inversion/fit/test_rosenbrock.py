"""Rosenbrock's rotating-coordinate search."""

import numpy as np
import pytest

from mpipe.inversion.fit.rosenbrock import palmer_directions, rosenbrock


def banana(x):
    return (1 - x[0]) ** 2 + 100 * (x[1] - x[0] ** 2) ** 2


def test_banana_minimum():
    r = rosenbrock(
        banana,
        np.array([-1.2, 1.0]),
        log_scale=False,
        initial_step=0.1,
        step_tolerance=1e-9,
        f_tolerance=0.0,
        max_evaluations=5000,
    )
    assert r.converged
    np.testing.assert_allclose(r.x, [1.0, 1.0], atol=1e-4)
    assert r.f < 1e-8
    assert r.n_evaluations == r.history.size
    assert np.all(np.diff(r.history) <= 0)


def test_log_scaled_banana_inside_bounds():
    def f(x):
        return (2 - x[0]) ** 2 + 100 * ((x[1] - 1) - (x[0] - 1) ** 2) ** 2

    r = rosenbrock(
        f,
        np.array([0.5, 3.0]),
        lower=[0.1, 0.1],
        upper=[10, 10],
        step_tolerance=1e-9,
        f_tolerance=0.0,
        max_evaluations=5000,
    )
    np.testing.assert_allclose(r.x, [2.0, 2.0], rtol=1e-4)


def test_infeasible_points_are_failures():
    # NaN and an "infeasible" plateau around x > 1.5 must not be accepted
    def f(x):
        if x[0] > 1.5:
            return float("nan")
        if x[1] > 1.5:
            return 1e9
        return (x[0] - 1.4) ** 2 + (x[1] - 1.4) ** 2

    r = rosenbrock(
        f,
        np.array([1.0, 1.0]),
        log_scale=False,
        infeasible_at=1e8,
        step_tolerance=1e-8,
        f_tolerance=0.0,
        initial_step=0.3,
    )
    np.testing.assert_allclose(r.x, [1.4, 1.4], atol=1e-5)


def test_evaluation_budget():
    r = rosenbrock(
        banana,
        np.array([-1.2, 1.0]),
        log_scale=False,
        max_evaluations=50,
        f_tolerance=0.0,
        step_tolerance=1e-12,
    )
    assert r.n_evaluations == 50
    assert not r.converged


def test_start_outside_bounds_raises():
    with pytest.raises(ValueError, match="outside the bounds"):
        rosenbrock(banana, np.array([3.0, 1.0]), lower=[0.1, 0.1], upper=[2.0, 2.0])


@pytest.mark.parametrize(
    "advances",
    [[1.0, 2.0, 0.5], [1.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 2.0], [1e-3, 5.0, 0.0, 0.0]],
)
def test_palmer_orthonormal_and_along_progress(advances):
    a = np.array(advances)
    rng = np.random.default_rng(1)
    d, _ = np.linalg.qr(rng.normal(size=(a.size, a.size)))
    new = palmer_directions(d, a)
    np.testing.assert_allclose(new @ new.T, np.eye(a.size), atol=1e-10)
    total = a @ d
    if np.linalg.norm(total) > 0:
        np.testing.assert_allclose(new[0], total / np.linalg.norm(total), atol=1e-12)


def test_palmer_matches_gram_schmidt_when_all_advances_nonzero():
    a = np.array([0.3, -1.0, 2.0, 0.7])
    d = np.eye(4)
    big_a = np.array([a[i:] @ d[i:] for i in range(4)])
    q, _ = np.linalg.qr(big_a.T)
    q = q.T * np.sign(np.diag(q.T @ big_a.T))[:, None]
    np.testing.assert_allclose(palmer_directions(d, a), q, atol=1e-12)


def test_infeasible_start_returns_at_once():
    from mpipe.inversion.fit.rosenbrock import rosenbrock as search

    calls = []

    def nowhere(x):
        calls.append(x)
        return float("inf")

    res = search(
        nowhere, np.array([1.0, 2.0]), lower=[1e-3] * 2, upper=[1e3] * 2, max_evaluations=50
    )
    assert not res.converged and res.message == "infeasible start point"
    assert len(calls) == 1 and not np.isfinite(res.f)


def test_infeasible_trials_are_failures_not_successes():
    from mpipe.inversion.fit.rosenbrock import rosenbrock as search

    # feasible only inside a disc; the minimum of the quadratic lies on its rim
    def f(x):
        return float("inf") if np.hypot(*np.log(x)) > 0.5 else float(np.sum(np.log(x) - 1) ** 2)

    res = search(f, np.array([1.0, 1.0]), lower=[1e-3] * 2, upper=[1e3] * 2, max_evaluations=3000)
    assert np.isfinite(res.f) and np.hypot(*np.log(res.x)) <= 0.5
    assert res.n_evaluations <= 3000
