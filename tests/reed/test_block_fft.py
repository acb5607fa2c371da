"""The compiled radix-2 FFT of the partitioned convolution against numpy.fft."""

import numpy as np
import pytest

from mpipe.reed.block_fft import _fft, fft_tables, irfft_last_half, rfft_block


@pytest.mark.parametrize("m", [4, 8, 64, 512])
def test_complex_and_real_transforms(m):
    rng = np.random.default_rng(m)
    tables = fft_tables(m)
    bitrev, tw_re, tw_im, w_re, w_im = tables
    z = rng.standard_normal(m) + 1j * rng.standard_normal(m)
    re, im = z.real.copy(), z.imag.copy()
    _fft(re, im, bitrev, tw_re, tw_im)
    np.testing.assert_allclose(re + 1j * im, np.fft.fft(z), rtol=0, atol=1e-12 * m)
    # real FFT of a segment of length 2M, with both conventions for bin M's imaginary part
    x = rng.standard_normal(3 * m)
    want = np.fft.rfft(x[m // 2 : m // 2 + 2 * m])
    for real_nyquist in (False, True):
        out_re, out_im = np.zeros(m + 1), np.zeros(m + 1)
        both = fft_tables(m, real_nyquist)
        rfft_block(x, m // 2, out_re, out_im, np.zeros(m), np.zeros(m), both)
        np.testing.assert_allclose(out_re + 1j * out_im, want, rtol=0, atol=1e-12 * m)
        assert (out_im[m] == 0.0) == real_nyquist
    # second half of the inverse
    out = np.zeros(m)
    irfft_last_half(want.real.copy(), want.imag.copy(), out, np.zeros(m), np.zeros(m), tables)
    np.testing.assert_allclose(out, x[m // 2 + m : m // 2 + 2 * m], rtol=0, atol=1e-12 * m)
