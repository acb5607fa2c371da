"""The harmonic fit through its closed-form Gram matrix against a least-squares solve."""

import numpy as np
import pytest

from mpipe.inversion.trust.harmonics import (
    HarmonicBasis,
    _fit_powers,
    _harmonic_parts,
    _harmonic_parts_reference,
    _refine_f0_reference,
    _scan_reference,
    _split,
    one_sided_weights,
    refine_f0,
    split_residual,
)


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


def _window(n, fs, f0, seed=0, harmonics=25):
    """A played window: p (Pa), the residual r (noise and a 1 % misfit), a Jacobian (n, 8)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    k = np.arange(1, harmonics + 1)
    phase = 2 * np.pi * f0 * np.outer(t, k) + rng.uniform(0, 2 * np.pi, harmonics)
    lines = np.cos(phase) * (1000.0 / k)
    p = lines.sum(axis=1) + rng.normal(0, 5.0, n)
    r = lines @ (0.01 * rng.normal(size=harmonics)) + rng.normal(0, 5.0, n)
    j = lines @ rng.normal(size=(harmonics, 8)) / harmonics
    return r, p, j


@pytest.mark.parametrize(("n", "f0"), [(1999, 233.7), (2000, 104.33), (2001, 466.1)])
def test_the_batched_scan_and_search_equal_one_fit_at_a_time(n, f0):
    fs = 100_000.0
    _, p, _ = _window(n, fs, f0)
    k = int(0.5 * fs / f0 - 0.5) // 4
    grid = f0 * (1 + np.linspace(-0.004, 0.004, 5))
    np.testing.assert_allclose(_fit_powers(p, fs, grid, k), _scan_reference(p, fs, grid, k),
                               rtol=1e-10)  # fmt: skip
    assert refine_f0(p, fs, f0 * 1.002, k) == pytest.approx(
        _refine_f0_reference(p, fs, f0 * 1.002, k), rel=1e-12
    )


@pytest.mark.parametrize(
    ("n", "f0", "k"), [(1999, 233.7, 30), (2000, 104.33, 51), (2000, 250.0, 12)]
)
def test_the_harmonic_parts_equal_the_orthonormal_basis_and_its_fft(n, f0, k):
    # 250 Hz on 2000 samples at 100 kHz: every harmonic on a DFT bin
    fs = 100_000.0
    r, p, _ = _window(n, fs, f0)
    h, ph, held = _harmonic_parts(r, p, fs, f0, k)
    h_ref, ph_ref, held_ref = _harmonic_parts_reference(r, p, fs, f0, k)
    np.testing.assert_allclose(h, h_ref, rtol=0, atol=1e-10 * np.abs(h_ref).max())
    np.testing.assert_allclose(ph, ph_ref, rtol=0, atol=1e-10 * np.abs(ph_ref).max())
    np.testing.assert_allclose(held, held_ref, rtol=0, atol=1e-12)
    # independent of either: held sums to the 2K + 1 dimensions of the fit, the fit of a
    # signal of the span is itself, and the fit takes nearly all of a harmonic's bin
    assert float(np.sum(one_sided_weights(n) * held)) == pytest.approx(2 * k + 1, rel=1e-12)
    t = np.arange(n) / fs
    inside = 3.0 + np.cos(2 * np.pi * 2 * f0 * t + 0.4) - 0.5 * np.sin(2 * np.pi * k * f0 * t)
    np.testing.assert_allclose(_harmonic_parts(inside, p, fs, f0, k)[0], inside, atol=1e-11)


@pytest.mark.parametrize("floor", [0.0, 0.05])
def test_split_residual_equals_the_split_one_fit_at_a_time(floor):
    fs = 100_000.0
    r, p, j = _window(1999, fs, 233.7, seed=4)
    new = split_residual(r, p, j, fs, floor=floor)
    ref = _split(r, p, j, fs, floor, _refine_f0_reference, _harmonic_parts_reference)
    assert new.harmonics == ref.harmonics and new.band_dof == ref.band_dof
    for name in ("f0", "noise_dof", "noise_residual", "model_residual"):
        assert getattr(new, name) == pytest.approx(getattr(ref, name), rel=1e-9), name
    np.testing.assert_allclose(new.noise, ref.noise, rtol=1e-9)
    # the excess is a clipped difference (zero in most bins): to 1e-9 of its largest bin
    np.testing.assert_allclose(new.excess, ref.excess, rtol=0, atol=1e-9 * ref.excess.max())


def test_a_degenerate_design_falls_back_to_the_rank_revealing_fits():
    # K harmonics of fs / 2K: the last one at Nyquist, its sine column zero
    fs, n, k = 100_000.0, 500, 5
    f0 = fs / (2 * k)
    r, p, _ = _window(n, fs, 1000.0, harmonics=5)
    np.testing.assert_allclose(_fit_powers(p, fs, np.array([f0]), k),
                               _scan_reference(p, fs, np.array([f0]), k), rtol=1e-9)  # fmt: skip
    for a, b in zip(_harmonic_parts(r, p, fs, f0, k), _harmonic_parts_reference(r, p, fs, f0, k),
                    strict=True):  # fmt: skip
        np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)
