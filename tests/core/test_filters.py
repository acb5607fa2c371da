"""The shared low-pass applied in blocks equals one convolution of the whole signal."""

import numpy as np
import pytest
from scipy import signal

from mpipe.core import filters
from mpipe.core.filters import apply_lowpass, design_lowpass


@pytest.mark.parametrize("n", [10, 1001, 2**18 - 1, 2**18 + 333, 3 * 2**18 + 7])
def test_blocked_lowpass_equals_one_convolution(n):
    # second method: the signal extended by its edge values, one full-length convolution
    lp = design_lowpass(100_000.0)
    x = np.random.default_rng(n).normal(size=(2, n))
    d = lp.delay
    padded = np.pad(x, [(0, 0), (d, d)], mode="edge")
    want = signal.fftconvolve(padded, lp.taps[None, :], mode="valid")
    np.testing.assert_allclose(apply_lowpass(x, lp), want, atol=1e-12)
    np.testing.assert_allclose(apply_lowpass(x.T, lp, axis=0), want.T, atol=1e-12)
    assert filters.LOWPASS_BLOCK == 2**18  # the lengths above straddle its blocks
