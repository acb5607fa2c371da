"""The harmonic fit through its closed-form Gram matrix against a least-squares solve."""

import numpy as np
import pytest

from mpipe.inversion.trust.harmonics import HarmonicBasis, refine_f0


@pytest.mark.parametrize(
    ("n", "f0", "harmonics"), [(2000, 61.3, 30), (2000, 466.0, 15), (700, 1100.0, 5)]
)
def test_gram_power_and_basis_match_an_explicit_least_squares_fit(n, f0, harmonics):
    fs = 100_000.0
    rng = np.random.default_rng(7)
    x = rng.normal(size=n) + 3 * np.cos(2 * np.pi * 2 * f0 * np.arange(n) / fs + 0.3)
    basis = HarmonicBasis(n, fs, f0, harmonics)
    t = np.arange(n) / fs
    arg = 2 * np.pi * f0 * np.outer(t, np.arange(1, harmonics + 1))
    h = np.column_stack([np.ones(n), np.cos(arg), np.sin(arg)])  # the design, by hand
    np.testing.assert_allclose(basis.gram, h.T @ h, rtol=0, atol=1e-9 * n)
    np.testing.assert_allclose(basis.design(), h, rtol=0, atol=1e-11)
    coef = np.linalg.lstsq(h, x, rcond=None)[0]
    assert basis.power(x) == pytest.approx(float(np.sum((h @ coef) ** 2)), rel=1e-10)
    q = basis.orthonormal()
    np.testing.assert_allclose(q.T @ q, np.eye(2 * harmonics + 1), atol=1e-9)
    np.testing.assert_allclose(q @ (q.T @ x), h @ coef, atol=1e-9 * np.max(np.abs(x)))


def test_refine_f0_finds_an_off_grid_playing_frequency():
    fs, n, f0 = 100_000.0, 2000, 233.7
    t = np.arange(n) / fs
    rng = np.random.default_rng(3)
    p = sum(np.cos(2 * np.pi * k * f0 * t + k) / k for k in range(1, 20)) + rng.normal(0, 1e-3, n)
    assert refine_f0(p, fs, f0 * 1.002, 19) == pytest.approx(f0, rel=2e-5)
