"""The batched harmonic fit against the explicit design, written out sample by sample."""

import numpy as np
import pytest

from mpipe.core.harmonic_fit import (
    amplitudes,
    bin_columns,
    centred_gram,
    centred_projection,
    harmonic_dft,
    harmonic_synthesis,
    symmetric_dirichlet,
    unit_powers,
)

#: (n, fundamental in cycles per sample, K): lengths that are not squares, a fundamental
#: on the DFT grid (every harmonic on a bin), one near Nyquist, a short frame.
CASES = [(7, 0.05, 2), (1999, 0.0061, 30), (2000, 0.00104334, 51), (2000, 0.005, 10),
         (3835, 0.00104334, 38), (2001, 0.0499, 9)]  # fmt: skip


def _centred(n, w, k):
    s = np.arange(n) - (n - 1) / 2
    return np.cos(np.outer(s, np.arange(k + 1)) * w), np.sin(np.outer(s, np.arange(1, k + 1)) * w)


def test_unit_powers_are_the_exponentials():
    m = np.array([[0, 1, 7], [2244, 999, 30]])
    w = np.array([0.37, 0.0012])
    expected = np.exp(1j * w[:, None, None] * m)
    np.testing.assert_allclose(unit_powers(w, m), expected, rtol=0, atol=1e-13)


@pytest.mark.parametrize(("n", "f", "k"), CASES)
def test_dft_and_synthesis_match_the_sums_written_out(n, f, k):
    rng = np.random.default_rng(n)
    x = rng.normal(size=(3, 2, n))
    w = 2 * np.pi * f * (1 + 0.01 * rng.normal(size=(3, 1)))
    orders = np.arange(k + 1)
    t = np.arange(n)
    e = np.exp(1j * w[..., None, None] * orders[:, None] * t)  # (3, 1, K + 1, n)
    expected = np.einsum("fcn,fckn->fck", x, e)
    got = harmonic_dft(x, w, orders)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12 * np.abs(x).sum(-1).max())
    amp = rng.normal(size=(3, k + 1)) + 1j * rng.normal(size=(3, k + 1))
    lines = np.real(np.einsum("fk,fkn->fn", amp, e[:, 0]))
    np.testing.assert_allclose(
        harmonic_synthesis(amp, w[:, 0], orders, n), lines, rtol=0, atol=1e-12 * k
    )


@pytest.mark.parametrize(("n", "f", "k"), CASES)
def test_gram_blocks_projection_and_fit_match_the_explicit_design(n, f, k):
    w = 2 * np.pi * f
    c, s = _centred(n, w, k)
    even, odd = centred_gram(n, w, k)
    np.testing.assert_allclose(even, c.T @ c, rtol=0, atol=1e-12 * n)
    np.testing.assert_allclose(odd, s.T @ s, rtol=0, atol=1e-12 * n)
    assert np.abs(c.T @ s).max() < 1e-12 * n  # the blocks are apart
    t = np.arange(n)
    x = np.random.default_rng(1).normal(size=n) + 3 * np.cos(2 * w * t + 0.3) + 0.5
    be, bo = centred_projection(x, w, k)
    np.testing.assert_allclose(be, c.T @ x, rtol=0, atol=1e-12 * np.abs(x).sum())
    np.testing.assert_allclose(bo, s.T @ x, rtol=0, atol=1e-12 * np.abs(x).sum())
    # the fit on the frame's own time: lstsq on [1, cos(k w t), sin(k w t)]
    h = np.column_stack([np.ones(n), np.cos(np.outer(t, np.arange(1, k + 1)) * w),
                         np.sin(np.outer(t, np.arange(1, k + 1)) * w)])  # fmt: skip
    coef = np.linalg.lstsq(h, x, rcond=None)[0]
    constant, lines = amplitudes(np.linalg.solve(even, be), np.linalg.solve(odd, bo), w, n)
    np.testing.assert_allclose(lines, coef[1 : k + 1] - 1j * coef[k + 1 :], atol=1e-10)
    fit = constant + harmonic_synthesis(lines, w, np.arange(1, k + 1), n)
    np.testing.assert_allclose(fit, h @ coef, rtol=0, atol=1e-11 * np.abs(x).max())


@pytest.mark.parametrize(("n", "f", "k"), CASES)
def test_bin_columns_are_the_design_at_the_dft_bins(n, f, k):
    w = 2 * np.pi * f
    c, s = _centred(n, w, k)
    centred = np.arange(n) - (n - 1) / 2
    theta = 2 * np.pi * np.arange(n // 2 + 1) / n
    even, odd = bin_columns(n, w, k)
    np.testing.assert_allclose(even, c.T @ np.cos(np.outer(centred, theta)), rtol=0,
                               atol=1e-12 * n)  # fmt: skip
    np.testing.assert_allclose(odd, s.T @ np.sin(np.outer(centred, theta)), rtol=0,
                               atol=1e-12 * n)  # fmt: skip


def test_symmetric_dirichlet_at_and_near_its_peaks():
    n = 11
    v = np.array([0.0, 1e-13, 0.3, 2 * np.pi, 2 * np.pi + 1e-13])
    s = np.arange(n) - (n - 1) / 2
    np.testing.assert_allclose(
        symmetric_dirichlet(v, n), np.cos(np.outer(v, s)).sum(axis=1), rtol=1e-12
    )
