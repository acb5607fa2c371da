"""Resampling of any rate to the pipeline's (issue 19): an analytic sine comes out exact."""

import numpy as np
import pytest

from mpipe.core.resampling import MAX_FACTOR, rate_ratio, resample

# interface, DAQ and simulator rates, prime and awkward ones included
RATES = [8000.0, 11_025.0, 44_100.0, 51_200.0, 93_034.0, 96_001.0, 192_000.0, 384_000.0]


def _fit(y, f, fs):
    """Complex amplitude of a sine at f (Hz) in the middle 60 % of y (least squares)."""
    t = np.arange(y.size) / fs
    inner = slice(y.size // 5, 4 * y.size // 5)
    basis = np.column_stack([np.cos(2 * np.pi * f * t[inner]), -np.sin(2 * np.pi * f * t[inner])])
    a, b = np.linalg.lstsq(basis, y[inner], rcond=None)[0]
    return a + 1j * b


@pytest.mark.parametrize("fs_in", RATES)
def test_a_sine_at_any_rate_comes_out_within_a_thousandth(fs_in):
    # A sine recorded at fs_in, resampled to 100 kHz, is the same sine (amplitude and phase
    # within 1e-3) at frequencies up to 0.8 of the lower Nyquist frequency (capped at the
    # 9 kHz the separation uses).
    fs_out = 100_000.0
    t = np.arange(int(0.1 * fs_in) + 1) / fs_in
    for frac in (0.05, 0.4, 0.8):
        f = frac * min(0.5 * min(fs_in, fs_out), 9000.0 / 0.8)
        x = np.column_stack([np.cos(2 * np.pi * f * t + 0.4), np.sin(2 * np.pi * f * t)])
        y = resample(x, fs_in, fs_out)
        assert abs(y.shape[0] - t.size * fs_out / fs_in) <= 1
        assert abs(_fit(y[:, 0], f, fs_out) - np.exp(0.4j)) < 1e-3
        assert abs(_fit(y[:, 1], f, fs_out) - np.exp(-0.5j * np.pi)) < 1e-3


def test_integer_rates_convert_exactly():
    for fs in (8000, 51_200, 93_034, 96_001, 383_999, 384_000):
        up, down, err = rate_ratio(float(fs), 100_000.0)
        assert err == 0.0 and up * fs == down * 100_000
        assert max(up, down) <= MAX_FACTOR


def test_other_rates_are_approximated_with_a_stated_tiny_error():
    for fs in (44_100.37, 48_000.01, 100_000 * np.pi):
        up, down, err = rate_ratio(fs, 100_000.0)
        assert max(up, down) <= MAX_FACTOR
        assert 0 < abs(err) < 1e-9
        assert abs(up / down / (100_000.0 / fs) - 1 - err) < 1e-12


def test_bad_rates_are_refused():
    for fs in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="positive and finite"):
            rate_ratio(fs, 100_000.0)


@pytest.mark.parametrize(
    ("fs_from", "fs_to", "n", "block"),
    [(48000.0, 44100.0, 20011, 4096), (44100.0, 48000.0, 9999, 1000), (96000.0, 44100.0, 7001, 3),
     (44100.0, 44100.0, 5000, 777)],
)  # fmt: skip
def test_resampling_in_blocks_equals_the_whole_array(fs_from, fs_to, n, block):
    # lengths that no block divides, three microphones: the blocks, joined, are the
    # whole array's resampling to within 1e-12 of the peak (the same sums)
    from mpipe.core.resampling import resample_blocks

    rng = np.random.default_rng(7)
    x = rng.normal(size=(n, 3))
    whole = resample(x, fs_from, fs_to)
    parts = list(resample_blocks(x, fs_from, fs_to, block=block))
    assert [j for j, _ in parts] == list(np.cumsum([0] + [y.shape[0] for _, y in parts[:-1]]))
    joined = np.concatenate([y for _, y in parts])
    assert joined.shape == whole.shape
    assert np.max(np.abs(joined - whole)) <= 1e-12 * np.max(np.abs(whole))
