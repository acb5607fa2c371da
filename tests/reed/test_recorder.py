"""The recorder of a virtual take: quantisation, noise, gains and rate ratios."""

import numpy as np
import pytest

from mpipe.reed.recorder import add_noise, apply_gains, output_rate_ratio, quantise, resample_by


def test_quantise_clips_to_the_converter_range():
    x = np.array([-2.0, -1.0, 0.3, 0.99999, 2.0])
    q = quantise(x, 1.0, 8)
    np.testing.assert_allclose(q, [-1.0, -1.0, 38 / 128, 127 / 128, 127 / 128])


def test_noise_is_seeded_and_scaled_per_channel():
    x = np.random.default_rng(0).standard_normal((50_000, 2)) * [1.0, 10.0]
    noisy, rms = add_noise(x, 20.0, seed=3)
    want = np.sqrt(np.mean(x**2, axis=0)) * 0.1
    np.testing.assert_allclose(rms, want, rtol=1e-12)
    np.testing.assert_allclose(np.std(noisy - x, axis=0), want, rtol=0.02)
    np.testing.assert_array_equal(add_noise(x, 20.0, seed=3)[0], noisy)
    clean, zero = add_noise(x, None, seed=3)
    assert clean is x and zero == (0.0, 0.0)


def test_unit_gains_and_equal_rates_leave_the_signal_alone():
    x = np.random.default_rng(1).standard_normal((1000, 3))
    np.testing.assert_array_equal(apply_gains(x, np.ones(3, complex), 64), x)
    assert resample_by(x, 1, 1) is x
    # positive real gains scale each channel, nothing else (DC and Nyquist get |g|)
    y = apply_gains(x, np.array([2.0, 0.5, 1.5], complex), 64)
    np.testing.assert_allclose(y, x * [2.0, 0.5, 1.5], rtol=0, atol=1e-12)


def test_rate_ratio():
    assert output_rate_ratio(100_000.0, 48_000.0) == (12, 25)
    assert output_rate_ratio(100_000.0, 93_034.0) == (46_517, 50_000)  # issue 19
    with pytest.raises(ValueError, match="rational"):
        output_rate_ratio(100_000.0, 100_000.0 * np.pi / 3)
    with pytest.raises(ValueError, match="positive"):
        output_rate_ratio(100_000.0, 0.0)
