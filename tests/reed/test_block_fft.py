"""The compiled radix-2 FFT of the partitioned convolution against numpy.fft."""

import numpy as np
import pytest

from mpipe.reed.block_fft import _fft, _fft_tables, _irfft_last_half, _rfft, _rfft_lean


@pytest.mark.parametrize("m", [4, 8, 64, 512])
def test_complex_and_real_transforms(m):
    rng = np.random.default_rng(m)
    bitrev, tw_re, tw_im, w_re, w_im = _fft_tables(m)
    z = rng.standard_normal(m) + 1j * rng.standard_normal(m)
    re, im = z.real.copy(), z.imag.copy()
    _fft(re, im, bitrev, tw_re, tw_im)
    np.testing.assert_allclose(re + 1j * im, np.fft.fft(z), rtol=0, atol=1e-12 * m)
    # real FFT of a segment of length 2M, both variants
    x = rng.standard_normal(3 * m)
    want = np.fft.rfft(x[m // 2 : m // 2 + 2 * m])
    for rfft in (_rfft, _rfft_lean):
        out_re, out_im = np.zeros(m + 1), np.zeros(m + 1)
        rfft(x, m // 2, out_re, out_im, np.zeros(m), np.zeros(m), bitrev, tw_re, tw_im, w_re, w_im)
        np.testing.assert_allclose(out_re + 1j * out_im, want, rtol=0, atol=1e-12 * m)
    # second half of the inverse
    out = np.zeros(m)
    _irfft_last_half(
        want.real.copy(), want.imag.copy(), out, np.zeros(m), np.zeros(m), bitrev, tw_re, tw_im,
        w_re, w_im,
    )  # fmt: skip
    np.testing.assert_allclose(out, x[m // 2 + m : m // 2 + 2 * m], rtol=0, atol=1e-12 * m)
