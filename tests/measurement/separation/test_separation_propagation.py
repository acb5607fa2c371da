"""Tests of the per-block estimate of theta (physics.md E.5).

Right within its standard errors, a bound is a warning, and the temperature is read with
the calibration's air model.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from mpipe.acoustics import ducts
from mpipe.measurement.separation.settings import SeparationConfig
from mpipe.measurement.separation.stage import separate
from tests.measurement.separation.separation_fields import (
    CAL,
    FS,
    mic_offsets,
    noisy,
    random_take,
)


def test_noisy_estimates_are_right_within_their_standard_errors():
    # Broadband field at 24 degC, 40 dB SNR, channel noise levels a few per cent apart.
    # For at least 4 of 5 noise seeds: every smoothed temperature is within 3 of its
    # standard errors of the truth, eta within 3 standard errors of 1, and the standard
    # errors are honest: the scatter of the raw per-block estimates is within a factor
    # 2.5 of their stated standard error (the curvature of the likelihood).
    x, _, _ = random_take(int(0.6 * FS), temperature_c=24.0, seed=7)
    ok = 0
    for seed in range(5):
        res = separate(noisy(x, 40.0, seed), FS, CAL, SeparationConfig(mach=0.0))
        b = res.blocks[res.blocks.trusted]
        err = np.abs(b.temperature_c - 24.0)
        ratio = float(np.std(b.temperature_raw_c) / np.median(b.temperature_raw_se_c))
        ok += bool(
            np.all(err < 3 * b.temperature_se_c + 0.02)
            and np.median(b.temperature_se_c) < 0.3
            and abs(np.median(b.loss_scale) - 1.0) < 3 * np.median(b.loss_scale_se)
            and 0.4 < ratio < 2.5
        )
    assert ok >= 4


def test_estimate_on_a_bound_is_a_warning(caplog):
    # the true loss scale 1 lies outside these bounds: eta sits on its upper bound
    x, _, _ = random_take(int(0.4 * FS), seed=2)
    cfg = SeparationConfig(mach=0.0, loss_bounds=(0.5, 0.8), loss_prior=None)
    with caplog.at_level("WARNING"):
        res = separate(x, FS, CAL, cfg)
    b = res.blocks[res.blocks.fitted]
    assert b.at_bound.str.contains("eta").all()
    assert res.bound_warnings() and "eta estimate on its bound" in caplog.text


def test_temperature_uses_the_calibrations_air_model():
    # an 'ernoult' calibration: the field is made with its air, and the estimate is read
    # back with its own inverse (the Keefe inverse would be ~0.6 degC off)
    cal = dataclasses.replace(CAL, air=dataclasses.replace(CAL.air, model="ernoult"))
    air = cal.air_properties(22.0)
    n = int(0.4 * FS)
    rng = np.random.default_rng(4)
    freqs = np.fft.rfftfreq(n, 1 / FS)
    shape = ((freqs > 20) & (freqs < 7500)).astype(float)
    P0 = 0.1 * shape * (rng.normal(size=freqs.size) + 1j * rng.normal(size=freqs.size))
    U0 = P0 * rng.normal(size=freqs.size) / air.impedance(np.pi * CAL.main_radius**2)
    omega = 2 * np.pi * freqs
    out = []
    for d in mic_offsets():
        t_inv = ducts.invert(ducts.cylinder_matrix(omega, CAL.main_radius, d, air))
        out.append(t_inv[:, 0, 0] * P0 + t_inv[:, 0, 1] * U0)
    x = np.fft.irfft(np.stack(out, axis=-1), n, axis=0)
    res = separate(x, FS, cal, SeparationConfig(mach=0.0))
    b = res.blocks[res.blocks.trusted]
    assert abs(np.median(b.temperature_c) - 22.0) < 0.05
    assert np.allclose(b.c_m_s, [cal.air_properties(t).c for t in b.temperature_c])
