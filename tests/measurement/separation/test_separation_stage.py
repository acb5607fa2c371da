"""End-to-end tests of the wave separation (physics.md E).

p0 and u0 reconstructed and theta estimated from virtual takes, held theta, bad input
refused.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mpipe.measurement.separation.blocks import block_layout
from mpipe.measurement.separation.result import BLOCK_COLUMNS
from mpipe.measurement.separation.settings import SeparationConfig, fixed_config
from mpipe.measurement.separation.stage import separate
from tests import lengths
from tests.measurement.separation.separation_fields import CAL, FS, band_nrmse, random_take


def test_clean_take_reconstructs_and_estimates_theta():
    # (a) and (c) in short: air 5 degC off the configuration and Mach 0.01
    x, p0, u0 = random_take(int(0.6 * FS), temperature_c=25.0, mach=0.01)
    res = separate(x, FS, CAL, SeparationConfig())
    b = res.blocks[res.blocks.trusted]
    assert abs(np.median(b.temperature_c) - 25.0) < 0.1
    assert abs(np.median(b.mach) - 0.01) < 5e-4
    assert band_nrmse(res.p0, p0) < 5e-3
    assert band_nrmse(res.u0, u0) < 5e-3
    for col in BLOCK_COLUMNS:
        assert col in res.blocks
    assert (b.band_hi_hz <= SeparationConfig().fmax_hz).all() and (b.bins > 10).all()


def test_fixed_theta_matches_true_field():
    x, p0, u0 = random_take(int(0.4 * FS))
    res = separate(x, FS, CAL, fixed_config(SeparationConfig()))
    assert np.allclose(res.blocks.temperature_c, 20.0)
    assert band_nrmse(res.p0, p0) < 1e-3
    assert band_nrmse(res.u0, u0) < 1e-3


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="shape"):
        separate(np.zeros((100, 2)), FS, CAL, SeparationConfig())
    with pytest.raises(ValueError, match="singular"):
        separate(
            np.zeros((1000, 3)),
            FS,
            CAL,
            dataclasses.replace(SeparationConfig(), band_edge_hz=8500.0),
        )


# --- every length and rate (issue 19) -------------------------------------------------------


def _field(n, fs, seed=0):
    """Periodic band-limited p0, u0 at rate fs and the microphone signals of their field."""
    from tests.measurement.separation.separation_fields import mic_spectra

    rng = np.random.default_rng(seed)
    freqs = np.fft.rfftfreq(n, 1 / fs)
    z0 = CAL.air_properties(20.0).impedance(np.pi * CAL.main_radius**2)
    shape = ((freqs > 50) & (freqs < min(3000.0, 0.3 * fs))).astype(float)
    P0 = shape * (rng.normal(size=freqs.size) + 1j * rng.normal(size=freqs.size))
    U0 = shape * (rng.normal(size=freqs.size) + 1j * rng.normal(size=freqs.size)) / z0
    x = np.fft.irfft(mic_spectra(P0, U0, freqs), n, axis=0)
    return x, np.fft.irfft(P0, n), np.fft.irfft(U0, n)


def _config_for(fs):
    """The default settings, with the band below 0.4 fs at low rates."""
    cfg = fixed_config(SeparationConfig())
    if cfg.band_edge_hz + cfg.band_taper_hz < 0.4 * fs:
        return cfg
    edge = 0.35 * fs
    return dataclasses.replace(
        cfg, band_edge_hz=edge, band_taper_hz=0.04 * fs, fmax_hz=min(cfg.fmax_hz, 0.3 * fs)
    )


def _check_separation(n, fs):
    x, p0, u0 = _field(n, fs)
    res = separate(x, fs, CAL, _config_for(fs))
    assert res.p0.shape == (n,) and res.u0.shape == (n,)
    assert np.all(np.isfinite(res.p0)) and np.all(np.isfinite(res.u0))
    # Away from the ends (where the periodic field meets the zero padding), the fixed-theta
    # separation of every length rebuilds the true p0 and u0.
    # u0's filter rises from u_highpass_hz / 2 (physics.md E.4): its impulse response, and so
    # the reach of the ends' zero padding into the take, lasts about 2 / u_highpass_hz.
    edge = int(2.0 / SeparationConfig().u_highpass_hz * fs)
    if n > 4 * edge:
        inner = slice(edge, n - edge)
        scale_p, scale_u = np.std(p0), np.std(u0)
        assert np.sqrt(np.mean((res.p0 - p0)[inner] ** 2)) < 0.02 * scale_p
        assert np.sqrt(np.mean((res.u0 - u0)[inner] ** 2)) < 0.02 * scale_u


@pytest.mark.parametrize(("n", "fs"), [(152_004, 1e5), (120_001, 1e5), (111_641, 93_034.0)])
def test_lengths_that_ran_past_the_buffer(n, fs):
    # Issue 19: the last block's overlap-add ran past the output buffer when the fast FFT
    # length exceeded the block plus its padding by more than the take's last partial hop.
    _check_separation(n, fs)


def test_adaptive_separation_of_a_length_that_crashed():
    x, p0, _ = _field(152_004, 1e5, seed=3)
    res = separate(x, 1e5, CAL, SeparationConfig())
    assert res.p0.shape == (152_004,)
    assert band_nrmse(res.p0, p0, fs=1e5, hi=2500.0) < 0.02


def _prime_at_least(n):
    n |= 1
    while any(n % k == 0 for k in range(3, int(n**0.5) + 1, 2)):
        n += 2
    return n


@given(
    duration_s=lengths.durations,
    fs=lengths.rates,
    extra=lengths.extras,
    prime=st.booleans(),
)
@settings(max_examples=10, deadline=None)
def test_separation_of_every_length_and_rate(duration_s, fs, extra, prime):
    # Lengths from 50 ms to 30 s at rates from 8 to 192 kHz; odd, even and prime counts.
    # A take longer than 2 s is shortened by whole hops: the blocks at its end, where a
    # length can go wrong, are then those of the full take (the test stays fast).
    n = int(duration_s * fs) + extra
    n = _prime_at_least(n) if prime else n
    hop = block_layout(n, fs, SeparationConfig().block_s)[0]
    n -= hop * max(0, -(-(n - int(2 * fs)) // hop))
    _check_separation(n, fs)


@given(duration_s=lengths.durations, fs=lengths.rates, extra=lengths.extras)
@settings(max_examples=20, deadline=None)
def test_blocks_cover_every_sample_of_every_length(duration_s, fs, extra):
    # The periodic Hann windows of the blocks sum to one over every sample of the take, for
    # the full lengths (50 ms to 30 s): nothing is lost or doubled at either end.
    n = int(duration_s * fs) + extra
    hop, length, starts = block_layout(n, fs, SeparationConfig().block_s)
    win = np.hanning(length + 1)[:-1]
    total = np.zeros(n + 2 * length)
    for s in starts:
        total[length + s : length + s + length] += win
    np.testing.assert_allclose(total[length : length + n], 1.0, atol=1e-12)


def test_the_noise_line_prints_each_channel_in_three_digits_or_says_none():
    # issue 42: the console printed "noise PSD per channel [0. 0. 0.]" for 1e-9 Pa^2/Hz
    from mpipe.measurement.separation.stage import noise_line

    line = noise_line(np.array([1.23e-9, 4.5e-10, 2e-9]))
    assert "1.23e-09, 4.5e-10, 2e-09 Pa^2/Hz" in line and "0." not in line
    assert "no noise measured" in noise_line(np.zeros(3))
