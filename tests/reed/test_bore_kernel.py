"""Preparation of the bore for the kernels: block sizes, partition spectra, lean levels."""

import numpy as np
import pytest

from mpipe.reed.bore_kernel import prepare_bore, prepare_lean


def test_invalid_block_sizes(setup):
    _, air, _, rf, kernel = setup
    with pytest.raises(ValueError, match="head_taps"):
        prepare_bore(rf, air, head_taps=100)
    with pytest.raises(ValueError, match="powers of two"):
        prepare_lean(kernel, 3, 512)
    with pytest.raises(ValueError, match="block1 < block2"):
        prepare_lean(kernel, 512, 64)


def test_tail_spectra_are_the_zero_padded_partitions(setup):
    # partition p holds h[B + p B : B + (p + 1) B] followed by B zeros (overlap-save)
    _, _, _, _, kernel = setup
    b, h = kernel.head_taps, kernel.h
    assert kernel.n_partitions == -(-(h.size - b) // b)
    for p in (0, kernel.n_partitions - 1):
        block = np.zeros(2 * b)
        part = h[b + p * b : b + (p + 1) * b]
        block[: part.size] = part
        spec = np.fft.rfft(block)
        np.testing.assert_array_equal(kernel.tail_re[p], spec.real)
        np.testing.assert_array_equal(kernel.tail_im[p], spec.imag)
    assert not kernel.h.flags.writeable and not kernel.tail_re.flags.writeable


def test_lean_levels_cover_every_lag_once(setup):
    _, _, _, _, kernel = setup
    lean = kernel.lean
    assert lean is kernel.lean  # made once
    b1, b2 = lean.block1, lean.block2
    np.testing.assert_array_equal(lean.head, kernel.h[1:b1])
    assert lean.h0 == kernel.h[0]
    # level 1 holds lags b1..b2-1, level 2 lags >= b2, in blocks of their own size
    assert lean.level1[0].shape == ((b2 - b1) // b1, b1 + 1)
    assert lean.level2[0].shape == (-(-(kernel.n_taps - b2) // b2), b2 + 1)
    assert lean.n0 >= kernel.n_taps - 1


def test_a_quiet_conv_record_is_the_conv_record_of_a_zero_history(setup):
    # the evaluators start every run on a zero history: its delay-line spectra, which
    # quiet_conv gives without an FFT, are those conv computes from zeros, bit for bit
    _, _, _, _, kernel = setup
    lean = kernel.lean
    n = 3000
    quiet = lean.quiet_conv(n)
    made = lean.conv(np.zeros(lean.n0 + n), n)
    np.testing.assert_array_equal(quiet[0], made[0])
    assert quiet[1].shape == made[1].shape
    for a, b in zip(quiet[2:], made[2:], strict=True):
        assert a[0] is b[0]  # the level's spectra, shared
        for x, y in zip(a[1:], b[1:], strict=True):
            assert x.shape == y.shape and x.dtype == y.dtype
            np.testing.assert_array_equal(x, y)
