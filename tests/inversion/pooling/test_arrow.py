"""The block-arrow solve and covariance against the dense joint system (exact algebra)."""

import numpy as np
import pytest

from mpipe.inversion.pooling.arrow import ArrowSystem


def _problem(seed: int, windows: int = 5, n: int = 40, f: int = 2, s: int = 4):
    rng = np.random.default_rng(seed)
    jacs = [rng.normal(size=(n, f + s)) for _ in range(windows)]
    res = [rng.normal(size=n) for _ in range(windows)]
    grams = []
    for _ in range(windows):
        q = rng.normal(size=(f + s, f + s))
        grams.append(q @ q.T)
    return jacs, res, np.asarray(grams)


def _dense_index(w: int, i: int, f: int, s: int) -> np.ndarray:
    """Joint indices of window i's fast then the slow parameters."""
    return np.concatenate([np.arange(i * f, (i + 1) * f), w * f + np.arange(s)])


@pytest.mark.parametrize("mu", [0.0, 0.3])
def test_schur_step_equals_the_dense_joint_solve(mu):
    jacs, res, _ = _problem(1)
    system = ArrowSystem.of(jacs, res, 2)
    a, g = system.dense()
    expected = np.linalg.solve(a + mu * np.diag(np.diag(a)), -g)
    d_fast, d_slow = system.step(mu)
    np.testing.assert_allclose(np.concatenate([d_fast.ravel(), d_slow]), expected, rtol=1e-10)


def test_dense_matrix_is_the_stacked_jacobians_gram():
    # independent construction: the joint Jacobian has window i's rows in its own fast
    # columns and the shared slow columns
    jacs, res, _ = _problem(2, windows=3)
    w, f, s, n = 3, 2, 4, 40
    big = np.zeros((w * n, w * f + s))
    for i, j in enumerate(jacs):
        big[i * n : (i + 1) * n, _dense_index(w, i, f, s)] = j
    a, g = ArrowSystem.of(jacs, res, f).dense()
    np.testing.assert_allclose(a, big.T @ big, rtol=1e-12)
    np.testing.assert_allclose(g, big.T @ np.concatenate(res), rtol=1e-12)


def test_predicted_fall_is_the_quadratic_model():
    jacs, res, _ = _problem(3)
    system = ArrowSystem.of(jacs, res, 2)
    a, g = system.dense()
    rng = np.random.default_rng(0)
    d_fast, d_slow = rng.normal(size=(5, 2)), rng.normal(size=4)
    d = np.concatenate([d_fast.ravel(), d_slow])
    assert system.predicted_fall(d_fast, d_slow) == pytest.approx(-(2 * g @ d + d @ a @ d))


def test_covariance_equals_the_dense_sandwich():
    jacs, res, grams = _problem(4, windows=6)
    w, f, s = 6, 2, 4
    system = ArrowSystem.of(jacs, res, f)
    a, _ = system.dense()
    b = np.zeros_like(a)
    for i in range(w):
        idx = _dense_index(w, i, f, s)
        b[np.ix_(idx, idx)] += grams[i]
    a_inv = np.linalg.inv(a)
    dense = a_inv @ b @ a_inv
    cov = system.covariance(grams)
    assert cov.null.size == 0
    for i in range(w):
        idx = _dense_index(w, i, f, s)
        np.testing.assert_allclose(cov.window(i), dense[np.ix_(idx, idx)], rtol=1e-9, atol=1e-14)


def test_one_window_is_the_per_window_sandwich():
    jacs, res, grams = _problem(5, windows=1)
    a = jacs[0].T @ jacs[0]
    a_inv = np.linalg.inv(a)
    cov = ArrowSystem.of(jacs, res, 2).covariance(grams)
    np.testing.assert_allclose(cov.window(0), a_inv @ grams[0] @ a_inv, rtol=1e-9)


def test_a_slow_direction_no_window_sees_is_null():
    jacs, res, grams = _problem(6)
    for j in jacs:
        j[:, -1] = 0.0  # the last slow parameter moves no residual
    cov = ArrowSystem.of(jacs, res, 2).covariance(grams)
    assert cov.null.shape == (1, 4)
    assert abs(cov.null[0, -1]) == pytest.approx(1.0)
