"""Tests of the sensor noise level and of the chi^2 it gives (physics.md E.5).

The noise level measured from a take is compared with the white noise the virtual
recording added; the chi^2 per degree of freedom of the blocks' fits with it must be
close to 1 on clean takes (no model error) at a high and a low signal-to-noise ratio.
"""

from __future__ import annotations

import numpy as np

from mpipe.measurement.separation.noise import noise_levels, resampler_response
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.stage import separate
from tests.measurement.separation.separation_fields import CAL, note_take

FS = 100_000.0


def test_noise_level_matches_the_added_noise_at_any_rate():
    # Every channel within 4 % of the added noise, for 3 of 3 seeds at each rate (the
    # 44.1 kHz take is resampled to 100 kHz, whose filter falls off below 22 kHz).
    cfg = SeparationConfig()
    for fs_out in (FS, 44_100.0):
        for seed in (1, 2, 3):
            x, truth = note_take(70.0, seed, fs_out)
            measured = noise_levels(x, FS, cfg, band_limit_hz=fs_out / 2)
            assert np.all(np.abs(measured / truth - 1.0) < 0.04), (fs_out, seed)


def test_resampler_response_is_flat_in_the_pass_band_and_falls_at_nyquist():
    f = np.array([1000.0, 10_000.0, 22_050.0, 30_000.0])
    r = resampler_response(f, FS, 44_100.0)
    assert np.all(np.abs(r[:2] - 1.0) < 0.01)
    assert 0.1 < r[2] < 0.5  # -6 dB in amplitude at the file's Nyquist frequency
    assert r[3] < 1e-6


def test_chi2_per_degree_of_freedom_is_one_on_clean_takes():
    # The median chi^2 per degree of freedom over the blocks within 10 % of 1, for 3 of 3
    # seeds at 70 dB and at 45 dB. At 70 dB the noise floor (relative to the strongest
    # bin) used to exceed the real noise, and chi^2 came out 0.35.
    for snr in (70.0, 45.0):
        for seed in (1, 2, 3):
            x, _ = note_take(snr, seed)
            res = separate(x, FS, CAL, SeparationConfig())
            chi2 = float(np.median(res.blocks.residual[res.blocks.trusted]))
            assert abs(chi2 - 1.0) < 0.1, (snr, seed, chi2)
